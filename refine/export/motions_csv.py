"""``motions.csv``: every motion of the program, one per row (the run's ``motions``, docs/outputs.md)."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

from refine.plan.motion import TABLE_COLUMNS, table_rows


def write_motions_csv(path: str | Path, motions: tuple[Any, ...]) -> Path:
    """Write ``motions`` (``refine.plan.motion.Motion``) as ``motions.csv``; returns the path."""
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(TABLE_COLUMNS))
        writer.writeheader()
        writer.writerows(table_rows(tuple(motions)))
    return path
