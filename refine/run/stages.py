"""The whole pipeline for one problem: read, fuse, refine, time, verify, write.

:func:`run` is what ``refine run PROBLEM`` calls. Each stage is a call into its own module (see the
diagram in the README); this module only strings them together, times them and collects the
figures for ``result.json``. A multi-pass weld runs the refine and timing stages once per pass.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any

import numpy as np

from refine.control import budget_s
from refine.errors import InputError
from refine.optimise.problem import ConstraintSource, RefinementNLP, Weights, build_refinement
from refine.optimise.solve import solve_refinement
from refine.optimise.warm import WarmStart
from refine.paths import FusedPath, Trajectory
from refine.problem import Problem
from refine.robot.model import Robot
from refine.run.clearance_kinds import kind_minima
from refine.run.result import EXECUTABLE, PassResult
from refine.stopwatch import Stopwatch
from refine.timing import time_parameterise

log = logging.getLogger(__name__)


REDUNDANT_MID_RANGE_WEIGHT = 2.0
"""Default ``[optimise] mid_range_weight`` for arms with more than 6 joints: on the LBR iiwa it
keeps every joint >= 18 deg from its limits on the test paths while costing < 0.05 deg of
orientation, and the solution moves by < 0.2 deg of joint angle when the demo is perturbed."""


def fused_path(
    problem: Problem,
    watch: Stopwatch | None = None,
    *,
    accept_frame_error: bool = False,
    qualities: list[Any] | None = None,
) -> FusedPath:
    """The fused path of ``problem``: CAD path + cleaned, aligned demonstration, or a PathML path.

    ``accept_frame_error`` turns the quality gate's stop on a tracker frame that looks wrong into a
    warning (see :mod:`refine.demo.quality`); the gate's figures are appended to ``qualities``.
    A CAD file with several tracks gives its first track's path (:func:`fused_tracks` gives all).
    """
    return fused_tracks(problem, watch, accept_frame_error=accept_frame_error, qualities=qualities)[0]


def fused_tracks(
    problem: Problem,
    watch: Stopwatch | None = None,
    *,
    accept_frame_error: bool = False,
    qualities: list[Any] | None = None,
) -> list[FusedPath]:
    """The fused path of every track of ``problem`` (one unless its CAD file has several).

    Several tracks are fused with the demonstration as one path, joined in the program's order
    (:mod:`refine.fuse.tracks`); see :func:`fused_path` for the arguments.
    """
    watch = watch or Stopwatch()
    if problem.cad is None:
        raise InputError(f"problem {problem.name!r} has no [cad] file: its path must be given in memory")
    if problem.cad.format == "pathml":
        from refine.cad.pathml_ import fused_from_pathml

        track = problem.cad.track
        fused = fused_from_pathml(
            problem.cad.file,
            problem.cad.spacing_m,
            track=track,
            reverse=problem.cad.reverse,
            start_near=problem.cad.start_near,
            chord_tolerance_m=problem.cad.chord_tolerance_m,
        )
        watch.lap("cad")
        return [fused]
    if problem.cad.format == "toolpath":  # positions and tool axes: the orientations without a demonstration
        from refine.cad.toolpath import fused_from_toolpath

        fused = fused_from_toolpath(
            problem.cad.file,
            problem.cad.units,
            problem.cad.spacing_m,
            float(problem.cad.speed_m_s),
            problem.frames.cad_in_world,
            reverse=problem.cad.reverse,
        )
        watch.lap("cad")
        return [fused]
    from refine.cad import read_cad_tracks
    from refine.demo import clean_demonstration, read_tracker_log
    from refine.demo.quality import gate_dropouts
    from refine.fuse.frame_check import gate_frame
    from refine.fuse.fusion import fuse

    assert problem.demonstration is not None  # Problem checks this
    tracks = read_cad_tracks(problem.cad, problem.frames.cad_in_world)
    check_dense_steps(problem, sum(c.length for c in tracks))
    if len(tracks) > 1:
        from refine.fuse.tracks import join_tracks

        if problem.multipass is not None and problem.multipass.layers > 1:
            raise InputError(
                f"cad.file {problem.cad.file.name!r} has {len(tracks)} tracks and [multipass] has "
                f"{problem.multipass.layers} layers: a multi-pass weld needs one track (choose it with cad.track)"
            )
        if problem.repair.placement is not None:
            raise InputError(
                f"cad.file {problem.cad.file.name!r} has {len(tracks)} tracks: [repair] placement moves one "
                "track's workpiece; choose the track with cad.track"
            )
        cad, ranges = join_tracks(tracks, problem.cad.spacing_m)
    else:
        cad = tracks[0]
    watch.lap("cad")
    raw, quality = gate_dropouts(read_tracker_log(problem.demonstration))
    demo = clean_demonstration(raw, problem.demonstration)
    watch.lap("demo")
    frames = problem.frames
    fused = fuse(cad, demo, frames.source_in_world, problem.tool.sensor_in_tcp)
    quality = gate_frame(
        quality, demo, fused, frames.source_in_world, problem.tool.sensor_in_tcp, accept=accept_frame_error
    )
    watch.lap("fuse")
    if qualities is not None:
        qualities.append(quality)
    if len(tracks) > 1:
        from refine.fuse.tracks import split_tracks

        return split_tracks(fused, tracks, ranges)
    return [fused]


def check_dense_steps(problem: Problem, length_m: float) -> None:
    """Refuse a dense collision check of more than ``MAX_CHECK_STEPS`` poses before solving."""
    from refine.settings import MAX_CHECK_STEPS

    c = problem.collision
    if c.enabled and (problem.cell or problem.tool.collision) and length_m / c.check_step_m > MAX_CHECK_STEPS:
        raise InputError(
            f"{problem.source or 'problem'}: collision.check_step_m = {c.check_step_m:g} m on a {length_m:.3f} m "
            f"path means more than {length_m / c.check_step_m:.0f} collision checks (limit {MAX_CHECK_STEPS}); "
            f"use at least {length_m / MAX_CHECK_STEPS:.2g} m"
        )


def refinement_for(problem: Problem, robot: Robot, fused: FusedPath) -> RefinementNLP:
    """The refinement NLP of one pass: the problem's placement, tool, tolerances, weights and time limit."""
    return build_refinement(
        robot,
        fused,
        problem.robot.base_in_world,
        problem.tool.tcp_in_flange,
        problem.tolerances,
        axisymmetric=problem.tool.axisymmetric,
        weights=weights_for(problem, robot),
        solver_options={"ipopt.max_wall_time": budget_s(problem.repair.time_limit_s)},
        joint_steps=(),  # the solve adds the joint-step rows that come near their bound
        solver=problem.optimise.solver,
        tool_in_world=problem.tool.tcp_in_world,
    )


