"""A robot's joint interaction limit (FANUC's J2/J3) is kept by the refinement and checked by the verifier."""

import dataclasses

import numpy as np
import pytest

from refine.optimise.problem import build_refinement
from refine.optimise.solve import solve_refinement
from refine.optimise.verify import check_path
from refine.problem import Tolerances
from refine.robot.coupling import JointInteraction
from refine.robot.kinematics import TcpKinematics
from refine.robot.model import Robot
from refine.synthetic import wave_path

MARGIN_DEG = 2.0  # Tolerances().joint_margin_deg, kept from the interaction limit as from any joint limit


@pytest.fixture(scope="module")
def free(irb4600, straight_tool):
    nlp = build_refinement(irb4600, wave_path(40), np.eye(4), straight_tool, Tolerances())
    result = solve_refinement(nlp)
    assert result.status == "ok", result.reason
    return result


def _coupled(irb4600, upper_deg: float) -> Robot:
    """The IRB 4600 with FANUC's joint counting and a cap on the controller's J3 (J3_urdf - J2_urdf)."""
    cap = JointInteraction((0.0, 0.0, 1.0, 0.0, 0.0, 0.0), -360.0, upper_deg, "J3 from the horizontal")
    spec = dataclasses.replace(
        irb4600.spec, controller="fanuc", joint_coupling="fanuc_j2_j3", joint_interaction=(cap,)
    )
    return Robot(spec, irb4600.model)


def test_the_refinement_keeps_the_interaction_limit_the_free_path_breaks(irb4600, straight_tool, free):
    j3_controller = np.degrees(free.q[:, 2] - free.q[:, 1])  # computed here from the URDF joints
    upper = float(j3_controller.max()) + MARGIN_DEG - 0.3  # the free answer comes 0.3 deg too close
    robot = _coupled(irb4600, upper)
    kin = TcpKinematics(robot, np.eye(4), straight_tool)
    broken = check_path(kin, free.q, wave_path(40), Tolerances(), False)
    assert any(v.reason == "joint limit (J3 from the horizontal)" for v in broken.violations)
    nlp = build_refinement(robot, wave_path(40), np.eye(4), straight_tool, Tolerances())
    result = solve_refinement(nlp)
    assert result.status == "ok", result.reason
    kept = np.degrees(result.q[:, 2] - result.q[:, 1])
    assert kept.max() <= upper - MARGIN_DEG + 1e-6
    poses = kin.poses(result.q)
    assert np.linalg.norm(poses[:, :3, 3] - nlp.fused.positions, axis=1).max() < 1e-6
