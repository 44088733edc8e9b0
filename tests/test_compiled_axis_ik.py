"""The compiled IK toward the TCP position and tool axis alone (``axis_only``, the spin about the axis free).

Expectations come from Pinocchio (poses, Jacobians), NumPy's dense algebra (the damped least-squares
step by ``lstsq`` of the stacked system with the spin's column taken out by hand), the angle
between the axes by ``arccos`` and the NumPy path (a chain that never compiles).
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
WORLD_TOOL = pin.SE3(pin.exp3(np.array([2.5, 0.4, -0.3])), np.array([0.9, 0.2, 0.6])).homogeneous


def _kins(name: str, held: bool) -> tuple[TcpKinematics, TcpKinematics]:
    """The same robot's TCP kinematics compiled and in NumPy, the TCP on the flange or at a standing tool."""
    robot = load_robot(name)
    robot.chain = CompiledChain.from_model(robot.model, robot.flange_id)
    slow = copy.copy(robot)
    slow.chain = CompiledChain.from_model(robot.model, robot.flange_id, compile=False)
    assert robot.chain.compiled and not slow.chain.compiled
    world = WORLD_TOOL if held else None
    return TcpKinematics(robot, BASE, TCP, world), TcpKinematics(slow, BASE, TCP, world)


def _pin_pose(robot, q: np.ndarray, held: bool) -> np.ndarray:
    """The TCP's world pose, or the standing tool's TCP seen from the held part, from Pinocchio alone."""
    pin.framesForwardKinematics(robot.model, data := robot.model.createData(), q)
    T = BASE @ data.oMf[robot.flange_id].homogeneous @ TCP
    return np.linalg.inv(T) @ WORLD_TOOL if held else T


def _axis_norm(T: np.ndarray, target: np.ndarray) -> float:
    """The position miss [m] and the angle between the z axes [rad], stacked."""
    angle = np.arccos(np.clip(T[:3, 2] @ target[:3, 2], -1.0, 1.0))
    return float(np.hypot(np.linalg.norm(target[:3, 3] - T[:3, 3]), angle))


