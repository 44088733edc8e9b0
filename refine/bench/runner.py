"""Run contenders on the problems of suites and write one CSV row per problem and contender.

Every row carries the machine and the package versions, so a report can be regenerated from the
CSV alone. Times are wall and process CPU seconds: on a shared machine the CPU time is the steadier
figure. Every contender first runs ``warmup`` times untimed on each problem (libraries loaded,
compiled kernels and caches warm, for every contender alike); then the ``repeat`` timed runs of the
contenders take turns (refine, Drake, refine, Drake, ...), so a change of the machine's load falls
on all of them alike. A row holds the median wall time of each stage, the median and minimum of the
total, the median and minimum CPU time, and the 1-minute load average before and after its runs.
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
    "solve_s", "total_s", "min_total_s", "cpu_s", "min_cpu_s", "iterations", "repeats", "warmup", "load_1min",
    "peak_rss_mb", "rss_growth_mb", "reason", "note", "date", "machine", "cpu", "cores", "python", "refine", "casadi", "pinocchio", "drake",
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


def _call(problem: BenchProblem, contender: str, function: Callable[[BenchProblem], Answer]) -> Answer:
    """One run of a contender; a crash is a ``failed`` answer (:class:`Unavailable` passes through)."""
    try:
        return function(problem)
    except Unavailable:
        raise
    except Exception as e:  # a contender crashing is a result, not the end of the benchmark
        log.warning("%s on %s failed: %s", contender, problem.name, e)
        return Answer("failed", None, note=f"{type(e).__name__}: {str(e)[:120]}")


def run_problem(
    problem: BenchProblem,
    contender: str,
    function: Callable[[BenchProblem], Answer],
    repeat: int,
    warmup: int = 0,
) -> dict[str, Any] | None:
    """One row for ``contender`` on ``problem`` after ``warmup`` untimed runs (see :func:`run_turns`)."""
    return run_turns(problem, {contender: function}, repeat, warmup)[contender]


def run_turns(
    problem: BenchProblem,
    functions: dict[str, Callable[[BenchProblem], Answer]],
    repeat: int,
    warmup: int = 0,
    echo: Callable[[str], None] = print,
) -> dict[str, dict[str, Any]]:
    """One row per contender of ``functions`` on ``problem``, the contenders taking turns.

    Each contender runs ``warmup`` times untimed, then the ``repeat`` timed runs go round the
    contenders in turn. A contender that raises :class:`Unavailable` is left out with a message.
    """
    functions = dict(functions)
    for name in list(functions):
        try:
            for _ in range(warmup):
                _call(problem, name, functions[name])
        except Unavailable as e:
            echo(f"skipping {name}: {e}")
            del functions[name]
    answers: dict[str, list[Answer]] = {name: [] for name in functions}
    load0 = _load()
    peak0 = _peak_rss_mb()
    for _ in range(repeat):
        for name in list(functions):
            try:
                answers[name].append(_call(problem, name, functions[name]))
            except Unavailable as e:
                echo(f"skipping {name}: {e}")
                del functions[name], answers[name]
    load = f"{load0:.2f}-{_load():.2f}"
    return {name: _row(problem, name, runs, warmup, load, peak0) for name, runs in answers.items() if runs}


def _load() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:
        return float("nan")


def _row(
    problem: BenchProblem, contender: str, runs: list[Answer], warmup: int, load: str, peak0: float
) -> dict[str, Any]:
    """The CSV row of ``contender``'s timed runs on ``problem``; the last answer is verified."""
    answer = runs[-1]
    walls = [a.times_s for a in runs]
    cpus = [a.cpu_s for a in runs]
    repeat = len(runs)
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
        "min_cpu_s": min(cpus),
        "iterations": answer.iterations,
        "repeats": repeat,
        "warmup": warmup,
        "load_1min": load,
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
    warmup: int = 0,
    echo: Callable[[str], None] = print,
) -> list[dict[str, Any]]:
    """Run every contender on every problem of ``suites`` and append the rows to ``csv_path``.

    Columns (:data:`COLUMNS`): the problem (suite, name, robot, waypoints, whether it has a cell, the
    outcome it is built for), the contender, its own status, the shared verification (``verified``:
    every tolerance kept; ``success``: see :func:`success`; worst position and orientation, least
    clearance), wall time per stage and in total (median over repeats, and the minimum total), CPU
    time (median and minimum), solver iterations, the repeats and untimed warm-up runs, the 1-minute
    load average before and after the timed runs, the process's peak resident memory after the row
    and its growth during it [MB] (memory stays allocated, so the growth is the row's own only
    where it sets a new peak), the first broken tolerance, and the machine and versions.
    Contenders take turns on each problem (:func:`run_turns`).
    """
    contenders = list(contenders)
    unknown = [c for c in contenders if c not in CONTENDERS]
    if unknown:
        raise InputError(f"unknown contender(s) {unknown}; contenders: {', '.join(CONTENDERS)}")
    if repeat < 1:
        raise InputError(f"repeat must be >= 1, got {repeat}")
    if warmup < 0:
        raise InputError(f"warmup must be >= 0, got {warmup}")
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
                t0 = time.perf_counter()
                functions = {name: CONTENDERS[name] for name in contenders if name not in skipped}
                found = run_turns(problem, functions, repeat, warmup, echo)
                skipped |= set(functions) - set(found)
                for name, row in found.items():
                    row.update(env)
                    writer.writerow({k: _cell(row.get(k, "")) for k in COLUMNS})
                    f.flush()
                    rows.append(row)
                    echo(
                        f"{suite:11s} {problem.name:28s} {name:16s} {row['status']:10s} "
                        f"verified {'yes' if row['verified'] else 'no ':3s} success {'yes' if row['success'] else 'no '} "
                        f"total {row['total_s']:7.3f} s cpu {row['cpu_s']:7.3f} s load {row['load_1min']} "
                        f"({time.perf_counter() - t0:.1f} s for the problem's runs)"
                    )
    return rows


def _cell(value: Any) -> Any:
    if isinstance(value, float):
        return "" if np.isnan(value) else f"{value:.6g}"
    return value
