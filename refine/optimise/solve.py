"""Solve a built refinement NLP with its solver (IPOPT, or fatrop), verify the answer, and repair it when it is infeasible.

The loop: chain IK for a seed (reporting points out of reach at once), solve, verify with plain
Pinocchio (:mod:`refine.optimise.verify`), add the constraints that only bind in places (the
singularity bound at waypoints and inside segments near a singularity, linearised clearance rows
from a :class:`ConstraintSource` such as the collision model) and solve again until the verified
path needs nothing more. When the strict problem has no answer and repair is on, the elastic problem
finds the smallest extra orientation slack per waypoint that makes it feasible (an exact L1
penalty), and the segments that needed slack are reported with the constraint that forced it.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from refine.errors import SolverError
from refine.optimise.diagnosis import Diagnoser, Finding, reach_gap, reach_tilts, segments
from refine.optimise.problem import ActiveSet, LinearRow, RefinementNLP
from refine.optimise.seed import alternative_seeds, ik_chain, reach_shortfall, start_candidates
from refine.optimise.verify import (
    PathCheck,
    Violation,
    check_path,
    runs,
    segment_singularity,
    singularity_measures,
)
from refine.robot.kinematics import CONVERGED, TcpKinematics, solve_ik_batch

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

REACH_TOLERANCE_M = 1e-3
"""A CAD point the best position-only IK misses by more than this is reported out of reach [m]."""

SEED_INSET_M = 0.05
"""The IK seed tilts a pose out of reach until its wrist centre is this far inside the arm's range
[m]: off the stretched elbow, which is a singularity."""

TILT_TOLERANCE_DEG = 0.1
"""A reach tilt counts as beyond the cone (or the cone + slack) by more than this [deg] (the tilt is
searched in 0.1 deg steps)."""

WARM_MU_INIT = 1e-4
"""IPOPT's initial barrier parameter when a round starts from the last round's answer and
multipliers (its default, 0.1, pushes a warm start off the constraints it had found active)."""

FATROP_REPAIR_MU_INIT = 1e-6
"""fatrop's initial barrier parameter in a round after the first and in the repair (see
:data:`refine.optimise.stagewise.FATROP_DEFAULTS`)."""

FATROP_FAILED = "not solved (return flag"
"""How fatrop's status begins when it stopped without converging (:mod:`refine.optimise.stagewise`)."""

FATROP_HINT = (
    "fatrop stopped without converging in at least one solve, so this verdict may be the solver's, not "
    "the problem's: fatrop has no restoration phase and can fail from a start that breaks a row, "
    "where IPOPT succeeds; run again with [optimise] solver = 'ipopt'"
)
"""Appended to the reason of an infeasible refinement in which fatrop failed to converge."""

SOLVER_LABELS = {"ipopt": "IPOPT", "fatrop": "fatrop"}
"""How messages name each solver of :data:`refine.settings.SOLVERS`."""

ELASTIC_ONLY = "not run (the elastic problem answers it: another IK branch, after the first failed)"
"""Why the strict solve is skipped on the IK branches tried after the first: with repair on, the
elastic problem's answer without slack is the strict problem's, so one solve does for both."""

BRANCH_CANDIDATES = 2
"""Other IK branches chained per branch tried when the first gives no answer; the best are tried
(:func:`_rank_chains`)."""

MAX_OUTER_ITERATIONS = 8

STEP_NEAR = 0.5
"""A problem built with only some joint-step rows gets the row of every joint step larger than
this fraction of the bound, in the seed and in each answer; an answer with a step that large
outside the rows is solved again with them. Steps under the bound do not bind, so the answer is the
complete problem's."""
"""Rounds of solve -> verify -> add constraints before giving up on adding more."""


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


@dataclass(frozen=True)
class Repair:
    """A segment the strict tolerances could not hold, and what it took.

    Attributes:
        index_start, index_end: first and last waypoint (inclusive).
        s_start_m, s_end_m: their arc lengths [m].
        slack_deg: the largest extra orientation slack used inside [deg].
        reason: the binding constraint: ``"joint limit (joint 5)"``, ``"singularity"``,
            ``"collision"``, ``"joint wrap (joint 6)"`` or ``"orientation"`` when none is active.
        objects: the cell objects or links involved (collision), else empty.
    """

    index_start: int
    index_end: int
    s_start_m: float
    s_end_m: float
    slack_deg: float
    reason: str
    objects: tuple[str, ...] = ()

    def describe(self) -> str:
        """One line for messages and reports."""
        objs = f" ({', '.join(self.objects)})" if self.objects else ""
        return (
            f"waypoints {self.index_start}-{self.index_end} (s = {self.s_start_m:.3f}-{self.s_end_m:.3f} m): "
            f"{self.slack_deg:.2f} deg extra orientation slack, {self.reason}{objs}"
        )


