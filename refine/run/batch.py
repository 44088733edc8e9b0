"""``refine batch PROBLEMS... --out DIR``: many problems in parallel, on this machine or a Dask cluster.

A plant's program library after a cell change, or a parameter sweep, is many independent problems.
Each runs as ``refine run`` would, into its own folder ``DIR/<problem folder name>/``, in a worker:

* on this machine by default, a process pool of ``--workers`` processes (default: the CPU count);
* on a Dask cluster with ``--scheduler tcp://host:port`` (``dask.distributed``; install the
  ``cluster`` extra). The problem and output folders must then be on a file system every worker
  sees under the same paths.

Each problem's files are written by its worker as soon as it finishes. A problem that fails (bad
input, a solver error, a worker lost) is recorded with its error and never stops the others. A
problem whose folder already holds a ``result.json`` (written last, so it marks a finished run) is
skipped with ``--resume``, so an interrupted batch goes on where it stopped; a failed one runs again.
A progress bar on standard error counts done, failed and remaining problems. At the end,
``DIR/summary.csv`` and ``DIR/summary.md`` list every problem with its status and figures.

Exit status: 0 when every problem is ok or repaired, 1 when some are infeasible, 2 when some failed,
130 when interrupted.
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from refine.errors import InputError
from refine.run.result import EXECUTABLE

log = logging.getLogger(__name__)

COLUMNS = (
    "problem",
    "status",
    "n_waypoints",
    "max_orientation_deviation_deg",
    "max_slack_deg",
    "min_clearance_m",
    "cycle_time_s",
    "wall_s",
    "run",
    "reason",
)
"""Columns of ``summary.csv``: the problem (its folder name), ``ok`` / ``repaired`` /
``infeasible`` / ``failed``, the verified figures of ``result.json`` (empty when not measured),
the wall time of its run in the worker [s], ``this batch`` or ``earlier`` (skipped by ``--resume``),
and the reason (error message of a failed problem)."""


@dataclass(frozen=True)
class BatchItem:
    """One problem of a batch.

    Attributes:
        key: the problem's folder name, unique in the batch; its output folder's name.
        problem: the problem file.
        out_dir: its output folder.
    """

    key: str
    problem: Path
    out_dir: Path


@dataclass
class BatchSummary:
    """What a batch did.

    Attributes:
        rows: one summary row per problem (keys of :data:`COLUMNS`), in the order given.
        wall_s: wall time of the batch [s] (the problems run now, not the skipped ones).
        workers: workers used (processes, or the cluster's workers).
        skipped: problems skipped because they had finished earlier (``--resume``).
        interrupted: the batch was stopped (Ctrl-C) before every problem ran.
    """

    rows: list[dict[str, Any]]
    wall_s: float
    workers: int
    skipped: int = 0
    interrupted: bool = False
    counts: dict[str, int] = field(default_factory=dict)

    def exit_status(self) -> int:
        """0 all ok or repaired, 1 some infeasible or timed out, 2 some failed, 130 interrupted."""
        statuses = {r["status"] for r in self.rows}
        if self.interrupted:
            return 130
        return 2 if "failed" in statuses else 1 if {"infeasible", "timeout"} & set(statuses) else 0


def collect(paths: Iterable[str | Path], out_dir: Path) -> list[BatchItem]:
    """The batch's problems, with their output folders.

    Each path is a problem folder, a ``problem.toml``, or a folder whose subfolders hold problems
    (taken in name order).

    Raises:
        InputError: a path holds no problem, or two problems share a folder name (their outputs
            would collide).
    """
    items: list[BatchItem] = []
    seen: dict[str, Path] = {}
    for raw in paths:
        path = Path(raw)
        if path.is_file():
            found = [path]
        elif (path / "problem.toml").is_file():
            found = [path / "problem.toml"]
        elif path.is_dir():
            found = sorted(p / "problem.toml" for p in path.iterdir() if (p / "problem.toml").is_file())
            if not found:
                raise InputError(f"{path}: no problem.toml in it or in its subfolders")
        else:
            raise InputError(f"{path}: no such problem folder or file")
        for f in found:
            key = f.resolve().parent.name
            if key in seen:
                raise InputError(
                    f"two problems share the folder name {key!r} ({seen[key]} and {f}); "
                    "their outputs would collide in the output folder"
                )
            seen[key] = f
            items.append(BatchItem(key, f.resolve(), out_dir / key))
    if not items:
        raise InputError("no problems given")
    return items


def finished_row(item: BatchItem) -> dict[str, Any] | None:
    """The summary row of a problem whose output folder holds a readable ``result.json``, else None."""
    path = item.out_dir / "result.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or "status" not in doc:
        return None
    return _row(item.key, doc, doc.get("timings_s", {}).get("run"), "earlier")


def _row(key: str, doc: dict[str, Any], wall_s: float | None, when: str) -> dict[str, Any]:
    metrics = doc.get("metrics") or {}
    return {
        "problem": key,
        "status": doc["status"],
        "n_waypoints": doc.get("n_waypoints"),
        **{
            k: metrics.get(k)
            for k in ("max_orientation_deviation_deg", "max_slack_deg", "min_clearance_m", "cycle_time_s")
        },
        "wall_s": wall_s,
        "run": when,
        "reason": doc.get("reason", ""),
    }


def run_one(
    key: str, problem: str, out_dir: str, programs: tuple[str, ...] | None, report: bool
) -> dict[str, Any]:
    """Run one problem into ``out_dir`` (in a worker) and return its summary row; never raises.

    A failure is returned as a row with status ``failed`` and the error, and written to
    ``out_dir/error.txt`` with its traceback.
    """
    t0 = time.perf_counter()
    try:
        (Path(out_dir) / "error.txt").unlink(missing_ok=True)  # from an earlier failed attempt
        from refine.export.result_json import write_timings
        from refine.interrupt import guarded
        from refine.problem import load_problem
        from refine.run.write import run

        with guarded():  # a pool worker of the batch command: its moves hold Ctrl-C back
            result = run(load_problem(problem), Path(out_dir), programs, report=report)
        result.timings_s["run"] = time.perf_counter() - t0
        # the run's wall time is known only now: rewrite timings_s alone (atomically), the rest of
        # the document and its files' SHA-256 standing as written
        path = write_timings(result.outputs["result"], result)
        return _row(key, json.loads(path.read_text(encoding="utf-8")), result.timings_s["run"], "this batch")
    except BaseException as e:  # noqa: BLE001 - one problem's failure must not stop the batch
        if isinstance(e, KeyboardInterrupt):
            raise
        message = f"{type(e).__name__}: {e}"
        try:
            Path(out_dir).mkdir(parents=True, exist_ok=True)
            (Path(out_dir) / "error.txt").write_text(
                message + "\n\n" + traceback.format_exc(), encoding="utf-8"
            )
        except OSError:
            pass
        return _failed(key, message, time.perf_counter() - t0)


def _failed(key: str, reason: str, wall_s: float | None = None) -> dict[str, Any]:
    row: dict[str, Any] = dict.fromkeys(COLUMNS)
    row.update(problem=key, status="failed", wall_s=wall_s, run="this batch", reason=reason)
    return row


# ---- executors ------------------------------------------------------------------------------------


def _local(workers: int, items: list[BatchItem], task: Callable[[BatchItem], tuple]) -> Iterator[tuple]:
    """Run on a process pool; yields (item, row) as each finishes."""
    from concurrent.futures import Future, ProcessPoolExecutor, as_completed  # only a batch needs a pool

    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures: dict[Future, BatchItem] = {pool.submit(run_one, *task(it)): it for it in items}
        try:
            for fut in as_completed(futures):
                yield futures[fut], _result(fut.result, futures[fut])
        except BaseException:
            for fut in futures:
                fut.cancel()
            pool.shutdown(wait=False, cancel_futures=True)
            raise


def _dask(scheduler: Any, items: list[BatchItem], task: Callable[[BatchItem], tuple]) -> Iterator[tuple]:
    """Run on a Dask cluster (an address or a ``distributed.Client``); yields (item, row)."""
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError as e:  # pragma: no cover - the extra is part of the test set-up
        raise InputError(
            "--scheduler needs dask.distributed: pip install 'refine[cluster]' (or 'dask[distributed]')"
        ) from e
    own = not isinstance(scheduler, Client)
    try:
        client = Client(scheduler, timeout="20s") if own else scheduler
    except OSError as e:
        raise InputError(f"--scheduler {scheduler}: cannot reach the Dask scheduler: {e}") from e
    try:
        futures = {
            client.submit(run_one, *task(it), pure=False, key=f"refine-batch-{it.key}-{time.time_ns()}"): it
            for it in items
        }
        try:
            for fut in dask_completed(list(futures)):
                yield futures[fut], _result(fut.result, futures[fut])
        except BaseException:
            client.cancel(list(futures))
            raise
    finally:
        if own:
            client.close()


def _result(get: Callable[[], dict[str, Any]], item: BatchItem) -> dict[str, Any]:
    """The row a finished task returned, or a failed row when the worker itself failed."""
    try:
        return get()
    except KeyboardInterrupt:
        raise
    except BaseException as e:  # noqa: BLE001 - a lost worker or an unpicklable error
        return _failed(item.key, f"worker failed: {type(e).__name__}: {e}")


def dask_workers(scheduler: Any) -> int:
    """Number of workers the cluster at ``scheduler`` has now (0 if it cannot be asked)."""
    try:
        from distributed import Client

        if isinstance(scheduler, Client):
            return len(scheduler.scheduler_info().get("workers", {}))
        with Client(scheduler, timeout="20s") as client:
            return len(client.scheduler_info().get("workers", {}))
    except Exception:  # noqa: BLE001 - only for the summary line
        return 0


# ---- the batch ------------------------------------------------------------------------------------


def run_batch(
    problems: Sequence[str | Path],
    out_dir: str | Path,
    *,
    workers: int | None = None,
    scheduler: Any = None,
    resume: bool = False,
    programs: tuple[str, ...] | None = None,
    report: bool = True,
    progress: bool = True,
    on_result: Callable[[dict[str, Any]], None] | None = None,
) -> BatchSummary:
    """Run many problems in parallel and write ``summary.csv`` and ``summary.md`` into ``out_dir``.

    Args:
        problems: problem folders, problem files, or folders of problem folders.
        out_dir: the batch's output folder; each problem writes into ``out_dir/<folder name>/``.
        workers: processes of the local pool (default: the CPU count); ignored with ``scheduler``.
        scheduler: a Dask scheduler address (``tcp://host:port``) or a ``distributed.Client``;
            None for the local pool.
        resume: skip problems whose output folder already holds a ``result.json``.
        programs: program formats overriding each problem's ``[output] programs``.
        report: write each problem's ``report.html``.
        progress: show a progress bar on standard error.
        on_result: called with each row as its problem finishes (in the calling process).

    Returns:
        The summary; ``summary.exit_status()`` is the command's exit status.
    """
    from tqdm import tqdm

    out = Path(out_dir)
    items = collect(problems, out)
    out.mkdir(parents=True, exist_ok=True)
    rows: dict[str, dict[str, Any]] = {}
    if resume:
        for it in items:
            row = finished_row(it)
            if row is not None:
                rows[it.key] = row
    todo = [it for it in items if it.key not in rows]
    skipped = len(rows)
    n_workers = dask_workers(scheduler) if scheduler is not None else max(1, workers or os.cpu_count() or 1)

    def task(it: BatchItem) -> tuple:
        return (it.key, str(it.problem), str(it.out_dir), programs, report)

    counts = {"done": 0, "failed": 0}
    bar = tqdm(
        total=len(todo),
        desc="refine batch",
        unit="problem",
        file=sys.stderr,
        disable=not progress,
        dynamic_ncols=True,
    )
    bar.set_postfix_str(f"done 0, failed 0, remaining {len(todo)}")
    t0 = time.perf_counter()
    interrupted = False
    stream = _dask(scheduler, todo, task) if scheduler is not None else _local(n_workers, todo, task)
    try:
        for it, row in stream:
            rows[it.key] = row
            counts["done" if row["status"] in EXECUTABLE else "failed"] += 1
            remaining = len(todo) - counts["done"] - counts["failed"]
            bar.update(1)
            bar.set_postfix_str(f"done {counts['done']}, failed {counts['failed']}, remaining {remaining}")
            if progress:
                wall = f" in {row['wall_s']:.1f} s" if row.get("wall_s") is not None else ""
                bar.write(f"{it.key}: {row['status']}{wall}", file=sys.stderr)
            if on_result is not None:
                on_result(row)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        stream.close()  # cancels what has not started (running problems finish)
        bar.close()
    wall_s = time.perf_counter() - t0
    ordered = [rows[it.key] for it in items if it.key in rows]
    summary = BatchSummary(ordered, wall_s, n_workers, skipped, interrupted, counts)
    write_summary(summary, out)
    return summary


def write_summary(summary: BatchSummary, out_dir: Path) -> tuple[Path, Path]:
    """Write ``summary.csv`` (every column of :data:`COLUMNS`) and ``summary.md`` (a short table)."""
    csv_path, md_path = out_dir / "summary.csv", out_dir / "summary.md"
    with csv_path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        for row in summary.rows:
            writer.writerow({k: "" if row.get(k) is None else row[k] for k in COLUMNS})
    statuses = [r["status"] for r in summary.rows]
    tally = ", ".join(
        f"{statuses.count(s)} {s}" for s in ("ok", "repaired", "infeasible", "timeout", "failed") if s in statuses
    )
    lines = [
        "# Batch summary",
        "",
        f"{len(summary.rows)} problems: {tally}. {len(summary.rows) - summary.skipped} run in "
        f"{summary.wall_s:.1f} s on {summary.workers} worker(s)"
        + (f", {summary.skipped} finished earlier (resumed)" if summary.skipped else "")
        + (" (interrupted)" if summary.interrupted else "")
        + ".",
        "",
        "| problem | status | waypoints | max orientation deviation [deg] | max slack [deg] "
        "| min clearance [mm] | cycle time [s] | wall time [s] | run |",
        "|---|---|---:|---:|---:|---:|---:|---:|---|",
    ]

    def num(v: Any, fmt: str, scale: float = 1.0) -> str:
        return "" if v is None else format(float(v) * scale, fmt)

    for r in summary.rows:
        lines.append(
            f"| {r['problem']} | {r['status']} | {'' if r['n_waypoints'] is None else r['n_waypoints']} "
            f"| {num(r['max_orientation_deviation_deg'], '.2f')} | {num(r['max_slack_deg'], '.2f')} "
            f"| {num(r['min_clearance_m'], '.1f', 1e3)} | {num(r['cycle_time_s'], '.2f')} "
            f"| {num(r['wall_s'], '.1f')} | {r['run']} |"
        )
    failed = [r for r in summary.rows if r["status"] == "failed"]
    if failed:
        lines += ["", "Failed:", ""] + [f"- {r['problem']}: {r['reason']}" for r in failed]
    md_path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return csv_path, md_path


# ---- command line ---------------------------------------------------------------------------------


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``refine batch`` to the subcommands of ``refine``."""
    p = sub.add_parser(
        "batch",
        help="run many problems in parallel (process pool, or a Dask cluster with --scheduler)",
        description=__doc__.split("\n\n")[1] if __doc__ else None,
    )
    p.add_argument(
        "problems",
        nargs="+",
        type=Path,
        help="problem folders, problem.toml files, or folders of problem folders",
    )
    p.add_argument(
        "--out", type=Path, required=True, help="output folder: one subfolder per problem + summary"
    )
    p.add_argument(
        "--workers", type=int, default=None, help="local worker processes (default: the CPU count)"
    )
    p.add_argument(
        "--scheduler", default=None, metavar="tcp://host:port", help="run on this Dask scheduler instead"
    )
    p.add_argument("--resume", action="store_true", help="skip problems whose folder holds a result.json")
    p.add_argument("--programs", default=None, help="comma-separated program formats for every problem")
    p.add_argument("--no-report", action="store_true", help="do not write report.html")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """``refine batch``: run, print the summary table, return the exit status."""
    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers must be at least 1, got {args.workers}")
    programs = tuple(p.strip() for p in args.programs.split(",") if p.strip()) if args.programs else None
    summary = run_batch(
        args.problems,
        args.out,
        workers=args.workers,
        scheduler=args.scheduler,
        resume=args.resume,
        programs=programs,
        report=not args.no_report,
        progress=not args.no_progress,
    )
    print((args.out / "summary.md").read_text(encoding="utf-8"), end="")
    return summary.exit_status()
