"""Peak memory against input size: the demonstration stage per tracker sample, the path per waypoint.

Each measurement runs in a fresh process and reports its peak resident set (``ru_maxrss``) above
the imports' baseline, so the slope is the memory per sample or per waypoint.

* ``log``: a synthetic Liberty ASCII log of M lines (smooth motion with noise, 240 Hz, frame counts)
  is read, passed through the quality gate and cleaned (Hampel, smoothing, motion start).
* ``path``: the glass bead (3.08 m) resampled to N waypoints by its spacing, fused with its
  demonstration and built into the refinement NLP (not solved).

    PYTHONPATH=. python3 benchmarks/memory.py log --sizes 250000 500000 1000000 2000000
    PYTHONPATH=. python3 benchmarks/memory.py path --sizes 2500 5000 10000 20000
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def make_log(path: Path, n: int) -> None:
    """Write an n-line Liberty ASCII log (station 1, frame counts) with numpy, quickly."""
    rng = np.random.default_rng(0)
    t = np.arange(n) / 240.0
    p = np.column_stack([24 + 12 * np.sin(0.05 * t), 8 * np.cos(0.03 * t), 12 + 4 * np.sin(0.07 * t)])
    p += rng.normal(0.0, 0.02, (n, 3))
    a = np.column_stack([20 * np.sin(0.02 * t), 10 * np.cos(0.04 * t), 5 * np.sin(0.01 * t)])
    table = np.column_stack([np.ones(n), np.arange(n), p, a])
    with open(path, "w") as f:
        f.write("# units: in\n# rate_hz: 240\n")
        np.savetxt(f, table, fmt=["%02d", "%9d", "%10.4f", "%10.4f", "%10.4f", "%9.3f", "%9.3f", "%9.3f"])


def measure_log(path: str) -> dict:
    from refine.demo import clean_demonstration, read_tracker_log
    from refine.demo.quality import gate_dropouts
    from refine.problem import DemoSettings

    base = _rss_mb()
    settings = DemoSettings(file=Path(path), format="liberty_ascii", units="in")
    t0 = time.perf_counter()
    log = read_tracker_log(settings)
    log, _ = gate_dropouts(log)
    clean_demonstration(log, settings)
    return {"n": len(log.t), "base_mb": base, "peak_mb": _rss_mb(), "time_s": time.perf_counter() - t0}


def measure_path(n: int) -> dict:
    from refine.problem import load_problem
    from refine.robot.registry import load_robot
    from refine.run.stages import fused_path, refinement_for

    problem = load_problem(ROOT / "problems" / "glass_adhesive")
    robot = load_robot(problem.robot.model)
    base = _rss_mb()
    problem = dataclasses.replace(problem, cad=dataclasses.replace(problem.cad, spacing_m=3.0807 / n))
    t0 = time.perf_counter()
    fused = fused_path(problem)
    refinement_for(problem, robot, fused)
    return {"n": len(fused), "base_mb": base, "peak_mb": _rss_mb(), "time_s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["log", "path"])
    ap.add_argument("--sizes", type=int, nargs="+", required=True)
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one is not None:  # the child process
        print(json.dumps(measure_log(args.one) if args.what == "log" else measure_path(int(args.one))))
        return
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.sizes:
            arg = str(size)
            if args.what == "log":
                arg = str(Path(tmp) / f"log{size}.liberty")
                make_log(Path(arg), size)
            out = subprocess.run(
                [sys.executable, __file__, args.what, "--sizes", "0", "--one", arg],
                capture_output=True,
                text=True,
                check=True,
            )
            row = json.loads(out.stdout.strip().splitlines()[-1])
            rows.append(row)
            print(
                f"{args.what} n = {row['n']:9d}: peak {row['peak_mb']:7.0f} MB, above imports "
                f"{row['peak_mb'] - row['base_mb']:7.0f} MB ({(row['peak_mb'] - row['base_mb']) * 1e6 / row['n']:6.0f} "
                f"bytes per {'sample' if args.what == 'log' else 'waypoint'}), {row['time_s']:.1f} s",
                flush=True,
            )
    if len(rows) > 1:
        n = np.array([r["n"] for r in rows], float)
        mb = np.array([r["peak_mb"] - r["base_mb"] for r in rows])
        slope, intercept = np.polyfit(n, mb, 1)
        print(f"linear fit: {slope * 1e6:.0f} bytes per item + {intercept:.0f} MB")


if __name__ == "__main__":
    main()
