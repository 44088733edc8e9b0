"""A CAM toolpath with tool axes (CSV): positions and the tool's z axis per point, read as a fused path.

A CAM system exports, per point of the toolpath, where the tool tip goes and which way the tool
points. One line per point, comma separated, in the path's order::

    x, y, z, i, j, k                  <- optional header (any order; other columns ignored)
    78.9071, 0, 23.7139, 0, 1, 0

Without a header a line holds six numbers (x, y, z, i, j, k) or seven, the first a point number
(``1, 78.9071, 0, 23.7139, 0, 1, 0``). Blank lines, ``#`` comments and label lines whose cells after
the first are all empty (``Line 1,,,,,,``) are skipped. Positions are in the ``[cad]`` unit; the axis
(i, j, k) is a direction, normalised here, the TCP's z axis (where the tool points).

The TCP's x axis is the direction of travel made square to the tool axis (the path's tangent less
its part along the axis; where the two are parallel, the previous point's x axis), so a tool that
is not axisymmetric keeps its x axis along the path. The path is resampled by arc length to
``spacing_m`` as the other CAD paths, the orientations by spherical interpolation; the speed is
``[cad] speed_m_s`` everywhere. The result replaces the demonstration (no tracker log).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from refine.cad.csv_ import metres_per_unit
from refine.cad.resample import DUPLICATE_TOLERANCE_M, resample_by_arc_length
from refine.errors import InputError
from refine.frames import check_transform
from refine.paths import FusedPath
from refine.plausible import CAD_COORDINATE_LIMIT_M, CAD_SPEED_LIMIT_M_S, check_point
from refine.settings.limits import check_waypoint_count
from refine.types import Array

logger = logging.getLogger(__name__)

COLUMNS = ("x", "y", "z", "i", "j", "k")


def _lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8-sig").splitlines()
    except OSError as e:
        raise InputError(f"toolpath {str(path)!r} cannot be read: {e}") from e
    except UnicodeDecodeError as e:
        raise InputError(f"toolpath {str(path)!r} is not UTF-8 text: {e}") from e


def read_toolpath(path: str | Path, units: str = "mm") -> tuple[Array, Array]:
    """The points [m] (K, 3) and unit tool axes (K, 3) of a toolpath CSV, in the CAD frame, in file order.

    Raises:
        InputError: a missing or unreadable file, a malformed line (naming the file and line), a
            zero tool axis, an implausible coordinate, or fewer than two points.
    """
    path = Path(path)
    scale = metres_per_unit(units, str(path))
    columns: list[int] | None = None
    points, axes = [], []
    for number, line in enumerate(_lines(path), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        cells = [c.strip() for c in text.split(",")]
        where = f"toolpath {path.name} line {number}"
        if all(not c for c in cells[1:]):
            continue  # a label line
        try:
            values = [float(c) for c in cells]
        except ValueError:
            if points or columns is not None:
                raise InputError(f"{where}: {text!r} is not {len(columns or COLUMNS)} numbers") from None
            names = [c.lower() for c in cells]
            missing = [c for c in COLUMNS if c not in names]
            if missing:
                raise InputError(
                    f"{where}: header {', '.join(names)} lacks column(s) {', '.join(missing)}"
                ) from None
            columns = [names.index(c) for c in COLUMNS]
            continue
        if columns is not None:
            if len(values) <= max(columns):
                raise InputError(
                    f"{where}: {len(values)} numbers, the header names {max(columns) + 1} columns"
                )
            row = [values[c] for c in columns]
        elif len(values) in (6, 7):
            row = values[-6:]
        else:
            raise InputError(
                f"{where}: {len(values)} numbers; expected x, y, z, i, j, k (or a point number first)"
            )
        point, axis = np.array(row[:3]) * scale, np.array(row[3:])
        check_point(point, CAD_COORDINATE_LIMIT_M, where, "position")
        norm = float(np.linalg.norm(axis))
        if not (np.all(np.isfinite(axis)) and norm > 1e-9):
            raise InputError(f"{where}: tool axis {row[3:]} is not a direction (zero or not finite)")
        points.append(point)
        axes.append(axis / norm)
    if len(points) < 2:
        raise InputError(f"toolpath {path}: needs at least 2 points, found {len(points)}")
    return np.array(points), np.array(axes)


def tool_frames(points: Array, axes: Array) -> Array:
    """R_CAD_TCP per point (K, 3, 3): z the tool axis, x the direction of travel square to it."""
    tangent = np.gradient(points, axis=0)
    frames = np.empty((len(points), 3, 3))
    previous = None
    for k, (z, t) in enumerate(zip(axes, tangent, strict=True)):
        x = t - np.dot(t, z) * z
        if np.linalg.norm(x) < 1e-9 * max(1.0, float(np.linalg.norm(t))):
            x = previous if previous is not None else np.cross(z, np.eye(3)[int(np.argmin(np.abs(z)))])
            x = x - np.dot(x, z) * z
        x = x / np.linalg.norm(x)
        frames[k] = np.column_stack([x, np.cross(z, x), z])
        previous = x
    return frames


def fused_from_toolpath(
    path: str | Path,
    units: str,
    spacing_m: float,
    speed_m_s: float,
    cad_in_world: Array,
    *,
    reverse: bool = False,
) -> FusedPath:
    """A toolpath CSV as a fused path in the world, resampled by arc length (see the module docstring).

    Args:
        path: the toolpath CSV.
        units: length unit of its positions (``"m"``, ``"mm"``, ``"in"``).
        spacing_m: largest waypoint spacing along the path [m].
        speed_m_s: the tool's speed along the path [m/s], > 0.
        cad_in_world: T_F_CAD, the frame the toolpath is given in, placed in the world (4, 4).
        reverse: run the toolpath against the order of its lines; each point keeps its axis.

    Raises:
        InputError: as :func:`read_toolpath`, a speed outside (0, 10] m/s, or a path too long for
            its spacing.
    """
    if not (0.0 < speed_m_s <= CAD_SPEED_LIMIT_M_S):
        raise InputError(
            f"cad.speed_m_s = {speed_m_s} m/s: a toolpath needs a speed in (0, {CAD_SPEED_LIMIT_M_S:g}] m/s"
        )
    T = check_transform(cad_in_world, "frames.cad_in_world")
    points, axes = read_toolpath(path, units)
    keep = np.r_[True, np.linalg.norm(np.diff(points, axis=0), axis=1) > DUPLICATE_TOLERANCE_M]
    points, axes = points[keep], axes[keep]
    if len(points) < 2:
        raise InputError(f"toolpath {path}: needs at least 2 distinct points")
    if reverse:
        points, axes = points[::-1].copy(), axes[::-1].copy()
    R_cad = tool_frames(points, axes)
    positions = points @ T[:3, :3].T + T[:3, 3]
    rotations = T[:3, :3] @ R_cad
    s_points = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))]
    check_waypoint_count(float(s_points[-1]), spacing_m, f"cad.file {Path(path).name!r}")
    s, resampled = resample_by_arc_length(positions, spacing_m)
    s = np.clip(s, 0.0, s_points[-1])
    R = Slerp(s_points, Rotation.from_matrix(rotations))(s).as_matrix()
    speed = np.full(len(s), float(speed_m_s))
    t = s / float(speed_m_s)
    logger.debug("toolpath %s: %d points -> %d waypoints", path, len(points), len(s))
    return FusedPath(s=s, positions=resampled, rotations=R, speed=speed, t_demo=t, residual=np.zeros(len(s)))
