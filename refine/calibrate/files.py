"""The files of a calibration: tracker logs, points, robot readings, and problem-file snippets.

* Tracker logs are read by the demonstration readers (``liberty_ascii``, ``liberty_binary``,
  ``csv``) with their unit and station options.
* A points file is a CSV with a header naming ``x, y, z`` [m] (any case and order) and optionally
  ``name``; ``#`` starts a comment line.
* Robot readings are a CSV with a header naming either the joints ``j1, ..., jn`` [deg] (one
  reading per line) or a flange (or TCP) pose ``x, y, z`` [m, or ``--units mm``] and
  ``qw, qx, qy, qz`` (scalar-first quaternion, as ABB RAPID prints it).
* Results are written as problem-file lines, ``key = { xyz = [...], rpy_deg = [...] }``; with
  ``--write`` the line replaces the key in its table of ``problem.toml`` (comments and layout kept),
  and the file is loaded again to check it before it replaces the old one.
"""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from refine.demo import read_demo_csv, read_liberty_ascii, read_liberty_binary
from refine.errors import InputError
from refine.frames import fixed_xyz_from_matrix, make_transform, matrix_from_quaternion
from refine.paths import TrackerLog
from refine.types import Array

LOG_FORMATS = ("liberty_ascii", "liberty_binary", "csv")
#: Length of one position unit of a readings file [m].
METRES_PER_UNIT = {"m": 1.0, "mm": 1e-3}
#: Farthest plausible point of a cell from its world origin [m]; farther means wrong units.
MAX_CELL_M = 50.0


def read_log(
    path: str | Path,
    fmt: str = "liberty_ascii",
    units: str | None = None,
    station: int = 1,
    rate_hz: float = 240.0,
) -> TrackerLog:
    """Read one station of a tracker log.

    Args:
        path: the log.
        fmt: one of :data:`LOG_FORMATS`.
        units: position unit; None takes the format's default (the Liberty ASCII file's
            ``# units:`` line or inches; inches for binary; metres for CSV).
        station: station (sensor) number; the CSV format has no stations and reads only 1.
        rate_hz: sample rate [Hz] of logs without times.

    Raises:
        InputError: an unknown format, a station the log does not hold (listing those it holds),
            units that contradict the file, or anything the reader rejects.
    """
    if fmt == "liberty_ascii":
        return read_liberty_ascii(path, units=units, station=station, rate_hz=rate_hz)
    if fmt == "liberty_binary":
        return read_liberty_binary(path, station=station, rate_hz=rate_hz, units=units or "in")
    if fmt == "csv":
        if station != 1:
            raise InputError(
                f"tracker log {str(path)!r}: a CSV log holds one station (1), not station {station}"
            )
        return read_demo_csv(path, units=units or "m")
    raise InputError(f"tracker log format {fmt!r} is not one of {', '.join(LOG_FORMATS)}")


def _csv_rows(path: Path) -> tuple[list[str], list[list[str]], list[int]]:
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path} cannot be read: {e}") from e
    header: list[str] | None = None
    rows, linenos = [], []
    for lineno, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        cells = [c.strip() for c in line.split(",")]
        if header is None:
            header = [c.lower() for c in cells]
            continue
        if len(cells) != len(header):
            raise InputError(f"{path}:{lineno}: expected {len(header)} values, got {len(cells)}: {line!r}")
        rows.append(cells)
        linenos.append(lineno)
    if header is None or not rows:
        raise InputError(f"{path}: no header line or no data lines")
    return header, rows, linenos


def _numbers(
    path: Path, header: list[str], rows: list[list[str]], linenos: list[int], cols: list[str]
) -> Array:
    idx = [header.index(c) for c in cols]
    out = np.empty((len(rows), len(cols)))
    for k, (row, lineno) in enumerate(zip(rows, linenos, strict=True)):
        try:
            out[k] = [float(row[i]) for i in idx]
        except ValueError as e:
            raise InputError(f"{path}:{lineno}: not a number in {','.join(row)!r} ({e})") from e
    if not np.all(np.isfinite(out)):
        raise InputError(f"{path}: non-finite values")
    return out


def read_points_csv(path: str | Path) -> tuple[Array, tuple[str, ...]]:
    """Read a points file: positions [m] (N, 3) and names (``P1``, ... when the file has none).

    Raises:
        InputError: missing columns, malformed lines, or points farther than :data:`MAX_CELL_M`
            from the origin (millimetres read as metres).
    """
    path = Path(path)
    header, rows, linenos = _csv_rows(path)
    missing = [c for c in ("x", "y", "z") if c not in header]
    if missing:
        raise InputError(
            f"{path}: header {','.join(header)!r} lacks column(s) {', '.join(missing)} (x, y, z in metres)"
        )
    points = _numbers(path, header, rows, linenos, ["x", "y", "z"])
    far = float(np.max(np.linalg.norm(points, axis=1)))
    if far > MAX_CELL_M:
        raise InputError(
            f"{path}: a point lies {far:.0f} m from the origin; points files are in metres: are "
            f"these millimetres?"
        )
    if "name" in header:
        names = tuple(row[header.index("name")] for row in rows)
    else:
        names = tuple(f"P{k + 1}" for k in range(len(rows)))
    return points, names


