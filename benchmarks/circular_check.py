"""Circular moves on the CAD's arcs, written and checked: the figures per problem.

For each problem (a folder, run with ``[output] circular_moves = true``) it solves the path
(``refine.solve``), then prints per circular move the controller's figures in each orientation
model (``refine.optimise.controller_arc``): radius, sweep, the largest distance from the CAD arc,
the tool axis's and the whole orientation's angle from the refined ones, the angle from the
demonstration (the cone), the least joint margin and singularity measure, the verdict; then the
pass's targets and its program time with straight moves only and with the circular moves (each
move's length over its programmed speed: the planned segment speed for a straight move, the
slowest of its segments' for a circular one), and the CPU time of the check.

    python3 benchmarks/circular_check.py DIR [DIR ...]
    python3 benchmarks/circular_check.py --arc ROBOT PROGRAM X Y Z [--arc ...]

``--arc`` writes a problem first (:func:`refine.synthetic.write_arc_problem`: a DXF of a 40 mm line, a 20 mm
quarter ARC and a 40 mm line at (X, Y, Z) m in the world, and a clean demonstration along it) for
the robot, asking for the program.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from refine import solve  # noqa: E402
from refine.export.motion import segment_speeds  # noqa: E402
from refine.problem import load_problem  # noqa: E402
from refine.run.stages import circular_moves  # noqa: E402
from refine.synthetic import write_arc_problem  # noqa: E402


def main() -> None:
    args, folders = sys.argv[1:], []
    while args:
        if args[0] == "--arc":
            robot, program, *xyz = args[1:6]
            folders.append(
                write_arc_problem(
                    Path(f"/tmp/circular_{program}"), robot, program, np.array([float(v) for v in xyz])
                ).parent
            )
            args = args[6:]
        else:
            folders.append(Path(args.pop(0)))
    for folder in folders:
        problem = load_problem(Path(folder))
        problem = replace(problem, output=replace(problem.output, circular_moves=True))
        result = solve(problem).run
        print(f"== {problem.name}: {result.passes[0].refinement.status}")
        for p in result.passes:
            tr = p.trajectory
            if tr is None:
                print("   no trajectory")
                continue
            v = segment_speeds(tr)
            for c in p.circular:  # the run's own checks (with its collision model)
                a = c.piece
                print(
                    f"   {c.model:10s} {a.start:4d}-{a.via:4d}-{a.end:4d} r {a.radius_m * 1e3:6.2f} mm "
                    f"sweep {math.degrees(a.sweep_rad):5.1f} deg v {a.speed_m_s * 1e3:5.2f} mm/s | CAD "
                    f"{c.cad_deviation_m * 1e3:.5f} mm, axis {c.axis_vs_refined_deg:.3f} deg, whole "
                    f"{c.rotation_vs_refined_deg:.3f} deg vs refined, {c.vs_demo_deg:.3f} deg vs demo "
                    f"(cone {problem.tolerances.orientation_deg:g}), margin {math.degrees(c.joint_margin_rad):.2f} deg, "
                    f"sing {c.singularity:.4f}, IK {c.ik_error:.1e} | {'ok' if c.ok else '; '.join(c.reasons)}"
                )
            t0 = time.process_time()
            circular_moves(problem, result.robot, tr, p.fused, ())  # again, for its CPU time (no cell)
            cpu = time.process_time() - t0
            L = np.linalg.norm(np.diff(tr.poses[:, :3, 3], axis=0), axis=1)
            straight = float(np.sum(L / v))
            written = tr.arcs
            with_arcs = straight
            replaced = 0
            for a in written:
                with_arcs += a.length_m / a.speed_m_s - float(np.sum(L[a.start : a.end] / v[a.start : a.end]))
                replaced += a.end - a.start - 2
            print(
                f"   pieces {len(p.circular) // 2}, written {len(written)}; targets {len(tr)} -> {len(tr) - replaced} "
                f"path moves {len(tr) - 1} -> {len(tr) - 1 - sum(a.end - a.start - 1 for a in written)}; "
                f"program path time {straight:.3f} s -> {with_arcs:.3f} s (planned {float(tr.t[-1]):.3f} s); "
                f"check CPU {cpu:.2f} s (without the cell)"
            )


if __name__ == "__main__":
    main()
