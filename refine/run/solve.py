"""Solving a problem: every pass refined, and the placement repair when asked.

Solving a problem: every pass refined (:func:`solve_problem`), and, when asked and the strict
problem has no answer, the placement repair: the smallest workpiece move found by
:func:`refine.optimise.placement.search_placement`, kept in its support plane and clear of the
cell, and verified by a strict run of the moved problem. The recursion (a moved problem solved
again) stays inside this module.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from refine.control import budget_s, stop_if_out_of_time, timed_out
from refine.optimise.moves import (
    CLEARANCE_ROUNDS,
    ClearanceRow,
    ObjectGap,
    Placement,
    cell_gaps,
    clearance_rows,
    moved_path,
    moved_problem,
    support_plane,
)
from refine.optimise.placement import SLACK_TOLERANCE_DEG, ZERO_MOVE, SearchResult, search_placement
from refine.optimise.problem import RefinementNLP
from refine.optimise.warm import WarmStart
from refine.paths import FusedPath
from refine.problem import Problem
from refine.robot.model import Robot
from refine.robot.registry import robot_for
from refine.run.evaluate import compare_with_truth
from refine.run.placement import PlacementRepair, plane_text
from refine.run.result import PassResult, RunResult
from refine.run.stages import constraint_sources, fused_tracks, log, refine_pass
from refine.settings import PlacementSettings
from refine.stopwatch import Stopwatch


def solve_problem(
    problem: Problem,
    *,
    accept_frame_error: bool = False,
    robot: Robot | None = None,
    fused: FusedPath | None = None,
    nlp: RefinementNLP | None = None,
    q0: np.ndarray | None = None,
    warm: WarmStart | None = None,
    tracks: Sequence[FusedPath] | None = None,
    demo_quality: Any = None,
) -> RunResult:
    """Run every stage up to the timed trajectories, without writing files.

    Args:
        problem: the problem.
        accept_frame_error: warn instead of stopping when the tracker frame looks wrong.
        robot: the robot, when the caller holds it already; None to load ``problem.robot``.
        fused: the first pass's path, when the caller holds it; None to read and fuse the
            problem's files.
        nlp: the first pass's problem, already built (re-solving); None to build it.
        q0: initial joints (N, n) [rad] of the first pass (warm start); None for the IK seed.
        warm: a previous answer of the first pass to re-solve from (:mod:`refine.optimise.warm`),
            and the previous motions to plan the program's from.
        tracks: the path of every track of the CAD file (:func:`refine.run.stages.fused_tracks`),
            when the caller holds them: each is a pass, as when the files are read; its first is
            ``fused`` (which may then be None).
        demo_quality: the demonstration quality gate's figures of ``tracks`` or ``fused``, kept in
            the result as when the files are read.
    """
    watch = Stopwatch()
    if robot is None:
        robot = robot_for(problem.robot)
    watch.lap("load")
    qualities: list[Any] = [] if demo_quality is None else [demo_quality]
    if tracks is not None:
        tracks = list(tracks)
        if fused is not None and fused is not tracks[0]:
            raise ValueError("solve_problem: fused must be the first of tracks")
        fused = tracks[0]
    else:
        tracks = [fused] if fused is not None else []
    if fused is None:
        tracks = fused_tracks(problem, watch, accept_frame_error=accept_frame_error, qualities=qualities)
        fused = tracks[0]
    sources = constraint_sources(problem, robot)
    watch.lap("load")
    first_name = "pass 1" if len(tracks) == 1 else "track 1"
    passes = [refine_pass(problem, robot, fused, watch, first_name, sources=sources, nlp=nlp, q0=q0, warm=warm)]
    for k, track in enumerate(tracks[1:], start=2):  # each further track of the CAD file is a pass
        if timed_out():  # a pass ran out of the call's time limit: no further pass is started
            break
        passes.append(refine_pass(problem, robot, track, watch, f"track {k}", 1, k, sources))
    if problem.multipass is not None and problem.multipass.layers > 1:
        from refine.fuse.passes import generate_passes

        for p in generate_passes(fused, problem.multipass)[1:]:
            if timed_out():
                break
            name = f"layer {p.layer} pass {p.index}"
            passes.append(refine_pass(problem, robot, p.path, watch, name, p.layer, p.index, sources))
    from refine.run.stages import plan_motions

    motions = plan_motions(problem, robot, passes, sources, () if warm is None else warm.motions)
    watch.lap("motions")
    truth = None
    first = passes[0]
    if (
        problem.demonstration is not None
        and problem.demonstration.truth is not None
        and first.trajectory is not None
        and len(tracks) == 1  # a simulator's truth runs along the whole demonstration
    ):
        assert first.timing is not None
        truth = compare_with_truth(
            problem.demonstration.truth,
            first.trajectory,
            first.timing,
            axisymmetric=problem.tool.axisymmetric,
        )
        watch.lap("truth")
    placement = None
    if problem.repair.placement is not None:  # the workpiece move as a second repair (refine.run.placement)
        from refine.run.solve import placement_repair

        placement = placement_repair(problem, robot, passes)
        if all(p.refinement.status != "timeout" for p in passes):
            stop_if_out_of_time("placement")  # the search or its strict run may have run out of it
        watch.add({"placement": sum(placement.timings_s.values())})
    return RunResult(
        problem,
        robot,
        tuple(passes),
        truth,
        watch.times,
        demo_quality=qualities[0] if qualities else None,
        placement=placement,
        motions=motions,
    )


ENLARGE = (1.0, 1.1, 1.25, 1.5, 2.0, 3.0)
"""Factors by which the move found is scaled, in turn, until the strict pipeline verifies it."""


def placement_repair(
    problem: Problem, robot: Robot, passes: tuple[PassResult, ...] | list[PassResult]
) -> PlacementRepair:
    """The placement repair of a run.

    ``not needed`` when every pass is ok as placed, else :func:`repair_by_placement` on the first
    (demonstrated) pass; its verification runs every pass.
    """
    bounds = problem.repair.placement
    assert bounds is not None
    if all(p.refinement.status == "ok" for p in passes):
        return PlacementRepair("not needed", bounds)
    if any(p.refinement.status == "timeout" for p in passes):
        return PlacementRepair(
            "not tried",
            bounds,
            reason="a pass ran out of its time limit ([repair] time_limit_s) before a verdict",
        )
    return repair_by_placement(problem, robot, passes[0])


def verify_placement(problem: Problem, robot: Robot, fused: FusedPath, placement: Placement) -> RunResult:
    """The ordinary strict pipeline on ``problem`` with its workpiece moved by ``placement``.

    The slack repair is off, so the run is ``ok`` only when the strict tolerances hold (clearance
    included, checked densely); ``fused`` is the problem's fused path as placed, moved rigidly (the
    same as fusing the moved problem's files: fusion depends only on the CAD path and the
    demonstration relative to each other).
    """
    from refine.run.solve import solve_problem

    moved = moved_problem(problem, placement.transform)
    strict = dataclasses.replace(moved, repair=dataclasses.replace(moved.repair, enabled=False))
    return solve_problem(strict, robot=robot, fused=moved_path(fused, placement.transform))


def repair_by_placement(problem: Problem, robot: Robot, first: PassResult) -> PlacementRepair:
    """Search the smallest workpiece move that makes the strict problem feasible, and verify it.

    The search is repeated with clearance rows (:func:`clearance_rows`) from its last answer until
    the moved objects keep their margins to the rest of the cell and to the robot, for at most
    :data:`CLEARANCE_ROUNDS` rounds.

    Args:
        problem: the problem as placed, with ``[repair] placement``.
        robot: the robot.
        first: the first pass's result as placed (its path, and its joints as the search's start).

    Returns:
        The outcome; ``status`` is ``ok`` only when the moved problem's strict run is ``ok`` and the
        moved objects keep their margins to the rest of the cell (:func:`cell_gaps`).
    """
    from refine.run.stages import weights_for

    bounds = problem.repair.placement
    assert bounds is not None
    timings: dict[str, float] = {}
    fused = first.fused
    support = support_plane(problem)
    rows: list[ClearanceRow] = []
    found: SearchResult | None = None
    gaps: list[ObjectGap] = []
    blocked: tuple[Placement, list[ObjectGap]] | None = None  # the last answer that broke a margin
    rounds = 0
    t0 = time.perf_counter()
    for rounds in range(1, CLEARANCE_ROUNDS + 1):
        found = search_placement(
            robot,
            fused,
            problem.robot.base_in_world,
            problem.tool.tcp_in_flange,
            problem.tolerances,
            bounds,
            first.refinement.q,
            axisymmetric=problem.tool.axisymmetric,
            weights=weights_for(problem, robot),
            time_limit_s=budget_s(problem.repair.time_limit_s),
            support=support,
            rows=tuple(rows),
            start=found,
        )
        log.info(
            "placement search round %d: %s after %d iterations, shift %.4f m, turn %.3f deg, %d clearance rows",
            rounds,
            found.solver_status,
            found.iterations,
            found.placement.distance_m,
            found.placement.angle_deg,
            len(rows),
        )
        if not found.success:
            break
        gaps, more = clearance_rows(problem, robot, found.placement, found.q, support)
        if all(g.kept for g in gaps):
            break
        blocked = (found.placement, [g for g in gaps if not g.kept])
        rows += more
    assert found is not None
    timings["search"] = time.perf_counter() - t0
    common = {
        "bounds": bounds,
        "solver_status": found.solver_status,
        "iterations": found.iterations,
        "support": support,
        "rounds": rounds,
    }
    # the gaps measured at the last answer found; a failed search's point is no answer
    broken = (
        sorted((g for g in gaps if not g.kept), key=lambda g: g.distance_m - g.margin_m)
        if found.success
        else []
    )
    near = sorted({f"{a!r} / {b!r}" for a, b in (r.pair for r in rows)})
    if not found.success or broken:
        short = ""
        if not rows and found.slack_deg.size and found.slack_deg.max() > SLACK_TOLERANCE_DEG:
            worst = int(np.argmax(found.slack_deg))
            s = fused.s
            short = (
                f": the best move (shift {found.placement.distance_m:.4f} m, turn "
                f"{found.placement.angle_deg:.3f} deg) still leaves the orientation up to "
                f"{found.slack_deg.max():.2f} deg beyond the cone, at waypoint {worst} (s = {s[worst]:.3f} m)"
            )
        solver = (
            ""
            if found.solver_status == "Solve_Succeeded"
            else f" (placement search: IPOPT {found.solver_status})"
        )
        keeps = "the strict tolerances"
        if rows:
            keeps += f" and the clearance of the moved objects ({', '.join(near)})"
        if broken:
            short += f": after {rounds} clearance rounds the best move still puts " + "; ".join(
                g.describe() for g in broken[:3]
            )
        elif blocked is not None:
            p, why = blocked
            short += (
                f"; the move that keeps the strict tolerances without them (shift {p.distance_m * 1e3:.1f} mm, "
                f"turn {p.angle_deg:.2f} deg) puts " + "; ".join(g.describe() for g in why[:3])
            )
        plane = "" if bounds.free == "all" else f" in the support plane ({plane_text(support)})"
        return PlacementRepair(
            "infeasible",
            reason=(
                f"no workpiece move within {bounds.translate_m:g} m and {bounds.rotate_deg:g} deg{plane} "
                f"found that keeps {keeps}{solver}{short}"
            ),
            timings_s=timings,
            **common,
        )
    base_norm = found.placement.norm(bounds)
    if base_norm < ZERO_MOVE:
        return PlacementRepair(
            "infeasible",
            reason=(
                "the placement search meets the strict tolerances without moving the workpiece, so what "
                "fails as placed is what it leaves out: the robot's clearance between waypoints (or an IK "
                "branch the strict solve did not find); no workpiece move is proposed (see the diagnosis)"
            ),
            timings_s=timings,
            **common,
        )
    t0 = time.perf_counter()
    result = None
    tried = []
    for factor in ENLARGE:
        if factor > 1.0 and not _within(found.placement.scaled(factor), bounds):
            break
        candidate = found.placement.scaled(factor)
        collided = [g for g in cell_gaps(problem, robot, candidate, support) if not g.kept]
        if collided:  # one object put into (or too near) another: refused before any run
            tried.append(f"x{factor:g}: refused, it puts {'; '.join(g.describe() for g in collided)}")
            continue
        result = verify_placement(problem, robot, fused, candidate)
        tried.append(f"x{factor:g}: {result.status}")
        if result.status == "ok":
            timings["verify"] = time.perf_counter() - t0
            return PlacementRepair(
                "ok",
                placement=candidate,
                scale=factor,
                result=result,
                timings_s=timings,
                **common,
                **_moved(problem, candidate),
            )
    timings["verify"] = time.perf_counter() - t0
    why = ""
    if result is not None:
        failed = "; ".join(m.reason for m in getattr(result, "failed_motions", ()))
        why = f": {failed or result.refinement.reason}"
    return PlacementRepair(
        "infeasible",
        placement=found.placement,
        reason=(
            f"the move found (shift {found.placement.distance_m:.4f} m, turn {found.placement.angle_deg:.3f} deg) "
            f"and its enlargements within the bounds are not verified ({'; '.join(tried)}; the placement "
            f"search checks the robot's clearance at the waypoints only){why}"
        ),
        result=result,
        timings_s=timings,
        **common,
        **_moved(problem, found.placement),
    )


def _moved(problem: Problem, placement: Placement) -> dict[str, Any]:
    """The moved frames (``cad_in_world``, ``source_in_world``) and the names of the objects moved."""
    moved = moved_problem(problem, placement.transform)
    return {
        "moved_frames": {
            "cad_in_world": moved.frames.cad_in_world,
            "source_in_world": moved.frames.source_in_world,
        },
        "moved_objects": tuple(o.name for o in problem.cell if o.workpiece),
    }


def _within(placement: Placement, bounds: PlacementSettings) -> bool:
    return (
        placement.distance_m <= bounds.translate_m + 1e-12 and placement.angle_deg <= bounds.rotate_deg + 1e-9
    )
