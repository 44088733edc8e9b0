"""The per-waypoint CasADi functions the NLPs map over the path.

The per-waypoint CasADi functions the NLPs map over the path: the path rows and the orientation
cost (:func:`waypoint_function`) and the singularity measure (:func:`singularity_function`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import casadi as ca

from refine.optimise.kinematics import fk_function, jacobian_function
from refine.robot.model import Robot
from refine.types import Array

ROW_NAMES = ("position x", "position y", "position z", "orientation cone")


def waypoint_function(
    robot: Robot, base_in_world: Array, tcp_in_flange: Array, axisymmetric: bool, tool_in_world: Array | None = None
) -> ca.Function:
    """Per-waypoint constraints ``g`` (4,) and orientation cost for joints ``q``.

    Inputs: ``q`` (n,), ``p_ref`` (3,) CAD point [m], ``R_demo`` (9,) demonstrated rotation
    (column-major). Outputs: ``g`` = [TCP position - p_ref (3), cos θ] and ``cost`` = 1 - cos θ,
    θ the angle between the reached and demonstrated orientations (between the tool axes for an
    axisymmetric tool). With a stationary tool (``tool_in_world``, T_F_TCP) the pose is the tool's
    in the held part's frame (``tcp_in_flange`` is then T_flange_part) and ``p_ref`` is in that frame.
    """
    fk = fk_function(robot, base_in_world, tcp_in_flange, tool_in_world)
    q = ca.SX.sym("q", robot.nq)
    p_ref = ca.SX.sym("p_ref", 3)
    r_demo = ca.SX.sym("R_demo", 9)
    R_demo = ca.reshape(r_demo, 3, 3)
    p, R = fk(q)
    if axisymmetric:
        cos_theta = ca.dot(R[:, 2], R_demo[:, 2])
    else:
        cos_theta = (ca.trace(ca.mtimes(R_demo.T, R)) - 1.0) / 2.0
    g = ca.vertcat(p - p_ref, cos_theta)
    return ca.Function(
        "waypoint", [q, p_ref, r_demo], [g, 1.0 - cos_theta], ["q", "p_ref", "R_demo"], ["g", "cost"]
    )


def singularity_function(robot: Robot, base_in_world: Array, tcp_in_flange: Array) -> ca.Function:
    """Scaled manipulability ``sqrt(det(Js Jsᵀ))`` of joints ``q`` [-].

    ``Js`` is the TCP Jacobian with its linear rows divided by the robot's reach, so both halves are
    unitless and the measure compares across robots. The measure does not depend on the point or
    frame the Jacobian is taken at (a change of either multiplies ``Js`` by a matrix of determinant
    one), so a stationary tool uses the held part's Jacobian.
    """
    jac = jacobian_function(robot, base_in_world, tcp_in_flange)
    q = ca.SX.sym("q", robot.nq)
    J = jac(q)
    Js = ca.vertcat(J[:3, :] / robot.spec.reach_m, J[3:, :])
    w = ca.sqrt(ca.det(ca.mtimes(Js, Js.T)) + 1e-12)
    return ca.Function("singularity", [q], [w], ["q"], ["w"])


INTERACTION_LABEL = "interaction limit"
"""Label prefix of the rows that keep a robot's joint interaction limits at every waypoint."""


def interaction_rows(
    robot: Robot, N: int, margin_rad: float, held: Sequence[Any] = ()
) -> list[tuple[int, Array, float, str]]:
    """Rows ``g·q_k >= lower`` that keep the robot's joint interaction limits at every waypoint.

    Each limit ``lower <= a·q <= upper`` on the URDF joints (:func:`refine.robot.coupling.interaction_rows`,
    from the controller's limits such as FANUC's J2/J3 interaction) gives two rows per waypoint,
    ``a·q >= lower + margin`` and ``-a·q >= -(upper - margin)``; a linear constraint held at the
    waypoints holds on the straight joint segments between them.

    Returns:
        (waypoint k, gradient (n,), lower bound, label) of each row; empty without limits or when
        ``held`` (the rows a problem already has, with a ``label``) holds them already.
    """
    if any(str(getattr(r, "label", "")).startswith(INTERACTION_LABEL) for r in held):
        return []
    from refine.robot.coupling import interaction_rows as limits

    spec = robot.spec
    A, lower, upper = limits(spec.joint_coupling, spec.joint_interaction, robot.nq)
    out = []
    for a, lo, hi, it in zip(A, lower, upper, spec.joint_interaction, strict=True):
        label = f"{INTERACTION_LABEL}: {it.label}"
        for k in range(N):
            out += [(k, a, float(lo) + margin_rad, label), (k, -a, -(float(hi) - margin_rad), label)]
    return out
