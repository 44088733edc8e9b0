"""The refinement NLP: one CasADi problem over the joint vectors of all waypoints.

Decision variables are the joints ``Q`` (n, N), column k the joints at waypoint k. Per waypoint, one
CasADi function gives the constraint rows and the cost term; ``Function.map`` applies it to every
waypoint, so the problem is block-banded and its size grows linearly with N:

* hard: TCP position equal to the CAD point (3 rows, equality); joint limits shrunk by the margin
  (variable bounds);
* bounded: orientation inside a cone around the demonstrated orientation (1 row; for an
  axisymmetric tool only the tool axis is constrained), singularity measure above the margin (1 row,
  on the waypoints of ``singular_waypoints`` only: the measure is a 6x6 determinant whose graph is
  fifteen times the rest, so it is imposed where it can bind and the solver's outer loop adds
  waypoints until the verified path keeps the margin everywhere);
* cost: orientation deviation from the demonstration, plus joint smoothness (squared first and
  second differences along the path, per metre of path).

:func:`build_refinement` returns the problem without solving it, so it can be inspected, dumped or
benchmarked; :func:`refine.optimise.solve.solve_refinement` solves and verifies it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from refine.errors import InputError
from refine.optimise.kinematics import fk_function, jacobian_function
from refine.paths import FusedPath
from refine.problem import Tolerances
from refine.robot import Robot

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Weights:
    """Cost weights of the refinement; the cost is a mean over waypoints, in squared degrees.

    The orientation term is ``2(1 - cos θ)·(180/π)²``, which is θ² in deg² for small θ, so an
    objective of about 1 means the path keeps about one degree from the demonstration (a scale
    IPOPT converges well on).

    Attributes:
        orientation: weight of the squared deviation from the demonstration [1/deg²·deg²].
        velocity: weight of the squared joint step per metre of path |Δq/Δs|² [deg²·m²/rad²].
        acceleration: weight of the squared second difference per metre² |Δ²q/Δs²|² [deg²·m⁴/rad²].
    """

    orientation: float = 1.0
    velocity: float = 5e-3
    acceleration: float = 5e-6

    def __post_init__(self) -> None:
        for name in ("orientation", "velocity", "acceleration"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise InputError(f"Weights.{name} must be a finite number >= 0, got {value!r}")


@dataclass(frozen=True)
class RefinementNLP:
    """A built refinement problem, ready for :func:`solve_refinement`.

    Attributes:
        nlp: the CasADi problem dict (``x``, ``p``, ``f``, ``g``).
        solver: the IPOPT solver CasADi built for it (derivatives included).
        solver_options: the options it was built with.
        params: numeric value of ``p`` (CAD points and demonstrated orientations).
        lbx, ubx: variable bounds (joint limits minus margin) [rad], shape (n·N,).
        lbg, ubg: constraint bounds, shape (4·N + len(singular_waypoints) + len(singular_segments),).
        n_waypoints, dof: sizes.
        row_names: names of the 4 constraint rows of each waypoint, in order; the singularity
            rows of ``singular_waypoints`` and then of ``singular_segments`` follow all of them.
        waypoint: the per-waypoint CasADi function (constraints and cost), for inspection.
        singular_waypoints: the waypoints whose singularity measure is bounded.
        singular_segments: the (segment, fraction) points whose singularity measure is bounded.
        robot, base_in_world, tcp_in_flange, fused, tolerances: what it was built from.
        build_time_s: wall time of the build [s].
    """

    nlp: dict[str, Any]
    solver: ca.Function
    solver_options: dict[str, Any]
    params: Array
    lbx: Array
    ubx: Array
    lbg: Array
    ubg: Array
    n_waypoints: int
    dof: int
    row_names: tuple[str, ...]
    waypoint: ca.Function
    robot: Robot
    base_in_world: Array
    tcp_in_flange: Array
    fused: FusedPath
    tolerances: Tolerances
    axisymmetric: bool
    weights: Weights = field(default_factory=Weights)
    singular_waypoints: tuple[int, ...] = ()
    singular_segments: tuple[tuple[int, float], ...] = ()
    build_time_s: float = 0.0

    def with_singularity_bounds(
        self, waypoints: tuple[int, ...], segments: tuple[int, ...] = ()
    ) -> RefinementNLP:
        """The same problem with the singularity bound on more waypoints and segment midpoints.

        The bounds already present are kept; the problem is rebuilt, not solved.
        """
        return build_refinement(
            self.robot,
            self.fused,
            self.base_in_world,
            self.tcp_in_flange,
            self.tolerances,
            axisymmetric=self.axisymmetric,
            weights=self.weights,
            singular_waypoints=self.singular_waypoints + tuple(waypoints),
            singular_segments=self.singular_segments + tuple(segments),
            solver_options=self.solver_options,
        )


IPOPT_DEFAULTS: dict[str, Any] = {
    "ipopt.print_level": 0,
    "ipopt.sb": "yes",
    "print_time": False,
    "ipopt.tol": 1e-9,
    "ipopt.constr_viol_tol": 1e-10,
    "ipopt.max_iter": 300,
    "ipopt.mu_strategy": "adaptive",
    "ipopt.warm_start_init_point": "yes",
    "ipopt.warm_start_bound_push": 1e-9,
    "ipopt.warm_start_mult_bound_push": 1e-9,
}
"""IPOPT settings: a warm start from the IK seed, which is usually close to the answer, and a
constraint tolerance well under the 1e-6 m position tolerance of the verification."""

ROW_NAMES = ("position x", "position y", "position z", "orientation cone")


def waypoint_function(
    robot: Robot, base_in_world: Array, tcp_in_flange: Array, axisymmetric: bool
) -> ca.Function:
    """Per-waypoint constraints ``g`` (4,) and orientation cost for joints ``q``.

    Inputs: ``q`` (n,), ``p_ref`` (3,) CAD point [m], ``R_demo`` (9,) demonstrated rotation
    (column-major). Outputs: ``g`` = [TCP position - p_ref (3), cos θ] and ``cost`` = 1 - cos θ,
    θ the angle between the reached and demonstrated orientations (between the tool axes for an
    axisymmetric tool).
    """
    fk = fk_function(robot, base_in_world, tcp_in_flange)
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
    unitless and the measure compares across robots.
    """
    jac = jacobian_function(robot, base_in_world, tcp_in_flange)
    q = ca.SX.sym("q", robot.nq)
    J = jac(q)
    Js = ca.vertcat(J[:3, :] / robot.spec.reach_m, J[3:, :])
    w = ca.sqrt(ca.det(ca.mtimes(Js, Js.T)) + 1e-12)
    return ca.Function("singularity", [q], [w], ["q"], ["w"])