@dataclass(frozen=True)
class Refinement:
    """The outcome of a refinement.

    Attributes:
        status: ``"ok"``, ``"repaired"`` (feasible with extra orientation slack) or ``"infeasible"``.
        reason: empty when ok; otherwise why, naming segments, constraint and figures.
        q: joints per waypoint [rad], shape (N, n).
        q_seed: the IK seed the solver started from [rad], shape (N, n).
        check: the numeric verification of ``q``.
        solver_status: the solver's return status (of the last solve).
        iterations: the solver's iterations, summed over all solves (with a redundant arm's coarse
            seed's, :func:`coarse_seed`).
        outer_iterations: solve -> verify rounds.
        active: the constraints added by the outer loop in the last round.
        slack_deg: extra orientation slack used per waypoint [deg], (N,) (zeros unless repaired).
        repairs: the repaired segments (derived from ``diagnosis``).
        timings_s: ``seed``, ``solve``, ``verify``, ``build`` (rebuilds) wall times [s]; a
            :class:`StageTimes`, whose ``cpu`` holds the process CPU time of the same stages.
        diagnosis: every segment that needed slack or has no answer, with its measured causes
            (:mod:`refine.optimise.diagnosis`); empty when ok.
        time_limit_reached: the time budget ran out before a verdict (status ``infeasible``).
    """

    status: str
    reason: str
    q: Array
    q_seed: Array
    check: PathCheck
    solver_status: str
    iterations: int
    outer_iterations: int = 1
    active: ActiveSet = field(default_factory=ActiveSet)
    slack_deg: Array = field(default_factory=lambda: np.zeros(0))
    repairs: tuple[Repair, ...] = ()
    timings_s: dict[str, float] = field(default_factory=dict)
    diagnosis: tuple[Finding, ...] = ()
    time_limit_reached: bool = False


# ---- seed ----------------------------------------------------------------------------------------


def _targets(problem: RefinementNLP) -> Array:
    targets = np.zeros((problem.n_waypoints, 4, 4))
    targets[:, :3, :3] = problem.fused.rotations
    targets[:, :3, 3] = problem.fused.positions
    targets[:, 3, 3] = 1.0
    return targets


def _kin(problem: RefinementNLP) -> TcpKinematics:
    return TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange)


def _bounds(problem: RefinementNLP) -> tuple[Array, Array]:
    n = problem.dof
    return problem.lbx[:n], problem.ubx[:n]


def initial_guess(problem: RefinementNLP, home: Array | None = None, rotations: Array | None = None) -> Array:
    """IK seed (N, n) [rad] chained along the path, from the best of several first-waypoint starts.

    ``rotations`` (N, 3, 3) replaces the demonstrated tool orientations as IK targets (e.g. tilted
    into reach, :func:`refine.optimise.diagnosis.reach_tilts`).
    """
    lower, upper = _bounds(problem)
    starts = start_candidates(lower, upper, home)
    targets = _targets(problem)
    if rotations is not None:
        targets[:, :3, :3] = rotations
    qs, _ = ik_chain(_kin(problem), targets, lower, upper, starts, prefer_first=home is not None)
    return qs


COARSE_SEED_MIN_PATH = 40
"""A redundant arm's seed on a path of at least this many waypoints comes from a coarse refinement
(:func:`coarse_seed`). Shorter paths keep the chained seed: there the coarse copy holds half the
waypoints or more and saves little or nothing (generated iiwa wave without mid-range cost, CPU of
the solve [s], chained / coarse seed: 30 waypoints 0.141 / 0.104, 36: 0.129 / 0.128, 40: 0.136 /
0.105; with the pipeline's mid-range cost 30: 0.047 / 0.050)."""
COARSE_SEED_WAYPOINTS = 16
"""The coarse refinement holds every :data:`COARSE_SEED_STRIDE`-th waypoint, and at least this many.
Without a mid-range cost its solve needs about as many iterations as the full one from the chained
seed (120-220 on the LBR iiwa, whatever the length), so the fewer waypoints it has the cheaper the
seed, down to where it misses the path's shape and the full solve's iterations grow again: 6-10
coarse waypoints leave the full solve 6 to 155 iterations, and on the bends of the TIG seam (237
waypoints, mid-range cost) 12 leave it 11 where 16-40 leave 5 (CPU 0.095 s against 0.077-0.080
s). On the wave without mid-range cost, chained / 40 / 16 coarse waypoints: 100 waypoints 0.257 /
- / 0.124 s, 120: - / 0.175 / 0.121 s, 400: - / 0.198 / 0.163 s."""
COARSE_SEED_STRIDE = 40
"""Waypoints per coarse step on long paths: wider steps leave the interpolated seed too far from the
answer (LBR iiwa, 6,400 waypoints: 40 coarse waypoints, 164 apart, 175 iterations; 160, 40 apart, 21)."""


