"""The KUKA KR 8 R1440-2 arc HW: its joints must be the controller's A1..A6, as KRL commands them.

Expected values come from KUKA's published facts, not from the model:

* the home position ``{A1 0, A2 -90, A3 90, A4 0, A5 0, A6 0}`` of every KR arm: lower arm upright,
  forearm level and pointing forward, the flange facing forward;
* KUKA's directions of rotation: A1, A4 and A6 turn left-handed about the upward base z axis and the
  outward forearm and flange axes (A1 positive is clockwise seen from above), A2, A3 and A5
  right-handed about the base y axis (A2 positive lowers the lower arm forward, A3 positive lowers
  the forearm);
* the dimensions of the arm (A2 425 mm above the mounting face and 170 mm in front of A1, lower arm
  610 mm, forearm axis 210 mm above A3, 627 mm from A3 to the wrist point, 80 mm from the wrist point
  to the flange) and its nominal reach, 1,440 mm (the model name), the largest distance of the wrist
  point from the A1 axis;
* the axis ranges of KUKA's own description of this arm (which KUKA marks verified), whose
  asymmetric A2, A3 and A5 ranges fix each of those axes' sign: mirrored, they would exclude the home
  position or turn the arm into the floor.

A sign flip of any axis in ``robots/kuka_kr8_r1440_2_arc_hw/robot.urdf`` fails these tests.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from refine.export.krl import kuka_status_turn
from refine.robot.registry import load_robot

NAME = "kuka_kr8_r1440_2_arc_hw"
HOME_DEG = [0.0, -90.0, 90.0, 0.0, 0.0, 0.0]
# KUKA's axis ranges [deg] and speeds [deg/s] of the KR 8 R1440-2 arc HW
RANGES_DEG = [(-170, 170), (-185, 65), (-119, 181), (-165, 165), (-115, 140), (-350, 350)]
SPEEDS_DEG_S = [220, 210, 270, 430, 430, 628.5714]
# dimensions [m]
A2_HEIGHT, A2_FORWARD, LOWER_ARM, FOREARM_OFFSET, A3_TO_WRIST, WRIST_TO_FLANGE = (
    0.425,
    0.170,
    0.610,
    0.210,
    0.627,
    0.080,
)
REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "robot-meshes" / NAME / "reference.urdf"


@pytest.fixture(scope="module")
def kr8():
    return load_robot(NAME)


def _wrist(robot, q_deg):
    """The wrist point (A4, A5, A6 meet) in the base frame [m]."""
    return robot.frame_pose(np.radians(q_deg), "link_5")[:3, 3]


def test_the_ranges_and_speeds_are_kukas_and_hold_the_home_position(kr8):
    lower, upper = np.array(RANGES_DEG, dtype=float).T
    np.testing.assert_allclose(np.degrees(kr8.spec.lower), lower, atol=1e-6)
    np.testing.assert_allclose(np.degrees(kr8.spec.upper), upper, atol=1e-6)
    np.testing.assert_allclose(np.degrees(kr8.spec.velocity), SPEEDS_DEG_S, atol=1e-3)
    home = np.radians(HOME_DEG)
    assert np.all((kr8.spec.lower < home) & (home < kr8.spec.upper))
    assert kr8.spec.controller == "kuka" and kr8.spec.default_program == "krl"


def test_at_home_the_lower_arm_is_upright_the_forearm_level_and_the_flange_forward(kr8):
    T = kr8.fk(np.radians(HOME_DEG))
    expected = [A2_FORWARD + A3_TO_WRIST + WRIST_TO_FLANGE, 0.0, A2_HEIGHT + LOWER_ARM + FOREARM_OFFSET]
    np.testing.assert_allclose(T[:3, 3], expected, atol=1e-6)  # 0.877, 0, 1.245
    np.testing.assert_allclose(T[:3, 2], [1.0, 0.0, 0.0], atol=1e-9)  # tool direction: forward
    # KUKA's flange frame at home reads A 0, B 90, C 0 (x down, y to the left)
    np.testing.assert_allclose(
        T[:3, :3], Rotation.from_euler("ZYX", [0.0, 90.0, 0.0], degrees=True).as_matrix(), atol=1e-9
    )
    a3 = kr8.frame_pose(np.radians(HOME_DEG), "link_3")[:3, 3]
    np.testing.assert_allclose(a3, [A2_FORWARD, 0.0, A2_HEIGHT + LOWER_ARM], atol=1e-9)


def test_at_zero_the_lower_arm_is_horizontal(kr8):
    a3 = kr8.frame_pose(np.zeros(6), "link_3")[:3, 3]
    np.testing.assert_allclose(a3, [A2_FORWARD + LOWER_ARM, 0.0, A2_HEIGHT], atol=1e-9)


@pytest.mark.parametrize(
    ("axis", "world_axis"),
    [(0, [0, 0, -1]), (1, [0, 1, 0]), (2, [0, 1, 0]), (3, [-1, 0, 0]), (4, [0, 1, 0]), (5, [-1, 0, 0])],
)
def test_each_axis_turns_the_way_kuka_counts_it(kr8, axis, world_axis):
    """From home, a small positive step of one axis turns the flange about KUKA's axis direction."""
    q = np.radians(HOME_DEG)
    step = np.zeros(6)
    step[axis] = 1e-4
    R0, R1 = kr8.fk(q)[:3, :3], kr8.fk(q + step)[:3, :3]
    turn = Rotation.from_matrix(R1 @ R0.T).as_rotvec() / 1e-4
    np.testing.assert_allclose(turn, world_axis, atol=1e-6)


