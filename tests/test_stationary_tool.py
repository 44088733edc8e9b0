"""A stationary tool: the robot holds the part, the TCP stands in the world; poses and Jacobians in the part's frame."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from refine.frames import make_transform, matrix_from_fixed_xyz
from refine.robot.kinematics import TcpKinematics, solve_ik
from refine.robot.registry import load_robot

PART_IN_FLANGE = make_transform(matrix_from_fixed_xyz([30.0, -20.0, 10.0], degrees=True), [0.05, -0.02, 0.15])
TOOL_IN_WORLD = make_transform(matrix_from_fixed_xyz([180.0, 0.0, 45.0], degrees=True), [1.2, 0.3, 0.9])
BASE = make_transform(matrix_from_fixed_xyz([0.0, 0.0, 20.0], degrees=True), [0.1, -0.2, 0.0])


@pytest.fixture(scope="module")
def kin():
    return TcpKinematics(load_robot("abb_irb4600_60_205"), BASE, PART_IN_FLANGE, TOOL_IN_WORLD)


Q = np.array([0.2, 0.3, -0.1, 0.7, 0.9, -0.4])


def test_the_pose_is_the_tool_seen_from_the_part(kin):
    held = TcpKinematics(kin.robot, BASE, PART_IN_FLANGE)  # the part's frame in the world, as a TCP
    expected = np.linalg.inv(held.pose(Q)) @ TOOL_IN_WORLD
    assert kin.pose(Q) == pytest.approx(expected, abs=1e-12)
    qs = np.array([Q, -Q, 0.5 * Q])
    assert kin.poses(qs) == pytest.approx(np.array([np.linalg.inv(held.pose(q)) @ TOOL_IN_WORLD for q in qs]))


def test_the_jacobian_is_the_derivative_of_that_pose_in_the_part_frame(kin):
    h = 1e-6
    numeric = np.empty((6, 6))
    for k in range(6):
        dq = np.zeros(6)
        dq[k] = h
        Tp, Tm = kin.pose(Q + dq), kin.pose(Q - dq)
        numeric[:3, k] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
        numeric[3:, k] = pin.log3(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * h)
    assert kin.jacobian(Q) == pytest.approx(numeric, abs=1e-6)
    T, J = kin.pose_jacobian(Q)
    assert T == pytest.approx(kin.pose(Q)) and J == pytest.approx(numeric, abs=1e-6)
    p, R, Js = kin.batch(np.array([Q, Q]))
    assert p[1] == pytest.approx(T[:3, 3]) and R[0] == pytest.approx(T[:3, :3])
    assert Js[0] == pytest.approx(numeric, abs=1e-6)


def test_ik_brings_the_part_point_to_the_tool(kin):
    target = kin.pose(Q) @ make_transform(matrix_from_fixed_xyz([2.0, -3.0, 4.0], degrees=True), [0.01, -0.02, 0.015])
    spec = kin.robot.spec
    q, error = solve_ik(kin, target, Q, spec.lower, spec.upper)
    assert error < 1e-6
    # the point of the part at the target, carried by the robot, is where the tool stands
    held = TcpKinematics(kin.robot, BASE, PART_IN_FLANGE)
    assert (held.pose(q) @ target) == pytest.approx(TOOL_IN_WORLD, abs=1e-6)
