"""Run contenders on the problems of suites and write one CSV row per problem and contender.

Every row carries the machine and the package versions, so a report can be regenerated from the
CSV alone. Times are wall and process CPU seconds: on a shared machine the CPU time is the steadier
figure. Every contender first runs ``warmup`` times untimed on each problem (libraries loaded,
compiled kernels and caches warm, for every contender alike); then the ``repeat`` timed runs of the
contenders take turns (refine, Drake, refine, Drake, ...), so a change of the machine's load falls
on all of them alike. A row holds the median wall time of each stage, the median and minimum of the
total, the median and minimum CPU time, and the 1-minute load average before and after its runs.
A row is scored by :mod:`refine.bench.outcomes`; every row of one call of :func:`run_suites` has
its run id, and the CSV's header is checked before anything is appended (:mod:`refine.bench.table`).
"""

from __future__ import annotations

import csv
import datetime
import json
import logging
import os
import platform
import resource
import statistics
import tempfile
import time
from collections.abc import Callable, Iterable
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from refine.bench import peers  # noqa: F401  (adds trajopt and descartes to CONTENDERS)
from refine.bench.contenders import CONTENDERS, Answer, NotPosed, Unavailable, verify
from refine.bench.outcomes import DEFAULT_TIME_LIMIT_S, penalised, score
from refine.bench.provenance import DEFAULT_BLAS_THREADS, fixed_threads, git_commit, solver_versions
from refine.bench.provenance import blas_threads as current_blas_threads
from refine.bench.quality import evaluate
from refine.bench.rules import columns as rules_columns
from refine.bench.suites import BenchProblem, load_suites, problems
from refine.bench.table import COLUMNS, NOT_POSED, SCHEMA_VERSION, check_header, new_run_id
from refine.bench.watchdog import Workers, captured, output_summary, prepare
from refine.errors import InputError

log = logging.getLogger(__name__)


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
        "git_commit": git_commit(),
        "casadi": version("casadi"),
        "solver_versions": solver_versions(),
        "pinocchio": version("pin"),
        "drake": version("drake"),
    }