def test_motions_from_home_go_where_a_kuka_operator_expects(kr8):
    home = _wrist(kr8, HOME_DEG)
    assert _wrist(kr8, [30, -90, 90, 0, 0, 0])[1] < -0.3  # A1 +30: clockwise from above, to the right
    lowered = _wrist(kr8, [0, -60, 90, 0, 0, 0])  # A2 +30: the lower arm leans forward
    assert lowered[0] > home[0] + 0.2 and lowered[2] < home[2]
    assert _wrist(kr8, [0, -90, 120, 0, 0, 0])[2] < home[2] - 0.2  # A3 +30: the forearm drops
    tool_down = kr8.fk(np.radians([0, -90, 90, 0, 90, 0]))[:3, 2]  # A5 +90: the flange faces the floor
    np.testing.assert_allclose(tool_down, [0.0, 0.0, -1.0], atol=1e-9)


def test_the_nominal_reach_is_the_wrist_points_largest_distance_from_a1(kr8):
    a3 = np.linspace(-60.0, 60.0, 2401)
    radius = [np.hypot(*_wrist(kr8, [0, 0, a, 0, 0, 0])[:2]) for a in a3]
    assert max(radius) == pytest.approx(
        A2_FORWARD + LOWER_ARM + np.hypot(A3_TO_WRIST, FOREARM_OFFSET), abs=1e-5
    )
    assert max(radius) == pytest.approx(1.440, abs=0.002)
    assert kr8.spec.reach_m == pytest.approx(1.44)


def test_home_status_and_turn_are_kukas_usual_ones(kr8):
    """Elbow up, wrist in front of A1, A5 = 0: S 2; only A2 is negative: T 2 (bit 1)."""
    status, turn = kuka_status_turn(kr8, np.radians(HOME_DEG))
    assert (status, turn) == (2, 2)


@pytest.mark.skipif(not REFERENCE.is_file(), reason=f"KUKA's reference description not found at {REFERENCE}")
def test_the_flange_equals_kukas_tool0_at_random_axis_values(kr8):
    """KUKA's description (base = $ROBROOT, tool0 = the controller's null $TOOL; its driver only turns
    radians into degrees) gives the same flange pose for the same A1..A6."""
    ref = pin.buildModelFromUrdf(str(REFERENCE))
    data = ref.createData()
    tool0 = ref.getFrameId("tool0")
    for q in np.random.default_rng(5).uniform(kr8.spec.lower, kr8.spec.upper, size=(200, 6)):
        pin.framesForwardKinematics(ref, data, q)
        np.testing.assert_allclose(kr8.fk(q), data.oMf[tool0].homogeneous, atol=1e-9)