def _spun_targets(kin_np: TcpKinematics, m: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Reachable poses spun about their z axis by a random angle (so the full pose is not the answer), starts."""
    rng = np.random.default_rng(seed)
    spec = kin_np.robot.spec
    q_goal = rng.uniform(0.7 * spec.lower, 0.7 * spec.upper, (m, kin_np.robot.nq))
    targets = kin_np.poses(q_goal)
    for k in range(m):
        targets[k, :3, :3] = targets[k, :3, :3] @ pin.exp3(np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)]))
    q0 = q_goal + rng.normal(size=q_goal.shape) * 0.2
    q0[:3] = q_goal[:3] + rng.normal(size=(3, kin_np.robot.nq)) * 1.5  # far starts: capped steps, stalls
    return targets, q0


def test_one_compiled_axis_step_is_the_damped_least_squares_step_without_the_spin(chain_cache) -> None:
    kin, kin_np = _kins("abb_irb4600_60_205", held=False)
    robot, nq = kin.robot, kin.robot.nq
    rng = np.random.default_rng(7)
    qs = rng.uniform(0.8 * robot.spec.lower, 0.8 * robot.spec.upper, (6, nq))
    targets = np.array([_pin_pose(robot, q, False) for q in qs])
    for k in range(6):  # turned off the axis and spun about it, moved a little
        targets[k, :3, :3] = pin.exp3(rng.normal(size=3) * 0.3) @ targets[k, :3, :3]
        targets[k, :3, 3] += rng.normal(size=3) * 0.01
    damping, lower, upper = 0.01, np.full(nq, -10.0), np.full(nq, 10.0)
    q, err, _, J_out, flag = robot.chain.ik_solve(
        qs, (BASE, TCP, None), targets, (lower, upper), damping, 0.0, 0.0, 1, None, axis_only=True
    )
    assert not flag.any()
    for k in range(6):
        model, data = robot.model, robot.model.createData()
        J = pin.computeFrameJacobian(model, data, qs[k], robot.flange_id, pin.LOCAL_WORLD_ALIGNED)
        T = BASE @ data.oMf[robot.flange_id].homogeneous @ TCP
        arm = data.oMf[robot.flange_id].rotation @ TCP[:3, 3]
        Jw = BASE[:3, :3] @ J[3:]
        Jv = BASE[:3, :3] @ (J[:3] - np.cross(arm, J[3:].T).T)
        # the turn taking z onto the target's: about z × z_t, by the angle between them
        z, zt = T[:3, 2], targets[k, :3, 2]
        axis = np.cross(z, zt) / np.linalg.norm(np.cross(z, zt))
        e = np.concatenate([targets[k, :3, 3] - T[:3, 3], np.arccos(z @ zt) * axis])
        # the angular rows seen in a frame whose third axis is z: drop that row (the free spin)
        frame = np.linalg.qr(np.column_stack([z, rng.normal(size=(3, 2))]))[0]
        rows = np.vstack([Jv, frame[:, 1:].T @ Jw])
        e5 = np.concatenate([e[:3], frame[:, 1:].T @ e[3:]])
        stacked = np.vstack([rows, damping * np.eye(nq)])
        step = np.linalg.lstsq(stacked, np.concatenate([e5, np.zeros(nq)]), rcond=None)[0]
        step *= min(1.0, 0.3 / np.abs(step).max())
        np.testing.assert_allclose(q[k], qs[k] + step, rtol=0, atol=1e-10)
        # the Jacobian handed back is the whole TCP Jacobian at the joints returned, the error there
        np.testing.assert_allclose(J_out[k], kin_np.jacobian(q[k]), rtol=0, atol=1e-12)
        assert err[k] == pytest.approx(_axis_norm(_pin_pose(robot, q[k], False), targets[k]), abs=1e-7)


@pytest.mark.parametrize(("name", "held"), [("kuka_iiwa14_r820", False), ("kuka_iiwa14_r820", True),
                                            ("abb_irb4600_60_205", True)])  # fmt: skip
def test_the_compiled_axis_ik_is_the_numpy_paths_single_and_batched(chain_cache, name, held) -> None:
    """The iiwa with its pull, a standing tool; single poses and the batch with its stall rule."""
    kin, kin_np = _kins(name, held)
    spec, nq = kin.robot.spec, kin.robot.nq
    targets, q0 = _spun_targets(kin_np, 16, 51 + held)
    out = {}
    for label, k in (("c", kin), ("np", kin_np)):
        J_out, T_out = np.empty((16, 6, nq)), np.empty((16, 4, 4))
        q, err = solve_ik_batch(
            k, targets, q0, spec.lower, spec.upper, axis_only=True, jacobians_out=J_out, poses_out=T_out
        )
        single = [solve_ik(k, targets[i], q0[i], spec.lower, spec.upper, axis_only=True) for i in range(16)]
        out[label] = q, err, J_out, T_out, np.array([s[0] for s in single]), np.array([s[1] for s in single])
    q, err, J_out, T_out, q1, err1 = out["c"]
    for got, want in zip(out["c"][:4], out["np"][:4], strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    # a single pose from a far start that has not converged after its 100 iterations (it wandered
    # along the limits and the pull) carries the rounding grown on the way: 1e-6 rad for those
    near = out["np"][5] < 1e-5
    np.testing.assert_allclose(q1[near], out["np"][4][near], rtol=0, atol=1e-9)
    np.testing.assert_allclose(q1, out["np"][4], rtol=0, atol=1e-6)
    np.testing.assert_allclose(err1, out["np"][5], rtol=0, atol=1e-9)
    assert (err < 1e-5).sum() >= 6 and (err1 < 1e-5).sum() >= 6  # the far starts may stall
    for i in range(16):  # poses, Jacobians and errors at the joints returned, from Pinocchio
        T_pin = _pin_pose(kin.robot, q[i], held)
        np.testing.assert_allclose(T_out[i], T_pin, rtol=0, atol=1e-12)
        np.testing.assert_allclose(J_out[i], kin_np.jacobian(q[i]), rtol=0, atol=1e-12)
        assert err[i] == pytest.approx(_axis_norm(T_pin, targets[i]), abs=1e-7)
        assert err1[i] == pytest.approx(_axis_norm(_pin_pose(kin.robot, q1[i], held), targets[i]), abs=1e-7)
    converged = err1 < 1e-5  # the axis and position reached, the spin left free: not the target's
    spins = [
        abs(np.arctan2(*(_pin_pose(kin.robot, q1[i], held)[:3, :3].T @ targets[i, :3, :3])[[1, 0], 0]))
        for i in np.flatnonzero(converged)
    ]
    assert max(spins) > 0.1


def test_axes_turned_over_are_solved_by_numpy_as_without_the_compiled_chain(chain_cache) -> None:
    kin, kin_np = _kins("kuka_iiwa14_r820", held=True)
    spec = kin.robot.spec
    targets, q0 = _spun_targets(kin_np, 6, 61)
    q0 = np.clip(q0, spec.lower, spec.upper)
    for k in range(3):  # the axis about π from the start's: axis_error's turn over (or near it)
        T0 = kin_np.pose(q0[k])
        targets[k, :3, :3] = T0[:3, :3] @ pin.exp3(np.array([np.pi - 3e-4 * k, 0.0, 0.0]))
    got = solve_ik_batch(kin, targets, q0, spec.lower, spec.upper, axis_only=True)
    want = solve_ik_batch(kin_np, targets, q0, spec.lower, spec.upper, axis_only=True)
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-9)
    for k in range(3):
        single = solve_ik(kin, targets[k], q0[k], spec.lower, spec.upper, axis_only=True)
        single_np = solve_ik(kin_np, targets[k], q0[k], spec.lower, spec.upper, axis_only=True)
        np.testing.assert_allclose(single[0], single_np[0], rtol=0, atol=1e-9)
