"""Air moves: a joint move checked against the cell, and where it collides a path planned around it.

:func:`plan_air` first checks the direct joint-interpolated move from start to goal (joint limits,
clearance with the run's margins along the continuous motion). Where that fails on clearance, a
collision-free joint-space path is planned with OMPL's RRT-Connect (bidirectional rapidly-exploring
random trees) and shortened by OMPL's path simplifier (shortcutting and vertex reduction). A
state is valid when refine's collision model finds every pair at least :data:`INFLATION_M` beyond
its margin (OMPL checks the motions between states at a fixed joint-space resolution, so the
extra distance covers what lies between its checks). The planner's random numbers come from a
fixed seed, so a run plans the same via points every time, and each attempt is limited in time.

The path found is written as via points, and verified again as a whole with the continuous
clearance check (:class:`refine.plan.verify.MotionChecker`): only a path whose every segment keeps
every margin along its continuous motion is called ``ok``. A path that fails that check is planned
again with twice the extra distance, up to :data:`ATTEMPTS` times.

**An air move planned again** (``previous``, the same move of an earlier run, e.g. after the part
moved a few millimetres) first checks the direct move as a move planned afresh (a previous direct
move's check proves it where its bounds, carried to the new ends, serve:
:func:`refine.plan.recheck.recheck`; else the dense check). Where that still collides, the previous via points are tried before the planner: with the new start and goal in
place of the old, when the previous check's distance bounds, less the motion of the start and the
goal since (:class:`refine.plan.verify.Known`), still prove every margin at both (they moved less
than the previous clearance allows), and only when the whole path then passes the check above
(first the motion bound's proof alone, :func:`refine.collision.margins_proved`, then limits and
the continuous clearance check; both start from the previous check's bounds less the motion since,
which at the via points is the cell's alone). Otherwise, or when the previous move was not
planned around the cell, the planner runs as for a move planned afresh. Nothing is kept unchecked.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence

import numpy as np

from refine.plan.motion import Motion, MotionIssue, joint_move_times
from refine.plan.verify import Known, MotionChecker
from refine.types import Array

INFLATION_M = 0.01
"""Extra clearance beyond the margin a planner state must keep at the first attempt [m]."""

ATTEMPTS = 3
"""Plans tried (each with twice the previous extra clearance) before an air move is given up."""

RESOLUTION_RAD = 0.02
"""Joint-space distance between OMPL's validity checks along a motion [rad]."""

SEED = 20260101
"""The planner's random seed (a run plans the same via points every time)."""

TIME_LIMIT_S = 5.0
"""Wall time one RRT-Connect attempt may take [s]."""

log = logging.getLogger(__name__)