def weights_for(problem: Problem, robot: Robot) -> Weights:
    """Cost weights from ``[optimise]``; a redundant arm gets a mid-range cost by default."""
    o = problem.optimise
    mid = (
        o.mid_range_weight
        if o.mid_range_weight is not None
        else (REDUNDANT_MID_RANGE_WEIGHT if robot.nq > 6 else 0.0)
    )
    return Weights(o.orientation_weight, o.velocity_weight, o.acceleration_weight, mid)


def constraint_sources(problem: Problem, robot: Robot) -> tuple[ConstraintSource, ...]:
    """Collision constraints when the problem has a cell or tool shapes and collision is on."""
    if not problem.collision.enabled or not (problem.cell or problem.tool.collision):
        return ()
    from refine.optimise.clearance import ClearanceSource

    return (ClearanceSource.for_problem(problem, robot),)


def refine_pass(
    problem: Problem,
    robot: Robot,
    fused: FusedPath,
    watch: Stopwatch,
    name: str = "pass 1",
    layer: int = 1,
    index: int = 1,
    sources: tuple[ConstraintSource, ...] = (),
    *,
    nlp: RefinementNLP | None = None,
    q0: np.ndarray | None = None,
    warm: WarmStart | None = None,
) -> PassResult:
    """Refine, verify and time one pass.

    Args:
        problem: the problem's settings.
        robot: the loaded robot.
        fused: the pass's path.
        watch: collects the stage times.
        name: the pass's name.
        layer: its 1-based layer.
        index: its 1-based number in the layer.
        sources: collision constraint sources.
        nlp: a problem already built for this pass (re-solving); None to build it.
        q0: initial joints (N, n) [rad] instead of the IK seed (warm start); None for the seed.
        warm: a previous answer to re-solve from (:mod:`refine.optimise.warm`), instead of ``q0``.
    """
    if nlp is None:
        nlp = refinement_for(problem, robot, fused)
    watch.lap("build")
    home = (
        None
        if problem.robot.home_deg is None
        else np.radians(robot.spec.from_controller(problem.robot.home_deg))
    )
    lines = line_source(problem, robot)
    if warm is not None and warm.line is not None:
        lines.previous = (warm.q, warm.line)  # the previous line's bows start this line's IK
    refinement = solve_refinement(
        nlp,
        q0,
        home=home,
        sources=sources + (lines,),
        repair_max_slack_deg=problem.repair.max_slack_deg if problem.repair.enabled else None,
        time_limit_s=budget_s(problem.repair.time_limit_s),
        warm=warm,
        **({"max_rounds": problem.collision.max_outer_iterations} if sources else {}),
    )
    watch.lap("refine")
    del watch.times["refine"]  # reported by stage: seed, solve, verify (and rebuilds under build)
    watch.add(refinement.timings_s)
    timing = trajectory = None
    if refinement.status in EXECUTABLE:
        spec = robot.spec
        accel = spec.acceleration
        if problem.robot.joint_acceleration_deg_s2 is not None:
            accel = np.radians(problem.robot.joint_acceleration_deg_s2)
        timing = time_parameterise(
            fused.s, refinement.q, fused.speed, spec.velocity * problem.robot.velocity_scale, accel
        )
        trajectory = Trajectory(
            t=timing.t,
            s=fused.s,
            q=refinement.q,
            positions_ref=fused.positions,
            poses=refinement.check.poses,
            rotations_demo=fused.rotations,
            speed=timing.speed,
        )
        watch.lap("timing")
    clearance = kinds = None
    for source in sources:
        clearance = source.clearance(refinement.q)  # the dense check's figures, for the report
        kinds = kind_minima(source.model, refinement.q, clearance)  # the cell and self pairs apart
    line = None
    if refinement.status in EXECUTABLE:
        line = controller_line_check(problem, robot, refinement.q, fused.s, sources, lines)
        watch.lap("line_check")
        if not line.ok:
            found = "; ".join(v.describe() for v in line.violations)
            refinement = replace(
                refinement,
                status="infeasible",
                reason=(f"{refinement.reason}; " if refinement.reason else "") + found,
                check=replace(refinement.check, violations=refinement.check.violations + line.violations),
            )
            timing = trajectory = None
    circular = None
    if (
        trajectory is not None
        and problem.output.circular_moves
        and not problem.tool.stationary  # a held part keeps straight moves
        and set(program_formats(problem, robot)) & {"rapid", "krl", "urscript"}
    ):
        arcs, circular = circular_moves(problem, robot, trajectory, fused, sources)
        trajectory = replace(trajectory, arcs=arcs)
        watch.lap("arc_check")
    return PassResult(
        name,
        layer,
        index,
        fused,
        refinement,
        timing,
        trajectory,
        clearance,
        nlp,
        line,
        clearance_kinds=kinds,
        circular=circular,
    )


