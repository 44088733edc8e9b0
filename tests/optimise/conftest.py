import numpy as np
import pytest

from refine.frames import transform_from_xyz_rpy
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot


@pytest.fixture(scope="session")
def irb4600():
    return load_robot("abb_irb4600_60_205")


@pytest.fixture(scope="session")
def straight_tool():
    return transform_from_xyz_rpy([0.0, 0.0, 0.35], [0.0, 0.0, 0.0])


@pytest.fixture(scope="session")
def kin(irb4600, straight_tool):
    return TcpKinematics(irb4600, np.eye(4), straight_tool)
