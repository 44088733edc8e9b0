"""Numeric TCP kinematics and damped least-squares IK of a robot with its tool and base.

Numeric TCP kinematics of a robot with a tool and base (:class:`TcpKinematics`: poses, Jacobians
and their batches, with Pinocchio) and damped least-squares IK, one pose (:func:`solve_ik`) or many
at once (:func:`solve_ik_batch`). The optimiser's seed, the verifier, the diagnosis, the program
writers and the simulators all use these; they depend on the robot alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from refine.errors import InputError
from refine.robot.model import Robot
from refine.types import Array

NULLSPACE_GAIN = 0.05
"""Step toward mid-range per IK iteration for redundant arms, in the task's null space [rad·rad]."""


CONVERGED = 1e-6
"""Pose error norm [m and rad stacked] under which an IK solution counts as converged."""


@dataclass(frozen=True)
class TcpKinematics:
    """Numeric TCP kinematics of a robot placed in the world with a tool.

    With a stationary tool (``tool_in_world``) the robot holds the part and the tool stands in the
    world: ``tcp_in_flange`` then places the part's frame on the flange (the robot-held work
    object), and every pose and Jacobian is the tool's TCP as seen from the part,
    ``T_part_TCP(q) = (T_F_R · fk(q) · T_flange_part)⁻¹ · T_F_TCP``, in the part's frame (the frame
    a path along the part is given in).

    Attributes:
        robot: the robot model.
        base_in_world: T_F_R (4, 4).
        tcp_in_flange: T_flange_TCP (4, 4); with a stationary tool, T_flange_part.
        tool_in_world: T_F_TCP of a stationary tool (4, 4), or None for a tool on the flange.
    """

    robot: Robot
    base_in_world: Array
    tcp_in_flange: Array
    tool_in_world: Array | None = None

    def pose(self, q: Array) -> Array:
        """T_F_TCP for joints ``q`` [rad], shape (4, 4) (with a stationary tool: T_part_TCP)."""
        T = self.base_in_world @ self.robot.fk(q) @ self.tcp_in_flange
        return T if self.tool_in_world is None else _rigid_inverse(T) @ self.tool_in_world

    def poses(self, qs: Array) -> Array:
        """T_F_TCP for joint rows ``qs`` (N, n), shape (N, 4, 4) (with a stationary tool: T_part_TCP)."""
        chain, rows = self.robot.chain, np.shape(qs)
        if chain is not None and len(rows) == 2 and rows[1] == self.robot.nq and rows[0] >= chain.min_rows:
            # the compiled chain places the robot and the tool (or the part and the standing tool) too
            tcp = chain.tcp_frames(qs, self.base_in_world, self.tcp_in_flange, False, self.tool_in_world)
            if tcp is not None:
                return tcp[0]
        T_bf = self.robot.fk_many(qs)
        if self.tool_in_world is not None:  # as :meth:`poses_jacobians` (the same products, the same bits)
            return _rigid_inverse(self.base_in_world @ T_bf @ self.tcp_in_flange) @ self.tool_in_world
        return _on_base(self.base_in_world, (T_bf.reshape(-1, 4) @ self.tcp_in_flange).reshape(T_bf.shape))

    def _stationary(self, T_wf: Array, Jv: Array, Jw: Array) -> tuple[Array, Array]:
        """T_part_TCP (..., 4, 4) and its Jacobian (..., 6, n) from the flange's pose and world Jacobian.

        The part moves, the tool stands: the TCP moves in the part's frame as the point of the part
        at the TCP moves backwards, ``v = -R_F_partᵀ (v_flange + ω × (p_TCP - o_flange))`` and
        ``ω_rel = -R_F_partᵀ ω``, both in the part's frame.
        """
        T_wp = T_wf @ self.tcp_in_flange
        tool = self.tool_in_world
        r = tool[:3, 3] - T_wf[..., :3, 3]  # flange origin -> tool TCP, world axes (..., 3)
        Jv_point = Jv - _cross_columns(r, Jw)
        Rt = np.swapaxes(T_wp[..., :3, :3], -1, -2)
        J = -np.concatenate([Rt @ Jv_point, Rt @ Jw], axis=-2)
        return _rigid_inverse(T_wp) @ tool, J

    def batch(self, qs: Array) -> tuple[Array, Array, Array]:
        """TCP positions (M, 3), rotations (M, 3, 3) and Jacobians (M, 6, n) for joint rows ``qs`` (M, n).

        The parts of :meth:`poses_jacobians`.
        """
        T, J = self.poses_jacobians(qs)
        return T[:, :3, 3], T[:, :3, :3], J

    def poses_jacobians(self, qs: Array) -> tuple[Array, Array]:
        """:meth:`poses` (M, 4, 4) and :meth:`jacobians` (M, 6, n) of joint rows ``qs`` (M, n) in one pass.

        The flange's placements and Jacobians come from the robot's batched chain
        (:class:`refine.robot.compiled_chain.CompiledChain`) for its ``min_rows`` rows or more,
        else from one pass of Pinocchio per row; compiled, the chain also places the robot and the
        tool (``tcp_frames``; a stationary tool too), else the change to the base placement and
        the TCP is done for all rows at once. The Jacobian as :meth:`jacobian`.
        """
        qs = np.atleast_2d(np.asarray(qs, dtype=float))
        robot = self.robot
        model, data, fid = robot.model, robot.data, robot.flange_id
        if qs.ndim != 2 or qs.shape[1] != robot.nq:
            raise InputError(f"qs: expected shape (M, {robot.nq}) [rad], got {qs.shape}")
        if robot.chain is not None and len(qs) >= robot.chain.min_rows:
            # the compiled chain places the robot and the tool (or the part and the standing tool) too
            tcp = robot.chain.tcp_frames(qs, self.base_in_world, self.tcp_in_flange, True, self.tool_in_world)
            if tcp is not None:
                return tcp
            T_bf, J = robot.chain.frame(qs, fid)
        else:
            J = np.empty((len(qs), 6, robot.nq))
            T_bf = np.empty((len(qs), 4, 4))
            for k, q in enumerate(qs):
                J[k] = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)
                T_bf[k] = data.oMf[fid].homogeneous
        if self.tool_in_world is not None:
            R_wb = self.base_in_world[:3, :3]
            return self._stationary(self.base_in_world @ T_bf, R_wb @ J[:, :3], R_wb @ J[:, 3:])
        return self._flange_tcp(T_bf, J)

    def _flange_tcp(self, T_bf: Array, J: Array) -> tuple[Array, Array]:
        """TCP poses (M, 4, 4) and Jacobians (M, 6, n) in the world from the flange's in the base frame.

        Done in the base frame first, where the TCP's placement on the flange is one matrix product
        for all rows (``T_bf · T_flange_TCP`` as a (4M, 4) by (4, 4) product) and the linear rows
        move to the TCP as ``v_TCP = v_flange - r × ω`` with ``r`` the flange origin -> TCP; then
        turned and shifted into the world (nothing to turn for a base without rotation).
        """
        M = len(T_bf)
        rows = T_bf.reshape(-1, 4)
        T = (rows @ self.tcp_in_flange).reshape(M, 4, 4)
        offset = np.append(self.tcp_in_flange[:3, 3], 0.0)
        r = (rows @ offset).reshape(M, 4)  # flange origin -> TCP, base axes (M, 3) and a 0
        x, y, z = r[:, 0, None], r[:, 1, None], r[:, 2, None]
        a, b, c = J[:, 3], J[:, 4], J[:, 5]
        out = np.empty_like(J)
        out[:, 0] = J[:, 0] - (y * c - z * b)
        out[:, 1] = J[:, 1] - (z * a - x * c)
        out[:, 2] = J[:, 2] - (x * b - y * a)
        out[:, 3:] = J[:, 3:]
        R_wb = self.base_in_world[:3, :3]
        if not np.array_equal(R_wb, np.eye(3)):
            out[:, :3] = R_wb @ out[:, :3]
            out[:, 3:] = R_wb @ out[:, 3:]
        return _on_base(self.base_in_world, T), out

    def jacobians(self, qs: Array) -> Array:
        """:meth:`jacobian` for joint rows ``qs`` (N, n), shape (N, 6, n) (see :meth:`batch`)."""
        return self.batch(qs)[2]

    def pose_jacobian(self, q: Array) -> tuple[Array, Array]:
        """:meth:`pose` (4, 4) and :meth:`jacobian` (6, n) at once: one pass of Pinocchio for both."""
        robot = self.robot
        J = pin.computeFrameJacobian(
            robot.model, robot.data, np.asarray(q, dtype=float), robot.flange_id, pin.LOCAL_WORLD_ALIGNED
        )
        T_wf = self.base_in_world @ robot.data.oMf[robot.flange_id].homogeneous
        R_wb = self.base_in_world[:3, :3]
        Jv, Jw = R_wb @ J[:3], R_wb @ J[3:]
        if self.tool_in_world is not None:
            return self._stationary(T_wf, Jv, Jw)
        rx, ry, rz = (T_wf[:3, :3] @ self.tcp_in_flange[:3, 3]).tolist()  # flange origin -> TCP, world axes
        # v_TCP = v_flange + ω × r = v_flange - [r]ₓ ω
        skew = np.array([[0.0, -rz, ry], [rz, 0.0, -rx], [-ry, rx, 0.0]])
        return T_wf @ self.tcp_in_flange, np.concatenate((Jv - skew @ Jw, Jw))

    def jacobian(self, q: Array) -> Array:
        """Geometric Jacobian (6, n) of the TCP, world-aligned axes, linear rows first."""
        R_wb = self.base_in_world[:3, :3]
        J = self.robot.jacobian(q)
        Jv, Jw = R_wb @ J[:3], R_wb @ J[3:]
        T_wf = self.base_in_world @ self.robot.fk(q)
        if self.tool_in_world is not None:
            return self._stationary(T_wf, Jv, Jw)[1]
        r = T_wf[:3, :3] @ self.tcp_in_flange[:3, 3]  # flange origin -> TCP, world axes
        return np.vstack([Jv - np.cross(r, Jw.T).T, Jw])