def plan_air(
    checker: MotionChecker,
    kind: str,
    name: str,
    q_start: Array,
    q_goal: Array,
    *,
    velocity: Array,
    acceleration: Array,
    time_limit_s: float = TIME_LIMIT_S,
    seed: int = SEED,
    previous: Motion | None = None,
) -> Motion:
    """An air move from ``q_start`` to ``q_goal`` [rad]: the direct joint move, or via points around the cell.

    Args:
        checker: what the motion is checked against.
        kind: ``"home"``, ``"link"`` or ``"return"``.
        name: the motion's name.
        q_start: start joints [rad], shape (n,).
        q_goal: goal joints [rad], shape (n,).
        velocity: joint speed limits for the duration [rad/s], shape (n,).
        acceleration: joint acceleration limits for the duration [rad/s^2], shape (n,).
        time_limit_s: wall time of one planner attempt [s].
        seed: the planner's random seed.
        previous: the same move of an earlier run, to start from (module notes); None to plan afresh.
    """
    t0 = time.perf_counter()
    q_start, q_goal = np.asarray(q_start, dtype=float), np.asarray(q_goal, dtype=float)
    direct = np.array([q_start, q_goal])
    again = None if previous is None or len(previous.q) != 2 else previous.check  # the direct move's check
    issues, check = _verify(checker, direct, again=again)
    planner, rows, direct_issues = "joint move", direct, ()
    if issues and all(i.cause in ("collision", "self-collision") for i in issues):
        inside = [_end_issue(checker, q, f) for q, f in ((q_start, 0.0), (q_goal, 1.0))]
        inside = [e for e in inside if e is not None]
        direct_issues = tuple(issues)
        if inside:
            issues = inside  # an end inside the margin: nothing can be planned from it
        else:
            planner = "RRT-Connect"
            found = None
            kept, known = _kept(checker, previous, q_start, q_goal)
            # the motion bound's proof first: a kept path it cannot prove clear is planned again
            # (without the dense sampling the check gives a broken segment)
            if kept is not None and checker.proved(kept, known):
                again, again_check = _verify(checker, kept, known)
                if not again:
                    rows, issues, check = kept, [], again_check
                    log.info("%s: the previous via points kept, verified again", name)
            for attempt in range(ATTEMPTS if issues else 0):
                found = _rrt_connect(
                    checker, q_start, q_goal, INFLATION_M * 2**attempt, seed + attempt, time_limit_s
                )
                if found is None:
                    continue
                again, again_check = _verify(checker, found)
                if not again:
                    rows, issues, check = found, [], again_check
                    break
            if issues:
                c, d, pair = checker.clearance_at(q_start)
                issues = list(direct_issues) + [
                    MotionIssue(
                        "no path found",
                        f"RRT-Connect found no joint path keeping every margin in {ATTEMPTS} attempts of at most "
                        f"{time_limit_s:g} s (extra clearance {INFLATION_M * 1e3:g} mm doubled each attempt)",
                        objects=direct_issues[0].objects,
                        fraction=direct_issues[0].fraction,
                        tcp_m=direct_issues[0].tcp_m,
                        distance_m=direct_issues[0].distance_m,
                    )
                ]
    poses = checker.kin.poses(rows)
    times = joint_move_times(rows, velocity, acceleration)
    return Motion(
        kind=kind,
        name=name,
        q=rows,
        start_pose=poses[0],
        end_pose=poses[-1],
        duration_s=float(np.sum(times)),
        move_s=tuple(float(t) for t in times),
        planner=planner,
        planner_time_s=time.perf_counter() - t0,
        status="failed" if issues else "ok",
        min_distance_m=None if check is None else check.min_distance_m,
        min_clearance_m=None if check is None else check.min_clearance_m,
        closest=("", "") if check is None else _worst_pair(check),
        min_joint_margin_rad=float(checker.joint_margin(rows).min()),
        issues=tuple(issues),
        direct_issues=direct_issues if planner == "RRT-Connect" else (),
        check=check,
    )


def _worst_pair(check) -> tuple[str, str]:  # noqa: ANN001 - PathClearance
    if not len(check.segment_clearance_m):
        return ("", "")
    return tuple(check.segment_pair[int(np.argmin(check.segment_clearance_m))])  # type: ignore[return-value]


def _verify(
    checker: MotionChecker, rows: Array, known: Sequence[Known | None] = (), again: object = None
) -> tuple[list[MotionIssue], object]:
    """Joint limits (hard: an air move may start at a home near a limit) and continuous clearance.

    ``again``: the earlier check of the same rows moved a little (:meth:`MotionChecker.clearance_again`), or None.
    """
    issues = checker.limit_issues(rows, 0.0)
    check = checker.clearance(rows, known) if again is None else checker.clearance_again(rows, again)
    return issues + checker.clearance_issues(rows, check), check


