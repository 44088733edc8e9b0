"""The whole pipeline for one problem: read, fuse, refine, time, verify, write.

:func:`run` is what ``refine run PROBLEM`` calls. Each stage is a call into its own module (see the
diagram in ``docs/design.md``); this module only strings them together, times them and collects the
figures for ``result.json``.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from refine.cad import read_cad_path
from refine.demo import clean_demonstration, read_tracker_log
from refine.evaluate import TruthComparison, compare_with_truth
from refine.fuse import fuse
from refine.optimise.problem import build_refinement
from refine.optimise.solve import Refinement, solve_refinement
from refine.paths import FusedPath, Trajectory
from refine.problem import Problem
from refine.robot import Robot, load_robot
from refine.timing import Timing, time_parameterise

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunResult:
    """Everything a run produced, in memory.

    Attributes:
        problem: the problem that was run.
        robot: the loaded robot.
        fused: the fused path (CAD points + demonstrated orientations and speeds).
        refinement: the optimiser's result and its verification.
        timing: the time parameterisation (None when the refinement was infeasible).
        trajectory: the timed path the exporters read (None when infeasible).
        truth: comparison with the simulator's truth, when the problem has one.
        timings_s: wall time per stage [s].
        outputs: kind -> file written.
    """

    problem: Problem
    robot: Robot
    fused: FusedPath
    refinement: Refinement
    timing: Timing | None
    trajectory: Trajectory | None
    truth: TruthComparison | None
    timings_s: dict[str, float] = field(default_factory=dict)
    outputs: dict[str, Path] = field(default_factory=dict)

    @property
    def status(self) -> str:
        """``ok`` or ``infeasible``."""
        return self.refinement.status


class _Stopwatch:
    def __init__(self) -> None:
        self.times: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.times[name] = self.times.get(name, 0.0) + now - self._t
        self._t = now


def solve_problem(problem: Problem) -> RunResult:
    """Run every stage up to the timed trajectory, without writing files."""
    watch = _Stopwatch()
    robot = load_robot(problem.robot.model)
    watch.lap("load")
    cad = read_cad_path(problem.cad, problem.frames.cad_in_world)
    watch.lap("cad")
    demo = clean_demonstration(read_tracker_log(problem.demonstration), problem.demonstration)
    watch.lap("demo")
    fused = fuse(cad, demo, problem.frames.source_in_world, problem.tool.sensor_in_tcp)
    watch.lap("fuse")
    nlp = build_refinement(
        robot,
        fused,
        problem.robot.base_in_world,
        problem.tool.tcp_in_flange,
        problem.tolerances,
        axisymmetric=problem.tool.axisymmetric,
    )
    watch.lap("build")
    home = None if problem.robot.home_deg is None else np.radians(problem.robot.home_deg)
    refinement = solve_refinement(nlp, home=home)
    watch.lap("refine")
    del watch.times["refine"]  # reported by stage below: seed, solve, verify (and any rebuild)
    for stage, seconds in refinement.timings_s.items():
        watch.times[stage] = watch.times.get(stage, 0.0) + seconds
    timing = trajectory = None
    if refinement.status == "ok":
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
    truth = None
    if problem.demonstration.truth is not None and trajectory is not None and timing is not None:
        truth = compare_with_truth(problem.demonstration.truth, trajectory, timing)
        watch.lap("truth")
    return RunResult(problem, robot, fused, refinement, timing, trajectory, truth, watch.times)


def run(problem: Problem, out_dir: Path, programs: tuple[str, ...] | None = None) -> RunResult:
    """Solve ``problem`` and write every output into ``out_dir``.

    Args:
        problem: the loaded problem.
        out_dir: folder for ``result.json``, ``trajectory.csv``, ``<name>.aml`` and programs.
        programs: program formats overriding ``[output] programs``.

    Returns:
        The run's result, with ``outputs`` naming the files written.
    """
    from refine.export import write_pathml, write_rapid, write_trajectory_csv
    from refine.export.result_json import write_result_json

    result = solve_problem(problem)
    t0 = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    outputs: dict[str, Path] = {}
    if result.trajectory is not None:
        outputs["trajectory"] = write_trajectory_csv(out_dir / "trajectory.csv", result.trajectory)
        outputs["pathml"] = write_pathml(out_dir / f"{problem.name}.aml", result.trajectory, problem)
        for kind in programs or problem.output.programs:
            if kind == "rapid":
                outputs["rapid"] = write_rapid(
                    out_dir / f"{problem.name}.mod", result.trajectory, problem, result.robot
                )
    result.timings_s["export"] = time.perf_counter() - t0
    result.outputs.update(outputs)
    outputs["result"] = out_dir / "result.json"
    result.outputs["result"] = outputs["result"]
    write_result_json(outputs["result"], result)
    return result


def summary_lines(result: RunResult) -> list[str]:
    """Human-readable summary of a run, for the CLI."""
    check = result.refinement.check
    lines = [
        f"problem      {result.problem.name}: {len(result.fused)} waypoints, robot {result.robot.spec.name}",
        f"status       {result.status}"
        + (f" ({result.refinement.reason})" if result.refinement.reason else ""),
        f"position     max error {check.position_error_m.max():.2e} m "
        f"(tolerance {result.problem.tolerances.position_m:.0e} m)",
        f"orientation  max deviation from demo {check.orientation_deviation_deg.max():.3f} deg "
        f"(cone {result.problem.tolerances.orientation_deg:g} deg)",
        f"joints       min margin to limits {math.degrees(check.joint_margin_rad.min()):.2f} deg",
        f"singularity  min scaled manipulability {check.singularity.min():.4f}, "
        f"min singular value {check.sigma_min.min():.4f}",
    ]
    if result.timing is not None:
        t = result.timing
        lines.append(
            f"timing       cycle {t.cycle_time_s:.2f} s, {len(t.slow_segments)} segment(s) slower than the demo"
        )
    if result.truth is not None:
        lines.append(f"truth        {result.truth.describe()}")
    total = result.timings_s.get("total")
    stages = ", ".join(f"{k} {v:.3f}" for k, v in result.timings_s.items() if k != "total")
    lines.append(f"time [s]     {stages}" + (f"; total {total:.2f}" if total else ""))
    return lines
