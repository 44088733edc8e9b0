"""The whole pipeline for one problem: read, fuse, refine, time, verify, write.

:func:`run` is what ``refine run PROBLEM`` calls. Each stage is a call into its own module (see the
diagram in the README); this module only strings them together, times them and collects the
figures for ``result.json``. A multi-pass weld runs the refine and timing stages once per pass.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from refine.evaluate import TruthComparison, compare_with_truth
from refine.optimise.problem import Weights, build_refinement
from refine.optimise.solve import ConstraintSource, Refinement, solve_refinement
from refine.paths import FusedPath, Trajectory
from refine.problem import Problem
from refine.robot import Robot, load_robot
from refine.timing import Timing, time_parameterise

log = logging.getLogger(__name__)

EXECUTABLE = ("ok", "repaired")

REDUNDANT_MID_RANGE_WEIGHT = 2.0
"""Default ``[optimise] mid_range_weight`` for arms with more than 6 joints: on the LBR iiwa it
keeps every joint >= 18 deg from its limits on the test paths while costing < 0.05 deg of
orientation, and the solution moves by < 0.2 deg of joint angle when the demo is perturbed."""


@dataclass(frozen=True)
class PassResult:
    """One pass of the path: the fused input, its refinement and its timing.

    Attributes:
        name: ``"pass 1"`` for a single pass, ``"layer 2 pass 1"`` in a multi-pass weld.
        layer: 1-based layer number.
        index: 1-based pass number within its layer.
        fused: the pass's fused path.
        refinement: the optimiser's result and its verification.
        timing: the time parameterisation (None when the refinement was infeasible).
        trajectory: the timed path the exporters read (None when infeasible).
        clearance: the dense clearance check of the refined path (None without collision).
    """

    name: str
    layer: int
    index: int
    fused: FusedPath
    refinement: Refinement
    timing: Timing | None
    trajectory: Trajectory | None
    clearance: Any = None


@dataclass(frozen=True)
class RunResult:
    """Everything a run produced, in memory.

    Attributes:
        problem: the problem that was run.
        robot: the loaded robot.
        passes: one entry per pass (one for a single-pass path).
        truth: comparison of the first pass with the simulator's truth, when there is one.
        timings_s: wall time per stage [s], summed over passes.
        outputs: kind -> file written.
    """

    problem: Problem
    robot: Robot
    passes: tuple[PassResult, ...]
    truth: TruthComparison | None
    timings_s: dict[str, float] = field(default_factory=dict)
    outputs: dict[str, Path] = field(default_factory=dict)

    @property
    def first(self) -> PassResult:
        """The first (demonstrated) pass."""
        return self.passes[0]

    @property
    def fused(self) -> FusedPath:
        """The first pass's fused path."""
        return self.first.fused

    @property
    def refinement(self) -> Refinement:
        """The first pass's refinement."""
        return self.first.refinement

    @property
    def timing(self) -> Timing | None:
        """The first pass's timing."""
        return self.first.timing

    @property
    def trajectory(self) -> Trajectory | None:
        """The first pass's timed trajectory."""
        return self.first.trajectory

    @property
    def status(self) -> str:
        """``ok`` when every pass is ok, ``infeasible`` when any is, else ``repaired``."""
        statuses = {p.refinement.status for p in self.passes}
        return "infeasible" if "infeasible" in statuses else "repaired" if "repaired" in statuses else "ok"


class _Stopwatch:
    def __init__(self) -> None:
        self.times: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.times[name] = self.times.get(name, 0.0) + now - self._t
        self._t = now

    def add(self, times: dict[str, float]) -> None:
        for stage, seconds in times.items():
            self.times[stage] = self.times.get(stage, 0.0) + seconds