def _kept(
    checker: MotionChecker, previous: Motion | None, q_start: Array, q_goal: Array
) -> tuple[Array | None, list[Known | None]]:
    """``previous``'s via points between ``q_start`` and ``q_goal`` [rad] (K, n), when they may serve.

    When ``previous`` is an ``ok`` move planned around the cell and its check's bounds, carried to
    the new start and goal, prove every margin there; else None. Also the bounds its check
    proved, for the new path's rows.
    """
    if previous is None or not previous.ok or previous.planner != "RRT-Connect" or checker.model is None:
        return None, []
    rows = np.array(previous.q, dtype=float)
    if rows.ndim != 2 or rows.shape[1] != len(q_start) or len(rows) < 3:
        return None, []
    rows[0], rows[-1] = q_start, q_goal
    ends = [0, len(rows) - 1]
    bounds, _ = checker.carried(rows[ends], [Known.of(previous.check, ends, (0, 1))])
    if bounds is None or np.min(bounds - checker.model.pair_margins) < 0.0:
        return None, []
    return rows, [Known.of(previous.check, range(len(rows)), range(len(rows)))]


def _end_issue(checker: MotionChecker, q: Array, fraction: float) -> MotionIssue | None:
    """The start or goal itself closer than its margin (no planner can leave or reach it)."""
    c, d, pair = checker.clearance_at(q)
    if c >= -1e-4:
        return None
    which = "start" if fraction == 0.0 else "end"
    return MotionIssue(
        "collision",
        f"the move's {which} itself has {pair[0]} vs {pair[1]} at {d * 1e3:.1f} mm ({-c * 1e3:.1f} mm inside "
        "the margin)",
        objects=tuple(sorted(pair)),
        fraction=fraction,
        tcp_m=checker.kin.pose(q)[:3, 3],
        distance_m=d,
    )


def _rrt_connect(
    checker: MotionChecker, q_start: Array, q_goal: Array, inflation_m: float, seed: int, time_limit_s: float
) -> Array | None:
    """RRT-Connect from ``q_start`` to ``q_goal`` in joint space, simplified; rows (K, n) [rad] or None.

    A state is valid when every pair keeps its margin plus ``inflation_m`` (less where the start or
    goal itself is closer: at most half their own extra clearance is asked there).
    """
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    n = len(q_start)
    margin = math.radians(checker.tolerances.joint_margin_deg)
    low = np.minimum(np.minimum(q_start, q_goal), np.maximum(checker.lower + margin, -2.0 * math.pi))
    high = np.maximum(np.maximum(q_start, q_goal), np.minimum(checker.upper - margin, 2.0 * math.pi))
    ends = min(checker.clearance_at(q_start)[0], checker.clearance_at(q_goal)[0])
    need = max(0.0, min(inflation_m, 0.5 * ends))
    ou.noOutputHandler()  # OMPL's console messages; the outcome is reported by the caller
    try:
        ou.RNG.setSeed(seed)
        space = ob.RealVectorStateSpace(n)
        bounds = ob.RealVectorBounds(n)
        for j in range(n):
            bounds.setLow(j, float(low[j]))
            bounds.setHigh(j, float(high[j]))
        space.setBounds(bounds)
        si = ob.SpaceInformation(space)

        def valid(state) -> bool:  # noqa: ANN001 - an OMPL state
            q = np.array([state[j] for j in range(n)])
            return checker.clearance_at(q)[0] >= need

        si.setStateValidityChecker(valid)
        si.setStateValidityCheckingResolution(RESOLUTION_RAD / si.getMaximumExtent())
        si.setup()
        start, goal = space.allocState(), space.allocState()
        for j in range(n):
            start[j], goal[j] = float(q_start[j]), float(q_goal[j])
        pdef = ob.ProblemDefinition(si)
        pdef.setStartAndGoalStates(start, goal)
        planner = og.RRTConnect(si)
        planner.setProblemDefinition(pdef)
        planner.setup()
        planner.solve(float(time_limit_s))
        if not pdef.hasExactSolution():
            return None
        path = pdef.getSolutionPath()
        og.PathSimplifier(si).simplifyMax(path)
        rows = np.array([[path.getState(k)[j] for j in range(n)] for k in range(path.getStateCount())])
    finally:
        ou.restorePreviousOutputHandler()
    rows[0], rows[-1] = q_start, q_goal
    return rows
