from types import SimpleNamespace

import numpy as np
import pytest

from refine.frames import transform_from_xyz_rpy


@pytest.fixture(scope="session")
def cell():
    """The glass cell's tracker set-up, as the simulators' truth.

    tip: the hand gun's tip in the sensor frame [m]; source_in_world: the receiver on its post;
    points: six reference points on the fixture, 0.5 to 1.5 m from the receiver, 0.45 to 0.95 m
    high [m]; pivot: a divot 0.65 m from the receiver, in the receiver frame [m].
    """
    return SimpleNamespace(
        tip=np.array([0.03, -0.01, 0.25]),
        source_in_world=transform_from_xyz_rpy([1.30, -0.82, 0.72], [0.0, 0.0, 90.0]),
        points=np.array(
            [
                [1.00, -0.55, 0.45],
                [1.70, -0.35, 0.60],
                [1.05, -0.05, 0.80],
                [1.75, 0.15, 0.45],
                [0.90, 0.40, 0.60],
                [1.55, 0.60, 0.95],
            ]
        ),
        pivot=np.array([0.55, 0.25, -0.25]),
    )