def read_robot_readings(path: str | Path, units: str = "m") -> tuple[str, Array]:
    """Read robot readings: ``("joints", q (N, n) [rad])`` or ``("poses", T (N, 4, 4) [m])``.

    Args:
        path: the CSV (format in the module docstring).
        units: position unit of pose columns, ``"m"`` or ``"mm"``.

    Raises:
        InputError: neither joint nor pose columns, malformed lines, an unknown unit, or
            positions that look like the wrong unit.
    """
    path = Path(path)
    header, rows, linenos = _csv_rows(path)
    joints = sorted((c for c in header if re.fullmatch(r"j\d+", c)), key=lambda c: int(c[1:]))
    if joints:
        expected = [f"j{k}" for k in range(1, len(joints) + 1)]
        if joints != expected:
            raise InputError(f"{path}: joint columns must be j1..jn without gaps, got {', '.join(joints)}")
        return "joints", np.radians(_numbers(path, header, rows, linenos, joints))
    pose_cols = ["x", "y", "z", "qw", "qx", "qy", "qz"]
    missing = [c for c in pose_cols if c not in header]
    if missing:
        raise InputError(
            f"{path}: header {','.join(header)!r} names neither joints (j1, ..., jn in degrees) nor "
            f"a pose (x, y, z, qw, qx, qy, qz); missing {', '.join(missing)}"
        )
    if units not in METRES_PER_UNIT:
        raise InputError(f"{path}: unknown unit {units!r}; use one of {', '.join(METRES_PER_UNIT)}")
    data = _numbers(path, header, rows, linenos, pose_cols)
    xyz = data[:, :3] * METRES_PER_UNIT[units]
    far = float(np.max(np.linalg.norm(xyz, axis=1)))
    if far > MAX_CELL_M:
        raise InputError(
            f"{path}: a position lies {far:.0f} m from the robot base: are the units right (--units)?"
        )
    q = data[:, 3:]
    norms = np.linalg.norm(q, axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-3):
        k = int(np.argmax(np.abs(norms - 1.0)))
        raise InputError(f"{path}:{linenos[k]}: quaternion norm {norms[k]:.4f}, not 1")
    return "poses", make_transform(matrix_from_quaternion(q / norms[:, None]), xyz)


# ---- snippets and problem files ---------------------------------------------------------------


def pose_line(key: str, T: ArrayLike) -> str:
    """The problem-file line ``key = { xyz = [...], rpy_deg = [...] }`` of a transform (4, 4) [m]."""
    T = np.asarray(T, dtype=float)
    xyz = ", ".join(f"{v:.6f}" for v in T[:3, 3] + 0.0)
    rpy = ", ".join(f"{v:.4f}" for v in np.round(fixed_xyz_from_matrix(T[:3, :3]), 4) + 0.0)
    return f"{key} = {{ xyz = [{xyz}], rpy_deg = [{rpy}] }}"


def snippet(table: str, key: str, T: ArrayLike, comment: str = "") -> str:
    """A problem-file snippet: the table header, an optional comment and the pose line."""
    lines = [f"[{table}]"]
    if comment:
        lines.append(f"# {comment}")
    lines.append(pose_line(key, T))
    return "\n".join(lines) + "\n"


def _table_of(line: str) -> str | None:
    m = re.match(r"^\s*\[([A-Za-z0-9_.\-]+)\]\s*(#.*)?$", line)
    return m.group(1) if m else None


def update_problem(problem: str | Path, table: str, key: str, T: ArrayLike) -> Path:
    """Set ``key`` of ``[table]`` in a problem file to the pose T (4, 4), keeping the rest.

    The key's line is replaced in place, or added right after the table's header; a missing table
    is appended. The new file is loaded with :func:`refine.problem.load_problem` before it
    replaces the old one (written to a temporary file and renamed), so a failed update leaves
    the problem as it was.

    Returns:
        The problem file written.

    Raises:
        InputError: the problem file is missing, or the updated file does not load.
    """
    from refine.problem import load_problem

    path = Path(problem)
    if path.is_dir():
        path = path / "problem.toml"
    if not path.is_file():
        raise InputError(f"problem file not found: {path}")
    lines = path.read_text(encoding="utf-8").splitlines()
    new = pose_line(key, T)
    current: str | None = None
    header_at: int | None = None
    replaced = False
    for i, line in enumerate(lines):
        name = _table_of(line)
        if name is not None or line.lstrip().startswith("[["):
            current = name
            if name == table:
                header_at = i
            continue
        if current == table and re.match(rf"^\s*{re.escape(key)}\s*=", line):
            lines[i] = new
            replaced = True
            break
    if not replaced:
        if header_at is None:
            lines += ["", f"[{table}]", new]
        else:
            lines.insert(header_at + 1, new)
    fd, tmp = tempfile.mkstemp(prefix=".problem-", suffix=".toml", dir=path.parent)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    os.chmod(tmp, path.stat().st_mode & 0o777)  # mkstemp makes it private; keep the file's mode
    try:
        load_problem(tmp)
    except InputError as e:
        os.unlink(tmp)
        raise InputError(f"{path}: not updated, the result would not load: {e}") from e
    os.replace(tmp, path)
    return path