def coarse_seed(problem: RefinementNLP, q_seed: Array) -> tuple[Array | None, int]:
    """A redundant arm's seed from the refinement of a coarse copy of the path, and the iterations it took.

    Returns the seed (N, n) [rad], None where there is none, and the solver iterations spent on the
    coarse copy (0 when none was solved), which count in the refinement's iterations.

    The chained IK leaves a redundant arm's elbow where the mid-range pull puts it, waypoint by
    waypoint, while the refined path puts it where the whole path's joint motion is least: IPOPT
    then needs 150-300 iterations to move it there (LBR iiwa without a mid-range cost). The same
    refinement over evenly spaced waypoints (every :data:`COARSE_SEED_STRIDE`-th, at least
    :data:`COARSE_SEED_WAYPOINTS`; seeded with the chained joints there; the joint-step bound
    scaled by the spacing, at most 360 deg; no clearance rows) finds that elbow cheaply. Its
    joints, interpolated along the arc length and projected onto every waypoint's exact pose by
    least-squares IK without null-space drift, start the full solve next to its answer. None for
    a non-redundant arm, a path shorter than :data:`COARSE_SEED_MIN_PATH`, a coarse refinement
    that is not ``ok`` or a projection that misses a pose.
    """
    from refine.paths import FusedPath

    N = problem.n_waypoints
    if problem.dof <= 6 or N < COARSE_SEED_MIN_PATH:
        return None, 0
    count = max(COARSE_SEED_WAYPOINTS, N // COARSE_SEED_STRIDE)
    idx = np.unique(np.linspace(0, N - 1, count).round().astype(int))
    f = problem.fused
    coarse_path = FusedPath(
        f.s[idx], f.positions[idx], f.rotations[idx], f.speed[idx], f.t_demo[idx], f.residual[idx]
    )
    spread = float(np.diff(idx).max())  # waypoint steps per coarse step
    step = min(problem.tolerances.joint_step_deg * spread, 360.0)  # 360 deg: no bound at all
    tolerances = replace(problem.tolerances, joint_step_deg=step)
    coarse = problem.rebuilt(fused=coarse_path, tolerances=tolerances, active=ActiveSet(), joint_steps=())
    answer = solve_refinement(coarse, q_seed[idx])
    if answer.status != "ok":
        log.info(
            "coarse seed: the %d-waypoint refinement is %s; the chained IK seed stays",
            len(idx),
            answer.status,
        )
        return None, answer.iterations
    log.info("coarse seed: %d waypoints refined in %d solver iterations", len(idx), answer.iterations)
    q = np.column_stack([np.interp(f.s, f.s[idx], answer.q[:, j]) for j in range(problem.dof)])
    lower, upper = _bounds(problem)
    q, err = solve_ik_batch(_kin(problem), _targets(problem), q, lower, upper, nullspace_gain=0.0)
    if not np.all(err < 10.0 * CONVERGED):
        log.info(
            "coarse seed: the projection misses %d poses; the chained IK seed stays",
            int((err >= 10.0 * CONVERGED).sum()),
        )
        return None, answer.iterations
    return q, answer.iterations


def _out_of_reach(problem: RefinementNLP, q_seed: Array, home: Array | None) -> list[Violation]:
    """Runs of waypoints whose CAD point no configuration inside the limits reaches."""
    kin = _kin(problem)
    missed = np.linalg.norm(kin.poses(q_seed)[:, :3, 3] - problem.fused.positions, axis=1) > REACH_TOLERANCE_M
    if not missed.any():
        return []
    lower, upper = _bounds(problem)
    shortfall = np.zeros(problem.n_waypoints)
    # points the wrist centre cannot bring into the arm's range at any orientation are out of reach
    # for certain (refine.optimise.diagnosis.ReachModel); IK measures the rest
    certain = reach_gap(kin, problem.fused.positions, problem.tolerances.joint_margin_deg)
    sure = missed & (certain > REACH_TOLERANCE_M)  # a lower bound: the wrist joints' limits ignored
    shortfall[sure] = certain[sure]
    idx = np.flatnonzero(missed & ~sure)
    if idx.size:
        starts = start_candidates(lower, upper, home)
        shortfall[idx] = reach_shortfall(kin, _targets(problem)[idx], lower, upper, starts)
    s = problem.fused.s
    return [
        Violation(
            a,
            b,
            float(s[a]),
            float(s[b]),
            "out of reach",
            float(shortfall[a : b + 1].max()),
            "m",
            REACH_TOLERANCE_M,
        )
        for a, b in runs(shortfall > REACH_TOLERANCE_M)
    ]


# ---- the outer loop ------------------------------------------------------------------------------


def _new_singular(kin: TcpKinematics, q: Array, margin: float, active: ActiveSet) -> ActiveSet:
    """Waypoints and segment points near the singularity not yet bounded in ``active``."""
    if margin <= 0:
        return ActiveSet()
    w, _ = singularity_measures(kin, q, smallest=False)
    near = np.flatnonzero(w < 1.5 * margin)
    widened = np.unique(np.clip(near[:, None] + np.arange(-2, 3), 0, len(q) - 1)) if near.size else near
    waypoints = tuple(sorted(set(widened.tolist()) - set(active.singular_waypoints)))
    w_between, frac = segment_singularity(kin, q)
    points = {(int(k), float(frac[k])) for k in np.flatnonzero(w_between < 1.5 * margin)}
    return ActiveSet(waypoints, tuple(sorted(points - set(active.singular_segments))))


def _new_steps(problem: RefinementNLP, q: Array) -> tuple[int, ...]:
    """Joint-step rows ``k·n + j`` near their bound in ``q`` (N, n) that ``problem`` does not hold."""
    if problem.joint_steps == "all":
        return ()
    step = math.radians(problem.tolerances.joint_step_deg)
    near = np.flatnonzero(np.abs(np.diff(q, axis=0)).ravel() > min(STEP_NEAR, 1.0) * step)
    return tuple(sorted(set(near.tolist()) - set(problem.joint_steps)))


def _with_steps(problem: RefinementNLP, more: tuple[int, ...]) -> tuple[int, ...] | None:
    """The joint-step rows of ``problem`` and ``more``, or None when nothing is added."""
    return tuple(sorted(set(problem.joint_steps) | set(more))) if more else None


def _singular_around(mask: Array, widen: int = 2) -> ActiveSet:
    """Singularity bounds at the waypoints of ``mask`` (N,) widened by ``widen``, and mid-segment."""
    N = len(mask)
    idx = np.flatnonzero(mask)
    idx = np.unique(np.clip(idx[:, None] + np.arange(-widen, widen + 1), 0, N - 1))
    return ActiveSet(tuple(int(k) for k in idx), tuple((int(k), 0.5) for k in idx if k < N - 1))


class StageTimes(dict):
    """Wall time per stage [s] (the dict itself), with the process CPU time of the same stages in ``cpu``."""

    def __init__(self) -> None:
        super().__init__()
        self.cpu: dict[str, float] = {}

    @staticmethod
    def clock() -> tuple[float, float]:
        """The wall and CPU clocks now."""
        return time.perf_counter(), time.process_time()


def _add(timings: dict[str, float], key: str, start: tuple[float, float]) -> None:
    """Add the wall time since ``start`` (:meth:`StageTimes.clock`) to stage ``key`` of ``timings``.

    The CPU time goes to ``timings.cpu`` where ``timings`` is a :class:`StageTimes`.
    """
    timings[key] = timings.get(key, 0.0) + time.perf_counter() - start[0]
    if isinstance(timings, StageTimes):
        timings.cpu[key] = timings.cpu.get(key, 0.0) + time.process_time() - start[1]


class TimeLimitReached(Exception):
    """The refinement's wall-time budget ran out before a verdict (internal to this module)."""


WARM_START_OPTIONS = {"ipopt.mu_init": WARM_MU_INIT, "fatrop.mu_init": FATROP_REPAIR_MU_INIT}
"""Solver options of a round that starts from the last round's answer (and, for IPOPT, multipliers)."""

ELASTIC_OPTIONS = {"ipopt.mu_strategy": "monotone", "fatrop.mu_init": FATROP_REPAIR_MU_INIT}
"""Solver options of the elastic (repair) problem (IPOPT's reasons below). Its start is far from the answer (the seed needs
several degrees more slack than the repair) and near the stretched elbow or a wrist singularity;
the adaptive barrier strategy drops the barrier to 1e-6 within ten iterations there and then crawls
(300 iterations without convergence on 2 of 20 noisy copies of ``reach_tilt``), while Fiacco-McCormick's
monotone decrease converges in about 40 (the same answer where both converge)."""


def _row_keys(problem: RefinementNLP) -> list[tuple]:
    """A name for every constraint row of ``problem``, stable when the active set grows."""
    N, a = problem.n_waypoints, problem.active
    return (
        [("path", i) for i in range(4 * N)]
        + [("step", i) for i in problem.step_rows().tolist()]
        + [("singular", k, 0.0) for k in a.singular_waypoints]
        + [("singular", k, f) for k, f in a.singular_segments]
        + [("row", r.k, r.f, r.label) for r in a.linear_rows]
    )


@dataclass
class _Loop:
    problem: RefinementNLP
    timings: dict[str, float]
    iterations: int = 0
    outer: int = 0
    max_rounds: int = MAX_OUTER_ITERATIONS
    deadline: float = math.inf
    multipliers: tuple[dict[tuple, float], Array] | None = None
    base_options: dict | None = None

    def solve(self, x0: Array, warm: bool = False) -> tuple[Array, dict]:
        """Solve from ``x0``; ``warm``: with the last solve's multipliers, row by row."""
        start = StageTimes.clock()
        if start[0] >= self.deadline:
            raise TimeLimitReached
        p = self.problem
        extra = {}
        if warm and self.multipliers is not None:
            lam_g, lam_x = self.multipliers
            extra["lam_g0"] = np.array([lam_g.get(key, 0.0) for key in _row_keys(p)])
            if len(lam_x) == len(p.lbx):
                extra["lam_x0"] = lam_x
        name = SOLVER_LABELS[p.solver_name]
        try:
            sol = p.solver(x0=x0, p=p.params, lbx=p.lbx, ubx=p.ubx, lbg=p.lbg, ubg=p.ubg, **extra)
        except RuntimeError as e:
            raise SolverError(f"{name} failed to run: {e}") from e
        stats = {**p.solver.stats(), "solver": name}
        self.multipliers = (
            dict(zip(_row_keys(p), np.asarray(sol["lam_g"]).ravel().tolist(), strict=True)),
            np.asarray(sol["lam_x"]).ravel(),
        )
        status = str(stats.get("return_status", "unknown"))
        if status in {"Invalid_Option", "Invalid_Problem_Definition", "Insufficient_Memory"}:
            raise SolverError(f"{name} could not solve the refinement: {status}")
        if status == "Maximum_WallTime_Exceeded" or time.perf_counter() >= self.deadline:
            _add(self.timings, "solve", start)
            raise TimeLimitReached
        self.iterations += int(stats.get("iter_count", 0))
        _add(self.timings, "solve", start)
        return np.asarray(sol["x"]).ravel(), stats

    def rebuild(self, warm: bool = False, **changes) -> None:
        """Rebuild with ``changes``; ``warm``: for a solve that starts at the last answer."""
        start = StageTimes.clock()
        if self.base_options is None:
            self.base_options = dict(self.problem.solver_options)
        options = dict(self.base_options)
        if changes.get("elastic_deg") is not None:
            options.update(ELASTIC_OPTIONS)
        if warm:
            options.update(WARM_START_OPTIONS)
        self.problem = replace(self.problem, solver_options=options).rebuilt(**changes)
        _add(self.timings, "build", start)


def _run_rounds(
    loop: _Loop, x0: Array, sources: tuple[ConstraintSource, ...]
) -> tuple[Array, dict, PathCheck, Array]:
    """Solve, verify and grow the active set until nothing more is needed (or the rounds run out)."""
    kin = _kin(loop.problem)
    margin = loop.problem.tolerances.singularity_margin
    warm = False
    while True:
        loop.outer += 1
        x, stats = loop.solve(x0, warm)
        p = loop.problem
        q, slack = p.joints(x), p.slack_deg(x)
        start = StageTimes.clock()
        check = check_path(
            kin, q, p.fused, p.tolerances, p.axisymmetric, slack if p.elastic_deg is not None else None
        )
        extra = [v for src in sources for v in src.violations(p, q)]
        if extra:
            check = replace(check, violations=check.violations + tuple(extra))
        _add(loop.timings, "verify", start)
        if not stats.get("success", False) or loop.outer >= loop.max_rounds:
            return x, stats, check, slack
        start = StageTimes.clock()  # finding what the next round adds is the outer loop's solving
        more = _new_singular(kin, q, margin, p.active)
        rows = tuple(r for src in sources for r in src.rows(p, q))
        steps = _new_steps(p, q)
        _add(loop.timings, "solve", start)
        if not (more.singular_waypoints or more.singular_segments or rows or steps):
            return x, stats, check, slack
        log.info(
            "outer round %d: +%d singular waypoints, +%d segment points, %d linear rows, +%d joint steps",
            loop.outer,
            len(more.singular_waypoints),
            len(more.singular_segments),
            len(rows),
            len(steps),
        )
        # rows accumulate, a pair's fresh linearisation at the same point replacing its old one:
        # replacing whole rounds lets the path swing between two sides of an obstacle
        grown = p.active.union(ActiveSet(more.singular_waypoints, more.singular_segments))
        active = ActiveSet(
            grown.singular_waypoints, grown.singular_segments, _merge_rows(p.active.linear_rows, rows)
        )
        loop.rebuild(warm=True, active=active, elastic_deg=p.elastic_deg, joint_steps=_with_steps(p, steps))
        x0, warm = (x if p.elastic_deg is not None else q.ravel()), True


def solve_refinement(
    problem: RefinementNLP,
    q0: Array | None = None,
    *,
    home: Array | None = None,
    sources: tuple[ConstraintSource, ...] = (),
    repair_max_slack_deg: float | None = None,
    max_rounds: int = MAX_OUTER_ITERATIONS,
    max_branches: int = 3,
    time_limit_s: float | None = None,
) -> Refinement:
    """Solve ``problem`` with its solver from ``q0`` (or the IK seed), verify, and repair if asked.

    When the answer from the seed's IK branch is infeasible (even repaired), the first waypoint's
    other IK branches are chained and tried in turn, up to ``max_branches`` in all.

    Args:
        problem: from :func:`refine.optimise.problem.build_refinement` (strict).
        q0: initial joints (N, n) [rad]; None to chain IK from ``home`` and other starts.
        home: preferred first configuration [rad] for the IK seed.
        sources: constraint sources (collision) adding linearised rows and dense checks.
        repair_max_slack_deg: when the strict problem is infeasible, the largest extra orientation
            slack [deg] the elastic problem may use; None for no repair.
        max_rounds: solve -> verify -> add constraints rounds at most.
        max_branches: IK branches of the first waypoint to try (only when ``q0`` is None).
        time_limit_s: wall-time budget [s] of the solves; when it runs out before any verdict the
            result is ``infeasible`` with ``time_limit_reached`` set and a reason saying so; when it
            runs out while other IK branches are tried, the first branch's verdict stands. Build
            the problem with ``ipopt.max_wall_time`` at most this so one solve cannot overrun it.

    Raises:
        SolverError: the solver itself failed (not an infeasibility): the message names its status.
    """
    timings = StageTimes()
    start = StageTimes.clock()
    t0 = start[0]
    # the tilt each demonstrated pose needs for the wrist centre to be in reach: a seed tilted into
    # reach (off the stretched elbow) converges where the demonstrated one cannot, and a tilt beyond
    # the cone (or cone + slack) proves the strict (or repaired) problem infeasible without a solve
    tilts, _ = reach_tilts(kin := _kin(problem), problem.fused, problem.tolerances, problem.axisymmetric)
    certain = _tilt_is_a_bound(problem)
    rotations = None
    stretched = np.zeros(problem.n_waypoints, dtype=bool)
    if tilts.max() > 0.0:
        inset, rotations = reach_tilts(
            kin, problem.fused, problem.tolerances, problem.axisymmetric, SEED_INSET_M
        )
        stretched = inset > 0.0
    q_seed = initial_guess(problem, home, rotations) if q0 is None else np.asarray(q0, dtype=float)
    unreachable = _out_of_reach(problem, q_seed, home)
    _add(timings, "seed", start)
    cone = problem.tolerances.orientation_deg
    slack_max = repair_max_slack_deg if repair_max_slack_deg is not None else 0.0
    beyond = certain & (tilts > cone + slack_max + TILT_TOLERANCE_DEG)
    if not unreachable and beyond.any():
        t1, c1 = StageTimes.clock()
        findings = _findings(problem, sources, "infeasible", q_seed, beyond)
        _add(timings, "diagnose", (t1, c1))
        reason = (
            f"no repair within {slack_max:g} deg of extra slack: "
            if slack_max > 0
            else "out of reach as demonstrated: "
        ) + "; ".join(f.describe() for f in findings)
        log.info("refinement infeasible before solving: %s", reason)
        return _unsolved(
            problem, q_seed, reason, "not run (orientation out of reach beyond the slack)", timings, findings
        )
    skip_strict = (
        "not run (the demonstrated orientation is out of reach beyond the cone)"
        if (certain & (tilts > cone + TILT_TOLERANCE_DEG)).any()
        else ""
    )
    if unreachable:
        check = check_path(kin, q_seed, problem.fused, problem.tolerances, problem.axisymmetric)
        t0, c0 = StageTimes.clock()
        mask = np.zeros(problem.n_waypoints, dtype=bool)
        for v in unreachable:
            mask[v.index_start : v.index_end + 1] = True
        findings = _findings(problem, sources, "infeasible", q_seed, mask)
        _add(timings, "diagnose", (t0, c0))
        reason = "; ".join([v.describe() for v in unreachable] + [f.describe() for f in findings])
        log.info("refinement infeasible before solving: %s", reason)
        return Refinement(
            "infeasible",
            reason,
            q_seed,
            q_seed,
            replace(check, violations=tuple(unreachable) + check.violations),
            "not run (out of reach)",
            0,
            0,
            timings_s=timings,
            diagnosis=findings,
        )

    coarse_iterations = 0
    if q0 is None and rotations is None and not skip_strict:
        seeding = StageTimes.clock()
        smooth, coarse_iterations = coarse_seed(problem, q_seed)
        q_seed = q_seed if smooth is None else smooth
        _add(timings, "seed", seeding)

    deadline = t0 + time_limit_s if time_limit_s is not None else math.inf

    repairing = repair_max_slack_deg is not None and repair_max_slack_deg > 0

    def attempt_from(seed: Array, skip: str = skip_strict) -> Refinement:
        return _attempt(
            problem,
            seed,
            sources,
            repair_max_slack_deg,
            max_rounds,
            timings,
            deadline,
            skip,
            stretched,
        )

    try:
        attempt = attempt_from(q_seed)
    except TimeLimitReached:
        return _timed_out(problem, q_seed, time_limit_s, timings)
    if attempt.status == "infeasible" and q0 is None and max_branches > 1 and time.perf_counter() < deadline:
        # the first IK branch may be the wrong one: try the first waypoint's other branches
        start = StageTimes.clock()
        lower, upper = _bounds(problem)
        # chained towards the same poses as the first seed (tilted into reach), more than will be
        # tried, and tried best chain first
        targets = _targets(problem)
        if rotations is not None:
            targets[:, :3, :3] = rotations
        chains = alternative_seeds(
            kin,
            targets,
            lower,
            upper,
            start_candidates(lower, upper, home),
            skip=q_seed,
            count=BRANCH_CANDIDATES * (max_branches - 1),
        )
        others = _rank_chains(kin, targets, lower, upper, chains)[: max_branches - 1]
        _add(timings, "seed", start)
        for k, q_other in enumerate(others, start=2):
            try:
                # the elastic problem alone: its answer without slack is the strict one, and the
                # strict solve already failed on the first branch
                other = attempt_from(q_other, skip_strict or (ELASTIC_ONLY if repairing else ""))
            except TimeLimitReached:
                note = f"IK branches after the first {k - 1} not tried: time limit {time_limit_s:g} s reached"
                attempt = replace(attempt, reason=f"{attempt.reason} ({note})")
                break
            log.info("IK branch %d: %s", k, other.status)
            if other.status != "infeasible":
                attempt = replace(other, iterations=attempt.iterations + other.iterations)
                break
        else:
            tried = f"{1 + len(others)} IK branch(es) tried"
            attempt = replace(attempt, reason=f"{attempt.reason} ({tried})" if others else attempt.reason)
    attempt = replace(attempt, iterations=attempt.iterations + coarse_iterations)
    if (
        attempt.status == "infeasible"
        and problem.solver_name == "fatrop"
        and FATROP_FAILED in attempt.solver_status
    ):
        attempt = replace(attempt, reason=f"{attempt.reason} ({FATROP_HINT})")
    log.info(
        "refinement %s after %d solver iterations in %d rounds",
        attempt.status,
        attempt.iterations,
        attempt.outer_iterations,
    )
    return attempt


def _attempt(
    problem: RefinementNLP,
    q_seed: Array,
    sources: tuple[ConstraintSource, ...],
    repair_max_slack_deg: float | None,
    max_rounds: int,
    timings: dict[str, float],
    deadline: float = math.inf,
    skip_strict: str = "",
    stretched: Array | None = None,
) -> Refinement:
    """Strict solve from ``q_seed``, then the elastic repair when the strict problem fails.

    With ``skip_strict`` (why the strict solve is not run: it is known to be infeasible, or the
    elastic problem answers it) the repair starts at once; an elastic answer that verifies without
    any slack is then ``ok``.
    ``stretched`` (N,) marks the waypoints whose wrist centre the demonstration puts near or beyond
    the end of the arm's range: the singularity bound holds there from the first solve (at and
    between the waypoints), so the elbow cannot pass through its stretched singularity while the
    solver pulls the wrist in.
    """
    kin = _kin(problem)
    loop = _Loop(problem, timings, max_rounds=max_rounds, deadline=deadline)
    start = StageTimes.clock()  # the constraints the seed shows to be needed count as seeding
    initial = _new_singular(kin, q_seed, problem.tolerances.singularity_margin, problem.active)
    if stretched is not None and stretched.any() and problem.tolerances.singularity_margin > 0:
        initial = initial.union(_singular_around(stretched))
    seed_rows = tuple(r for src in sources for r in src.rows(problem, q_seed))
    seed_steps = _new_steps(problem, q_seed)
    _add(timings, "seed", start)
    if initial.singular_waypoints or initial.singular_segments or seed_rows or seed_steps:
        loop.rebuild(
            active=problem.active.union(
                ActiveSet(initial.singular_waypoints, initial.singular_segments, seed_rows)
            ),
            joint_steps=_with_steps(problem, seed_steps),
        )
    if skip_strict:
        q = q_seed
        slack = np.zeros(problem.n_waypoints)
        check = check_path(kin, q, problem.fused, problem.tolerances, problem.axisymmetric)
        stats = {"return_status": skip_strict}
        strict_reason = skip_strict
    else:
        x, stats, check, slack = _run_rounds(loop, q_seed.ravel(), sources)
        q = loop.problem.joints(x)
        strict_reason = _describe(check, stats)
    status = "ok" if check.ok and not skip_strict else "infeasible"
    repairs: tuple[Repair, ...] = ()

    if status == "infeasible" and repair_max_slack_deg is not None and repair_max_slack_deg > 0:
        loop.rebuild(active=loop.problem.active, elastic_deg=repair_max_slack_deg)
        # start from the seed (on the path, orientation off only where the limits clamped it), with
        # each slack at what that start needs, so IPOPT begins feasible wherever it can
        q_start = q_seed
        clock = StageTimes.clock()
        start = check_path(kin, q_start, problem.fused, problem.tolerances, problem.axisymmetric)
        cos_needed = math.cos(math.radians(problem.tolerances.orientation_deg)) - np.cos(
            np.radians(start.orientation_deviation_deg)
        )
        sigma0 = np.clip(cos_needed, 0.0, loop.problem.ubx[problem.n_waypoints * problem.dof :])
        _add(timings, "solve", clock)
        x, stats, check, slack = _run_rounds(loop, np.concatenate([q_start.ravel(), sigma0]), sources)
        q = loop.problem.joints(x)
        if check.ok:
            status = "repaired"
            if skip_strict == ELASTIC_ONLY and slack.max() <= 1e-3:
                # the elastic problem found an answer without slack: ok if it verifies strictly
                strict = check_path(kin, q, problem.fused, problem.tolerances, problem.axisymmetric)
                extra = tuple(v for src in sources for v in src.violations(loop.problem, q))
                if strict.ok and not extra:
                    status, check, slack = "ok", strict, np.zeros(problem.n_waypoints)
        else:
            log.info("repair within %.1f deg failed: %s", repair_max_slack_deg, _describe(check, stats))
            note = f"no repair within {repair_max_slack_deg:g} deg of extra slack"
            stats = {
                **stats,
                "return_status": f"{stats.get('return_status')}; {note} (strict: {strict_reason})",
            }

    solver_status = str(stats.get("return_status", "unknown"))
    if status == "ok" and not stats.get("success", False):
        log.warning(
            "%s returned %s but the verified path meets every tolerance",
            SOLVER_LABELS[problem.solver_name],
            solver_status,
        )
    t0, c0 = StageTimes.clock()
    findings: tuple[Finding, ...] = ()
    if status == "repaired":
        findings = _findings(problem, sources, status, q, slack > 1e-3, slack)
        repairs = tuple(
            Repair(
                f.index_start,
                f.index_end,
                f.s_start_m,
                f.s_end_m,
                float(f.slack_deg or 0.0),
                f.cause.label,
                f.cause.objects,
            )
            for f in findings
        )
    elif status == "infeasible":
        mask = np.zeros(problem.n_waypoints, dtype=bool)
        for v in check.violations:
            mask[v.index_start : v.index_end + 1] = True
        findings = _findings(problem, sources, status, q, mask)
    _add(timings, "diagnose", (t0, c0))
    reason = (
        ""
        if status == "ok"
        else "; ".join(f.describe() for f in findings) + f" ({_describe(check, stats)})"
        if status == "infeasible"
        else "; ".join(f.describe() for f in findings)
    )
    return Refinement(
        status=status,
        reason=reason,
        q=q,
        q_seed=q_seed,
        check=check,
        solver_status=solver_status,
        iterations=loop.iterations,
        outer_iterations=loop.outer,
        active=loop.problem.active,
        slack_deg=slack if status == "repaired" else np.zeros(problem.n_waypoints),
        repairs=repairs,
        timings_s=timings,
        diagnosis=findings,
    )


def _rank_chains(
    kin: TcpKinematics, targets: Array, lower: Array, upper: Array, chains: list[Array]
) -> list[Array]:
    """IK chains (N, n) best first: those on the targets (N, 4, 4) everywhere, then by joint margin.

    A chain reaches every target within :data:`REACH_TOLERANCE_M` (position [m] plus rotation
    [rad]) or it does not; among either kind, the larger the smallest distance to a joint limit
    along the whole path, the better. A branch judged by its first pose alone can run into a joint
    limit further on, and its repair then needs the orientation it cannot reach there.
    """

    def key(qs: Array) -> tuple[bool, float]:
        poses = kin.poses(qs)
        position = np.linalg.norm(poses[:, :3, 3] - targets[:, :3, 3], axis=1)
        cos = (np.einsum("kij,kij->k", poses[:, :3, :3], targets[:, :3, :3]) - 1.0) / 2.0
        error = position + np.arccos(np.clip(cos, -1.0, 1.0))
        margin = float(np.min(np.minimum(qs - lower, upper - qs)))
        return bool(error.max() > REACH_TOLERANCE_M), -margin

    return sorted(chains, key=key)


def _tilt_is_a_bound(problem: RefinementNLP) -> bool:
    """Whether the reach tilt bounds the orientation deviation from below for this tool.

    Always for a tool whose whole orientation counts; for an axisymmetric tool only when the wrist
    centre lies on the tool axis (the free spin about the axis then cannot move it).
    """
    if not problem.axisymmetric:
        return True
    from refine.optimise.diagnosis import _reach_model

    reach = _reach_model(problem.robot, math.radians(problem.tolerances.joint_margin_deg))
    v = (np.linalg.inv(problem.tcp_in_flange) @ np.append(reach.point_in_flange, 1.0))[:3]
    return bool(np.linalg.norm(np.cross(v, [0.0, 0.0, 1.0])) <= 1e-6 * max(np.linalg.norm(v), 1e-9))


def _timed_out(
    problem: RefinementNLP, q_seed: Array, time_limit_s: float | None, timings: dict[str, float]
) -> Refinement:
    """The answer when the time budget ran out before any verdict: infeasible, saying so."""
    reason = (
        f"time limit of {time_limit_s:g} s ([repair] time_limit_s) reached before a verdict: neither an "
        "answer nor a proof of infeasibility was found; raise the limit to let the solver finish"
    )
    log.warning("refinement stopped: %s", reason)
    return _unsolved(problem, q_seed, reason, "time limit reached", timings, time_limit_reached=True)


def _unsolved(
    problem: RefinementNLP,
    q_seed: Array,
    reason: str,
    solver_status: str,
    timings: dict[str, float],
    findings: tuple[Finding, ...] = (),
    time_limit_reached: bool = False,
) -> Refinement:
    """An infeasible answer without a solve: the seed, checked, with the reason and diagnosis."""
    check = check_path(_kin(problem), q_seed, problem.fused, problem.tolerances, problem.axisymmetric)
    return Refinement(
        "infeasible",
        reason,
        q_seed,
        q_seed,
        check,
        solver_status,
        0,
        0,
        slack_deg=np.zeros(problem.n_waypoints),
        timings_s=timings,
        diagnosis=findings,
        time_limit_reached=time_limit_reached,
    )


def _merge_rows(old: tuple[LinearRow, ...], new: tuple[LinearRow, ...]) -> tuple[LinearRow, ...]:
    merged = {(r.k, r.f, r.label): r for r in old}
    merged.update({(r.k, r.f, r.label): r for r in new})
    return tuple(merged.values())


def _describe(check: PathCheck, stats: dict) -> str:
    text = f"{stats.get('solver', 'IPOPT')}: {stats.get('return_status', 'unknown')}; " + "; ".join(
        v.describe() for v in check.violations[:10]
    )
    if len(check.violations) > 10:
        text += f"; and {len(check.violations) - 10} more segments"
    return text


def _findings(
    problem: RefinementNLP,
    sources: tuple[ConstraintSource, ...],
    status: str,
    q: Array,
    mask: Array,
    slack: Array | None = None,
) -> tuple[Finding, ...]:
    """The diagnosis of every run of ``mask`` (waypoints that needed slack or break a tolerance)."""
    model = next((getattr(src, "model", None) for src in sources if hasattr(src, "model")), None)
    diagnoser = Diagnoser(_kin(problem), problem.fused, problem.tolerances, problem.axisymmetric, model)
    return tuple(
        diagnoser.segment(status, a, b, q, None if slack is None else float(np.max(slack[a : b + 1])))
        for a, b in segments(mask)
    )
