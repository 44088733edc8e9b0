"""The placement search: the smallest workpiece move that makes the path executable.

The placement search: the smallest rigid move of the workpiece (in its support plane unless
``free = "all"``) under which the demonstrated orientations are reachable within the strict
tolerances, posed as one CasADi NLP over the joints and the move, with the moved objects' clearance
rows added round by round (:func:`search_placement`).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np

from refine.optimise.moves import WORLD_Z, ClearanceRow, Placement, SupportPlane, move_basis
from refine.paths import FusedPath
from refine.settings import PlacementSettings
from refine.types import Array

if TYPE_CHECKING:
    from refine.robot.model import Robot
log = logging.getLogger(__name__)


INSET_DEG = 0.05
"""The placement search keeps the orientation cone and the joint limits this far inside their
bounds [deg], so that the strict re-solve of the moved problem does not start on a bound's edge."""


SINGULARITY_INSET = 1.05
"""The placement search bounds the singularity measure by this factor times the margin."""


PATH_COST_WEIGHT = 1e-3
"""Weight of the usual path cost (orientation deviation in deg², joint smoothness) against the
squared placement norm: it settles the joints (a redundant arm's elbow) without moving the optimum
of the placement by more than about 1e-3 of its bounds."""


ELASTIC_WEIGHT = 1e4
"""Cost per unit of elastic cone slack (cosine units) in the placement search: 0.1 deg beyond a
3 deg cone costs about 0.9, 1 deg about 9, against a squared norm of at most 2 for the largest
move, so slack is used only where no move within the bounds avoids it (an exact L1 penalty)."""


ZERO_MOVE = 1e-3
"""A move whose norm (against the bounds) is below this is no move at all: it is within what the
small path cost (:data:`PATH_COST_WEIGHT`) may pull the answer by (0.2 mm and 0.015 deg of bounds
of 0.2 m and 15 deg)."""


SLACK_TOLERANCE_DEG = 1e-3
"""A placement search answer whose elastic slack stays below this everywhere is a feasible move [deg]."""


SKIP_SINGULARITY_CURVATURE = True
"""Leave the singularity rows' second derivatives out of the Hessian IPOPT is given: they cost
about 30 times the rest of it (a 6x6 determinant differentiated twice at every waypoint)."""


def _rotation(r: ca.MX) -> ca.MX:
    """Rodrigues' rotation of the rotation vector ``r`` (3,), smooth at 0 (half-angle form)."""
    theta = ca.sqrt(ca.dot(r, r) + 1e-14)
    K = ca.skew(r)
    half = theta / 2.0
    return ca.DM.eye(3) + (ca.sin(theta) / theta) * K + 0.5 * (ca.sin(half) / half) ** 2 * ca.mtimes(K, K)


@dataclass(frozen=True)
class SearchResult:
    """The placement problem's answer (not yet verified).

    Attributes:
        placement: the move found.
        q: joints at every waypoint on the moved path [rad], (N, n).
        success: IPOPT reported success.
        solver_status: IPOPT's return status.
        iterations: IPOPT iterations.
        time_s: wall time of build and solve [s].
        slack_deg: the orientation beyond the (inset) cone each waypoint still needs with this
            move [deg], (N,); all zero (below :data:`SLACK_TOLERANCE_DEG`) when the move is feasible.
        x: the solver's variables at the answer (to start the next clearance round from).
    """

    placement: Placement
    q: Array
    success: bool
    solver_status: str
    iterations: int
    time_s: float
    slack_deg: Array = field(default_factory=lambda: np.zeros(0))
    x: Array = field(default_factory=lambda: np.zeros(0))


