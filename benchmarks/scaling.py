"""How the refinement NLP grows with the number of waypoints.

Builds and solves the refinement of a generated path (a horizontal sine wave in front of an ABB
IRB 4600, tool pointing down, see ``refine.synthetic.wave_path``) for N = 100, 400, 1,600 and 6,400
waypoints on a path of fixed length, and prints the time of each stage and its growth per 4x
waypoints. A growth near 4 is linear in N.

    python3 benchmarks/scaling.py [--sizes 100 400 1600 6400] [--repeat 3] [--csv FILE]

Each figure is the median of ``--repeat`` runs in this process. Results are also appended to
``benchmarks/results/scaling.csv`` with the date, the machine and the package versions.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import platform
import statistics
import time
from pathlib import Path

import casadi
import numpy as np
import pinocchio

from refine.frames import transform_from_xyz_rpy
from refine.optimise.problem import build_refinement
from refine.optimise.solve import solve_refinement
from refine.problem import Tolerances
from refine.robot.registry import load_robot
from refine.synthetic import wave_path

RESULTS = Path(__file__).resolve().parent / "results" / "scaling.csv"


def run_once(n: int) -> dict[str, float]:
    robot = load_robot("abb_irb4600_60_205")
    tcp_in_flange = transform_from_xyz_rpy([0.0, 0.0, 0.35], [0.0, 0.0, 0.0])
    fused = wave_path(n, length_m=1.0)
    t0 = time.perf_counter()
    nlp = build_refinement(robot, fused, np.eye(4), tcp_in_flange, Tolerances())
    build = time.perf_counter() - t0
    result = solve_refinement(nlp)
    return {
        "build_s": build,
        "seed_s": result.timings_s["seed"],
        "solve_s": result.timings_s["solve"],
        "verify_s": result.timings_s["verify"],
        "iterations": result.iterations,
        "status_ok": float(result.status == "ok"),
        "max_position_error_m": float(result.check.position_error_m.max()),
        "max_orientation_deviation_deg": float(result.check.orientation_deviation_deg.max()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 400, 1600, 6400])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--csv", type=Path, default=RESULTS)
    args = parser.parse_args()

    rows = []
    for n in args.sizes:
        runs = [run_once(n) for _ in range(args.repeat)]
        row = {"n": n, **{k: statistics.median(r[k] for r in runs) for k in runs[0]}}
        rows.append(row)

    print(f"refinement of a {1.0:.1f} m-wide wave path, IRB 4600, median of {args.repeat} runs")
    print(
        f"{'N':>6} {'build s':>9} {'seed s':>8} {'solve s':>8} {'iter':>5} {'verify s':>9} "
        f"{'build+solve':>12} {'growth':>7} {'max pos err m':>14} {'max dev deg':>12} ok"
    )
    prev = None
    for row in rows:
        total = row["build_s"] + row["solve_s"]
        growth = "" if prev is None else f"{total / prev:7.2f}"
        print(
            f"{row['n']:>6} {row['build_s']:9.3f} {row['seed_s']:8.3f} {row['solve_s']:8.3f} "
            f"{int(row['iterations']):>5} {row['verify_s']:9.3f} {total:12.3f} {growth:>7} "
            f"{row['max_position_error_m']:14.2e} {row['max_orientation_deviation_deg']:12.3f} "
            f"{'yes' if row['status_ok'] else 'NO'}"
        )
        prev = total
    ns = np.array([r["n"] for r in rows], dtype=float)
    totals = np.array([r["build_s"] + r["solve_s"] for r in rows])
    if len(ns) > 1:
        slope = np.polyfit(np.log(ns), np.log(totals), 1)[0]
        print(f"fitted exponent of build+solve time in N: {slope:.2f} (1.00 = linear)")

    args.csv.parent.mkdir(parents=True, exist_ok=True)
    new = not args.csv.exists()
    with args.csv.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["date", "machine", "casadi", "pinocchio", *rows[0].keys()])
        if new:
            writer.writeheader()
        stamp = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        for row in rows:
            writer.writerow(
                {
                    "date": stamp,
                    "machine": platform.node(),
                    "casadi": casadi.__version__,
                    "pinocchio": pinocchio.__version__,
                    **row,
                }
            )


if __name__ == "__main__":
    main()
