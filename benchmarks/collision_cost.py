"""What collision checking costs: the refine stage with and without it, on the bundled cells.

For each problem, the first (demonstrated) pass is refined twice in this process, once with the
problem's ``[collision]`` on and once with it off, and the script prints the time of the refine
stage (seed + build + solve + verify, the dense clearance check included), the outer rounds, the
linearised clearance rows, the dense check's queries and time, and the smallest clearance. Each
figure is the median of ``--repeat`` runs.

With ``--dense`` it times the dense clearance check alone instead: each problem's first pass is
refined once with collision on, and :func:`refine.collision.check_path_clearance` is run
``--repeat`` times on the refined joints, printing the median wall and CPU time
(``time.process_time``), the FCL queries and the least clearance, with the load average. The
figures the targets refer to ("before" = the last commit with the hand-made primitive link shapes,
``539ef0f^``, measured by running this script in a worktree of that commit) are in
``benchmarks/COLLISION_COST.md``.

    python3 benchmarks/collision_cost.py [--problems glass_adhesive tig_weld ur10e_sealing] [--repeat 3]
    python3 benchmarks/collision_cost.py --dense --repeat 5
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time
from pathlib import Path

from refine.problem import load_problem
from refine.robot.registry import load_robot
from refine.run.stages import constraint_sources, fused_path, refine_pass
from refine.stopwatch import Stopwatch

ROOT = Path(__file__).resolve().parents[1]


def refine_once(problem, robot, fused, collision: bool) -> dict[str, float]:
    problem = dataclasses.replace(
        problem, collision=dataclasses.replace(problem.collision, enabled=collision)
    )
    sources = constraint_sources(problem, robot)
    watch = Stopwatch()
    t0 = time.perf_counter()
    result = refine_pass(problem, robot, fused, watch, sources=sources)
    wall = time.perf_counter() - t0 - watch.times.get("timing", 0.0)
    ref = result.refinement
    stats = sources[0].stats if sources else {}
    clearance = result.clearance
    if clearance is None:  # measure the clearance of the collision-free plan too, for comparison
        from refine.optimise.clearance import ClearanceSource

        clearance = ClearanceSource.for_problem(problem, robot).clearance(ref.q)
    return {
        "refine_s": wall,
        "status_ok": float(ref.status in ("ok", "repaired")),
        "outer": ref.outer_iterations,
        "ipopt_iterations": ref.iterations,
        "rows": len(ref.active.linear_rows),
        "check_s": stats.get("check_s", 0.0),
        "rows_s": stats.get("rows_s", 0.0),
        "queries": clearance.queries,
        "min_distance_mm": clearance.min_distance_m * 1e3,
    }


def dense_once(source, q) -> dict[str, float]:
    """One dense check of joints ``q`` with the source's model, timed by wall and CPU clock."""
    from refine.collision import check_path_clearance

    queries = source.model.queries
    w0, c0 = time.perf_counter(), time.process_time()
    found = check_path_clearance(source.model, q, source.kin, source.check_step_m)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "queries": source.model.queries - queries,
        "min_clearance_mm": found.min_clearance_m * 1e3,
        "ok": float(found.ok),
    }


def dense(names: list[str], repeat: int) -> None:
    """Print the dense check's median wall and CPU time and queries on each problem's refined pass."""
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(
        f"{'problem':32} {'waypoints':>9} {'wall s':>8} {'cpu s':>8} {'queries':>8} {'min clear mm':>12} ok"
    )
    for name in names:
        problem = load_problem(ROOT / "problems" / name)
        robot = load_robot(problem.robot.model)
        fused = fused_path(problem)
        sources = constraint_sources(problem, robot)
        if not sources:
            print(f"{name:32} no collision checking")
            continue
        q = refine_pass(problem, robot, fused, Stopwatch(), sources=sources).refinement.q
        runs = [dense_once(sources[0], q) for _ in range(repeat)]
        m = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        print(
            f"{name:32} {len(q):9d} {m['wall_s']:8.3f} {m['cpu_s']:8.3f} {int(m['queries']):8d} "
            f"{m['min_clearance_mm']:12.2f} {'yes' if m['ok'] else 'NO'}"
        )
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--problems",
        nargs="+",
        default=[
            "glass_adhesive",
            "glass_calibrated",
            "tig_weld",
            "ur10e_sealing",
            "kr8_arc_weld",
            "unreachable/tool_through_fixture",
        ],
    )
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--dense", action="store_true", help="time the dense clearance check alone")
    args = parser.parse_args()
    if args.dense:
        dense(args.problems, args.repeat)
        return
    print(
        f"{'problem':16} {'collision':9} {'refine s':>9} {'outer':>5} {'IPOPT it':>8} {'rows':>5} "
        f"{'check s':>8} {'rows s':>7} {'queries':>8} {'min dist mm':>11} ok"
    )
    for name in args.problems:
        problem = load_problem(ROOT / "problems" / name)
        robot = load_robot(problem.robot.model)
        fused = fused_path(problem)
        for collision in (False, True):
            runs = [refine_once(problem, robot, fused, collision) for _ in range(args.repeat)]
            m = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
            print(
                f"{name:16} {'on' if collision else 'off':9} {m['refine_s']:9.3f} {int(m['outer']):5d} "
                f"{int(m['ipopt_iterations']):8d} {int(m['rows']):5d} {m['check_s']:8.3f} {m['rows_s']:7.3f} "
                f"{int(m['queries']):8d} {m['min_distance_mm']:11.1f} {'yes' if m['status_ok'] else 'NO'}"
            )


if __name__ == "__main__":
    main()
