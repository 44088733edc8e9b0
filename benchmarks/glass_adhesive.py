"""Wall time of the whole ``refine run problems/glass_adhesive``, from process start to files written.

Runs the command-line tool ``--repeat`` times in fresh processes (so imports are counted) and prints
the wall time measured outside the process, the total the process itself records in
``result.json`` (from its start to the last file written), the CPU time of the process (user and
system, the steadier figures on a shared machine), the 1-minute load average before and after the
runs, and the median time of each stage. The target is a total under 1.5 s on the project's
2-core machine, idle.

Bytecode: the runs are made as a user's second run is, with Python's bytecode cache in use
(``PYTHONDONTWRITEBYTECODE`` is removed from the runs' environment). ``--first-run`` instead runs a
fresh copy of the ``refine`` package without its ``__pycache__`` and without writing one, so every
run compiles refine's own modules as the first run after an install does (the libraries keep the
bytecode their installer wrote).

``--imports`` adds one run under ``python3 -X importtime`` and prints the import time of the
heaviest packages (summed self times; the importtime figures run slower than a plain import).

    python3 benchmarks/glass_adhesive.py [--repeat 5] [--problem problems/glass_adhesive]
        [--first-run] [--imports]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 1.5


def _environment(tmp: Path, first_run: bool) -> tuple[dict[str, str], Path]:
    """The runs' environment and folder: bytecode cache in use, or a fresh uncompiled package copy."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    package_root = ROOT
    if first_run:  # run from the copy's folder: ``-m`` puts the working folder first on the path
        package_root = tmp / "fresh"
        shutil.copytree(
            ROOT / "refine", package_root / "refine", ignore=shutil.ignore_patterns("__pycache__")
        )
        (package_root / "robots").symlink_to(ROOT / "robots")  # the registry sits beside the package
        env["PYTHONDONTWRITEBYTECODE"] = "1"
    env["PYTHONPATH"] = os.pathsep.join([str(package_root), *filter(None, [env.get("PYTHONPATH")])])
    return env, package_root


def _import_breakdown(cmd: list[str], env: dict[str, str], cwd: Path, top: int = 14) -> None:
    """One run under ``-X importtime``: the packages with the largest summed self time."""
    proc = subprocess.run(
        [sys.executable, "-X", "importtime", *cmd[1:]], capture_output=True, text=True, cwd=cwd, env=env
    )
    self_us: dict[str, int] = defaultdict(int)
    total_us = 0
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        self_field, cumulative, name = line[len("import time:") :].split("|")
        package = name.strip().split(".")[0]
        self_us[package] += int(self_field)
        if not name[1:].startswith(" "):  # a top-level import: its cumulative time counts once
            total_us += int(cumulative)
    print(f"imports under -X importtime: {total_us / 1e6:.3f} s in all; largest packages (self time):")
    for package, us in sorted(self_us.items(), key=lambda kv: -kv[1])[:top]:
        print(f"  {package:24s} {us / 1e3:7.1f} ms")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--problem", type=Path, default=ROOT / "problems" / "glass_adhesive")
    parser.add_argument("--first-run", action="store_true", help="compile refine's modules in every run")
    parser.add_argument("--imports", action="store_true", help="also print an -X importtime breakdown")
    args = parser.parse_args()

    walls, results, users, systems = [], [], [], []
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        env, cwd = _environment(Path(tmp), args.first_run)
        for i in range(args.repeat):
            out = Path(tmp) / f"run{i}"
            cmd = [sys.executable, "-m", "refine.cli", "run", str(args.problem.resolve()), "--out", str(out)]
            t0 = time.perf_counter()
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            proc = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd, env=env)
            walls.append(time.perf_counter() - t0)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            users.append(after.ru_utime - before.ru_utime)
            systems.append(after.ru_stime - before.ru_stime)
            if proc.returncode != 0:
                print(proc.stdout, proc.stderr, sep="\n")
                return 1
            results.append(json.loads((out / "result.json").read_text()))
        load_after = os.getloadavg()[0]
        if args.imports:
            _import_breakdown(cmd, env, cwd)

    cpus = [u + s for u, s in zip(users, systems, strict=True)]
    first = results[0]
    print(
        f"{first['problem']}: {first['n_waypoints']} waypoints, status {first['status']}, "
        f"{args.repeat} runs ({'first run: refine compiled each time' if args.first_run else 'bytecode cached'}), "
        f"load average (1 min) {load_before:.2f} before, {load_after:.2f} after"
    )
    print(
        f"wall time (outside the process)   median {statistics.median(walls):.2f} s, "
        f"min {min(walls):.2f} s, max {max(walls):.2f} s"
    )
    print(
        f"CPU time of the process (user+sys)  median {statistics.median(cpus):.2f} s, "
        f"min {min(cpus):.2f} s (user median {statistics.median(users):.2f} s, "
        f"sys {statistics.median(systems):.2f} s)"
    )
    totals = [r["timings_s"]["total"] for r in results]
    print(
        f"total (process start -> files)    median {statistics.median(totals):.2f} s, "
        f"max {max(totals):.2f} s   target < {TARGET_S:g} s: "
        f"{'met' if max(totals) < TARGET_S else 'MISSED'}"
    )
    stages = [k for k in first["timings_s"] if k not in ("total", "run")]
    for k in stages:
        print(f"  {k:14s} {statistics.median(r['timings_s'][k] for r in results):7.3f} s")
    run = statistics.median(r["timings_s"]["run"] for r in results)
    print(f"  {'imports etc.':14s} {statistics.median(totals) - run:7.3f} s (total minus the pipeline call)")
    return 0 if max(totals) < TARGET_S else 1


if __name__ == "__main__":
    sys.exit(main())