def _cross_columns(r: Array, M: Array) -> Array:
    """``r × M[..., :, k]`` for every column k: r (..., 3), M (..., 3, n) (np.cross is slow on small arrays)."""
    x, y, z = r[..., 0, None], r[..., 1, None], r[..., 2, None]
    a, b, c = M[..., 0, :], M[..., 1, :], M[..., 2, :]
    return np.stack([y * c - z * b, z * a - x * c, x * b - y * a], axis=-2)


def _on_base(T_wb: Array, T: Array) -> Array:
    """``T_wb · T[k]`` for every rigid transform of ``T`` (M, 4, 4); ``T`` itself, shifted, when ``T_wb`` does not turn.

    A rotation that is exactly the identity changes no digit of a product, so it is skipped.
    """
    if not np.array_equal(T_wb[:3, :3], np.eye(3)):
        return T_wb @ T
    if T_wb[:3, 3].any():
        T[:, :3, 3] += T_wb[:3, 3]
    return T


def _rigid_inverse(T: Array) -> Array:
    """The inverse of rigid transforms (..., 4, 4)."""
    inv = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    inv[..., :3, :3] = Rt
    inv[..., :3, 3] = -(Rt @ T[..., :3, 3, None])[..., 0]
    inv[..., 3, 3] = 1.0
    return inv


