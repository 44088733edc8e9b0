"""The path registration from far first guesses on symmetric contours: the simulator's truth or a refusal."""

import math

import numpy as np
import pytest

from refine.calibrate.receiver_path import register_receiver_to_path
from refine.calibrate.simulate import calibration_tracker_model
from refine.demo.simulate import simulate_demonstration
from refine.errors import InputError
from refine.frames import rotation_angle_deg, transform_from_xyz_rpy
from refine.synthetic import rounded_rectangle

TRUTH = transform_from_xyz_rpy([0.9, -0.5, 0.75], [0.0, 0.0, 30.0])
TOOL = transform_from_xyz_rpy([-0.03, 0.0, -0.25], [180.0, 0.0, 30.0])  # sensor 250 mm above the tip
FAR = [([0.5, 0.4, 0.0], [0.0, 0.0, 60.0]), ([-0.4, 0.3, 0.05], [0.0, 0.0, 175.0])]
ANYWHERE = {"max_guess_offset_m": math.inf, "max_guess_turn_deg": 360.0}


def _contour(kind: str) -> np.ndarray:
    """A flat contour on a table 0.6 m up, centred at (1.2, 0, 0.6) [m], counter-clockwise."""
    if kind == "circle":
        phi = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
        u, v = 0.25 * np.cos(phi - np.pi / 2), 0.25 * np.sin(phi - np.pi / 2)
    else:
        half_v, r = (0.2, 0.04) if kind == "rectangle" else (0.06, 0.06 - 1e-6)
        u, v, *_ = rounded_rectangle(0.35, half_v, r, 400)
    return np.column_stack([1.2 + u, v, np.full_like(u, 0.6)])


def _trace(path: np.ndarray, seed: int):
    closed = np.vstack([path, path[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    n = len(s)
    down = np.broadcast_to(np.diag([1.0, -1.0, -1.0]), (n, 3, 3))
    demo = simulate_demonstration(
        s,
        closed,
        down,
        np.full(n, 0.2),
        TRUTH,
        TOOL,
        calibration_tracker_model(seed=seed, pause_s=0.5, z_distortion_max_m=0.0),
    )
    return demo.log, closed


def _tip() -> np.ndarray:
    from refine.frames import invert_transform

    return invert_transform(TOOL)[:3, 3]


@pytest.mark.parametrize("kind", ["rectangle", "slot"])
@pytest.mark.parametrize("offset", FAR)
def test_symmetric_contours_register_to_the_truth_from_far_guesses(kind, offset):
    """Distances alone fit turned copies; the tool's attitude and the travel pick the true frame.

    The tracker has no far-field z error here: over a flat contour a tilt and a z error trade off.
    """
    log, path = _trace(_contour(kind), seed=3)
    guess = TRUTH @ transform_from_xyz_rpy(*offset)
    cal = register_receiver_to_path(log, _tip(), path, guess, fit_z=False, **ANYWHERE)
    T = cal.values["source_in_world"]
    assert np.linalg.norm(T[:3, 3] - TRUTH[:3, 3]) < 2e-3
    assert rotation_angle_deg(T[:3, :3], TRUTH[:3, :3]) < 0.2
    with pytest.raises(InputError, match=r"mm and \d+\.\d deg from the first guess"):
        register_receiver_to_path(log, _tip(), path, guess, fit_z=False)


def test_a_circle_is_refused_naming_the_frame_and_the_free_turn():
    """A circle fits turned about its axis by any angle: the distances cannot fix the frame."""
    log, path = _trace(_contour("circle"), seed=4)
    with pytest.raises(InputError, match=r"free to turn or shift.*RMS .* mm.*deg away"):
        register_receiver_to_path(log, _tip(), path, TRUTH, fit_z=False, **ANYWHERE)
