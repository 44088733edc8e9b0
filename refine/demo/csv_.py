"""Demonstrations as plain CSV: one tracker sample per line, with a header.

The format::

    # optional comment lines start with '#'
    t, x, y, z, azimuth, elevation, roll
    0.000, 0.1234, -0.0456, 0.2100, -12.345, 45.678, 170.123

* The header names the seven columns, any case, spaces allowed, in any order; other columns are
  ignored.
* ``t`` is the sample time [s] and must strictly increase; it is shifted so the first sample is at
  ``t = 0``.
* ``x, y, z`` is the sensor position in the receiver frame {S}, in the unit the caller names
  (``m``, ``mm``, ``cm`` or ``in``); it is returned in metres.
* ``azimuth, elevation, roll`` are the Polhemus angles: ``R = Rz(azimuth)·Ry(elevation)·Rx(roll)``,
  in degrees, or radians when the caller says so (``angle_units``).

Units are never guessed silently: a log whose motion or turning is implausible for the stated
units stops with a message naming the likely unit and the key to set
(:func:`refine.plausible.check_demo_units`).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from refine.errors import InputError
from refine.frames import matrix_from_tracker_angles, tracker_angles_from_matrix
from refine.paths import TrackerLog
from refine.plausible import (
    CSV_ANGLE_LIMIT_DEG,
    DEMO_POSITION_LIMIT_M,
    check_angles,
    check_coordinates,
    check_demo_units,
    check_times,
)

logger = logging.getLogger(__name__)

#: Length of one position unit [m].
METRES_PER_UNIT = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "in": 0.0254}
COLUMNS = ("t", "x", "y", "z", "azimuth", "elevation", "roll")
ANGLE_UNITS = ("deg", "rad")


def read_demo_csv(path: str | Path, units: str = "m", angle_units: str | None = None) -> TrackerLog:
    """Read a demonstration CSV (format in the module docstring).

    Args:
        path: the CSV file.
        units: position unit in the file: ``"m"``, ``"mm"``, ``"cm"`` or ``"in"``.
        angle_units: angle unit in the file: ``"deg"`` or ``"rad"``; None: degrees, and a log whose
            angles look like radians stops (:func:`refine.plausible.check_demo_units`).

    Returns:
        The samples: times [s] from 0, positions [m], rotations R_S_E.

    Raises:
        InputError: unreadable file, unknown unit, missing header columns (naming them), a
            malformed line (naming file, line number and text), time that does not increase,
            motion or angles implausible for the stated units (naming the likely unit).
    """
    path = Path(path)
    if units not in METRES_PER_UNIT:
        raise InputError(f"{path}: unknown position unit {units!r}; use one of {', '.join(METRES_PER_UNIT)}")
    if angle_units is not None and angle_units not in ANGLE_UNITS:
        raise InputError(f"{path}: unknown angle unit {angle_units!r}; use one of {', '.join(ANGLE_UNITS)}")
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"demonstration CSV {str(path)!r} cannot be read: {e}") from e
    idx: list[int] | None = None
    rows: list[list[float]] = []
    linenos: list[int] = []
    for lineno, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        cells = [c.strip() for c in line.split(",")]
        where = f"{path}:{lineno}"
        if idx is None:
            names = [c.lower() for c in cells]
            missing = [c for c in COLUMNS if c not in names]
            if missing:
                raise InputError(
                    f"{where}: header {line!r} lacks column(s) {', '.join(missing)} "
                    f"(expected {', '.join(COLUMNS)})"
                )
            idx = [names.index(c) for c in COLUMNS]
            continue
        if len(cells) <= max(idx):
            raise InputError(f"{where}: expected {max(idx) + 1} values, got {len(cells)}: {line!r}")
        try:
            values = [float(cells[i]) for i in idx]
        except ValueError as e:
            raise InputError(f"{where}: not a number in {line!r} ({e})") from e
        if not np.all(np.isfinite(values)):
            raise InputError(f"{where}: non-finite value in {line!r}")
        rows.append(values)
        linenos.append(lineno)
    if idx is None:
        raise InputError(f"demonstration CSV {str(path)!r}: no header line ({', '.join(COLUMNS)})")
    if len(rows) < 2:
        raise InputError(f"demonstration CSV {str(path)!r}: needs at least 2 samples, got {len(rows)}")
    data = np.asarray(rows, dtype=float)
    bad = np.flatnonzero(np.diff(data[:, 0]) <= 0.0)
    if bad.size:
        k = int(bad[0]) + 1
        raise InputError(
            f"{path}:{linenos[k]}: t = {data[k, 0]} s does not increase after "
            f"t = {data[k - 1, 0]} s (line {linenos[k - 1]})"
        )

    def where(k: int) -> str:
        return f"{path}:{linenos[k]}"

    check_times(data[:, 0], where)
    check_demo_units(
        str(path),
        data[:, 0],
        data[:, 1:4],
        units,
        METRES_PER_UNIT,
        data[:, 4:7],
        angle_units,
        lambda a: matrix_from_tracker_angles(a[:, 0], a[:, 1], a[:, 2], degrees=True),
    )
    positions = data[:, 1:4] * METRES_PER_UNIT[units]
    check_coordinates(positions, DEMO_POSITION_LIMIT_M, where, "position", units)
    angles_deg = np.degrees(data[:, 4:7]) if angle_units == "rad" else data[:, 4:7]
    check_angles(angles_deg, [CSV_ANGLE_LIMIT_DEG] * 3, where, COLUMNS[4:7])
    logger.debug("%s: %d samples over %.3f s", path, len(data), data[-1, 0] - data[0, 0])
    return TrackerLog(
        t=data[:, 0] - data[0, 0],
        positions=positions,
        rotations=matrix_from_tracker_angles(
            angles_deg[:, 0], angles_deg[:, 1], angles_deg[:, 2], degrees=True
        ),
        source=str(path),
    )


def write_demo_csv(path: str | Path, log: TrackerLog, units: str = "mm") -> None:
    """Write a tracker log as a demonstration CSV that :func:`read_demo_csv` reads.

    Args:
        path: the file to write.
        log: samples; positions [m], rotations R_S_E.
        units: position unit in the file: ``"m"``, ``"mm"``, ``"cm"`` or ``"in"``.

    Raises:
        InputError: an unknown unit.
    """
    if units not in METRES_PER_UNIT:
        raise InputError(
            f"write_demo_csv: unknown position unit {units!r}; use one of {', '.join(METRES_PER_UNIT)}"
        )
    angles = tracker_angles_from_matrix(log.rotations)
    rows = np.column_stack([log.t, np.asarray(log.positions) / METRES_PER_UNIT[units], angles])
    with Path(path).open("w", encoding="utf-8") as f:
        f.write(f"# positions in {units}, angles in deg\nt,x,y,z,azimuth,elevation,roll\n")
        np.savetxt(f, rows, delimiter=",", fmt="%.6f")
