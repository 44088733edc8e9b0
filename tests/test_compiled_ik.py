"""The compiled IK step and determinants (CompiledChain.ik_steps, dets6) and solve_ik_batch on them.

Expectations come from Pinocchio (poses, Jacobians, ``log3``), NumPy's dense algebra (the damped
least-squares step by ``lstsq`` of the stacked system, ``np.linalg.det``) and the NumPy path of
:func:`solve_ik_batch` (a chain that never compiles).
"""

from __future__ import annotations

import copy

import numpy as np
import pinocchio as pin
import pytest

from refine.robot import compiled_chain as compiled_module
from refine.robot.compiled_chain import CompiledChain
from refine.robot.kinematics import TcpKinematics, solve_ik, solve_ik_batch
from refine.robot.registry import load_robot

pytestmark = pytest.mark.skipif(compiled_module.compiler() is None, reason="no C compiler")

BASE = pin.SE3(pin.exp3(np.array([0.05, -0.1, 0.4])), np.array([0.3, -0.2, 0.1])).homogeneous
TCP = pin.SE3(pin.exp3(np.array([0.2, 0.3, -0.1])), np.array([0.01, 0.02, 0.25])).homogeneous


def _kins(name: str = "abb_irb4600_60_205") -> tuple[TcpKinematics, TcpKinematics]:
    """The same robot's TCP kinematics compiled and in NumPy (a chain that never compiles)."""
    robot = load_robot(name)
    robot.chain = CompiledChain.from_model(robot.model, robot.flange_id)
    slow = copy.copy(robot)
    slow.chain = CompiledChain.from_model(robot.model, robot.flange_id, compile=False)
    assert robot.chain.compiled and not slow.chain.compiled
    return TcpKinematics(robot, BASE, TCP), TcpKinematics(slow, BASE, TCP)


