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
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import casadi as ca
import numpy as np

from refine.errors import InputError
from refine.optimise.derivatives import (
    derivative_functions,
    orientation_factor,
    smoothness_matrix,
    waypoint_kernels,
)
from refine.optimise.stagewise import FATROP_PREFIX, StagewiseSolver, check_size, fatrop_options, stage_rows
from refine.optimise.threads import limit_solver_threads
from refine.optimise.verify import Violation
from refine.optimise.watch import iteration_watch
from refine.optimise.waypoint import ROW_NAMES, interaction_rows, singularity_function, waypoint_function
from refine.paths import FusedPath
from refine.robot.model import Robot
from refine.settings import Tolerances, check_solver
from refine.types import Array


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
        mid_range: weight of the squared distance of each joint from the middle of its range,
            divided by the half range [deg²]: the secondary cost that settles a redundant arm's
            self-motion (elbow) away from the limits.
    """

    orientation: float = 1.0
    velocity: float = 5e-3
    acceleration: float = 5e-8
    mid_range: float = 0.0

    def __post_init__(self) -> None:
        for name in ("orientation", "velocity", "acceleration", "mid_range"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise InputError(f"Weights.{name} must be a finite number >= 0, got {value!r}")


@dataclass(frozen=True)
class RefinementNLP:
    """A built refinement problem, ready for :func:`solve_refinement`.

    Attributes:
        nlp: the CasADi problem dict (``x``, ``p``, ``f``, ``g``).
        solver: the solver built for it: CasADi's IPOPT solver (derivatives included), or a
            :class:`refine.optimise.stagewise.StagewiseSolver` (fatrop), called the same way.
        solver_options: the options it was built with.
        given_options: the options its caller gave (before refine's defaults); a round never overrides them.
        solver_name: ``"ipopt"`` or ``"fatrop"`` (see :func:`build_refinement`).
        params: numeric value of ``p`` (CAD points and demonstrated orientations).
        lbx, ubx: variable bounds: joint limits minus margin [rad] (n·N), then the slacks (N) when elastic.
        lbg, ubg: constraint bounds: 4 rows per waypoint, the joint-step rows (n per segment, or those
            of ``joint_steps``), then the active set's rows.
        n_waypoints, dof: sizes.
        row_names: names of the 4 constraint rows of each waypoint, in order; then the joint
            steps (n per segment), then the active set's rows (singularity points, linear rows).
        waypoint: the per-waypoint CasADi function (constraints and cost), for inspection.
        active: the singularity bounds and linearised rows beyond the per-waypoint ones.
        elastic_deg: None for the strict problem, else the largest extra cone slack [deg].
        derivatives: the ``grad_f``, ``jac_g`` and ``hess_lag`` functions the solver was given
            (:func:`refine.optimise.derivatives.derivative_functions`); empty in ``"casadi"`` mode.
        derivative_mode: how the derivatives are made (see :func:`build_refinement`).
        singularity_hessian: whether the Hessian includes the singularity rows' second derivatives.
        joint_steps: ``"all"``, or the joint-step rows the problem holds, as indices ``k·n + j``
            (segment k, joint j) in increasing order (see :func:`build_refinement`).
        robot, base_in_world, tcp_in_flange, fused, tolerances: what it was built from.
        build_time_s: wall time of the build [s].
        watch: IPOPT's iteration callback (:mod:`refine.optimise.watch`), kept alive with the solver;
            None for fatrop.
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
    tool_in_world: Array | None = None  # T_F_TCP of a stationary tool
    active: ActiveSet = field(default_factory=lambda: ActiveSet())
    elastic_deg: float | None = None
    build_time_s: float = 0.0
    derivatives: dict[str, ca.Function] = field(default_factory=dict)
    derivative_mode: str = "assembled"
    singularity_hessian: bool = False
    joint_steps: str | tuple[int, ...] = "all"
    solver_name: str = "ipopt"
    watch: Any = None
    given_options: dict[str, Any] = field(default_factory=dict)

    def rebuilt(
        self,
        *,
        active: ActiveSet | None = None,
        elastic_deg: float | None = None,
        joint_steps: str | tuple[int, ...] | None = None,
        fused: FusedPath | None = None,
        tolerances: Tolerances | None = None,
    ) -> RefinementNLP:
        """The same problem with other settings, rebuilt (not solved).

        Any of the active set, elastic setting, joint-step rows, path and tolerances may change; a
        new path needs an active set of its own waypoints.
        """
        built = build_refinement(
            self.robot,
            self.fused if fused is None else fused,
            self.base_in_world,
            self.tcp_in_flange,
            self.tolerances if tolerances is None else tolerances,
            axisymmetric=self.axisymmetric,
            weights=self.weights,
            active=self.active if active is None else active,
            elastic_deg=elastic_deg,
            solver_options=self.solver_options,
            derivative_mode=self.derivative_mode,
            singularity_hessian=self.singularity_hessian,
            joint_steps=self.joint_steps if joint_steps is None else joint_steps,
            solver=self.solver_name,
            tool_in_world=self.tool_in_world,
        )
        return replace(built, given_options=self.given_options)

    def step_rows(self) -> Array:
        """Indices ``k·n + j`` of the joint-step rows the problem holds, in row order, (S,)."""
        return step_rows(self.joint_steps, self.n_waypoints, self.dof)

    def joints(self, x: Array) -> Array:
        """The joints (N, n) [rad] in a solution vector ``x``."""
        return np.asarray(x).ravel()[: self.n_waypoints * self.dof].reshape(self.n_waypoints, self.dof)

    def slack_deg(self, x: Array) -> Array:
        """Extra orientation slack per waypoint [deg] in a solution of the elastic problem, (N,)."""
        if self.elastic_deg is None:
            return np.zeros(self.n_waypoints)
        sigma = np.clip(np.asarray(x).ravel()[self.n_waypoints * self.dof :], 0.0, None)
        alpha = math.radians(self.tolerances.orientation_deg)
        return (
            np.degrees(np.arccos(np.clip(math.cos(alpha) - sigma, -1.0, 1.0)))
            - self.tolerances.orientation_deg
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
    "ipopt.mumps_scaling": 0,
    "ipopt.mumps_permuting_scaling": 0,
    "ipopt.mumps_pivot_order": 6,
}
"""IPOPT settings: a warm start from the IK seed, which is usually close to the answer, and a
constraint tolerance well under the 1e-6 m position tolerance of the verification. MUMPS's own
matrix scaling is off: the problem is scaled by construction (metres, radians, cost in deg²), and
the scaling pass costs more than the factorisation at thousands of waypoints (6,400 waypoints:
2.3 s -> 1.1 s, same iterations). MUMPS orders the banded KKT matrix with QAMD (pivot order 6)
rather than letting it choose: its automatic choice took 2.5 times as long at 6,400 waypoints."""


REDUNDANT_IPOPT: dict[str, Any] = {"ipopt.acceptable_iter": 1, "ipopt.acceptable_constr_viol_tol": 1e-10}
"""IPOPT settings added for an arm of more than six joints: stop at the first iteration at the
acceptable level (error 1e-6, constraints met to 1e-10). On the LBR iiwa at 6,400 waypoints the full
solve reaches it three iterations after the coarse seed (error 2.9e-9) and cannot reach 1e-9 (the
dual error stays at 2.4e-9): 15 acceptable iterations in a row took 42 in all, 2 took 30, 1 takes 28."""
HELD_PART_IPOPT = {"ipopt.max_iter": 1000, "ipopt.mu_strategy": "monotone"}
"""A held part on a redundant arm: the monotone barrier (Tesseract's puzzle: 189 iterations, adaptive 320)."""


@dataclass(frozen=True)
class LinearRow:
    """A linearised constraint ``g·((1-f)·q_k + f·q_{k+1}) >= lower`` on the joints [rad].

    Collision avoidance adds one per close pair and outer iteration: the signed distance's
    gradient at the witness points, ``g``, and ``lower = margin - d0 + g·q0``.

    Attributes:
        k: segment start waypoint.
        f: position inside the segment, 0 for the waypoint itself, in [0, 1).
        gradient: shape (n,).
        lower: the bound.
        label: what the row keeps apart (for messages), e.g. ``"link_3 / table"``.
    """

    k: int
    f: float
    gradient: Array
    lower: float
    label: str = ""


@dataclass(frozen=True)
class ActiveSet:
    """The constraints added where they can bind, grown by the solver's outer loop.

    Attributes:
        singular_waypoints: waypoints whose singularity measure is bounded below by the margin.
        singular_segments: points inside segments, as (k, f): the joints ``(1-f)·q_k + f·q_{k+1}``
            get the same bound (how a wrist flip between two waypoints is kept out).
        linear_rows: linearised constraints, e.g. clearance to the cell.
    """

    singular_waypoints: tuple[int, ...] = ()
    singular_segments: tuple[tuple[int, float], ...] = ()
    linear_rows: tuple[LinearRow, ...] = ()

    def union(self, other: ActiveSet) -> ActiveSet:
        """Both sets together (singularity points merged, rows appended)."""
        return ActiveSet(
            tuple(sorted(set(self.singular_waypoints) | set(other.singular_waypoints))),
            tuple(sorted(set(self.singular_segments) | set(other.singular_segments))),
            self.linear_rows + other.linear_rows,
        )


def build_refinement(
    robot: Robot,
    fused: FusedPath,
    base_in_world: Array,
    tcp_in_flange: Array,
    tolerances: Tolerances,
    *,
    axisymmetric: bool = False,
    weights: Weights | None = None,
    active: ActiveSet | None = None,
    elastic_deg: float | None = None,
    solver_options: dict[str, Any] | None = None,
    derivative_mode: str = "assembled",
    singularity_hessian: bool = False,
    joint_steps: str | Sequence[int] = "all",
    solver: str = "ipopt",
    tool_in_world: Array | None = None,
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
        active: singularity bounds and linearised rows beyond the per-waypoint ones.
        elastic_deg: None for the strict problem; otherwise the largest extra orientation slack
            per waypoint [deg]: each cone row gets a slack variable σ_k >= 0 (in cosine units) with
            an L1 penalty, so the answer uses the least slack where it must (repair).
        solver_options: CasADi/IPOPT options overriding :data:`IPOPT_DEFAULTS`.
        derivative_mode: ``"assembled"`` (compiled per-waypoint kernels, derivatives assembled from
            their blocks: :mod:`refine.optimise.derivatives`) or ``"casadi"`` (the per-waypoint
            functions in CasADi's virtual machine, CasADi differentiating the whole problem; slower
            to build and evaluate, kept for comparison).
        singularity_hessian: give IPOPT the singularity rows' second derivatives too (``"assembled"``
            mode; see :func:`refine.optimise.derivatives.derivative_functions`); off by default.
        joint_steps: which joint-step rows ``-step <= q_{k+1,j} - q_{k,j} <= step`` the problem
            holds: ``"all"`` (the complete problem), or the indices ``k·n + j`` of some of them. A
            step far inside its bound does not change the answer, and the rows are most of the
            problem's rows, so :func:`refine.optimise.solve.solve_refinement` solves a problem built
            with only some of them by adding those where the seed or an answer comes near the bound
            (:data:`refine.optimise.rounds.STEP_NEAR`) and solving again until none is left out.
        solver: ``"ipopt"`` (default: the faster by measurement, benchmarks/SPEED.md) or ``"fatrop"``
            (the same problem posed stage by stage for CasADi's structure-exploiting solver:
            :mod:`refine.optimise.stagewise`; at most
            :data:`refine.optimise.stagewise.MAX_FATROP_WAYPOINTS` waypoints). Options for fatrop
            in ``solver_options`` carry the prefix ``"fatrop."``; IPOPT's (``"ipopt."``) are then ignored.
        tool_in_world: T_F_TCP of a stationary tool (``tcp_in_flange`` T_flange_part, ``fused`` in the part).

    Returns:
        The problem with bounds and parameters filled in.
    """
    t0 = time.perf_counter()
    check_solver(solver)
    weights = weights or Weights()
    active = active or ActiveSet()
    N, n = len(fused), robot.nq
    held = interaction_rows(robot, N, math.radians(tolerances.joint_margin_deg), active.linear_rows)
    active = active.union(ActiveSet(linear_rows=tuple(LinearRow(k, 0.0, *r) for k, *r in held)))
    if N < 3:
        raise InputError(f"refinement needs at least 3 waypoints, got {N}")
    if solver == "fatrop":
        check_size(N)
    spec = robot.spec
    lower, upper = joint_bounds(robot, tolerances)
    _check_active(active, N, n)

    # ---- decision variables and parameters
    elastic = elastic_deg is not None
    x = ca.MX.sym("x", N * n + (N if elastic else 0))
    p = ca.MX.sym("p", 12 * N)
    Q = ca.reshape(x[: N * n], n, N)
    P_ref = ca.reshape(p[: 3 * N], 3, N)
    R_demo = ca.reshape(p[3 * N :], 9, N)
    sigma = x[N * n :]

    # ---- path constraints and orientation cost, mapped over the waypoints (compiled kernels)
    if derivative_mode not in ("assembled", "casadi"):
        raise InputError(f"derivative_mode must be 'assembled' or 'casadi', got {derivative_mode!r}")
    chain = (robot, base_in_world, tcp_in_flange)
    kernels = (
        waypoint_kernels(*chain, axisymmetric, tool_in_world)
        if derivative_mode == "assembled"
        else {"waypoint": waypoint_function(*chain, axisymmetric, tool_in_world), "singularity": singularity_function(*chain)}
    )
    path_values = G, cost = kernels["waypoint"].map(N)(Q, P_ref, R_demo)  # f's and g's, for grad_f and jac_g
    if elastic:
        G = ca.vertcat(G[:3, :], G[3, :] + sigma.T)  # cos θ_k + σ_k >= cos α
    rows, lbg_extra, ubg_extra = [ca.vec(G)], [], []
    steps = step_rows(joint_steps, N, n)
    steps_list = steps.tolist()
    if len(steps_list) == n * (N - 1):
        rows.append(ca.vec(Q[:, 1:] - Q[:, :-1]))  # continuity: every joint moves at most `step` per waypoint
    elif steps_list:
        rows.append(x[[i + n for i in steps_list]] - x[steps_list])

    def at(k_idx: list[int], f: list[float]) -> ca.MX:
        Qa, Qb = Q[:, k_idx], Q[:, [min(k + 1, N - 1) for k in k_idx]]
        return Qa + (Qb - Qa) * ca.repmat(ca.DM(f).T, n, 1)

    points = [(k, 0.0) for k in active.singular_waypoints] + list(active.singular_segments)
    if points:
        Qs = at([k for k, _ in points], [f for _, f in points])
        rows.append(ca.vec(kernels["singularity"].map(len(points))(Qs)))
        lbg_extra.append(np.full(len(points), tolerances.singularity_margin))
        ubg_extra.append(np.full(len(points), np.inf))
    if active.linear_rows:
        Ql = at([r.k for r in active.linear_rows], [r.f for r in active.linear_rows])
        Gm = ca.DM(np.array([r.gradient for r in active.linear_rows]).T)  # (n, R)
        rows.append(ca.sum1(Ql * Gm).T)
        lbg_extra.append(np.array([r.lower for r in active.linear_rows]))
        ubg_extra.append(np.full(len(active.linear_rows), np.inf))

    # ---- objective: orientation deviation + joint smoothness per metre of path (+ secondary, slack)
    # The smoothness and mid-range terms are the constant quadratic ½ qᵀKq + bᵀq + c of q = vec(Q).
    h = float(np.mean(np.diff(fused.s)))
    mid, half = 0.5 * (spec.lower + spec.upper), 0.5 * (spec.upper - spec.lower)
    K = smoothness_matrix(n, N, h, weights.velocity, weights.acceleration, weights.mid_range, half) / N
    b = np.tile(-2.0 * weights.mid_range / N * mid / half**2, N)
    c0 = weights.mid_range * N * float(np.sum((mid / half) ** 2)) / N
    qv = x[: N * n]
    coef = orientation_factor(weights.orientation, N)
    f = coef * ca.sum2(cost) + 0.5 * ca.dot(qv, ca.mtimes(K, qv)) + ca.dot(ca.DM(b), qv) + c0
    if elastic:
        f += ELASTIC_WEIGHT * ca.sum1(sigma)
    g = ca.vertcat(*rows)

    # ---- bounds
    alpha = math.radians(tolerances.orientation_deg)
    lbg_path, ubg_path = path_row_bounds(tolerances, N, n, elastic=elastic_deg is not None, steps=steps)
    lbx, ubx = np.tile(lower, N), np.tile(upper, N)
    if elastic_deg is not None:
        sigma_max = math.cos(alpha) - math.cos(min(alpha + math.radians(elastic_deg), math.pi))
        lbx, ubx = np.concatenate([lbx, np.zeros(N)]), np.concatenate([ubx, np.full(N, sigma_max)])
    params = path_params(fused)
    nlp = {"x": x, "p": p, "f": f, "g": g}
    derivatives = (
        {}
        if derivative_mode == "casadi" or solver == "fatrop"
        else derivative_functions(
            kernels,
            N=N, n=n, x=x, p=p, f=f, g=g,  # fmt: skip
            orientation_coef=coef,
            K=K,
            b=b,
            elastic_weight=ELASTIC_WEIGHT if elastic else None,
            singular_points=points,
            linear_rows=[(r.k, r.f, np.asarray(r.gradient, dtype=float)) for r in active.linear_rows],
            singularity_hessian=singularity_hessian,
            step_rows=steps, path_values=path_values,  # fmt: skip
        )
    )
    limit_solver_threads()
    watch = None
    if solver == "fatrop":
        options = dict(solver_options or {})
        built: Any = StagewiseSolver(
            waypoint_function(robot, base_in_world, tcp_in_flange, axisymmetric, tool_in_world),
            singularity_function(robot, base_in_world, tcp_in_flange),
            N=N,
            n=n,
            orientation_coef=coef,
            velocity=weights.velocity,
            acceleration=weights.acceleration,
            mid_range=weights.mid_range,
            h=h,
            mid=mid,
            half=half,
            elastic_weight=ELASTIC_WEIGHT if elastic else None,
            rows=stage_rows(steps, N, n, points, list(active.linear_rows), 4 * N + len(steps_list)),
            n_rows=4 * N + len(steps_list) + len(points) + len(active.linear_rows),
            options=fatrop_options(options),
        )
    else:
        held = HELD_PART_IPOPT if n > 6 and tool_in_world is not None else {}
        options = {**IPOPT_DEFAULTS, **(REDUNDANT_IPOPT if n > 6 else {}), **held, **(solver_options or {})}
        ipopt = {k: v for k, v in options.items() if not k.startswith(FATROP_PREFIX)}
        watch = iteration_watch(x.numel(), g.numel(), p.numel())
        given = {k: v for k, v in derivatives.items() if isinstance(v, ca.Function)}  # nlpsol's options
        built = ca.nlpsol("refine", "ipopt", nlp, {**given, **ipopt, "iteration_callback": watch})
    return RefinementNLP(
        nlp=nlp,
        solver=built,
        solver_options=options,
        given_options=dict(solver_options or {}),
        watch=watch,
        params=params,
        lbx=lbx,
        ubx=ubx,
        lbg=np.concatenate([lbg_path, *lbg_extra]),
        ubg=np.concatenate([ubg_path, *ubg_extra]),
        n_waypoints=N,
        dof=n,
        row_names=ROW_NAMES,
        waypoint=kernels["waypoint"],
        robot=robot,
        base_in_world=np.asarray(base_in_world, dtype=float),
        tcp_in_flange=np.asarray(tcp_in_flange, dtype=float),
        tool_in_world=None if tool_in_world is None else np.asarray(tool_in_world, dtype=float),
        fused=fused,
        tolerances=tolerances,
        axisymmetric=axisymmetric,
        weights=weights,
        active=active,
        elastic_deg=elastic_deg,
        build_time_s=time.perf_counter() - t0,
        derivatives=derivatives,
        derivative_mode=derivative_mode,
        singularity_hessian=singularity_hessian,
        joint_steps="all" if len(steps_list) == n * (N - 1) else tuple(steps_list),
        solver_name=solver,
    )


def step_rows(joint_steps: str | Sequence[int], N: int, n: int) -> Array:
    """The joint-step rows ``joint_steps`` names (``"all"`` or indices ``k·n + j``), sorted, (S,) int."""
    if isinstance(joint_steps, str):
        if joint_steps != "all":
            raise InputError(f"joint_steps must be 'all' or row indices k*n + j, got {joint_steps!r}")
        return np.arange(n * (N - 1))
    rows = np.unique(np.asarray(list(joint_steps), dtype=np.int64))
    if rows.size and not (0 <= rows[0] and rows[-1] < n * (N - 1)):
        raise InputError(
            f"joint-step rows must lie in [0, {n * (N - 1)}) for {N} waypoints of {n} joints, "
            f"got {rows[0]}..{rows[-1]}"
        )
    return rows


def joint_bounds(robot: Robot, tolerances: Tolerances) -> tuple[Array, Array]:
    """The joint limits shrunk by ``tolerances.joint_margin_deg``: lower, upper (n,) [rad]."""
    margin = math.radians(tolerances.joint_margin_deg)
    lower, upper = robot.spec.lower + margin, robot.spec.upper - margin
    if np.any(lower >= upper):
        margin_deg = tolerances.joint_margin_deg
        raise InputError(f"tolerances.joint_margin_deg = {margin_deg} deg leaves no joint range")
    return lower, upper


def path_row_bounds(
    tolerances: Tolerances, N: int, n: int, *, elastic: bool = False, steps: Array | None = None
) -> tuple[Array, Array]:
    """Bounds of the per-waypoint rows (position, cone) and the joint-step rows, in row order.

    ``steps``: the joint-step rows held (:func:`step_rows`); None for all of them.
    """
    lbg_k = np.array([0.0, 0.0, 0.0, math.cos(math.radians(tolerances.orientation_deg))])
    ubg_k = np.array([0.0, 0.0, 0.0, np.inf if elastic else 1.0 + 1e-9])
    step = math.radians(tolerances.joint_step_deg)
    S = n * (N - 1) if steps is None else len(steps)
    return (
        np.concatenate([np.tile(lbg_k, N), np.full(S, -step)]),
        np.concatenate([np.tile(ubg_k, N), np.full(S, step)]),
    )


def path_params(fused: FusedPath) -> Array:
    """The numeric value of the problem's parameters: CAD points, then demonstrated rotations."""
    N = len(fused)
    # CasADi vectorises column-major: Q[:, k] is x[k*n:(k+1)*n] and R_demo[:, k] is R_k column-major.
    return np.concatenate(
        [fused.positions.ravel(), np.transpose(fused.rotations, (0, 2, 1)).reshape(N, 9).ravel()]
    )


SPACING_REUSE_REL = 1e-3
"""A built problem is reused for a new path when the mean waypoint spacing changed by less than this
fraction: the smoothness weights keep the built spacing (a relative change under 0.4 %)."""


def reuse_for(problem: RefinementNLP, fused: FusedPath, tolerances: Tolerances) -> RefinementNLP | None:
    """``problem`` with a new path and tolerances, without rebuilding it; None where it cannot be.

    The solver is kept and only the parameters (CAD points, demonstrated orientations) and the
    bounds (joint margin, cone, joint step) change. That needs the strict problem with no active
    set, the same number of waypoints, and a mean waypoint spacing within
    :data:`SPACING_REUSE_REL` of the built one (the spacing scales the smoothness cost).
    """
    N = problem.n_waypoints
    a = problem.active
    if problem.elastic_deg is not None or a.singular_waypoints or a.singular_segments or a.linear_rows or len(fused) != N:
        return None
    h_old, h_new = float(np.mean(np.diff(problem.fused.s))), float(np.mean(np.diff(fused.s)))
    if abs(h_new / h_old - 1.0) > SPACING_REUSE_REL:
        return None
    lower, upper = joint_bounds(problem.robot, tolerances)
    lbg, ubg = path_row_bounds(tolerances, N, problem.dof, steps=problem.step_rows())
    lbx, ubx = np.tile(lower, N), np.tile(upper, N)
    params = path_params(fused)
    return replace(problem, params=params, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg, fused=fused, tolerances=tolerances, build_time_s=0.0)


ELASTIC_WEIGHT = 1e4
"""Penalty per unit of cone slack (cosine units) in the elastic problem: one degree of slack at a
3° cone (about 1.1e-3) costs about 11, more than the whole orientation cost of a good path, so
slack is used only where the strict problem has no answer (an exact L1 penalty)."""


def _check_active(active: ActiveSet, N: int, n: int) -> None:
    for k in active.singular_waypoints:
        if not 0 <= k < N:
            raise InputError(f"singular waypoint {k} outside [0, {N})")
    for k, f in active.singular_segments:
        if not (0 <= k < N - 1 and 0.0 < f < 1.0):
            raise InputError(f"singular segment point ({k}, {f}) needs 0 <= k < {N - 1} and 0 < f < 1")
    for r in active.linear_rows:
        if not (0 <= r.k < N and 0.0 <= r.f < 1.0 and np.shape(r.gradient) == (n,)):
            raise InputError(f"linear row {r.label!r}: k = {r.k}, f = {r.f}, gradient {np.shape(r.gradient)}")


class ConstraintSource(Protocol):
    """Adds linearised rows where a constraint binds and checks the final path (e.g. collision)."""

    def rows(self, problem: RefinementNLP, q: Array) -> tuple[LinearRow, ...]:
        """New rows for the close pairs of joints ``q`` (N, n) not yet in ``problem.active``."""
        ...

    def violations(self, problem: RefinementNLP, q: Array) -> list[Violation]:
        """Runs of waypoints/segments where the dense check finds the constraint broken."""
        ...

    def clearance(self, q: Array) -> object:
        """The dense check's figures for joints ``q`` (N, n), for reports."""
        ...
