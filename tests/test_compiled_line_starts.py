"""The controller line's compiled starts (CompiledChain.line_starts, line_start.linear_starts).

Expectations come from Pinocchio (the TCP poses, Jacobians and ``log3``), NumPy's dense algebra (the
damped inverses by ``lstsq`` of the stacked system, per sample) and the NumPy path of
:func:`refine.optimise.line_start.linear_starts` (a chain that never compiles).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from refine.optimise.line_ik import line_poses, segment_lines
from refine.optimise.line_start import NEWTON_DAMPING, NEWTON_STEP_MAX, linear_starts
from refine.robot import compiled_chain as compiled_module
from tests.test_compiled_ik import _kins, _kins_held, _pin_pose_jacobian, _pin_seen_from_part

pytestmark = pytest.mark.skipif(compiled_module.compiler() is None, reason="no C compiler")


def _line(kin, seed: int, n: int = 5, per: int = 6):
    """Waypoints close together, joint-linear samples between them and targets off them by a little."""
    rng = np.random.default_rng(seed)
    spec = kin.robot.spec
    q = rng.uniform(0.6 * spec.lower, 0.6 * spec.upper, kin.robot.nq) + np.cumsum(
        rng.normal(size=(n, kin.robot.nq)) * 0.02, axis=0
    )
    segment = np.repeat(np.arange(n - 1), per)
    t = np.tile((np.arange(per) + 0.5) / per, n - 1)
    q_lin = q[segment] + t[:, None] * (q[segment + 1] - q[segment])
    targets = kin.poses(q_lin)
    for k in range(len(t)):  # the line's targets: off the joint-linear poses by some 0.02 mm / mrad
        targets[k, :3, :3] = pin.exp3(rng.normal(size=3) * 2e-5) @ targets[k, :3, :3]
        targets[k, :3, 3] += rng.normal(size=3) * 2e-5
    return q, segment, t, q_lin, targets


def _damped_inverse(J: np.ndarray) -> np.ndarray:
    """``Jᵀ (J Jᵀ + λ² I)⁻¹`` column by column: the least-squares answers of ``[J; λ I] x = [e_i; 0]``."""
    n = J.shape[1]
    stacked = np.vstack([J, NEWTON_DAMPING * np.eye(n)])
    rhs = np.vstack([np.eye(6), np.zeros((n, 6))])
    return np.linalg.lstsq(stacked, rhs, rcond=None)[0]


@pytest.mark.parametrize("held", [False, True])
@pytest.mark.parametrize("name", ["abb_irb4600_60_205", "kuka_iiwa14_r820"])
def test_the_starts_are_the_interpolated_damped_step_of_pinocchios_error(chain_cache, name, held) -> None:
    kin, kin_np = _kins_held(name) if held else _kins(name)
    robot = kin.robot
    q, segment, t, q_lin, targets = _line(kin_np, 5 + held)
    pose = (lambda x: _pin_seen_from_part(robot, x)) if held else (lambda x: _pin_pose_jacobian(robot, x)[0])
    J_wp = np.array([kin_np.jacobian(x) for x in q])
    T, e, start = linear_starts(kin, J_wp, segment, t, q_lin, targets)
    P = [_damped_inverse(J) for J in J_wp]
    for k in range(len(t)):
        T_pin = pose(q_lin[k])
        np.testing.assert_allclose(T[k], T_pin, rtol=0, atol=1e-12)
        w = pin.log3(targets[k, :3, :3] @ T_pin[:3, :3].T)
        e_pin = np.concatenate([targets[k, :3, 3] - T_pin[:3, 3], w])
        np.testing.assert_allclose(e[k], e_pin, rtol=0, atol=1e-12)
        s = segment[k]
        dq = (P[s] + t[k] * (P[s + 1] - P[s])) @ e_pin
        expected = q_lin[k] + (dq if np.abs(dq).max() <= NEWTON_STEP_MAX else 0.0)
        np.testing.assert_allclose(start[k], expected, rtol=0, atol=1e-12)
    big = np.abs(start - q_lin).max(axis=1)
    assert (big > 0).sum() >= len(t) // 2  # most samples took their step


def test_the_compiled_starts_are_the_numpy_paths_with_far_and_half_turned_targets(chain_cache) -> None:
    kin, kin_np = _kins()
    q, segment, t, q_lin, targets = _line(kin_np, 11)
    targets[3, :3, 3] += 0.05  # a step beyond NEWTON_STEP_MAX: from q_lin as it is
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    for k, angle in ((7, np.pi - 1e-4), (8, np.pi - 5e-4)):  # the rotation vector's branch near π
        targets[k, :3, :3] = pin.exp3(angle * axis) @ targets[k, :3, :3]
    J_wp = np.array([kin_np.jacobian(x) for x in q])
    out = linear_starts(kin, J_wp, segment, t, q_lin, targets)
    ref = linear_starts(kin_np, J_wp, segment, t, q_lin, targets)
    for a, b in zip(out, ref, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    assert np.array_equal(out[2][3], q_lin[3]) and np.array_equal(out[2][7], q_lin[7])
    plain = linear_starts(kin, J_wp, segment, t, q_lin, targets, newton=False)  # every row from its bow
    np.testing.assert_allclose(plain[0], ref[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(plain[1], ref[1], rtol=0, atol=1e-12)
    assert np.array_equal(plain[2], q_lin)
    assert np.array_equal(linear_starts(kin_np, J_wp, segment, t, q_lin, targets, newton=False)[2], q_lin)
    for k in (7, 8):  # the half-turned rows' errors are log3's
        T_pin = _pin_pose_jacobian(kin.robot, q_lin[k])[0]
        np.testing.assert_allclose(out[1][k, 3:], pin.log3(targets[k, :3, :3] @ T_pin[:3, :3].T), atol=1e-9)


def test_line_starts_rejects_mismatched_rows(chain_cache) -> None:
    kin, _ = _kins()
    chain, n = kin.robot.chain, 6
    q = np.zeros((n, kin.robot.nq))
    P = np.zeros((2, kin.robot.nq, 12))
    placements = (kin.base_in_world, kin.tcp_in_flange, None)
    with pytest.raises(ValueError):
        chain.line_starts(q, placements, np.zeros((n - 1, 4, 4)), P, np.zeros(n, int), np.zeros(n), 1e-3)
    with pytest.raises(ValueError):
        chain.line_starts(q, placements, np.zeros((n, 4, 4)), P, np.full(n, 2), np.zeros(n), 1e-3)


@pytest.mark.parametrize("held", [False, True])
def test_the_compiled_targets_are_the_chord_and_pinocchios_slerp_or_the_wrists_orientation(
    chain_cache, held
) -> None:
    kin, kin_np = _kins_held("kuka_iiwa14_r820") if held else _kins("kuka_iiwa14_r820")
    robot = kin.robot
    q, segment, t, q_lin, _ = _line(kin_np, 17 + held)
    poses = kin_np.poses(q)
    poses[3, :3, :3] = poses[2, :3, :3] @ pin.exp3(np.array([3e-5, -2e-5, 1e-5]))  # the series' branch
    wrist = np.array([False, True, False, True])
    pose = (lambda x: _pin_seen_from_part(robot, x)) if held else (lambda x: _pin_pose_jacobian(robot, x)[0])
    J_wp = np.array([kin_np.jacobian(x) for x in q])
    targets = np.empty((len(t), 4, 4))
    T, e, start = linear_starts(kin, J_wp, segment, t, q_lin, targets, segment_lines(poses, wrist))
    for k in range(len(t)):
        s = segment[k]
        expected = np.eye(4)
        expected[:3, 3] = poses[s, :3, 3] + t[k] * (poses[s + 1, :3, 3] - poses[s, :3, 3])
        Ra, Rb = poses[s, :3, :3], poses[s + 1, :3, :3]
        expected[:3, :3] = pose(q_lin[k])[:3, :3] if wrist[s] else Ra @ pin.exp3(t[k] * pin.log3(Ra.T @ Rb))
        np.testing.assert_allclose(targets[k], expected, rtol=0, atol=1e-12)
    # and the rest as the NumPy path's from those targets: line_poses' targets, NumPy's starts
    ref_targets = line_poses(poses, q, segment, t, kin_np, wrist)
    np.testing.assert_allclose(targets, ref_targets, rtol=0, atol=1e-13)
    ref = linear_starts(kin_np, J_wp, segment, t, q_lin, ref_targets)
    for a, b in zip((T, e, start), ref, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    assert linear_starts(kin_np, J_wp, segment, t, q_lin, targets, segment_lines(poses, wrist)) is None


def test_the_damped_inverses_are_the_least_squares_answers_of_the_stacked_system(chain_cache) -> None:
    kin, kin_np = _kins("kuka_iiwa14_r820")
    robot = kin.robot
    qs = np.random.default_rng(8).uniform(robot.spec.lower, robot.spec.upper, (7, robot.nq))
    qs[0, 3] = 0.0  # near the iiwa's elbow singularity: the damping holds the inverse
    J = np.array([kin_np.jacobian(q) for q in qs])
    P = robot.chain.damped_inverses(J, NEWTON_DAMPING)
    for k in range(len(qs)):
        ref = _damped_inverse(J[k])
        np.testing.assert_allclose(P[k], ref, rtol=0, atol=1e-9 * max(1.0, np.abs(ref).max()))
    assert kin_np.robot.chain.damped_inverses(J, NEWTON_DAMPING) is None
