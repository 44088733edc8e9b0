"""``motions.csv``: every motion of the program, one per row (the run's ``motions``, docs/outputs.md)."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

from refine.export.sink import put_text
from refine.plan.motion import TABLE_COLUMNS, table_rows


def write_motions_csv(path: str | Path, motions: tuple[Any, ...]) -> Path:
    """Write ``motions`` (``refine.plan.motion.Motion``) as ``motions.csv``; returns the path."""
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, fieldnames=list(TABLE_COLUMNS))
    writer.writeheader()
    writer.writerows(table_rows(tuple(motions)))
    return put_text(Path(path), text.getvalue())