def pose_error(T: Array, T_target: Array) -> Array:
    """Pose error (6,) of ``T`` to ``T_target``: position [m] and rotation vector [rad], both in {base}."""
    e_p = T_target[:3, 3] - T[:3, 3]
    e_r = pin.log3(T_target[:3, :3] @ T[:3, :3].T)
    return np.concatenate([e_p, e_r])


def solve_ik(
    kin: TcpKinematics,
    T_target: Array,
    q0: Array,
    lower: Array,
    upper: Array,
    *,
    max_iterations: int = 100,
    damping: float = 1e-3,
    tol: float = CONVERGED,
    position_only: bool = False,
    axis_only: bool = False,
) -> tuple[Array, float]:
    """Damped least-squares IK for one TCP pose, clamped to [lower, upper].

    With the robot's chain compiled the iterations run in C (:meth:`CompiledChain.ik_solve
    <refine.robot.compiled_chain.CompiledChain.ik_solve>`: the same steps, rounded otherwise)
    unless only the position is asked for, or the rotation error (with ``axis_only`` the angle
    between the axes) comes within 1e-3 rad of a half turn (then NumPy's, from ``q0`` again).

    Args:
        kin: TCP kinematics.
        T_target: wanted T_F_TCP (4, 4).
        q0: start joints [rad], shape (n,).
        lower: lower joint bounds [rad], shape (n,).
        upper: upper joint bounds [rad], shape (n,).
        max_iterations: iteration cap.
        damping: DLS damping λ [-] (on a Jacobian with rows in m and rad).
        tol: stop when the pose error norm is below this [m and rad stacked].
        position_only: solve for the TCP position alone (orientation free).
        axis_only: solve for the TCP position and its z axis (the spin about the axis free, as for
            an axisymmetric tool); the angle counted is the one between the axes.

    Returns:
        joints [rad] (n,) and the remaining pose error norm (position [m] and angle [rad] stacked).
    """
    rows = slice(0, 3) if position_only else slice(0, 6)
    chain = kin.robot.chain
    if not position_only and damping > 0.0 and chain is not None and chain.compiled:
        gain = NULLSPACE_GAIN if kin.robot.nq > 6 else 0.0
        found = chain.ik_solve(
            np.reshape(q0, (1, -1)), _placements(kin), np.asarray(T_target)[None], (lower, upper),
            damping, tol, gain, max_iterations, None, axis_only=axis_only,
        )  # fmt: skip
        if found is not None and not found[4][0]:  # else the rotation came near a half turn: NumPy's log3
            return found[0][0], float(found[1][0])
    # np.minimum(np.maximum(...)) is np.clip's answer (the bounds are never crossed), at a third of its cost
    q = np.minimum(np.maximum(np.asarray(q0, dtype=float), lower), upper)
    T, J = kin.pose_jacobian(q)
    err = (axis_error(T[None], T_target[None], J[None])[0] if axis_only else pose_error(T, T_target))[rows]
    damped = damping**2 * np.eye(len(err))
    for _ in range(max_iterations):
        if float(err @ err) < tol * tol:
            break
        J = J[rows]
        JJt_inv = np.linalg.inv(J @ J.T + damped)
        dq = J.T @ JJt_inv @ err
        if J.shape[1] > J.shape[0]:  # redundant: drift toward mid-range in the null space of the task
            mid, half = 0.5 * (lower + upper), 0.5 * (upper - lower)
            pull = np.where(np.isfinite(half), (mid - q) / np.where(np.isfinite(half), half, 1.0) ** 2, 0.0)
            dq += NULLSPACE_GAIN * (pull - J.T @ (JJt_inv @ (J @ pull)))
        step = float(np.abs(dq).max())
        if step > 0.3:  # keep steps small so the chain does not jump branches
            dq *= 0.3 / step
        q = np.minimum(np.maximum(q + dq, lower), upper)
        T, J = kin.pose_jacobian(q)
        err = (axis_error(T[None], T_target[None], J[None])[0] if axis_only else pose_error(T, T_target))[
            rows
        ]
    return q, float(np.linalg.norm(err))


