"""Run contenders on the problems of suites and write one CSV row per problem and contender.

Every row carries the machine and the package versions, so a report can be regenerated from the
CSV alone. Times are wall and process CPU seconds: on a shared machine the CPU time is the steadier
figure. With ``repeat > 1`` each problem is run that many times per contender and the row holds the
median wall time of each stage and the minimum of the total (``min_total_s``).
"""

from __future__ import annotations

import csv
import datetime
import logging
import os
import platform
import resource
import statistics
import time
from collections.abc import Callable, Iterable
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from refine.bench.contenders import CONTENDERS, Answer, Unavailable, verify
from refine.bench.suites import BenchProblem, load_suites, problems
from refine.errors import InputError

log = logging.getLogger(__name__)

COLUMNS = [
    "suite", "problem", "robot", "n_waypoints", "obstacles", "expected", "contender", "status", "verified",
    "success", "max_position_error_m", "max_orientation_deviation_deg", "min_clearance_m", "build_s", "seed_s",
    "solve_s", "total_s", "min_total_s", "cpu_s", "iterations", "repeats", "peak_rss_mb", "rss_growth_mb",
    "reason", "note", "date", "machine", "cpu", "cores", "python", "refine", "casadi", "pinocchio", "drake",
]  # fmt: skip
"""The CSV columns, in order (see docs of :func:`run_suites`)."""


def environment() -> dict[str, str]:
    """Machine and versions, repeated in every row."""

    def version(name: str) -> str:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return ""

    cpu = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "machine": f"{platform.system()} {platform.machine()}",
        "cpu": cpu,
        "cores": str(os.cpu_count()),
        "python": platform.python_version(),
        "refine": version("refine"),
        "casadi": version("casadi"),
        "pinocchio": version("pin"),
        "drake": version("drake"),
    }


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kilobytes


def success(problem: BenchProblem, answer: Answer, verified: bool, verified_repaired: bool) -> bool:
    """Did the contender do what the problem asks?

    A normal problem: a verified answer. A problem built to be repaired: a verified answer, or a
    repaired one that verifies with the slack it reports. A problem built to be infeasible: reporting
    it infeasible (no executable answer claimed).
    """
    if problem.expected == "infeasible":
        return answer.status in ("infeasible", "failed")
    if problem.expected == "repaired":
        return verified or (answer.status == "repaired" and verified_repaired)
    return verified


def run_problem(
    problem: BenchProblem, contender: str, function: Callable[[BenchProblem], Answer], repeat: int
) -> dict[str, Any] | None:
    """One row for ``contender`` on ``problem`` (None when the contender is unavailable)."""
    walls: list[dict[str, float]] = []
    cpus: list[float] = []
    answer: Answer | None = None
    peak0 = _peak_rss_mb()
    for _ in range(repeat):
        try:
            answer = function(problem)
        except Unavailable:
            raise
        except Exception as e:  # a contender crashing is a result, not the end of the benchmark
            log.warning("%s on %s failed: %s", contender, problem.name, e)
            answer = Answer("failed", None, note=f"{type(e).__name__}: {str(e)[:120]}")
        walls.append(answer.times_s)
        cpus.append(answer.cpu_s)
    assert answer is not None
    verdict = verify(problem, answer.q)
    repaired = answer.status == "repaired" and verify(problem, answer.q, answer.slack_deg).verified
    totals = [sum(w.values()) for w in walls]
    stage = {k: statistics.median(w.get(k, 0.0) for w in walls) for k in ("build", "seed", "solve")}
    peak = _peak_rss_mb()
    return {
        "suite": problem.suite,
        "problem": problem.name,
        "robot": problem.robot.spec.name,
        "n_waypoints": problem.n_waypoints,
        "obstacles": bool(problem.sources),
        "expected": problem.expected,
        "contender": contender,
        "status": answer.status,
        "verified": verdict.verified,
        "success": success(problem, answer, verdict.verified, repaired),
        "max_position_error_m": verdict.max_position_error_m,
        "max_orientation_deviation_deg": verdict.max_orientation_deviation_deg,
        "min_clearance_m": verdict.min_clearance_m,
        "build_s": stage["build"],
        "seed_s": stage["seed"],
        "solve_s": stage["solve"],
        "total_s": statistics.median(totals),
        "min_total_s": min(totals),
        "cpu_s": statistics.median(cpus),
        "iterations": answer.iterations,
        "repeats": repeat,
        "peak_rss_mb": peak,
        "rss_growth_mb": peak - peak0,
        "reason": verdict.reason[:160],
        "note": answer.note,
    }


def run_suites(
    suites: Iterable[str],
    contenders: Iterable[str],
    csv_path: Path,
    *,
    suites_file: Path | None = None,
    repeat: int = 1,
    echo: Callable[[str], None] = print,
) -> list[dict[str, Any]]:
    """Run every contender on every problem of ``suites`` and append the rows to ``csv_path``.

    Columns (:data:`COLUMNS`): the problem (suite, name, robot, waypoints, whether it has a cell, the
    outcome it is built for), the contender, its own status, the shared verification (``verified``:
    every tolerance kept; ``success``: see :func:`success`; worst position and orientation, least
    clearance), wall time per stage and in total (median over repeats, and the minimum total), CPU
    time, solver iterations, the process's peak resident memory after the row and its growth during
    it [MB] (memory stays allocated, so the growth is the row's own only where it sets a new
    peak), the first broken tolerance, and the machine and versions.
    """
    contenders = list(contenders)
    unknown = [c for c in contenders if c not in CONTENDERS]
    if unknown:
        raise InputError(f"unknown contender(s) {unknown}; contenders: {', '.join(CONTENDERS)}")
    if repeat < 1:
        raise InputError(f"repeat must be >= 1, got {repeat}")
    data = load_suites(suites_file) if suites_file else load_suites()
    env = environment()
    rows: list[dict[str, Any]] = []
    skipped: set[str] = set()
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    new = not csv_path.exists() or csv_path.stat().st_size == 0
    with csv_path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        if new:
            writer.writeheader()
        for suite in suites:
            for problem in problems(data, suite):
                for name in contenders:
                    if name in skipped:
                        continue
                    t0 = time.perf_counter()
                    try:
                        row = run_problem(problem, name, CONTENDERS[name], repeat)
                    except Unavailable as e:
                        echo(f"skipping {name}: {e}")
                        skipped.add(name)
                        continue
                    assert row is not None
                    row.update(env)
                    writer.writerow({k: _cell(row.get(k, "")) for k in COLUMNS})
                    f.flush()
                    rows.append(row)
                    echo(
                        f"{suite:11s} {problem.name:28s} {name:16s} {row['status']:10s} "
                        f"verified {'yes' if row['verified'] else 'no ':3s} success {'yes' if row['success'] else 'no '} "
                        f"total {row['total_s']:7.3f} s cpu {row['cpu_s']:7.3f} s "
                        f"({time.perf_counter() - t0:.1f} s with verification)"
                    )
    return rows


def _cell(value: Any) -> Any:
    if isinstance(value, float):
        return "" if np.isnan(value) else f"{value:.6g}"
    return value