def circular_moves(
    problem: Problem, robot: Robot, trajectory: Trajectory, fused: Any, sources: tuple[ConstraintSource, ...]
) -> tuple[tuple[Any, ...], tuple[Any, ...]]:
    """The CAD's arcs as circular moves that pass their checks in every controller's model.

    The pieces (:func:`refine.optimise.controller_arc.arc_pieces`) are checked as each circular
    move's controller runs it (:func:`refine.optimise.controller_arc.check_circular_moves`, both
    orientation models), with the problem's collision model where it has one; a piece that fails
    in either keeps its straight moves (logged), as does one inside a run the programs hand to the
    controller's wrist handling (:func:`wrist_segments`).

    Returns:
        The pieces that pass (``Trajectory.arcs``) and every check, per model in turn.
    """
    from refine.collision.check import check_path_clearance, margins_proved
    from refine.export.motion import segment_speeds
    from refine.optimise.controller_arc import MODELS, arc_pieces, check_circular_moves
    from refine.robot.kinematics import TcpKinematics

    kin = TcpKinematics(robot, problem.robot.base_in_world, problem.tool.tcp_in_flange)
    model = next(
        (getattr(src, "model", None) for src in sources if getattr(src, "model", None) is not None), None
    )

    def clearance(dense: np.ndarray) -> tuple[float | None, float]:
        if margins_proved(model, dense):
            return None, 1e-4
        found = check_path_clearance(model, dense, kin, problem.collision.check_step_m)
        return float(np.min(found.segment_clearance_m)), found.tolerance_m

    from refine.cad import cad_circles

    circles = [] if problem.cad is None else cad_circles(problem.cad, problem.frames.cad_in_world)  # no CAD: no arcs
    pieces = arc_pieces(trajectory.positions_ref, segment_speeds(trajectory), problem.output.speed_share, circles)
    if pieces:
        wrist = wrist_segments(problem, robot, trajectory.q)  # the programs keep straight moves there
        pieces = [a for a in pieces if not wrist[a.start : a.end].any()]
    ok = [True] * len(pieces)
    done: list[Any] = []
    for kind in MODELS:
        checks = check_circular_moves(
            kin,
            trajectory.q,
            trajectory.poses,
            pieces,
            kind,
            problem.tolerances,
            rotations_demo=trajectory.rotations_demo,
            axisymmetric=problem.tool.axisymmetric,
            exact=getattr(fused, "exact", None),
            clearance=None if model is None else clearance,
        )
        done += checks
        for i, c in enumerate(checks):
            if not c.ok:
                ok[i] = False
                log.info("circular move at waypoints %d-%d kept straight: %s", c.piece.start, c.piece.end, "; ".join(c.reasons))
    return tuple(p for p, good in zip(pieces, ok, strict=True) if good), tuple(done)




