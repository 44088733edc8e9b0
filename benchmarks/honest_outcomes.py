"""The unreachable suite with two contenders that only pretend, beside the real ones.

``always-raises`` raises on every problem; ``always-infeasible`` answers ``infeasible`` at once,
without joints. By the rules of docs/bench.md the first scores 0 successes and 0 detections, the
second 0 successes, and both count as the time limit in the penalised times. The real contenders
(refine, greedy-ik, drake-ik, and trajopt and descartes where tesseract-robotics is installed) run
beside them in turns; the rows go to one run of a new CSV and the report is written from it.

    python benchmarks/honest_outcomes.py --out out/bench/honest [--time-limit 60]
"""

from __future__ import annotations

import argparse
import csv
from collections import defaultdict
from pathlib import Path

from refine.bench import contenders as contenders_module
from refine.bench.contenders import Answer
from refine.bench.report import write_report
from refine.bench.runner import run_suites


def always_raises(problem):
    raise RuntimeError("this contender always raises")


def always_infeasible(problem):
    return Answer("infeasible", None, {"solve": 0.0}, 0.0, note="answers infeasible without trying")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench/honest"))
    parser.add_argument("--time-limit", type=float, default=60.0, help="wall seconds per run (default 60)")
    parser.add_argument(
        "--contender", action="append", default=None, help="real contenders (default: all installed)"
    )
    args = parser.parse_args()
    contenders_module.CONTENDERS["always-raises"] = always_raises
    contenders_module.CONTENDERS["always-infeasible"] = always_infeasible
    real = args.contender or ["refine", "greedy-ik", "drake-ik", "trajopt", "descartes"]
    csv_path = args.out / "bench.csv"
    if csv_path.exists():
        csv_path.unlink()  # one run per file
    run_suites(
        ["unreachable"],
        [*real, "always-raises", "always-infeasible"],
        csv_path,
        warmup=0,
        time_limit_s=args.time_limit,
    )
    with csv_path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    score: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0, 0])
    for r in rows:
        stated = r["expected"] == "infeasible"
        s = score[r["contender"]]
        s[0] += r["success"] == "True"
        s[1] += not stated
        s[2] += r["detected_infeasible"] == "True"
        s[3] += stated
    print(f"run {rows[0]['run_id']}, time limit {args.time_limit:g} s")
    for contender, (ok, feasible, detected, stated) in score.items():
        print(f"{contender:18s} successes {ok}/{feasible + stated}, detections {detected}/{stated}")
    print(f"wrote {write_report(csv_path, args.out)}")


if __name__ == "__main__":
    main()
