"""Symbolic forward kinematics and Jacobian in CasADi, translated from a Pinocchio model.

The PyPI build of Pinocchio has no ``pinocchio.casadi``, so the chain is rebuilt here from the
model's joint placements, joint axes and the flange frame placement:

    T_world_tcp(q) = T_world_base · Π_i (jointPlacements[i] · Rot(axis_i, q_i))
                     · frames[flange].placement · tcp_in_flange

Only revolute joints are supported: Pinocchio's ``JointModelRX``, ``RY``, ``RZ`` and
``JointModelRevoluteUnaligned``. Each joint contributes one ``cos`` and one ``sin`` of its
angle; constant entries that are zero or one to 1e-14 (e.g. cos(π/2) in a URDF rpy) are snapped
so that CasADi can drop the terms they multiply.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from refine.errors import InputError
from refine.frames import check_transform

if TYPE_CHECKING:
    from refine.robot.model import Robot

# column pairs (i, j) mixed by a rotation about x, y, z: R·Rot = [.., c·r_i + s·r_j, -s·r_i + c·r_j]
_ALIGNED = {"JointModelRX": (0, (1, 2)), "JointModelRY": (1, (2, 0)), "JointModelRZ": (2, (0, 1))}
_UNALIGNED = "JointModelRevoluteUnaligned"
_SNAP = 1e-14


def _snap(a: ArrayLike) -> NDArray[np.float64]:
    a = np.array(a, dtype=float)
    for v in (0.0, 1.0, -1.0):
        a[np.abs(a - v) < _SNAP] = v
    return a


def _skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _joint_axis(robot: Robot, joint_id: int) -> NDArray[np.float64]:
    """Unit joint axis in the joint frame, or InputError naming an unsupported joint type."""
    joint = robot.model.joints[joint_id]
    kind = joint.shortname()
    if kind in _ALIGNED:
        return np.eye(3)[_ALIGNED[kind][0]]
    if kind == _UNALIGNED:
        axis = np.asarray(joint.extract().axis, dtype=float)
        return _snap(axis / np.linalg.norm(axis))
    raise InputError(
        f"robot {robot.spec.name!r}: joint {robot.model.names[joint_id]!r} is a {kind}; "
        f"supported joint types: {', '.join([*_ALIGNED, _UNALIGNED])}"
    )


def _rotate(R: ca.SX, kind: str, axis: NDArray[np.float64], c: ca.SX, s: ca.SX) -> ca.SX:
    """R · Rot(axis, q) given c = cos q and s = sin q."""
    if kind in _ALIGNED:
        i, j = _ALIGNED[kind][1]
        cols = [R[:, k] for k in range(3)]
        cols[i], cols[j] = c * cols[i] + s * cols[j], -s * cols[i] + c * cols[j]
        return ca.horzcat(*cols)
    Ra = R @ ca.DM(axis)
    return c * R + s * (R @ ca.DM(_skew(axis))) + (1 - c) * (Ra @ ca.DM(axis).T)


def _chain(
    robot: Robot, q: ca.SX, base_in_world: ArrayLike, tcp_in_flange: ArrayLike
) -> tuple[ca.SX, ca.SX, list[tuple[int, ca.SX, ca.SX]]]:
    """TCP position, rotation and (velocity index, world axis, world origin) of each joint.

    Only joints supporting the flange are visited, so a tree-shaped model is handled too.
    """
    model = robot.model
    T_wb = _snap(check_transform(base_in_world, "base_in_world"))
    T_ft = check_transform(tcp_in_flange, "tcp_in_flange")
    frame = model.frames[robot.flange_id]
    R, p = ca.SX(ca.DM(T_wb[:3, :3])), ca.SX(ca.DM(T_wb[:3, 3]))
    joints = []
    for jid in list(model.supports[frame.parentJoint])[1:]:
        placement = model.jointPlacements[jid]
        p = p + R @ ca.DM(_snap(placement.translation))
        R = R @ ca.DM(_snap(placement.rotation))
        axis = _joint_axis(robot, jid)
        qi = q[model.joints[jid].idx_q]
        c, s = ca.cos(qi), ca.sin(qi)
        joints.append((model.joints[jid].idx_v, R @ ca.DM(axis), p))
        R = _rotate(R, model.joints[jid].shortname(), axis, c, s)
    T_jt = _snap(frame.placement.homogeneous) @ T_ft
    return p + R @ ca.DM(T_jt[:3, 3]), R @ ca.DM(_snap(T_jt[:3, :3])), joints


def fk_function(
    robot: Robot, base_in_world: ArrayLike, tcp_in_flange: ArrayLike, tool_in_world: ArrayLike | None = None
) -> ca.Function:
    """Symbolic TCP pose in the world frame (with a stationary tool: in the held part's frame).

    Args:
        robot: a loaded robot (revolute joints only).
        base_in_world: T_world_base, the robot base in the world frame, (4, 4) [m].
        tcp_in_flange: T_flange_tcp, the tool centre point in the flange frame, (4, 4) [m]; with a
            stationary tool, T_flange_part, the held part's frame on the flange.
        tool_in_world: T_world_tcp of a stationary tool (4, 4) [m], or None for a tool on the
            flange. With it the pose is the tool's seen from the part, ``T_world_part(q)⁻¹ · T_world_tcp``.

    Returns:
        ``ca.Function("fk", [q], [p, R], ["q"], ["p", "R"])`` with q the joints [rad] (n, 1),
        p the TCP position in the world [m] (3, 1) and R its rotation in the world (3, 3).

    Raises:
        InputError: for a transform that is not rigid or an unsupported joint type.
    """
    q = ca.SX.sym("q", robot.nq)
    p, R, _ = _chain(robot, q, base_in_world, tcp_in_flange)
    if tool_in_world is not None:
        T_wt = _snap(check_transform(tool_in_world, "tool_in_world"))
        p, R = R.T @ (ca.DM(T_wt[:3, 3]) - p), R.T @ ca.DM(T_wt[:3, :3])
    return ca.Function("fk", [q], [p, R], ["q"], ["p", "R"])


def jacobian_function(robot: Robot, base_in_world: ArrayLike, tcp_in_flange: ArrayLike) -> ca.Function:
    """Symbolic geometric Jacobian of the TCP with world-aligned axes.

    Column k maps joint speed k [rad/s] to the TCP's linear velocity [m/s] (rows 0-2) and the
    tool's angular velocity [rad/s] (rows 3-5), both in world coordinates:
    ``J[:, k] = [ω_k × (p_tcp - o_k); ω_k]`` for a revolute joint with world axis ω_k through o_k.

    Args:
        robot: a loaded robot (revolute joints only).
        base_in_world: T_world_base, (4, 4) [m].
        tcp_in_flange: T_flange_tcp, (4, 4) [m].

    Returns:
        ``ca.Function("jacobian", [q], [J], ["q"], ["J"])``, q (n, 1) [rad], J (6, n). (CasADi
        reserves the name ``"jac"``.)

    Raises:
        InputError: for a transform that is not rigid or an unsupported joint type.
    """
    q = ca.SX.sym("q", robot.nq)
    p_tcp, _, joints = _chain(robot, q, base_in_world, tcp_in_flange)
    J = ca.SX.zeros(6, robot.model.nv)
    for idx_v, w, o in joints:
        J[:3, idx_v] = ca.cross(w, p_tcp - o)
        J[3:, idx_v] = w
    return ca.Function("jacobian", [q], [J], ["q"], ["J"])