def plan_motions(
    problem: Problem,
    robot: Robot,
    passes: list[PassResult],
    sources: tuple[ConstraintSource, ...],
    previous: tuple[Any, ...] = (),
) -> tuple[Any, ...]:
    """Every motion of the program (``refine.plan.program``), verified; () when a pass is not executable.

    The collision model is the run's own (the clearance source's, with its margins) when the run
    checks collision, else the motions are checked for limits and singularity only. ``previous``:
    the motions of an earlier run of the same robot, planned again from (each still verified).
    """
    if not passes or any(p.trajectory is None for p in passes):
        return ()
    from refine.plan.program import PlannedPass, plan_program
    from refine.plan.verify import MotionChecker
    from refine.robot.kinematics import TcpKinematics

    model = next((getattr(s, "model", None) for s in sources if getattr(s, "model", None) is not None), None)
    kin = TcpKinematics(robot, problem.robot.base_in_world, problem.tool.tcp_in_flange, problem.tool.tcp_in_world)
    checker = MotionChecker(kin, model, problem.tolerances, problem.collision.check_step_m)
    planned = []
    for p in passes:
        assert p.trajectory is not None and p.timing is not None
        check = p.refinement.check
        planned.append(
            PlannedPass(
                p.name,
                p.trajectory.q,
                p.trajectory.poses,  # the refinement's verified poses of these joints
                p.timing.cycle_time_s,
                p.clearance,
                float(check.joint_margin_rad.min()),
                float(check.singularity.min()),
            )
        )
    from refine.plan.motion import air_limits

    velocity, accel = air_limits(problem, robot)
    spec = robot.spec
    home = None if problem.robot.home_deg is None else np.radians(spec.from_controller(problem.robot.home_deg))
    return plan_program(checker, planned, home, velocity=velocity, acceleration=accel, previous=previous)