def build_refinement(
    robot: Robot,
    fused: FusedPath,
    base_in_world: Array,
    tcp_in_flange: Array,
    tolerances: Tolerances,
    *,
    axisymmetric: bool = False,
    weights: Weights | None = None,
    singular_waypoints: tuple[int, ...] = (),
    singular_segments: tuple[tuple[int, float], ...] = (),
    solver_options: dict[str, Any] | None = None,
) -> RefinementNLP:
    """Build the refinement NLP for ``fused`` on ``robot`` (no solve).

    Args:
        robot: the robot model.
        fused: CAD points with demonstrated orientations, N waypoints.
        base_in_world: T_F_R (4, 4).
        tcp_in_flange: T_flange_TCP (4, 4).
        tolerances: orientation cone [deg], joint margin [deg], singularity margin [-].
        axisymmetric: leave the spin about the tool axis free.
        weights: cost weights (defaults of :class:`Weights`).
        singular_waypoints: waypoints whose singularity measure is bounded below by the margin.
        singular_segments: points inside segments, as (k, f): the joints ``(1-f)·q_k + f·q_{k+1}``
            get the same bound (how a wrist flip between two waypoints is kept out).
        solver_options: CasADi/IPOPT options overriding :data:`IPOPT_DEFAULTS`.

    Returns:
        The problem with bounds and parameters filled in.
    """
    t0 = time.perf_counter()
    weights = weights or Weights()
    N, n = len(fused), robot.nq
    if N < 3:
        raise InputError(f"refinement needs at least 3 waypoints, got {N}")
    spec = robot.spec
    margin = math.radians(tolerances.joint_margin_deg)
    lower, upper = spec.lower + margin, spec.upper - margin
    if np.any(lower >= upper):
        raise InputError(
            f"tolerances.joint_margin_deg = {tolerances.joint_margin_deg} deg leaves no joint range"
        )

    # ---- decision variables and parameters
    Q = ca.MX.sym("Q", n, N)
    P_ref = ca.MX.sym("P_ref", 3, N)
    R_demo = ca.MX.sym("R_demo", 9, N)

    # ---- path constraints and orientation cost, mapped over the waypoints
    waypoint = waypoint_function(robot, base_in_world, tcp_in_flange, axisymmetric)
    G, cost = waypoint.map(N)(Q, P_ref, R_demo)
    singular = tuple(sorted(set(int(k) for k in singular_waypoints)))
    if singular and not 0 <= singular[0] <= singular[-1] < N:
        raise InputError(f"singular_waypoints must lie in [0, {N}), got {singular[0]}..{singular[-1]}")
    segments = tuple(sorted({(int(k), float(f)) for k, f in singular_segments}))
    for k, f in segments:
        if not (0 <= k < N - 1 and 0.0 < f < 1.0):
            raise InputError(f"singular_segments: ({k}, {f}) needs 0 <= k < {N - 1} and 0 < f < 1")
    rows = [ca.vec(G)]
    q_bounded = []
    if singular:
        q_bounded.append(Q[:, list(singular)])
    if segments:
        idx = [k for k, _ in segments]
        frac = ca.DM([f for _, f in segments]).T
        Qa, Qb_ = Q[:, idx], Q[:, [k + 1 for k in idx]]
        q_bounded.append(Qa + (Qb_ - Qa) * ca.repmat(frac, robot.nq, 1))
    if q_bounded:
        Qb = ca.horzcat(*q_bounded)
        W = singularity_function(robot, base_in_world, tcp_in_flange).map(Qb.shape[1])(Qb)
        rows.append(ca.vec(W))

    # ---- objective: orientation deviation + joint smoothness per metre of path
    h = float(np.mean(np.diff(fused.s)))
    dQ = Q[:, 1:] - Q[:, :-1]
    d2Q = Q[:, 2:] - 2 * Q[:, 1:-1] + Q[:, :-2]
    f = (
        weights.orientation * 2.0 * (180.0 / math.pi) ** 2 * ca.sum2(cost)
        + weights.velocity * ca.sumsqr(dQ) / h**2
        + weights.acceleration * ca.sumsqr(d2Q) / h**4
    ) / N

    # ---- bounds
    cos_alpha = math.cos(math.radians(tolerances.orientation_deg))
    lbg_k = np.array([0.0, 0.0, 0.0, cos_alpha])
    ubg_k = np.array([0.0, 0.0, 0.0, 1.0 + 1e-9])
    n_s = len(singular) + len(segments)
    # CasADi vectorises column-major: Q[:, k] is x[k*n:(k+1)*n] and R_demo[:, k] is R_k column-major.
    params = np.concatenate(
        [fused.positions.ravel(), np.transpose(fused.rotations, (0, 2, 1)).reshape(N, 9).ravel()]
    )
    nlp = {
        "x": ca.vec(Q),
        "p": ca.vertcat(ca.vec(P_ref), ca.vec(R_demo)),
        "f": f,
        "g": ca.vertcat(*rows),
    }
    options = {**IPOPT_DEFAULTS, **(solver_options or {})}
    return RefinementNLP(
        nlp=nlp,
        solver=ca.nlpsol("refine", "ipopt", nlp, options),
        solver_options=options,
        params=params,
        lbx=np.tile(lower, N),
        ubx=np.tile(upper, N),
        lbg=np.concatenate([np.tile(lbg_k, N), np.full(n_s, tolerances.singularity_margin)]),
        ubg=np.concatenate([np.tile(ubg_k, N), np.full(n_s, np.inf)]),
        n_waypoints=N,
        dof=n,
        row_names=ROW_NAMES,
        waypoint=waypoint,
        robot=robot,
        base_in_world=np.asarray(base_in_world, dtype=float),
        tcp_in_flange=np.asarray(tcp_in_flange, dtype=float),
        fused=fused,
        tolerances=tolerances,
        axisymmetric=axisymmetric,
        weights=weights,
        singular_waypoints=singular,
        singular_segments=segments,
        build_time_s=time.perf_counter() - t0,
    )
