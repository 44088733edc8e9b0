"""CAD/CAM paths as CSV point lists.

The file holds one path point per line, comma separated, in the path's order::

    # glass pane, outer bead          <- comment lines start with '#'
    x, y, z                           <- optional header (any case, spaces allowed)
    0.0, 0.0, 0.0
    120.5, 0.0, 0.0

With a header the columns named ``x``, ``y`` and ``z`` are read, in whatever position, and other
columns (normals, feed rates) are ignored. Without a header every line has exactly three numbers.
Blank lines and ``#`` comments are skipped. A closed path repeats its first point on its last line.
Coordinates are in the unit the caller names (``m``, ``mm`` or ``in``) and returned in metres.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from refine.errors import InputError
from refine.plausible import CAD_COORDINATE_LIMIT_M, check_point

#: Length of one file unit [m], for the units CAD/CAM files use.
METRES_PER_UNIT = {"m": 1.0, "mm": 1e-3, "in": 0.0254}


def metres_per_unit(units: str, source: str) -> float:
    """Scale from a CAD length unit to metres.

    Args:
        units: ``"m"``, ``"mm"`` or ``"in"``.
        source: file name, for the message.

    Raises:
        InputError: an unknown unit, naming the file and the units allowed.
    """
    if units not in METRES_PER_UNIT:
        raise InputError(f"{source}: unknown length unit {units!r}; use one of {', '.join(METRES_PER_UNIT)}")
    return METRES_PER_UNIT[units]


def _read_lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8-sig").splitlines()
    except OSError as e:
        raise InputError(f"CAD file {str(path)!r} cannot be read: {e}") from e
    except UnicodeDecodeError as e:
        raise InputError(f"CAD file {str(path)!r} is not UTF-8 text: {e}") from e


def _header_columns(cells: list[str], where: str) -> tuple[int, int, int] | None:
    """Indices of x, y, z if ``cells`` is a header line, None if it is a data line."""
    names = [c.strip().lower() for c in cells]
    try:
        [float(c) for c in names]
        return None
    except ValueError:
        pass
    missing = [k for k in ("x", "y", "z") if k not in names]
    if missing:
        raise InputError(
            f"{where}: header {', '.join(names)} lacks column(s) {', '.join(missing)} (expected x, y, z)"
        )
    return names.index("x"), names.index("y"), names.index("z")


def points_from_csv(path: str | Path, units: str = "mm") -> NDArray:
    """Read a CSV point list (see the module docstring for the format).

    Args:
        path: the CSV file.
        units: length unit of the coordinates in the file: ``"m"``, ``"mm"`` or ``"in"``.

    Returns:
        The path points in the CAD frame [m], shape (K, 3), K >= 2, in file order.

    Raises:
        InputError: unreadable file, unknown unit, bad header, a malformed or non-finite value
            (naming the file, the line number and the text), or fewer than two points.
    """
    path = Path(path)
    scale = metres_per_unit(units, str(path))
    columns: tuple[int, int, int] | None = None
    seen_data = False
    rows: list[tuple[float, float, float]] = []
    for lineno, raw in enumerate(_read_lines(path), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        where = f"{path}:{lineno}"
        cells = line.split(",")
        if not seen_data and columns is None:
            columns = _header_columns(cells, where)
            seen_data = columns is None
            if columns is not None:
                continue
        seen_data = True
        if columns is None and len(cells) != 3:
            raise InputError(f"{where}: expected 3 values x, y, z [{units}], got {line!r}")
        idx = columns or (0, 1, 2)
        if max(idx) >= len(cells):
            raise InputError(f"{where}: expected at least {max(idx) + 1} values, got {line!r}")
        try:
            xyz = tuple(float(cells[i]) for i in idx)
        except ValueError as e:
            raise InputError(f"{where}: not a number in {line!r} ({e})") from e
        if not all(np.isfinite(xyz)):
            raise InputError(f"{where}: non-finite coordinate in {line!r}")
        check_point([c * scale for c in xyz], CAD_COORDINATE_LIMIT_M, where, "coordinate")
        rows.append(xyz)  # type: ignore[arg-type]
    if len(rows) < 2:
        raise InputError(f"CAD file {str(path)!r}: needs at least 2 points, found {len(rows)}")
    return np.asarray(rows, dtype=float) * scale
