"""The benchmark CSV: its columns and schema version, run ids, the header check, and one run's rows.

Every ``refine bench run`` gets a run id written in each of its rows; a CSV is appended to only
when its header is exactly :data:`COLUMNS` (docs/bench.md). The report takes the rows of one run.
"""

from __future__ import annotations

import csv
import datetime
import uuid
from pathlib import Path

from refine.errors import InputError

SCHEMA_VERSION = "6"
"""Version of :data:`COLUMNS`, written in every row (``schema``); raised whenever the columns change."""

COLUMNS = [
    "schema", "run_id", "suite", "problem", "robot", "n_waypoints", "obstacles", "expected", "contender",
    "status", "solver_status", "verified", "verified_runs", "claimed_runs", "strict_runs", "success",
    "detected_infeasible", "timed_out", "time_limit_s", "objective", "primal_residual", "dual_residual",
    "max_position_error_m", "max_orientation_deviation_deg", "min_clearance_m", "max_joint_step_deg",
    "rules_kept", "rules_not_kept", "setup_s", "setup_cpu_s", "build_s", "seed_s", "solve_s", "total_s",
    "min_total_s", "max_total_s", "penalised_total_s", "cpu_s", "min_cpu_s", "max_cpu_s", "penalised_cpu_s",
    "verify_s", "verify_cpu_s", "iterations", "repeats", "warmup", "load_1min", "peak_rss_mb",
    "rss_growth_mb", "reason", "note", "solver_options", "blas_threads", "date", "machine", "cpu", "cores",
    "python", "refine", "git_commit", "casadi", "solver_versions", "pinocchio", "drake",
]  # fmt: skip
"""The CSV columns, in order (docs/bench.md)."""

Row = dict[str, str]


def new_run_id() -> str:
    """A run id: the UTC start time to the second and 6 random hex digits, e.g. ``20261201T213000Z-3fa2c1``."""
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    return f"{now}-{uuid.uuid4().hex[:6]}"


def check_header(csv_path: Path) -> bool:
    """Whether ``csv_path`` is new (absent or empty); raises unless its header is :data:`COLUMNS`.

    Raises:
        InputError: the file's header differs, naming the file and both column counts.
    """
    path = Path(csv_path)
    if not path.exists() or path.stat().st_size == 0:
        return True
    with path.open(newline="") as f:
        header = next(csv.reader(f), [])
    if header != COLUMNS:
        pairs = zip(header, COLUMNS, strict=False)
        differ = next((i for i, (a, b) in enumerate(pairs) if a != b), min(len(header), len(COLUMNS)))
        raise InputError(
            f"benchmark CSV {path}: its header has {len(header)} columns, this version writes "
            f"{len(COLUMNS)} (schema {SCHEMA_VERSION}; first difference at column {differ + 1}); "
            "rows would be misaligned, so nothing was appended: give another file with --csv"
        )
    return False


def read_runs(csv_path: Path, run_ids: list[str] | None = None) -> list[tuple[str, list[Row]]]:
    """The rows of some runs of a benchmark CSV (as strings), run by run: ``run_ids``', or the last run's.

    The last run is that of the file's last row (runs are appended). Returns (run id, its rows) per run.

    Raises:
        InputError: unreadable file, no rows, a header of another schema, or an unknown run id.
    """
    path = Path(csv_path)
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            header = reader.fieldnames or []
            rows = list(reader)
    except OSError as e:
        raise InputError(f"benchmark CSV {path}: {e}") from e
    if header != COLUMNS:
        raise InputError(
            f"benchmark CSV {path}: its header has {len(header)} columns, schema {SCHEMA_VERSION} has "
            f"{len(COLUMNS)}; it was written by another version (its columns would be misread): "
            "run the benchmark again into a new file"
        )
    if not rows:
        raise InputError(f"benchmark CSV {path} has no rows")
    runs = list(dict.fromkeys(r["run_id"] for r in rows))
    chosen = list(dict.fromkeys(run_ids)) if run_ids else [runs[-1]]
    unknown = [r for r in chosen if r not in runs]
    if unknown:
        raise InputError(f"benchmark CSV {path} has no run {', '.join(unknown)}; its runs: {', '.join(runs)}")
    return [(run, [r for r in rows if r["run_id"] == run]) for run in chosen]


def read_run(csv_path: Path, run_id: str | None = None) -> tuple[str, list[Row]]:
    """The rows of one run (:func:`read_runs`): ``run_id``'s, or the last run's; returns the id and rows."""
    return read_runs(csv_path, [run_id] if run_id else None)[0]


NOT_POSED = "not posed:"
"""How the ``note`` of a row begins whose contender did not pose its problem (status ``unavailable``;
:class:`refine.bench.contenders.NotPosed`)."""