def axis_error(T: Array, T_target: Array, J: Array) -> Array:
    """The pose errors (M, 6) of poses ``T`` to ``T_target`` (M, 4, 4) with the spin about z free.

    The rotation part is the rotation vector turning each z axis onto its target's by the shortest
    way; the Jacobians ``J`` (M, 6, n) lose, in place, their angular rows' component about the
    current z axis, so a step never spends effort on the free spin.
    """
    z, zt = T[:, :3, 2], T_target[:, :3, 2]
    cross = _cross_columns(z, zt[:, :, None])[:, :, 0]
    sin = np.linalg.norm(cross, axis=1)
    angle = np.arctan2(sin, np.einsum("ki,ki->k", z, zt))
    flipped = (sin <= 1e-12) & (angle > 1.0)  # opposite axes: any axis normal to z turns it over
    cross[flipped] = np.cross(
        z[flipped], np.where(np.abs(z[flipped, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    )
    sin = np.where(flipped, np.linalg.norm(cross, axis=1), sin)
    safe = np.where(sin > 1e-12, sin, 1.0)
    e_r = np.where((sin > 1e-12)[:, None], cross * (angle / safe)[:, None], 0.0)
    J[:, 3:] -= z[:, :, None] * np.einsum("ki,kin->kn", z, J[:, 3:])[:, None, :]
    return np.concatenate([T_target[:, :3, 3] - T[:, :3, 3], e_r], axis=1)


def solve_ik_batch(
    kin: TcpKinematics,
    targets: Array,
    q0: Array,
    lower: Array,
    upper: Array,
    *,
    max_iterations: int = 100,
    damping: float = 1e-3,
    tol: float = CONVERGED,
    position_only: bool = False,
    nullspace_gain: float = NULLSPACE_GAIN,
    axis_only: bool = False,
    jacobians_out: Array | None = None,
    poses_out: Array | None = None,
    start: tuple[Array, Array, Array] | None = None,
) -> tuple[Array, Array]:
    """:func:`solve_ik` for many independent poses at once, vectorised over them.

    The arguments are :func:`solve_ik`'s, with ``targets`` (M, 4, 4) and ``q0`` (M, n) holding one
    pose and start per row. A pose whose error stalls (:data:`STALL_ITERATIONS`) is given up before
    ``max_iterations``. ``nullspace_gain``: a redundant arm's step toward mid-range in the task's
    null space per iteration [rad·rad]; 0 to keep the start's redundancy (a projection onto the
    poses that moves the joints the least). ``jacobians_out``: an array (M, 6, n) to receive the
    TCP Jacobian (:meth:`TcpKinematics.jacobian`) at each returned row, or None; every row's last
    evaluation is at the joints returned (a row is never moved after its last check), so a caller
    needing the Jacobians of the answer gets them without another pass. ``poses_out``: likewise an
    array (M, 4, 4) to receive the TCP pose at each returned row, or None. ``start``: the TCP
    positions (M, 3), rotations (M, 3, 3) and Jacobians (M, 6, n) at ``q0`` (inside the limits) when
    the caller has them, used for the first iteration instead of evaluating them again; or None.

    With the robot's chain compiled, the full pose or the axis asked for and ``damping`` > 0 the
    iterations run in C: the step alone (:func:`_solve_compiled`) for the full pose of a TCP on
    the flange without a pull, every row's whole IK (:func:`_solve_iterated`, ``start`` not
    needed) with a redundant arm's pull, a stationary tool or ``axis_only``; the same answers to
    rounding.

    Returns:
        joints [rad] (M, n) and the remaining pose error norm per pose (M,).
    """
    rows = 3 if position_only else 6
    q = np.clip(np.array(q0, dtype=float), lower, upper)
    m, n = q.shape
    chain = kin.robot.chain
    if not position_only and damping > 0.0 and chain is not None and chain.compiled:
        if n > rows and nullspace_gain > 0.0 or kin.tool_in_world is not None or axis_only:
            return _solve_iterated(
                kin, targets, q, lower, upper, max_iterations, damping, tol, nullspace_gain,
                jacobians_out, poses_out, axis_only,
            )  # fmt: skip
        return _solve_compiled(
            kin, targets, q, lower, upper, max_iterations, damping, tol, jacobians_out, poses_out, start
        )
    return _solve_numpy(
        kin, targets, q, lower, upper, max_iterations, damping, tol, position_only, nullspace_gain,
        axis_only, jacobians_out, poses_out, start,
    )  # fmt: skip


def _solve_numpy(
    kin: TcpKinematics, targets: Array, q: Array, lower: Array, upper: Array, max_iterations: int,
    damping: float, tol: float, position_only: bool, nullspace_gain: float, axis_only: bool,
    jacobians_out: Array | None, poses_out: Array | None, start: tuple[Array, Array, Array] | None,
) -> tuple[Array, Array]:  # fmt: skip
    """:func:`solve_ik_batch`'s iterations in NumPy; ``q``: the clipped start (M, n), changed in place."""
    rows = 3 if position_only else 6
    m, n = q.shape
    err = np.zeros(m)
    active = np.arange(m)
    with np.errstate(invalid="ignore"):  # unbounded (multi-turn) joints have no mid-range
        mid, half = 0.5 * (lower + upper), 0.5 * (upper - lower)
    finite = np.isfinite(half)
    best, last_gain = np.full(m, np.inf), np.zeros(m, dtype=int)
    for it in range(max_iterations + 1):
        if not active.size:
            break
        rows_now = slice(None) if active.size == m else active  # all rows: views, not copies
        p, R, J = kin.batch(q[rows_now]) if it or start is None else start
        if jacobians_out is not None:
            jacobians_out[rows_now] = J
        if poses_out is not None:
            poses_out[rows_now, :3, :3], poses_out[rows_now, :3, 3] = R, p
            poses_out[rows_now, 3] = (0.0, 0.0, 0.0, 1.0)
        T = targets[rows_now]
        e = T[:, :3, 3] - p
        if axis_only:
            reached = np.zeros_like(T)
            reached[:, :3, :3], reached[:, :3, 3] = R, p
            e = axis_error(reached, T, J)
        elif not position_only:
            e = np.concatenate([e, rotation_vectors(T[:, :3, :3] @ np.transpose(R, (0, 2, 1)))], axis=1)
        J = J[:, :rows]
        norm = np.linalg.norm(e, axis=1)
        err[active] = norm
        going = _still_going(norm, it, active, best, last_gain, tol)
        if it == max_iterations:
            break
        active, J, e = active[going], J[going], e[going]
        if not active.size:
            break
        A = J @ np.transpose(J, (0, 2, 1)) + damping**2 * np.eye(rows)
        dq = np.einsum("kji,kj->ki", J, np.linalg.solve(A, e[:, :, None])[:, :, 0])
        if n > rows and nullspace_gain > 0.0:  # redundant: drift toward mid-range in the task's null space
            pull = np.where(finite, (mid - q[active]) / np.where(finite, half, 1.0) ** 2, 0.0)
            Jp = np.einsum("kij,kj->ki", J, pull)
            dq += nullspace_gain * (
                pull - np.einsum("kji,kj->ki", J, np.linalg.solve(A, Jp[:, :, None])[:, :, 0])
            )
        step = np.max(np.abs(dq), axis=1)
        dq *= np.where(step > 0.3, 0.3 / np.maximum(step, 1e-300), 1.0)[:, None]
        q[active] = np.clip(q[active] + dq, lower, upper)
    return q, err


def _solve_iterated(
    kin: TcpKinematics, targets: Array, q: Array, lower: Array, upper: Array, max_iterations: int,
    damping: float, tol: float, nullspace_gain: float, jacobians_out: Array | None, poses_out: Array | None,
    axis_only: bool = False,
) -> tuple[Array, Array]:  # fmt: skip
    """:func:`solve_ik_batch`'s iterations for 6 task rows, every row iterated in C.

    :meth:`refine.robot.compiled_chain.CompiledChain.ik_solve` with the stall rule: a redundant
    arm's null-space pull, a stationary tool, the tool axis alone. The rows whose rotation error
    (the angle between the axes with ``axis_only``) came within 1e-3 rad of a half turn are
    solved again by :func:`_solve_numpy` (the whole pose's error by :func:`rotation_vectors`' axis
    branch, the axis' by :func:`axis_error`'s turn over). ``q``: the clipped start (M, n).
    """
    gain = nullspace_gain if q.shape[1] > 6 else 0.0
    q_out, err, T, J, flag = kin.robot.chain.ik_solve(
        q, _placements(kin), targets, (lower, upper), damping, tol, gain, max_iterations,
        (STALL_ITERATIONS, 1.0 - STALL_FRACTION), axis_only=axis_only,
    )  # fmt: skip
    again = np.flatnonzero(flag)
    if again.size:
        q_out[again], err[again] = _solve_numpy(
            kin, np.asarray(targets)[again], q[again], lower, upper, max_iterations, damping, tol, False,
            nullspace_gain, axis_only, None, None, None,
        )  # fmt: skip
        T[again], J[again] = kin.poses_jacobians(q_out[again])
    if jacobians_out is not None:
        jacobians_out[:] = J
    if poses_out is not None:
        poses_out[:] = T
    return q_out, err


def _placements(kin: TcpKinematics) -> tuple[Array, Array, Array | None]:
    """The robot's base, the TCP (or held part) on the flange and a stationary tool (or None)."""
    return kin.base_in_world, kin.tcp_in_flange, kin.tool_in_world


def _solve_compiled(
    kin: TcpKinematics,
    targets: Array,
    q: Array,
    lower: Array,
    upper: Array,
    max_iterations: int,
    damping: float,
    tol: float,
    jacobians_out: Array | None,
    poses_out: Array | None,
    start: tuple[Array, Array, Array] | None,
) -> tuple[Array, Array]:
    """:func:`solve_ik_batch`'s iterations for 6 task rows without a null-space pull, the step compiled.

    The compiled chain (:meth:`refine.robot.compiled_chain.CompiledChain.ik_steps`) gives each
    active row's TCP pose, Jacobian, pose error, its norm and the damped least-squares step; the
    stall, the tolerance, the 0.3 rad step cap and the limits are :func:`solve_ik_batch`'s. A row
    whose rotation error is within 1e-3 rad of π has its error taken by :func:`rotation_vectors`
    (the axis from ``R + Rᵀ``) and its step by NumPy. The compiled step is 0 for a row whose
    squared norm is under ``tol²`` by more than rounding (``1 - 1e-12``): a row this loop stops.
    With every row active the poses and Jacobians are written into ``poses_out`` and
    ``jacobians_out`` directly. ``q``: the clipped start (M, n), changed in place.
    """
    chain = kin.robot.chain
    m, n = q.shape
    targets = np.ascontiguousarray(targets, dtype=float)
    T_all, J_all = np.empty((m, 4, 4)), np.empty((m, 6, n))
    err = np.zeros(m)
    active = np.arange(m)
    best, last_gain = np.full(m, np.inf), np.zeros(m, dtype=int)
    for it in range(max_iterations + 1):
        if not active.size:
            break
        every = active.size == m
        k = active.size
        T, J = T_all[:k], J_all[:k]
        if every and given_out(jacobians_out, (m, 6, n)):  # all rows: into the caller's arrays at once
            J = jacobians_out
        if every and given_out(poses_out, (m, 4, 4)):
            T = poses_out
        given = it == 0 and start is not None
        if given:
            p, R, J0 = start
            T[:, :3, :3], T[:, :3, 3], T[:, 3] = R, p, (0.0, 0.0, 0.0, 1.0)
            J[:] = J0
        e, norm, dq, theta = chain.ik_steps(
            q if every else q[active],
            kin.base_in_world,
            kin.tcp_in_flange,
            targets if every else targets[active],
            damping,
            T,
            J,
            given,
            tol,
        )
        near_pi = theta > np.pi - 1e-3
        if near_pi.any():  # rotation_vectors' branch: the axis from R + Rᵀ, NumPy's step
            Tn, Jn = T[near_pi], J[near_pi]
            e[near_pi, 3:] = rotation_vectors(
                targets[active[near_pi], :3, :3] @ np.transpose(Tn[:, :3, :3], (0, 2, 1))
            )
            norm[near_pi] = np.linalg.norm(e[near_pi], axis=1)
            A = Jn @ np.transpose(Jn, (0, 2, 1)) + damping**2 * np.eye(6)
            dq[near_pi] = np.einsum("kji,kj->ki", Jn, np.linalg.solve(A, e[near_pi][:, :, None])[:, :, 0])
        if jacobians_out is not None and J is not jacobians_out:
            jacobians_out[slice(None) if every else active] = J
        if poses_out is not None and T is not poses_out:
            poses_out[slice(None) if every else active] = T
        err[active] = norm
        going = _still_going(norm, it, active, best, last_gain, tol)
        if it == max_iterations:
            break
        active, dq = active[going], dq[going]
        if not active.size:
            break
        step = np.max(np.abs(dq), axis=1)
        dq *= np.where(step > 0.3, 0.3 / np.maximum(step, 1e-300), 1.0)[:, None]
        q[active] = np.clip(q[active] + dq, lower, upper)
    return q, err


def given_out(a: Array | None, shape: tuple[int, ...]) -> bool:
    """Whether ``a`` is a C-contiguous float64 array of ``shape`` the compiled chain may write into."""
    return a is not None and a.shape == shape and a.dtype == np.float64 and a.flags.c_contiguous


STALL_ITERATIONS = 30


STALL_FRACTION = 0.01
"""A pose of :func:`solve_ik_batch` whose error has not fallen by 1 % in 30 iterations is given up
(a start that leads nowhere, e.g. against a joint limit); its last joints and error are returned."""


def _still_going(norm: Array, it: int, active: Array, best: Array, last_gain: Array, tol: float) -> Array:
    """Which of the ``active`` rows of an IK iteration ``it`` go on, given their pose error ``norm``.

    A row stops at the tolerance ``tol`` or when its error has not fallen by
    :data:`STALL_FRACTION` in :data:`STALL_ITERATIONS` iterations; ``best`` and ``last_gain``
    (per row of the whole batch) are updated in place.
    """
    improved = norm < (1.0 - STALL_FRACTION) * best[active]
    best[active] = np.where(improved, norm, best[active])
    last_gain[active] = np.where(improved, it, last_gain[active])
    stalled = it - last_gain[active] >= STALL_ITERATIONS
    return (norm * norm >= tol * tol) & ~stalled


def rotation_vectors(R: Array) -> Array:
    """Rotation vectors (M, 3) [rad] of rotation matrices (M, 3, 3): the vectorised ``log3``."""
    cos = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    vee = 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    sin = np.sin(theta)
    small = theta < 1e-6
    scale = np.where(small, 1.0 + theta**2 / 6.0, theta / np.where(small, 1.0, sin))
    out = vee * scale[:, None]
    near_pi = theta > np.pi - 1e-3  # the skew part vanishes there: take the axis from R + Rᵀ
    if near_pi.any():
        out[near_pi] = Rotation.from_matrix(R[near_pi]).as_rotvec()
    return out