def program_formats(problem: Problem, robot: Robot) -> tuple[str, ...]:
    """The program formats a run writes by default: ``[output] programs`` or the robot's own."""
    if problem.output.programs is not None:
        return problem.output.programs
    return (robot.spec.default_program,)


def wrist_segments(problem: Problem, robot: Robot, q: np.ndarray) -> np.ndarray:
    r"""Per segment of joints ``q``, True where a RAPID or KRL program hands the wrist to the controller.

    The runs near the wrist singularity (``SingArea \Wrist``, ``$ORI_TYPE = #JOINT``): the moves from
    the one onto each run's first target to its last.
    """
    from refine.export.program import singular_runs

    wrist = np.zeros(len(q) - 1, dtype=bool)
    if {"rapid", "krl"} & set(program_formats(problem, robot)):
        for a, b in singular_runs(robot, q):
            wrist[max(a, 1) - 1 : b + 1] = True
    return wrist


def line_source(problem: Problem, robot: Robot) -> Any:
    """The controller's line as a constraint source of the refinement's rounds (joint margins, singularity)."""
    from refine.optimise.controller_line import ControllerLineSource
    from refine.robot.kinematics import TcpKinematics

    kin = TcpKinematics(robot, problem.robot.base_in_world, problem.tool.tcp_in_flange, problem.tool.tcp_in_world)
    return ControllerLineSource(kin, problem.tolerances, lambda q: wrist_segments(problem, robot, q))


def controller_line_check(
    problem: Problem,
    robot: Robot,
    q: np.ndarray,
    s: np.ndarray,
    sources: tuple[ConstraintSource, ...] = (),
    lines: Any = None,
) -> Any:
    r"""The controller's straight-line motion between the waypoints of ``q``, checked.

    The orientation model is the slerp of :mod:`refine.optimise.controller_line`; where a RAPID or
    KRL program hands a run near the wrist singularity to the controller (``SingArea \Wrist``,
    ``$ORI_TYPE = #JOINT``), the wrist's joint-linear orientation. Clearance comes from the
    problem's collision source (the first that has a collision model): proved along the joints
    through the samples of the line, checked densely where the proof falls short.

    ``lines``: the refinement's own line source (:func:`line_source`); where it checked these joints
    with the same kinematics and wrist (:meth:`ControllerLineSource.checked`), the line's IK and
    singularity measures are its, not solved again; None to solve them.

    Returns:
        a :class:`refine.optimise.controller_line.LineCheck`.
    """
    from refine.collision.carry import bounds_between, proved_between
    from refine.collision.check import check_path_clearance, joint_reach, margins_proved
    from refine.optimise.controller_line import check_controller_lines
    from refine.robot.kinematics import TcpKinematics

    kin = TcpKinematics(robot, problem.robot.base_in_world, problem.tool.tcp_in_flange, problem.tool.tcp_in_world)
    wrist = wrist_segments(problem, robot, q)
    source = next((src for src in sources if getattr(src, "model", None) is not None), None)
    model = None if source is None else source.model

    def clearance(dense: np.ndarray, place: np.ndarray) -> tuple[np.ndarray | None, float]:
        # the waypoints' own dense check (kept by the source) bounds every pair along the line
        checked = getattr(source.clearance(q), "bounds", None)
        if checked is not None and proved_between(model, checked, dense, place):
            return None, 1e-4  # what margins_proved with bounds_between's prior would prove
        prior = None if checked is None else bounds_between(model, checked, dense, place)
        if margins_proved(model, dense, prior=prior):
            return None, 1e-4  # margins_proved's and check_path_clearance's default tolerance
        found = check_path_clearance(model, dense, kin, problem.collision.check_step_m)
        return found.segment_clearance_m, found.tolerance_m

    return check_controller_lines(
        kin,
        q,
        s,
        problem.tolerances,
        wrist=wrist,
        clearance=None if model is None else clearance,
        reach=None if model is None else joint_reach(model),
        known=None if lines is None else lines.checked(q, kin, wrist),
    )
