"""What deciding the IK seed's clearance costs: the dense check against the motion bound's proof alone.

Before the first solve, the collision source asks whether the seed keeps every margin: a seed that
does gets no clearance rows. The dense check (:func:`refine.collision.check_path_clearance`) answers
with its figures, the proof (:func:`refine.collision.margins_proved`) with the verdict alone; the
source asks the proof first and runs the check only for a seed the proof cannot pass. For each
problem, the first pass is refined once to get its seed (``Refinement.q_seed``), then each way is
timed ``--repeat`` times on a fresh collision model (no witness normal known yet, as on a seed),
printing the median wall time, the FCL queries and the verdicts (a proof never passes a seed the
check fails), with the load average.

    python3 benchmarks/seed_clearance.py [--problems glass_adhesive ...] [--repeat 5]
"""

from __future__ import annotations

import argparse
import logging
import os
import statistics
import time
from pathlib import Path

from refine.collision import check_path_clearance, margins_proved
from refine.optimise.clearance import ClearanceSource
from refine.problem import load_problem
from refine.robot.registry import load_robot
from refine.run.stages import constraint_sources, fused_path, refine_pass
from refine.stopwatch import Stopwatch

ROOT = Path(__file__).resolve().parents[1]

PROBLEMS = [
    "glass_adhesive",
    "glass_calibrated",
    "kr8_arc_weld",
    "tig_weld",
    "ur10e_sealing",
    "unreachable/elbow_through_table",
    "unreachable/reach_near_post",
    "unreachable/tool_through_fixture",
]


def timed(decide, problem, robot, q, repeat: int) -> tuple[bool, int, float]:
    """The verdict, FCL queries and median wall time [s] of ``decide(source, q)`` on fresh models."""
    walls = []
    for _ in range(repeat):
        source = ClearanceSource.for_problem(problem, robot)
        queries, start = source.model.queries, time.perf_counter()
        verdict = decide(source, q)
        walls.append(time.perf_counter() - start)
        queries = source.model.queries - queries
    return verdict, queries, statistics.median(walls)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", nargs="+", default=PROBLEMS)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    logging.getLogger("refine").setLevel(logging.ERROR)  # a model built per repeat repeats its warnings
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(
        f"{'problem':32} {'N':>5} {'check ms':>9} {'queries':>8} {'ok':>5} {'proof ms':>9} {'queries':>8} proved"
    )
    for name in args.problems:
        problem = load_problem(ROOT / "problems" / name)
        robot = load_robot(problem.robot.model)
        sources = constraint_sources(problem, robot)
        if not sources:
            print(f"{name:32} no collision checking")
            continue
        q = refine_pass(problem, robot, fused_path(problem), Stopwatch(), sources=sources).refinement.q_seed
        ok, check_queries, check_s = timed(
            lambda s, q: check_path_clearance(s.model, q, s.kin, s.check_step_m).ok,
            problem,
            robot,
            q,
            args.repeat,
        )
        proved, proof_queries, proof_s = timed(
            lambda s, q: margins_proved(s.model, q), problem, robot, q, args.repeat
        )
        print(
            f"{name:32} {len(q):5d} {check_s * 1e3:9.1f} {check_queries:8d} {'yes' if ok else 'no':>5} "
            f"{proof_s * 1e3:9.1f} {proof_queries:8d} {'yes' if proved else 'no'}"
            + ("  PROOF PASSED A SEED THE CHECK FAILS" if proved and not ok else "")
        )
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
