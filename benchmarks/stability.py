"""The same verdict for the same demonstration: through every reader and under the tracker's noise.

One demonstration of ``problems/unreachable`` is read as Liberty ASCII, Liberty binary and CSV (the
shipped files, or written here from the ASCII log), and perturbed ``N`` times by white noise of the
size the tracker model gives its samples (1 mm per axis, 0.15 deg rotation RMS); each copy is run
through the whole pipeline and the status and the largest repair slack are printed with their spread.

    python benchmarks/stability.py                    # reach_tilt, 20 perturbations
    python benchmarks/stability.py joint_limit -n 5
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from refine.demo import read_tracker_log
from refine.demo.csv_ import write_demo_csv
from refine.demo.liberty import write_liberty_ascii
from refine.demo.liberty_binary import write_liberty_binary
from refine.demo.simulate import TrackerModel, perturb_log
from refine.problem import load_problem
from refine.run.solve import solve_problem

ROOT = Path(__file__).resolve().parents[1]


def variants(problem, folder: Path, n: int):
    """(label, demonstration settings) for every reader and ``n`` perturbations."""
    demo = problem.demonstration
    log = read_tracker_log(demo)
    yield "liberty ascii", demo
    binary, csv = problem.root / "demo.lbin", problem.root / "demo.csv"
    if not binary.is_file():
        binary = folder / "demo.lbin"
        write_liberty_binary(binary, log, with_timestamp=True, units="in")
    yield "liberty binary", dataclasses.replace(demo, file=binary, format="liberty_binary", units="in")
    if not csv.is_file():
        csv = folder / "demo.csv"
        write_demo_csv(csv, log, units="mm")
    yield "csv", dataclasses.replace(demo, file=csv, format="csv", units="mm")
    for k in range(n):
        path = folder / f"perturbed_{k}.liberty"
        noisy = perturb_log(log, TrackerModel(), 1000 + k)
        write_liberty_ascii(path, noisy, units="in", rate_hz=1.0 / float(np.median(np.diff(log.t))))
        yield f"perturbed {k + 1}", dataclasses.replace(demo, file=path, format="liberty_ascii", units="in")


def run(case: str, n: int) -> list[tuple[str, str, float, float]]:
    """Status, largest slack [deg] and wall time [s] of every variant of ``case``."""
    problem = load_problem(ROOT / "problems" / "unreachable" / case)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, demo in variants(problem, Path(tmp), n):
            t0 = time.perf_counter()
            result = solve_problem(dataclasses.replace(problem, demonstration=demo))
            slack = float(result.refinement.slack_deg.max()) if result.refinement.slack_deg.size else 0.0
            out.append((label, result.status, slack, time.perf_counter() - t0))
            print(f"{label:16s} {result.status:10s} slack {slack:6.2f} deg  {out[-1][3]:6.1f} s", flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    """Run every variant of a case; exit 1 unless one status and the slack within 0.5 deg."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", nargs="?", default="reach_tilt")
    parser.add_argument("-n", type=int, default=20, help="perturbations (default 20)")
    args = parser.parse_args(argv)
    rows = run(args.case, args.n)
    statuses = sorted({r[1] for r in rows})
    slack = np.array([r[2] for r in rows])
    print(
        f"{args.case}: {len(rows)} runs, statuses {statuses}, slack {slack.min():.2f}-{slack.max():.2f} deg "
        f"(spread {slack.max() - slack.min():.2f} deg), slowest {max(r[3] for r in rows):.1f} s"
    )
    return 0 if len(statuses) == 1 and slack.max() - slack.min() <= 0.5 else 1


if __name__ == "__main__":
    sys.exit(main())