def _peak_rss_mb() -> float:
    """The peak resident memory [MB] of this process or of the largest child it has waited for.

    The children are the watchdog's (:mod:`refine.bench.watchdog`), which run the forked contenders.
    """
    peaks = (resource.getrusage(who).ru_maxrss for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    return max(peaks) / 1024.0  # Linux: kilobytes


def run_problem(
    problem: BenchProblem,
    contender: str,
    function: Callable[[BenchProblem], Answer],
    repeat: int,
    warmup: int = 0,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    isolate: bool = True,
) -> dict[str, Any] | None:
    """One row for ``contender`` on ``problem`` after ``warmup`` untimed runs (see :func:`run_turns`)."""
    return run_turns(
        problem, {contender: function}, repeat, warmup, time_limit_s=time_limit_s, isolate=isolate
    ).get(contender)


def run_turns(
    problem: BenchProblem,
    functions: dict[str, Callable[[BenchProblem], Answer]],
    repeat: int,
    warmup: int = 0,
    echo: Callable[[str], None] = print,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    unavailable: dict[str, str] | None = None,
    isolate: bool = True,
    log_dir: Path | None = None,
    output: dict[str, str] | None = None,
) -> dict[str, dict[str, Any]]:
    """One row per contender of ``functions`` on ``problem``, the contenders taking turns.

    Each contender first makes its declared set-up (:func:`refine.bench.watchdog.prepare`, in this
    process, untimed; its wall and CPU time go to ``setup_s`` and ``setup_cpu_s``) and runs
    ``warmup`` times untimed, then the ``repeat`` timed runs go round the contenders in turn. A
    contender that raises :class:`Unavailable` is left out with a message (and its reason put in
    ``unavailable``, by name, when given); one that raises :class:`NotPosed` is left out of this
    problem only, and its row here is status ``unavailable`` with ``not posed:`` and the reason in
    ``note``.
    Every run (warm-up ones included) is held to ``time_limit_s``
    (:class:`refine.bench.watchdog.Workers`): refine's contenders stop there themselves, any
    other runs in its worker, a child forked once for the problem that makes all its runs, warm-up
    ones included, and is killed at the limit (``isolate``; with False, or without
    ``fork``, it runs in this process and a run over the limit is only scored so). A timed run
    that ends ``timeout``, or takes longer than the limit on its own clock, times the row out.
    ``log_dir``: a folder for each run's log (``CONTENDER-warmup-K.log``, ``CONTENDER-K.log``, K
    from 1; ``CONTENDER-setup.log``: its declared set-up): what the run printed, the solver's
    iteration log included. Without ``log_dir`` each run's output goes to a temporary file, and
    ``output`` (when given) receives, by name, a line saying how many lines a contender printed
    and the last error-like one (:func:`refine.bench.watchdog.output_summary`); the files are
    then removed.
    """
    with tempfile.TemporaryDirectory(prefix="refine-bench-") as scratch:
        folder = Path(scratch) if log_dir is None else log_dir
        logs: dict[str, list[Path]] = {}
        rows = _turns(
            problem, functions, repeat, warmup, echo, time_limit_s, unavailable, isolate, folder, logs
        )
        if log_dir is None and output is not None:
            for name, paths in logs.items():
                summary = output_summary(paths, name)
                if summary is not None:
                    output[name] = summary
    return rows


def _turns(
    problem: BenchProblem,
    functions: dict[str, Callable[[BenchProblem], Answer]],
    repeat: int,
    warmup: int,
    echo: Callable[[str], None],
    time_limit_s: float,
    unavailable: dict[str, str] | None,
    isolate: bool,
    folder: Path,
    logs: dict[str, list[Path]],
) -> dict[str, dict[str, Any]]:
    """:func:`run_turns` with each run's output sent to a file in ``folder``, listed in ``logs``."""

    def log(name: str, kind: str, k: int | None) -> Path:
        path = folder / (f"{name}{kind}.log" if k is None else f"{name}{kind}-{k + 1}.log")
        logs.setdefault(name, []).append(path)
        return path

    functions = dict(functions)
    setups: dict[str, tuple[float, float]] = {}  # name -> the declared set-up's wall and CPU time [s]
    answers: dict[str, list[tuple[Answer, float]]] = {}

    not_posed: dict[str, str] = {}  # name -> why it does not pose this problem

    def drop(name: str, e: Exception) -> None:
        del functions[name]
        answers.pop(name, None)
        if isinstance(e, NotPosed):
            echo(f"{name} does not pose {problem.name}: {e}")
            not_posed[name] = str(e)
            return
        echo(f"skipping {name}: {e}")
        if unavailable is not None:
            unavailable[name] = str(e)

    with Workers() as workers:
        for name in list(functions):
            try:
                setup_log = log(name, "-setup", None)
                try:
                    with captured(setup_log):
                        setups[name] = prepare(problem, functions[name])
                finally:
                    if setup_log.is_file() and setup_log.stat().st_size == 0:  # a set-up that printed nothing leaves no file
                        setup_log.unlink()
                for k in range(warmup):
                    workers.run(
                        problem, name, functions[name], time_limit_s, isolate, log(name, "-warmup", k)
                    )
            except (Unavailable, NotPosed) as e:
                drop(name, e)
        answers = {name: [] for name in functions}
        load0 = _load()
        peak0 = _peak_rss_mb()
        for k in range(repeat):
            for name in list(functions):
                try:
                    answers[name].append(
                        workers.run(problem, name, functions[name], time_limit_s, isolate, log(name, "", k))
                    )
                except (Unavailable, NotPosed) as e:
                    drop(name, e)
    load = f"{load0:.2f}-{_load():.2f}"
    rows = {
        name: _row(problem, name, runs, warmup, load, peak0, time_limit_s, setups.get(name, (0.0, 0.0)))
        for name, runs in answers.items()
        if runs
    }
    for name, reason in not_posed.items():
        rows[name] = _unavailable_row(problem, name, f"{NOT_POSED} {reason}", warmup, time_limit_s)
    return rows


def _load() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:
        return float("nan")


def _row(
    problem: BenchProblem,
    contender: str,
    timed: list[tuple[Answer, float]],
    warmup: int,
    load: str,
    peak0: float,
    time_limit_s: float,
    setup: tuple[float, float] = (0.0, 0.0),
) -> dict[str, Any]:
    """The CSV row of ``contender``'s timed runs on ``problem``: every answer verified and scored.

    The row is a success (a detection) only when every timed run is one; its verification figures
    and quality columns are the last answer's.
    """
    runs = [a for a, _ in timed]
    answer = runs[-1]
    walls = [a.times_s for a in runs]
    cpus = [a.cpu_s for a in runs]
    repeat = len(runs)
    timed_out = any(wall > time_limit_s or a.status == "timeout" for a, wall in timed)
    verdicts, scores, kept = [], [], []
    for a in runs:
        verdict = verify(problem, a.q)
        repaired = a.status == "repaired" and verify(problem, a.q, a.slack_deg).verified
        verdicts.append(verdict)
        kept.append(claim_kept(a.status, verdict.verified, repaired))
        scores.append(
            score(
                problem.expected,
                problem.expected_s_range_m,
                a.status,
                a.q,
                problem.n_waypoints,
                verdict.verified,
                repaired,
                verdict.broken_s_m,
                timed_out,
                a.solver_status,
            )
        )
    verdict = verdicts[-1]
    success = all(s.success for s in scores)
    detected = all(s.detected_infeasible for s in scores)
    failed = not (success or detected)
    quality = evaluate(problem, answer.q)
    totals = [sum(w.values()) for w in walls]
    stage = {k: statistics.median(w.get(k, 0.0) for w in walls) for k in ("build", "seed", "solve")}
    peak = _peak_rss_mb()
    return {
        **_problem_columns(problem, contender),
        "status": "timeout" if timed_out else answer.status,
        "solver_status": answer.solver_status,
        **_claims_columns(kept, verdicts),
        "success": success,
        "detected_infeasible": detected,
        "timed_out": timed_out,
        "time_limit_s": time_limit_s,
        "objective": quality.objective,
        "primal_residual": quality.primal_residual,
        "dual_residual": quality.dual_residual,
        "max_position_error_m": verdict.max_position_error_m,
        "max_orientation_deviation_deg": verdict.max_orientation_deviation_deg,
        "min_clearance_m": verdict.min_clearance_m,
        "max_joint_step_deg": verdict.max_joint_step_deg,
        **rules_columns(contender, CONTENDERS.get(contender)),
        "setup_s": setup[0],
        "setup_cpu_s": setup[1],
        "build_s": stage["build"],
        "seed_s": stage["seed"],
        "solve_s": stage["solve"],
        "total_s": statistics.median(totals),
        "min_total_s": min(totals),
        "max_total_s": max(totals),
        "penalised_total_s": penalised(statistics.median(totals), failed, time_limit_s),
        "cpu_s": statistics.median(cpus),
        "min_cpu_s": min(cpus),
        "max_cpu_s": max(cpus),
        "penalised_cpu_s": penalised(statistics.median(cpus), failed, time_limit_s),
        "verify_s": statistics.median(a.verify_s for a in runs),
        "verify_cpu_s": statistics.median(a.verify_cpu_s for a in runs),
        "iterations": answer.iterations,
        "repeats": repeat,
        "warmup": warmup,
        "load_1min": load,
        "peak_rss_mb": peak,
        "rss_growth_mb": peak - peak0,
        "reason": verdict.reason[:160],
        "note": answer.note,
        "solver_options": json.dumps(answer.solver_options, sort_keys=True, default=str),
    }


def claim_kept(status: str, verified: bool, verified_with_slack: bool) -> bool | None:
    """Whether an answer keeps every rule it claims; None when it claims no path.

    ``ok`` claims the problem's tolerances (``verified``: the shared verification passed); ``repaired``
    claims them widened by the slack it reports and no more (``verified_with_slack``); any other
    status (``infeasible``, ``failed``, ``error``, ``timeout``) claims no path, so there is none to
    verify (a stated infeasibility's detection is scored apart: :func:`refine.bench.outcomes.score`).
    """
    if status == "ok":
        return verified
    if status == "repaired":
        return verified_with_slack
    return None


def _claims_columns(kept: list[bool | None], verdicts: list[Any]) -> dict[str, Any]:
    """``verified``, ``verified_runs``, ``claimed_runs`` and ``strict_runs`` of a row's timed runs.

    ``kept``: :func:`claim_kept` per run; ``verdicts``: the shared verification per run. ``verified``
    is empty when no run claims a path.
    """
    claimed = [k for k in kept if k is not None]
    return {
        "verified": all(claimed) if claimed else "",
        "verified_runs": sum(claimed),
        "claimed_runs": len(claimed),
        "strict_runs": sum(v.verified for v in verdicts),
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
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    run_id: str | None = None,
    blas_threads: int = DEFAULT_BLAS_THREADS,
    solver_options: dict[str, Any] | None = None,
    isolate: bool = True,
    log_dir: Path | None = None,
) -> list[dict[str, Any]]:
    """Run every contender on every problem of ``suites`` and append the rows to ``csv_path``.

    Every row carries the schema version and the run id (``run_id``, or a new one:
    :func:`refine.bench.table.new_run_id`). An existing ``csv_path`` is appended to only when its
    header is this version's (else :class:`InputError`, before any contender runs).

    Columns (:data:`COLUMNS`): the problem (suite, name, robot, waypoints, whether it has a cell, the
    outcome it is built for), the contender, its own status (``error`` when it raised, ``timeout``
    when a timed run took longer than ``time_limit_s``), the shared verification (``verified``:
    every tolerance kept; ``success`` and ``detected_infeasible``: :mod:`refine.bench.outcomes`;
    worst position and orientation, least clearance, largest joint step between waypoints), the
    rules the contender poses and those it does not (:func:`refine.bench.rules.columns`), wall time per stage and in total (median over
    repeats, the minimum total, and the total counted as the time limit for a row that is neither a
    success nor a detection), CPU time (likewise), solver iterations, the repeats and untimed warm-up runs, the 1-minute
    load average before and after the timed runs, the peak resident memory of the process or of a
    watchdog's child after the row and its growth during it [MB] (memory stays allocated, so the growth is the row's own only
    where it sets a new peak), the first broken tolerance, and the machine and versions.
    Contenders take turns on each problem (:func:`run_turns`). Every BLAS runs with
    ``blas_threads`` threads throughout (:func:`refine.bench.provenance.fixed_threads`, recorded
    in ``blas_threads``); the quality columns are :func:`refine.bench.quality.evaluate`'s.
    ``solver_options`` (keyed with the
    solver's prefix, ``ipopt.max_iter``) go to every problem (``BenchProblem.solver_options``); each
    row's ``solver_options`` is what its contender reports it used, as JSON. ``isolate``: run the
    contenders that do not keep the time limit themselves under the watchdog (:func:`run_turns`).
    ``log_dir``: each run's log goes to ``log_dir/RUN_ID/SUITE/PROBLEM/`` (:func:`run_turns`), and
    refine's IPOPT prints its iteration log there (``ipopt.print_level`` 5 unless given).
    """
    contenders = list(contenders)
    unknown = [c for c in contenders if c not in CONTENDERS]
    if unknown:
        raise InputError(f"unknown contender(s) {unknown}; contenders: {', '.join(CONTENDERS)}")
    if repeat < 1:
        raise InputError(f"repeat must be >= 1, got {repeat}")
    if warmup < 0:
        raise InputError(f"warmup must be >= 0, got {warmup}")
    if not time_limit_s > 0:
        raise InputError(f"time limit must be > 0 s, got {time_limit_s} s")
    if blas_threads < 1:
        raise InputError(f"BLAS threads must be >= 1, got {blas_threads}")
    data = load_suites(suites_file) if suites_file else load_suites()
    new = check_header(csv_path)
    env = environment()
    env.update(schema=SCHEMA_VERSION, run_id=run_id or new_run_id())
    echo(f"run {env['run_id']} into {csv_path}")
    rows: list[dict[str, Any]] = []
    skipped: dict[str, str] = {}  # contender -> why it cannot run here
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    with csv_path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        if new:
            writer.writeheader()
        for suite in suites:
            for problem in problems(data, suite):
                problem.solver_options = dict(solver_options or {})
                logs = None if log_dir is None else Path(log_dir) / env["run_id"] / suite / problem.name
                if logs is not None:
                    problem.solver_options.setdefault("ipopt.print_level", LOG_PRINT_LEVEL)
                t0 = time.perf_counter()
                functions = {name: CONTENDERS[name] for name in contenders if name not in skipped}
                output: dict[str, str] = {}  # contender -> what its runs printed, without log_dir
                with fixed_threads(blas_threads):  # libraries loaded by earlier problems included
                    found = run_turns(
                        problem, functions, repeat, warmup, echo, time_limit_s, skipped, isolate, logs,
                        output,
                    )
                    threads = current_blas_threads()  # as they were for these runs
                for name in contenders:  # a contender that cannot run here still leaves its row
                    if name in skipped and name not in found:
                        found[name] = _unavailable_row(problem, name, skipped[name], warmup, time_limit_s)
                found = {name: found[name] for name in contenders if name in found}
                for name, row in found.items():
                    row.update(env, blas_threads=threads)
                    writer.writerow({k: _cell(row.get(k, ""), k in EXACT) for k in COLUMNS})
                    f.flush()
                    rows.append(row)
                    echo(
                        f"{suite:11s} {problem.name:28s} {name:16s} {row['status']:10s} "
                        f"verified {_said(row['verified']):3s} success {'yes' if row['success'] else 'no '} "
                        f"detected {'yes' if row['detected_infeasible'] else 'no '} "
                        f"total {row['total_s']:7.3f} s cpu {row['cpu_s']:7.3f} s set-up {row.get('setup_s', 0.0):6.3f} s load {row.get('load_1min', '')} "
                        f"({time.perf_counter() - t0:.1f} s for the problem's runs)"
                    )
                    if name in output:
                        echo(f"  {output[name]}")
    return rows


def _problem_columns(problem: BenchProblem, contender: str) -> dict[str, Any]:
    """The columns that name the problem and the contender."""
    return {
        "suite": problem.suite,
        "problem": problem.name,
        "robot": problem.robot.spec.name,
        "n_waypoints": problem.n_waypoints,
        "obstacles": bool(problem.sources),
        "expected": problem.expected,
        "contender": contender,
    }


def _unavailable_row(
    problem: BenchProblem, contender: str, reason: str, warmup: int, time_limit_s: float
) -> dict[str, Any]:
    """The row of a contender that cannot run here: status ``unavailable``, the reason in ``note``."""
    return {
        **_problem_columns(problem, contender),
        "status": "unavailable",
        "verified": "",
        "verified_runs": 0,
        "claimed_runs": 0,
        "strict_runs": 0,
        "success": False,
        "detected_infeasible": False,
        "timed_out": False,
        "time_limit_s": time_limit_s,
        "total_s": float("nan"),
        "cpu_s": float("nan"),
        "penalised_total_s": time_limit_s,
        "penalised_cpu_s": time_limit_s,
        "repeats": 0,
        "warmup": warmup,
        "note": reason[:160],
    }


LOG_PRINT_LEVEL = 5
"""IPOPT's print level for the runs of ``bench run --log-dir`` (one line per iteration)."""

EXACT = ("objective", "primal_residual", "dual_residual")
"""Columns written with 15 significant digits (the others with 6): an objective is compared closely."""


def _said(verified: Any) -> str:
    """``yes``, ``no``, or ``–`` when no run claimed a path."""
    return "–" if verified == "" else "yes" if verified else "no"


def _cell(value: Any, exact: bool = False) -> Any:
    if isinstance(value, float):
        return "" if np.isnan(value) else f"{value:.15g}" if exact else f"{value:.6g}"
    return value