def search_placement(
    robot: Robot,
    fused: FusedPath,
    base_in_world: Array,
    tcp_in_flange: Array,
    tolerances: Any,
    bounds: PlacementSettings,
    q0: Array,
    *,
    axisymmetric: bool = False,
    weights: Any = None,
    time_limit_s: float = 120.0,
    support: SupportPlane | None = None,
    rows: tuple[ClearanceRow, ...] = (),
    start: SearchResult | None = None,
) -> SearchResult:
    """The smallest move of the workpiece for which the joints meet the strict constraints.

    Args:
        robot: the robot.
        fused: the path as placed (N waypoints).
        base_in_world: T_F_R (4, 4).
        tcp_in_flange: T_flange_TCP (4, 4).
        tolerances: the strict tolerances (:class:`refine.settings.Tolerances`).
        bounds: the largest shift [m] and turn [deg], and what may move (``free``).
        q0: joints to start from (N, n) [rad], e.g. the slack repair's or the IK seed.
        axisymmetric: only the tool axis counts in the cone.
        weights: the path cost weights (:class:`refine.optimise.problem.Weights`), or None.
        time_limit_s: IPOPT's wall-time limit [s].
        support: the plane the workpiece rests on; with ``bounds.free == "plane"`` the shift stays
            in it and the turn is about its normal. None: the world z plane.
        rows: clearance rows of the moved objects (:func:`clearance_rows`), kept as constraints.
        start: an earlier answer to start from (the previous clearance round), or None.
    """
    from refine.optimise.derivatives import smoothness_matrix
    from refine.optimise.problem import Weights, joint_bounds
    from refine.optimise.waypoint import singularity_function, waypoint_function

    t0 = time.perf_counter()
    weights = weights or Weights()
    N, n = len(fused), robot.nq
    centre = fused.positions.mean(axis=0)
    T_max, A_max = bounds.translate_m, math.radians(bounds.rotate_deg)

    # decision variables: joints, the shift and the rotation vector scaled by their bounds, and an
    # elastic slack per waypoint on the cone (cosine units), so that the problem always has an
    # answer: with the slack zero the move is feasible; otherwise it says how far from it the largest
    # move within the bounds leaves the path
    E_t, E_r = move_basis(support or WORLD_Z, bounds.free)
    m_t, m_r = E_t.shape[1], E_r.shape[1]
    m = m_t + m_r
    x = ca.MX.sym("x", N * n + m + N)
    Q = ca.reshape(x[: N * n], n, N)
    u, v, sigma = x[N * n : N * n + m_t], x[N * n + m_t : N * n + m], x[N * n + m :]
    t, r = T_max * ca.mtimes(ca.DM(E_t), u), A_max * ca.mtimes(ca.DM(E_r), v)
    R = _rotation(r)
    P = ca.DM(fused.positions.T)  # (3, N)
    c = ca.DM(centre)
    P_moved = ca.mtimes(R, P - ca.repmat(c, 1, N)) + ca.repmat(c + t, 1, N)
    R_demo = ca.DM(np.concatenate(list(fused.rotations), axis=1))  # (3, 3N): R_0 | R_1 | ...
    R_moved = ca.reshape(ca.mtimes(R, R_demo), 9, N)  # column k: R·R_k, column-major

    G, cost = waypoint_function(robot, base_in_world, tcp_in_flange, axisymmetric).map(N)(Q, P_moved, R_moved)
    cos_theta = G[3, :]
    clearance = rows
    rows = [ca.vec(ca.vertcat(G[:3, :], cos_theta + sigma.T)), ca.vec(Q[:, 1:] - Q[:, :-1])]
    inset = math.radians(INSET_DEG)
    cone = math.radians(tolerances.orientation_deg) - inset
    step = math.radians(tolerances.joint_step_deg)
    lbg = [np.tile([0.0, 0.0, 0.0, math.cos(cone)], N)]
    ubg = [np.tile([0.0, 0.0, 0.0, np.inf], N)]
    lbg.append(np.full(n * (N - 1), -step + inset))
    ubg.append(np.full(n * (N - 1), step - inset))
    if tolerances.singularity_margin > 0:
        rows.append(ca.vec(singularity_function(robot, base_in_world, tcp_in_flange).map(N)(Q)))
        lbg.append(np.full(N, SINGULARITY_INSET * tolerances.singularity_margin))
        ubg.append(np.full(N, np.inf))
    rows.append(ca.vertcat(ca.dot(u, u), ca.dot(v, v)))
    lbg.append(np.array([-np.inf, -np.inf]))
    ubg.append(np.array([1.0, 1.0]))
    for row in clearance:
        # the signed distance linearised at its witness points: the moved object's point follows
        # the move exactly, a robot link's point the joints to first order
        moved = c + ca.mtimes(R, ca.DM(row.point_m - centre)) + t
        d = row.distance_m + ca.dot(ca.DM(row.normal), moved - ca.DM(row.moved_point_m))
        if row.waypoint >= 0:
            d += ca.dot(ca.DM(row.gradient), Q[:, row.waypoint] - ca.DM(row.q))
        rows.append(d)
        lbg.append(np.array([row.bound_m]))
        ubg.append(np.array([np.inf]))

    spec = robot.spec
    h = float(np.mean(np.diff(fused.s)))
    half = 0.5 * (spec.upper - spec.lower)
    K = smoothness_matrix(n, N, h, weights.velocity, weights.acceleration, 0.0, half) / N
    qv = x[: N * n]
    path_cost = weights.orientation * (180.0 / math.pi) ** 2 * 2.0 * ca.sum2(cost) / N + 0.5 * ca.dot(
        qv, ca.mtimes(ca.DM(K), qv)
    )
    f = ca.dot(u, u) + ca.dot(v, v) + PATH_COST_WEIGHT * path_cost + ELASTIC_WEIGHT * ca.sum1(sigma)

    lower, upper = joint_bounds(robot, tolerances)
    lower, upper = lower + inset, upper - inset
    free_t, free_r = float(T_max > 0), float(A_max > 0)  # a part with a zero bound stays at 0
    lbx = np.concatenate([np.tile(lower, N), np.full(m_t, -free_t), np.full(m_r, -free_r), np.zeros(N)])
    ubx = np.concatenate([np.tile(upper, N), np.full(m_t, free_t), np.full(m_r, free_r), np.full(N, 2.0)])
    options = {
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "print_time": False,
        "ipopt.tol": 1e-8,
        "ipopt.constr_viol_tol": 1e-9,
        "ipopt.max_iter": 300,
        "ipopt.mu_strategy": "adaptive",
        "ipopt.max_wall_time": float(time_limit_s),
    }
    g = ca.vertcat(*rows)
    if SKIP_SINGULARITY_CURVATURE and tolerances.singularity_margin > 0:
        # the Hessian of the Lagrangian without the singularity rows' curvature (their λ·∇²w)
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.size1())
        first = 4 * N + n * (N - 1)
        keep = ca.vertcat(lam_g[:first], ca.MX(N, 1), lam_g[first + N :])
        H = ca.triu(ca.hessian(lam_f * f + ca.dot(keep, g), x)[0])
        p_empty = ca.MX.sym("p", 0)
        options["hess_lag"] = ca.Function(
            "hess_lag", [x, p_empty, lam_f, lam_g], [H], ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"]
        )
    solver = ca.nlpsol("placement", "ipopt", {"x": x, "f": f, "g": g}, options)
    if start is not None and start.x.size == x.size1():
        x0 = np.clip(start.x, lbx, ubx)
    else:
        q_start = np.clip(np.asarray(q0, dtype=float), lower, upper).ravel()
        start_cos = ca.Function("cos_theta", [x], [cos_theta])(np.concatenate([q_start, np.zeros(m + N)]))
        sigma0 = np.clip(math.cos(cone) - np.asarray(start_cos).ravel(), 0.0, 2.0)  # what the start needs
        x0 = np.concatenate([q_start, np.zeros(m), sigma0])
    sol = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=np.concatenate(lbg), ubg=np.concatenate(ubg))
    stats = solver.stats()
    log.debug("placement search timings: %s", {k: v for k, v in stats.items() if k.startswith("t_wall")})
    xs = np.asarray(sol["x"]).ravel()
    placement = Placement(
        centre, T_max * (E_t @ xs[N * n : N * n + m_t]), A_max * (E_r @ xs[N * n + m_t : N * n + m])
    )
    slack = np.clip(xs[N * n + m :], 0.0, None)
    slack_deg = np.degrees(np.arccos(np.clip(math.cos(cone) - slack, -1.0, 1.0)) - cone)
    return SearchResult(
        placement,
        xs[: N * n].reshape(N, n),
        bool(stats.get("success", False)) and float(slack_deg.max()) <= SLACK_TOLERANCE_DEG,
        str(stats.get("return_status", "unknown")),
        int(stats.get("iter_count", 0)),
        time.perf_counter() - t0,
        slack_deg,
        xs,
    )