def _pin_pose_jacobian(robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The TCP's world pose and Jacobian (linear rows first, world axes) from Pinocchio alone."""
    model, data = robot.model, robot.model.createData()
    J = pin.computeFrameJacobian(model, data, q, robot.flange_id, pin.LOCAL_WORLD_ALIGNED)
    T_f = data.oMf[robot.flange_id].homogeneous
    arm = T_f[:3, :3] @ TCP[:3, 3]
    Jv = J[:3] - np.cross(arm, J[3:].T).T
    return BASE @ T_f @ TCP, np.vstack([BASE[:3, :3] @ Jv, BASE[:3, :3] @ J[3:]])


def test_the_step_is_the_damped_least_squares_step_of_pinocchios_error(chain_cache) -> None:
    kin, _ = _kins()
    robot = kin.robot
    rng = np.random.default_rng(3)
    qs = rng.uniform(robot.spec.lower, robot.spec.upper, (9, robot.nq))
    targets = np.empty((9, 4, 4))
    turns = [rng.normal(size=3) * 0.4 for _ in range(7)] + [np.array([1e-8, -2e-8, 0.5e-8]), np.zeros(3)]
    for k, w in enumerate(turns):  # rows 7 and 8: the small-angle branch
        T_pin, _ = _pin_pose_jacobian(robot, qs[k])
        targets[k] = T_pin
        targets[k, :3, :3] = pin.exp3(w) @ T_pin[:3, :3]
        targets[k, :3, 3] += rng.normal(size=3) * 0.01
    damping = 0.02
    T, J = np.empty((9, 4, 4)), np.empty((9, 6, robot.nq))
    e, norm, dq, theta = robot.chain.ik_steps(qs, BASE, TCP, targets, damping, T, J)
    for k, q in enumerate(qs):
        T_pin, J_pin = _pin_pose_jacobian(robot, q)
        np.testing.assert_allclose(T[k], T_pin, rtol=0, atol=1e-12)
        np.testing.assert_allclose(J[k], J_pin, rtol=0, atol=1e-12)
        w = pin.log3(targets[k, :3, :3] @ T_pin[:3, :3].T)
        e_pin = np.concatenate([targets[k, :3, 3] - T_pin[:3, 3], w])
        np.testing.assert_allclose(e[k], e_pin, rtol=0, atol=1e-12)
        assert norm[k] == pytest.approx(np.linalg.norm(e_pin), rel=1e-13, abs=1e-18)
        assert theta[k] == pytest.approx(np.linalg.norm(w), abs=1e-7)  # arccos near 1: sqrt(eps)
        # dq minimises |J dq - e|² + λ²|dq|²: the least-squares answer of [J; λI] dq = [e; 0]
        stacked = np.vstack([J_pin, damping * np.eye(robot.nq)])
        ref = np.linalg.lstsq(stacked, np.concatenate([e_pin, np.zeros(robot.nq)]), rcond=None)[0]
        np.testing.assert_allclose(dq[k], ref, rtol=0, atol=1e-10 * max(1.0, np.abs(ref).max()))
    # a tolerance: no step for the rows under it, the same step for the others
    tol = float(np.median(norm))
    _, _, dq_tol, _ = robot.chain.ik_steps(qs, BASE, TCP, targets, damping, T.copy(), J.copy(), tol=tol)
    below = norm < tol
    assert below.any() and (~below).any()
    assert np.array_equal(dq_tol[below], np.zeros_like(dq[below])) and np.array_equal(
        dq_tol[~below], dq[~below]
    )
    # given: T and J read, not computed (a Jacobian scaled by 2 halves the undamped step's size)
    J2 = 2.0 * J
    T2 = T.copy()
    e2, _, dq2, _ = robot.chain.ik_steps(qs + 1.0, BASE, TCP, targets, 1e-9, T2, J2, given=True)
    np.testing.assert_allclose(e2, e, rtol=0, atol=1e-15)
    np.testing.assert_allclose(J2, 2.0 * J, rtol=0, atol=0)
    undamped = np.array([np.linalg.solve(J[k], e[k]) for k in range(9)])
    np.testing.assert_allclose(dq2, 0.5 * undamped, rtol=1e-6, atol=1e-9)


def test_dets6_are_numpys_determinants(chain_cache) -> None:
    kin, _ = _kins()
    rng = np.random.default_rng(5)
    a = rng.normal(size=(20, 6, 6))
    a[3, 2] = a[3, 4]  # singular: two equal rows
    a[4] = np.eye(6)[[1, 0, 2, 3, 5, 4]]  # a permutation: +1
    a[5, :, 0] = 0.0  # a zero column
    got = kin.robot.chain.dets6(a)
    np.testing.assert_allclose(got, np.linalg.det(a), rtol=1e-12, atol=1e-13)
    assert got[4] == 1.0 and got[5] == 0.0


def _targets(kin_ref: TcpKinematics, rng: np.random.Generator, m: int) -> tuple[np.ndarray, np.ndarray]:
    spec = kin_ref.robot.spec
    q_goal = rng.uniform(0.7 * spec.lower, 0.7 * spec.upper, (m, kin_ref.robot.nq))
    targets = np.array([_pin_pose_jacobian(kin_ref.robot, q)[0] for q in q_goal])
    return q_goal, targets


def test_solve_ik_batch_compiled_is_the_numpy_paths_answer(chain_cache) -> None:
    kin, kin_np = _kins()
    spec = kin.robot.spec
    rng = np.random.default_rng(11)
    q_goal, targets = _targets(kin_np, rng, 40)
    q0 = q_goal + rng.normal(size=q_goal.shape) * 0.2
    q0[:5] = q_goal[:5] + rng.normal(size=(5, kin.robot.nq)) * 1.5  # far starts: capped steps, stalls
    out = {}
    for name, k in (("c", kin), ("np", kin_np)):
        J_out, T_out = np.empty((40, 6, kin.robot.nq)), np.empty((40, 4, 4))
        q, err = solve_ik_batch(
            k, targets, q0, spec.lower, spec.upper, nullspace_gain=0.0, jacobians_out=J_out, poses_out=T_out
        )
        out[name] = q, err, J_out, T_out
    # outputs the chain cannot write into directly (not contiguous): the same answers
    J_wide, T_wide = np.zeros((40, 6, kin.robot.nq + 2)), np.zeros((40, 4, 5))
    q_wide, _ = solve_ik_batch(
        kin,
        targets,
        q0,
        spec.lower,
        spec.upper,
        nullspace_gain=0.0,
        jacobians_out=J_wide[:, :, 1:-1],
        poses_out=T_wide[:, :, :4],
    )
    q, err, J_out, T_out = out["c"]
    assert (
        np.array_equal(q_wide, q)
        and np.array_equal(J_wide[:, :, 1:-1], J_out)
        and np.array_equal(T_wide[:, :, :4], T_out)
    )
    np.testing.assert_allclose(q, out["np"][0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(err, out["np"][1], rtol=0, atol=1e-9)
    assert (err < 1e-6).sum() == (out["np"][1] < 1e-6).sum() >= 35
    for k in range(40):  # the poses and Jacobians out are Pinocchio's at the joints returned
        T_pin, J_pin = _pin_pose_jacobian(kin.robot, q[k])
        np.testing.assert_allclose(T_out[k], T_pin, rtol=0, atol=1e-12)
        np.testing.assert_allclose(J_out[k], J_pin, rtol=0, atol=1e-12)
        e = np.concatenate([targets[k, :3, 3] - T_pin[:3, 3], pin.log3(targets[k, :3, :3] @ T_pin[:3, :3].T)])
        assert np.linalg.norm(e) == pytest.approx(err[k], abs=1e-12)


def test_solve_ik_batch_compiled_from_a_given_start_and_near_a_half_turn(chain_cache) -> None:
    kin, kin_np = _kins()
    spec = kin.robot.spec
    rng = np.random.default_rng(12)
    q_goal, targets = _targets(kin_np, rng, 12)
    q0 = np.clip(q_goal + rng.normal(size=q_goal.shape) * 0.1, spec.lower, spec.upper)
    for k in range(4):  # targets turned by about π from the start's TCP: rotation_vectors' axis branch
        T0, _ = _pin_pose_jacobian(kin.robot, q0[k])
        axis = rng.normal(size=3)
        targets[k, :3, :3] = pin.exp3((np.pi - 1e-4 * k) * axis / np.linalg.norm(axis)) @ T0[:3, :3]
    p, R, J = kin_np.batch(q0)
    results = [
        solve_ik_batch(k, targets, q0, spec.lower, spec.upper, nullspace_gain=0.0, start=(p, R, J))
        for k in (kin, kin_np)
    ]
    np.testing.assert_allclose(results[0][0], results[1][0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(results[0][1], results[1][1], rtol=0, atol=1e-9)
    assert (results[0][1][4:] < 1e-6).all()


def test_pulls_and_partial_tasks_keep_the_numpy_path(chain_cache, monkeypatch) -> None:
    kin, kin_np = _kins()
    spec = kin.robot.spec
    rng = np.random.default_rng(13)
    q_goal, targets = _targets(kin_np, rng, 6)
    q0 = q_goal + rng.normal(size=q_goal.shape) * 0.1

    def refuse(*args, **kwargs):
        raise AssertionError("the compiled step was used")

    monkeypatch.setattr(kin.robot.chain, "ik_steps", refuse)
    for kwargs in ({"position_only": True}, {"damping": 0.0}):
        q, err = solve_ik_batch(kin, targets, q0, spec.lower, spec.upper, nullspace_gain=0.0, **kwargs)
        q_np, err_np = solve_ik_batch(
            kin_np, targets, q0, spec.lower, spec.upper, nullspace_gain=0.0, **kwargs
        )
        np.testing.assert_allclose(q, q_np, rtol=0, atol=1e-9)
    with pytest.raises(AssertionError, match="compiled step"):
        solve_ik_batch(kin, targets, q0, spec.lower, spec.upper, nullspace_gain=0.0)


WORLD_TOOL = pin.SE3(pin.exp3(np.array([2.5, 0.4, -0.3])), np.array([0.9, 0.2, 0.6])).homogeneous


def _kins_held(name: str) -> tuple[TcpKinematics, TcpKinematics]:
    """A robot holding the part (``TCP`` places it on the flange) at a standing tool, compiled and in NumPy."""
    kin, kin_np = _kins(name)
    return (TcpKinematics(k.robot, BASE, TCP, WORLD_TOOL) for k in (kin, kin_np))


def _pin_seen_from_part(robot, q: np.ndarray) -> np.ndarray:
    """The standing tool's TCP in the held part's frame, from Pinocchio's flange alone."""
    pin.framesForwardKinematics(robot.model, data := robot.model.createData(), q)
    return np.linalg.inv(BASE @ data.oMf[robot.flange_id].homogeneous @ TCP) @ WORLD_TOOL


@pytest.mark.parametrize("name", ["kuka_iiwa14_r820", "abb_irb4600_60_205"])
def test_a_standing_tools_compiled_pose_and_jacobian_are_pinocchios_pose_and_its_derivative(
    chain_cache, name
) -> None:
    kin, _ = _kins_held(name)
    robot = kin.robot
    qs = np.random.default_rng(21).uniform(0.8 * robot.spec.lower, 0.8 * robot.spec.upper, (7, robot.nq))
    T, J = kin.poses_jacobians(qs)  # 7 rows: the compiled chain's
    np.testing.assert_allclose(kin.poses(qs), T, rtol=0, atol=0)
    h = 1e-6
    for k, q in enumerate(qs):
        np.testing.assert_allclose(T[k], _pin_seen_from_part(robot, q), rtol=0, atol=1e-12)
        numeric = np.empty((6, robot.nq))
        for j in range(robot.nq):  # central differences: the TCP's velocity and its turn, part axes
            step = np.zeros(robot.nq)
            step[j] = h
            Tp, Tm = _pin_seen_from_part(robot, q + step), _pin_seen_from_part(robot, q - step)
            numeric[:3, j] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
            numeric[3:, j] = pin.log3(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * h)
        np.testing.assert_allclose(J[k], numeric, rtol=0, atol=1e-7)


def _starts(kin_np: TcpKinematics, m: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    spec = kin_np.robot.spec
    q_goal = rng.uniform(0.7 * spec.lower, 0.7 * spec.upper, (m, kin_np.robot.nq))
    q0 = q_goal + rng.normal(size=q_goal.shape) * 0.2
    q0[:4] = q_goal[:4] + rng.normal(size=(4, kin_np.robot.nq)) * 1.5  # far starts: capped steps, stalls
    return kin_np.poses(q_goal), q0


@pytest.mark.parametrize("held", [False, True])
def test_the_redundant_arms_compiled_ik_with_its_pull_is_the_numpy_paths(chain_cache, held) -> None:
    """The iiwa's batch and single-pose IK with the null-space pull, a TCP on the flange or a standing tool."""
    kin, kin_np = _kins_held("kuka_iiwa14_r820") if held else _kins("kuka_iiwa14_r820")
    spec, nq = kin.robot.spec, kin.robot.nq
    targets, q0 = _starts(kin_np, 24, 31 + held)
    out = {}
    for name, k in (("c", kin), ("np", kin_np)):
        J_out, T_out = np.empty((24, 6, nq)), np.empty((24, 4, 4))
        q, err = solve_ik_batch(k, targets, q0, spec.lower, spec.upper, jacobians_out=J_out, poses_out=T_out)
        single = [solve_ik(k, targets[i], q0[i], spec.lower, spec.upper) for i in range(24)]
        out[name] = q, err, J_out, T_out, np.array([s[0] for s in single]), np.array([s[1] for s in single])
    q, err, J_out, T_out, q1, err1 = out["c"]
    np.testing.assert_allclose(q, out["np"][0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(err, out["np"][1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(q1, out["np"][4], rtol=0, atol=1e-9)
    np.testing.assert_allclose(err1, out["np"][5], rtol=0, atol=1e-9)
    assert (err < 1e-6).sum() == (out["np"][1] < 1e-6).sum() >= 6
    assert (err1 < 1e-6).sum() == (out["np"][5] < 1e-6).sum() >= 6
    for i in range(24):  # poses and Jacobians out at the joints returned; the errors are Pinocchio's
        T_pin = _pin_seen_from_part(kin.robot, q[i]) if held else _pin_pose_jacobian(kin.robot, q[i])[0]
        np.testing.assert_allclose(T_out[i], T_pin, rtol=0, atol=1e-12)
        np.testing.assert_allclose(J_out[i], kin_np.jacobian(q[i]), rtol=0, atol=1e-12)
        e = np.concatenate([targets[i, :3, 3] - T_pin[:3, 3], pin.log3(targets[i, :3, :3] @ T_pin[:3, :3].T)])
        assert np.linalg.norm(e) == pytest.approx(err[i], abs=1e-12)


def test_rows_turned_by_a_half_turn_are_solved_by_numpy_as_without_the_compiled_chain(
    chain_cache, monkeypatch
) -> None:
    kin, kin_np = _kins_held("kuka_iiwa14_r820")
    spec = kin.robot.spec
    targets, q0 = _starts(kin_np, 8, 41)
    q0 = np.clip(q0, spec.lower, spec.upper)
    for k in range(3):  # about π from the start's pose: rotation_vectors' and log3's axis branch
        T0 = kin_np.pose(q0[k])
        axis = np.random.default_rng(k).normal(size=3)
        targets[k, :3, :3] = T0[:3, :3] @ pin.exp3((np.pi - 2e-4 * k) * axis / np.linalg.norm(axis))
    J_out = np.empty((8, 6, kin.robot.nq))
    q, err = solve_ik_batch(kin, targets, q0, spec.lower, spec.upper, jacobians_out=J_out)
    q_np, err_np = solve_ik_batch(kin_np, targets, q0, spec.lower, spec.upper)
    np.testing.assert_allclose(q, q_np, rtol=0, atol=1e-9)
    np.testing.assert_allclose(err, err_np, rtol=0, atol=1e-9)
    for k in range(8):
        np.testing.assert_allclose(J_out[k], kin_np.jacobian(q[k]), rtol=0, atol=1e-12)
    single = solve_ik(kin, targets[0], q0[0], spec.lower, spec.upper)
    single_np = solve_ik(kin_np, targets[0], q0[0], spec.lower, spec.upper)
    np.testing.assert_allclose(single[0], single_np[0], rtol=0, atol=1e-9)