def fused_path(problem: Problem, watch: _Stopwatch | None = None) -> FusedPath:
    """The fused path of ``problem``: CAD path + cleaned, aligned demonstration, or a PathML path."""
    watch = watch or _Stopwatch()
    if problem.cad.format == "pathml":
        from refine.cad.pathml_ import fused_from_pathml

        track = problem.cad.track
        fused = fused_from_pathml(problem.cad.file, problem.cad.spacing_m, track=track)
        watch.lap("cad")
        return fused
    from refine.cad import read_cad_path
    from refine.demo import clean_demonstration, read_tracker_log
    from refine.fuse import fuse

    assert problem.demonstration is not None  # Problem checks this
    cad = read_cad_path(problem.cad, problem.frames.cad_in_world)
    watch.lap("cad")
    demo = clean_demonstration(read_tracker_log(problem.demonstration), problem.demonstration)
    watch.lap("demo")
    fused = fuse(cad, demo, problem.frames.source_in_world, problem.tool.sensor_in_tcp)
    watch.lap("fuse")
    return fused


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
    watch: _Stopwatch,
    name: str = "pass 1",
    layer: int = 1,
    index: int = 1,
    sources: tuple[ConstraintSource, ...] = (),
) -> PassResult:
    """Refine, verify and time one pass."""
    nlp = build_refinement(
        robot,
        fused,
        problem.robot.base_in_world,
        problem.tool.tcp_in_flange,
        problem.tolerances,
        axisymmetric=problem.tool.axisymmetric,
        weights=weights_for(problem, robot),
    )
    watch.lap("build")
    home = None if problem.robot.home_deg is None else np.radians(problem.robot.home_deg)
    refinement = solve_refinement(
        nlp,
        home=home,
        sources=sources,
        repair_max_slack_deg=problem.repair.max_slack_deg if problem.repair.enabled else None,
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
    clearance = None
    for source in sources:
        clearance = source.clearance(refinement.q)  # the dense check's figures, for the report
    return PassResult(name, layer, index, fused, refinement, timing, trajectory, clearance)


def solve_problem(problem: Problem) -> RunResult:
    """Run every stage up to the timed trajectories, without writing files."""
    watch = _Stopwatch()
    robot = load_robot(problem.robot.model)
    watch.lap("load")
    fused = fused_path(problem, watch)
    sources = constraint_sources(problem, robot)
    watch.lap("load")
    passes = [refine_pass(problem, robot, fused, watch, sources=sources)]
    if problem.multipass is not None and problem.multipass.layers > 1:
        from refine.multipass import generate_passes

        for p in generate_passes(fused, problem.multipass)[1:]:
            name = f"layer {p.layer} pass {p.index}"
            passes.append(refine_pass(problem, robot, p.path, watch, name, p.layer, p.index, sources))
    truth = None
    first = passes[0]
    if (
        problem.demonstration is not None
        and problem.demonstration.truth is not None
        and first.trajectory is not None
    ):
        assert first.timing is not None
        truth = compare_with_truth(
            problem.demonstration.truth,
            first.trajectory,
            first.timing,
            axisymmetric=problem.tool.axisymmetric,
        )
        watch.lap("truth")
    return RunResult(problem, robot, tuple(passes), truth, watch.times)


def run(
    problem: Problem, out_dir: Path, programs: tuple[str, ...] | None = None, *, report: bool = True
) -> RunResult:
    """Solve ``problem`` and write every output into ``out_dir``.

    Args:
        problem: the loaded problem.
        out_dir: folder for ``result.json``, ``trajectory.csv``, ``<name>.aml`` and programs.
        programs: program formats overriding ``[output] programs``.
        report: also write ``report.html``.

    Returns:
        The run's result, with ``outputs`` naming the files written.
    """
    from refine.export.result_json import write_result_json
    from refine.export.writers import write_outputs

    result = solve_problem(problem)
    t0 = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    result.outputs.update(write_outputs(result, out_dir, programs or problem.output.programs))
    result.timings_s["export"] = time.perf_counter() - t0
    if report:
        from refine.report.html import write_report

        t0 = time.perf_counter()
        result.outputs["report"] = write_report(out_dir / "report.html", result)
        result.timings_s["report"] = time.perf_counter() - t0
    result.outputs["result"] = out_dir / "result.json"
    write_result_json(result.outputs["result"], result)
    return result


def summary_lines(result: RunResult) -> list[str]:
    """Human-readable summary of a run, for the CLI."""
    lines = [
        f"problem      {result.problem.name}: robot {result.robot.spec.name}, {len(result.passes)} pass(es)"
    ]
    tol = result.problem.tolerances
    for p in result.passes:
        check = p.refinement.check
        head = f"{p.name}: " if len(result.passes) > 1 else ""
        lines += [
            f"status       {head}{p.refinement.status}, {len(p.fused)} waypoints"
            + (f" ({p.refinement.reason})" if p.refinement.reason else ""),
            f"position     max error {check.position_error_m.max():.2e} m (tolerance {tol.position_m:.0e} m)",
            f"orientation  max deviation from demo {check.orientation_deviation_deg.max():.3f} deg "
            f"(cone {tol.orientation_deg:g} deg)",
            f"joints       min margin to limits {math.degrees(check.joint_margin_rad.min()):.2f} deg",
            f"singularity  min scaled manipulability {check.singularity.min():.4f}, "
            f"min singular value {check.sigma_min.min():.4f}",
        ]
        if p.clearance is not None:
            c = p.clearance
            lines.append(
                f"clearance    min distance {c.min_distance_m * 1e3:.1f} mm (margin {result.problem.collision.margin_m * 1e3:g} mm), "
                f"checked between waypoints: {c.queries} queries in {c.time_s:.2f} s"
            )
        if p.timing is not None:
            lines.append(
                f"timing       cycle {p.timing.cycle_time_s:.2f} s, "
                f"{len(p.timing.slow_segments)} segment(s) slower than the demo"
            )
    if result.truth is not None:
        lines.append(f"truth        {result.truth.describe()}")
    total = result.timings_s.get("total")
    stages = ", ".join(f"{k} {v:.3f}" for k, v in result.timings_s.items() if k != "total")
    lines.append(f"time [s]     {stages}" + (f"; total {total:.2f}" if total else ""))
    return lines
