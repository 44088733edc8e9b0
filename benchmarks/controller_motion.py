"""The motion as the controllers run it, on the bundled problems: the straight line, the zones, the speeds.

For each problem every pass is solved once in this process and the script prints:

* the controller's straight-line check (:mod:`refine.optimise.controller_line`) against the
  joint-linear motion: the largest TCP distance [mm], orientation angle [deg] and joint difference
  [deg], the line's verdict and its time;
* per program the problem writes, the largest corner deviation its zones allow with the zones as
  they were written before ``[process] path_tolerance_m`` (the program's zone at every target:
  the same rules run with the largest tolerance, 50 mm) and as they are written now, with the
  number of targets narrowed;
* per program, the segments that run below their planned speed by more than ``[output]
  speed_share`` and the time the programmed speeds add, before (RAPID: ``speed_levels`` levels,
  no share) and now.

    python3 benchmarks/controller_motion.py [--problems glass_adhesive tig_weld]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

from refine.export.motion import MOTION_FORMATS, program_motion
from refine.export.program import speed_levels
from refine.problem import load_problem
from refine.run.solve import solve_problem
from refine.run.stages import program_formats

ROOT = Path(__file__).resolve().parents[1]
BUNDLED = ("glass_adhesive", "glass_calibrated", "kr8_arc_weld", "tig_weld", "ur10e_sealing")


def _before_speeds(problem, trajectory, kind):  # noqa: ANN001, ANN202 - a measurement script
    """Programmed speeds as written before the speed share: RAPID's levels without it."""
    m = program_motion(kind, trajectory, problem)
    if kind != "rapid":
        return m.programmed_m_s, m
    levels, index = speed_levels(m.planned_m_s, m.lengths_m, problem.output.speed_levels, 1e-4)
    return levels[index], m


def main() -> None:
    """Print the figures of every problem asked for."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--problems", nargs="*", default=list(BUNDLED))
    args = parser.parse_args()
    print(f"load {os.getloadavg()[0]:.2f}")
    for name in args.problems:
        problem = load_problem(ROOT / "problems" / name)
        t0 = time.perf_counter()
        result = solve_problem(problem)
        took = time.perf_counter() - t0
        print(f"\n{name}: {result.status}, {len(result.passes)} pass(es), solved in {took:.1f} s")
        wide = dataclasses.replace(
            problem, process=dataclasses.replace(problem.process, path_tolerance_m=0.05)
        )
        kinds = [k for k in program_formats(problem, result.robot) if k in MOTION_FORMATS]
        for p in result.passes:
            line = p.line
            if line is not None:
                print(
                    f"  {p.name}: line vs joint-linear {line.position_difference_m.max() * 1e3:.4f} mm, "
                    f"{line.orientation_difference_deg.max():.4f} deg orientation, "
                    f"{line.joint_difference_deg.max():.4f} deg joints; line {'ok' if line.ok else 'BROKEN'}; "
                    f"line_check {result.timings_s.get('line_check', float('nan')):.2f} s (all passes)"
                )
            if p.trajectory is None:
                continue
            for kind in kinds:
                before_zones = program_motion(kind, p.trajectory, wide).zones
                now = program_motion(kind, p.trajectory, problem)
                before_v, _ = _before_speeds(problem, p.trajectory, kind)
                planned, lengths = now.planned_m_s, now.lengths_m
                share = problem.output.speed_share
                below_before = int(np.count_nonzero((planned - before_v) / planned > share * (1 + 1e-9)))
                extra_before = float(np.sum(lengths / before_v) - np.sum(lengths / planned))
                print(
                    f"    {kind}: zones: largest deviation {before_zones.largest_deviation_m * 1e3:.3f} mm before, "
                    f"{now.zones.largest_deviation_m * 1e3:.3f} mm now (tolerance "
                    f"{now.zones.tolerance_m * 1e3:g} mm, {len(now.zones.narrowed)} of {len(p.trajectory)} narrowed); "
                    f"speeds: {below_before} of {len(planned)} segments > {share:.0%} below plan before "
                    f"({len(np.unique(before_v))} levels, {extra_before:+.3f} s), {len(now.beyond_share)} now "
                    f"({len(now.levels)} levels, {now.extra_time_s:+.3f} s); planned cycle "
                    f"{p.timing.cycle_time_s:.2f} s"
                )


if __name__ == "__main__":
    main()
