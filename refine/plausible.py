"""Plausibility ranges for the numbers the readers take from input files.

A finite number can still be absurd: ``1e308`` in a tracker log, a CAD coordinate in the wrong
unit, a sample time in microseconds read as seconds. Every reader checks its values against these
ranges and stops (:class:`~refine.errors.InputError`, exit 2) naming the file and the line, record
or entity, the value and the range, so nothing absurd reaches the optimisation.

The ranges, with their reasons (docs/problem-file.md, "Plausibility ranges"):

* :data:`DEMO_POSITION_LIMIT_M`: a tracker sample's coordinate [m]; a magnetic tracker's field
  reaches a few metres from its source, and an optical one's volume is a room.
* :data:`EULER_LIMITS_DEG`: a Polhemus record's azimuth, elevation and roll [deg], the ranges the
  device prints (azimuth and roll within ±180 deg, elevation within ±90 deg), plus
  :data:`ANGLE_TOLERANCE_DEG` for the printed rounding; :data:`CSV_ANGLE_LIMIT_DEG` for angles
  written by other software.
* :data:`QUATERNION_NORM_TOLERANCE`: how far a quaternion's norm may be from 1 [-].
* :data:`MAX_DURATION_S`, :data:`MIN_STEP_S`, :data:`MAX_ABS_TIME_S`: a demonstration lasts at
  most a day, its samples are at least a microsecond apart (no tracker samples at 1 MHz), and an
  absolute time stamp [s] is below 1e10 s (Unix time in the year 2286).
* :data:`CAD_COORDINATE_LIMIT_M`: a CAD/CAM coordinate after its unit conversion [m]; no robot
  cell spans a kilometre, while a unit slip of a thousand or a million still shows.
* :data:`CAD_SPEED_LIMIT_M_S`: a PathML point's speed [m/s]; industrial robots move their tool at
  a few metres per second.
* Units of a demonstration CSV (:func:`check_demo_units`): the *extent* of a log is the diagonal
  of the box its positions fill after a running median over :data:`EXTENT_MEDIAN_S` (tracker noise
  of 1 mm and single-sample spikes then span a millimetre or two). A log whose extent in the
  stated unit is below :data:`MIN_DEMO_EXTENT_M` (metres read as millimetres: the whole motion
  spans a few mm) or whose extent or median distance from the receiver is beyond
  :data:`DEMO_POSITION_LIMIT_M` (millimetres read as metres: kilometres) while another unit puts
  it between :data:`PLAIN_MOTION_EXTENT_M` and that limit stops, naming the unit. A log that plainly
  moves (extent at least :data:`PLAIN_MOTION_EXTENT_M`) with every angle within
  ±:data:`RADIAN_LIKE_LIMIT` "degrees" is taken for radians read as degrees (a tool that turns
  less than 3.2 deg about every receiver axis while it travels 20 mm is not a worker's hand);
  angles stated in radians beyond ±2π, or turning at a median rate above
  :data:`MAX_TURN_RATE_DEG_S`, are taken for degrees read as radians. Logs shorter than
  :data:`MIN_UNIT_CHECK_S` are not judged.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from refine.errors import InputError

DEMO_POSITION_LIMIT_M = 10.0
"""Largest accepted |x|, |y| or |z| of a demonstration sample [m]."""
EULER_LIMITS_DEG = (180.0, 90.0, 180.0)
"""Largest |azimuth|, |elevation|, |roll| of a Polhemus record [deg]."""
ANGLE_TOLERANCE_DEG = 0.01
"""Allowance on :data:`EULER_LIMITS_DEG` for the device's printed rounding [deg]."""
CSV_ANGLE_LIMIT_DEG = 360.0
"""Largest |angle| in a demonstration CSV [deg]."""
QUATERNION_NORM_TOLERANCE = 0.01
"""Largest | |q| - 1 | of an orientation quaternion [-]."""
MAX_DURATION_S = 86_400.0
"""Longest demonstration, first to last sample [s] (a day)."""
MIN_STEP_S = 1e-6
"""Shortest time between two samples [s]."""
MAX_ABS_TIME_S = 1e10
"""Largest |t| of a sample time stamp [s]."""
CAD_COORDINATE_LIMIT_M = 1_000.0
"""Largest accepted |x|, |y| or |z| of a CAD/CAM point, in metres after the unit conversion."""
CAD_SPEED_LIMIT_M_S = 10.0
"""Largest accepted speed of a PathML point [m/s]."""

EXTENT_MEDIAN_S = 0.1
"""Running median window over which a log's positions are taken before its extent [s]."""
MIN_DEMO_EXTENT_M = 0.005
"""A demonstration whose extent is below this [m] did not move (or its unit is wrong)."""
PLAIN_MOTION_EXTENT_M = 0.02
"""A demonstration whose extent reaches this [m] plainly moves."""
RADIAN_LIKE_LIMIT = 3.2
"""Angles that all stay within ± this (π and some rounding) look like radians [deg or rad]."""
MIN_UNIT_CHECK_S = 0.5
"""Logs shorter than this [s] are not judged by :func:`check_demo_units` (a snippet, no
demonstration: a worker's start pause alone lasts longer)."""
MAX_TURN_RATE_DEG_S = 1500.0
"""Median turning rate [deg/s] above which the angles are not a hand's (the quality gate's
``MAX_HAND_RATE_DEG_S``); degrees read as radians turn 57 times too fast."""

Where = Callable[[int], str]
"""Names the location of sample ``k`` for an error message, e.g. ``"log.txt:17"``."""


def _first_beyond(values: np.ndarray, limits: np.ndarray) -> tuple[int, int] | None:
    """(row, column) of the first value whose magnitude exceeds its column's limit, or None."""
    bad = ~(np.abs(values) <= limits)  # NaN counts as beyond
    if not bad.any():
        return None
    k, j = np.argwhere(bad)[0]
    return int(k), int(j)


def check_coordinates(
    points: ArrayLike, limit_m: float, where: Where, what: str, units: str | None = None
) -> None:
    """Stop at the first point with a coordinate beyond ±``limit_m``.

    Args:
        points: coordinates [m], shape (K, 3).
        limit_m: the range [m] (:data:`DEMO_POSITION_LIMIT_M` or :data:`CAD_COORDINATE_LIMIT_M`).
        where: names point ``k``'s file and line (or record, entity).
        what: what the points are, e.g. ``"position"``.
        units: the unit the file was read in, named in the message (a unit slip is the usual cause).

    Raises:
        InputError: naming the location, the coordinate [m] and the range.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    hit = _first_beyond(p, np.full(3, limit_m))
    if hit is not None:
        k, j = hit
        cause = (
            f"read as {units!r}: are the units right?" if units else "a value in the wrong unit, or garbage"
        )
        raise InputError(
            f"{where(k)}: {what} {'xyz'[j]} = {p[k, j]:.6g} m is outside the plausible range ±{limit_m:g} m ({cause})"
        )


def check_point(xyz: Sequence[float], limit_m: float, where: str, what: str) -> None:
    """:func:`check_coordinates` for one point [m] at ``where`` (plain Python: cheap per line)."""
    for j, c in enumerate(xyz):
        if not abs(c) <= limit_m:
            raise InputError(
                f"{where}: {what} {'xyz'[j]} = {c:.6g} m is outside the plausible range "
                f"±{limit_m:g} m (a value in the wrong unit, or garbage)"
            )


def check_angles(
    angles_deg: ArrayLike, limits_deg: Sequence[float], where: Where, names: Sequence[str]
) -> None:
    """Stop at the first angle beyond its range (each column ``j`` within ±``limits_deg[j]``).

    Raises:
        InputError: naming the location, the angle [deg] and its range.
    """
    a = np.asarray(angles_deg, dtype=float)
    lim = np.asarray(limits_deg, dtype=float)
    hit = _first_beyond(a, lim)
    if hit is not None:
        k, j = hit
        raise InputError(
            f"{where(k)}: {names[j]} {a[k, j]:.6g} deg is outside the plausible range ±{lim[j]:g} deg"
        )


def check_euler(angles_deg: ArrayLike, where: Where) -> None:
    """Polhemus Euler angles (azimuth, elevation, roll) [deg] within :data:`EULER_LIMITS_DEG`."""
    lim = np.asarray(EULER_LIMITS_DEG) + ANGLE_TOLERANCE_DEG
    check_angles(angles_deg, lim, where, ("azimuth", "elevation", "roll"))


def check_quaternions(quats: ArrayLike, where: Where) -> None:
    """Quaternions (K, 4) of norm 1 within :data:`QUATERNION_NORM_TOLERANCE`.

    Raises:
        InputError: naming the location, the quaternion and its norm.
    """
    q = np.asarray(quats, dtype=float)
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(~(np.abs(norm - 1.0) <= QUATERNION_NORM_TOLERANCE))
    if bad.size:
        k = int(bad[0])
        raise InputError(
            f"{where(k)}: quaternion {np.round(q[k], 6).tolist()} has norm {norm[k]:.6g}; a rotation "
            f"needs 1 ± {QUATERNION_NORM_TOLERANCE:g}"
        )


def check_times(t: ArrayLike, where: Where) -> None:
    """Check sample times [s] against :data:`MAX_ABS_TIME_S`, :data:`MIN_STEP_S`, :data:`MAX_DURATION_S`.

    |t| must stay below the first, times must increase by at least the second, and the last
    sample lie at most the third after the first.

    Raises:
        InputError: naming the location and the time [s].
    """
    t = np.asarray(t, dtype=float)
    big = np.flatnonzero(~(np.abs(t) <= MAX_ABS_TIME_S))
    if big.size:
        k = int(big[0])
        raise InputError(
            f"{where(k)}: time {t[k]:.6g} s is outside the plausible range ±{MAX_ABS_TIME_S:g} s"
        )
    steps = np.diff(t)
    short = np.flatnonzero(~(steps >= MIN_STEP_S))
    if short.size:
        k = int(short[0]) + 1
        raise InputError(
            f"{where(k)}: time {t[k]:.9g} s is {steps[k - 1]:.3g} s after the sample before; samples "
            f"must be at least {MIN_STEP_S:g} s apart and in order"
        )
    if len(t) and t[-1] - t[0] > MAX_DURATION_S:
        k = int(np.flatnonzero(t - t[0] > MAX_DURATION_S)[0])
        raise InputError(
            f"{where(k)}: time {t[k] - t[0]:.6g} s after the first sample; a demonstration lasts at "
            f"most {MAX_DURATION_S:g} s"
        )


def demo_extent(t: ArrayLike, positions: ArrayLike) -> float:
    """The extent of a demonstration [unit of ``positions``] (module docstring).

    Args:
        t: sample times [s], shape (M,).
        positions: positions, shape (M, 3).
    """
    from scipy.ndimage import median_filter

    t = np.asarray(t, dtype=float)
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    step = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    window = max(1, min(len(p), int(round(EXTENT_MEDIAN_S / step)) | 1))
    smooth = median_filter(p, size=(window, 1), mode="nearest")
    return float(np.linalg.norm(smooth.max(axis=0) - smooth.min(axis=0)))


def _median_turn_rate_deg_s(t: np.ndarray, rotations: np.ndarray) -> float:
    """Median angle between consecutive rotations divided by their time step [deg/s]."""
    if len(t) < 2:
        return 0.0
    rel = np.einsum("kji,kjl->kil", rotations[:-1], rotations[1:])  # R_k^T R_{k+1}
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.median(np.degrees(np.arccos(cos)) / np.diff(t)))


def check_demo_units(
    source: str,
    t: ArrayLike,
    positions_in_file: ArrayLike,
    units: str,
    metres_per_unit: dict[str, float],
    angles_in_file: ArrayLike,
    angle_units: str | None,
    to_rotations: Callable[[np.ndarray], np.ndarray],
) -> None:
    """Stop a demonstration whose motion or turning is implausible for its stated units.

    Args:
        source: the file, for messages.
        t: sample times [s], shape (M,).
        positions_in_file: positions as written, in ``units``, shape (M, 3).
        units: the stated position unit (a key of ``metres_per_unit``).
        metres_per_unit: length of one unit [m], per unit name.
        angles_in_file: azimuth, elevation, roll as written, shape (M, 3).
        angle_units: ``"deg"`` or ``"rad"`` as stated; None: not stated, read as degrees and
            checked for radians.
        to_rotations: rotation matrices (M, 3, 3) from angles [deg] (M, 3).

    Raises:
        InputError: naming the extent or the angles found, the likely unit and the key to set
            (module docstring for the rules).
    """
    t = np.asarray(t, dtype=float)
    if len(t) < 2 or t[-1] - t[0] < MIN_UNIT_CHECK_S:
        return
    raw = np.asarray(positions_in_file, dtype=float).reshape(-1, 3)
    extent_raw = demo_extent(t, raw)
    distance_raw = float(np.median(np.linalg.norm(raw, axis=1)))
    extent_m = extent_raw * metres_per_unit[units]
    distance_m = distance_raw * metres_per_unit[units]

    def plausible(unit: str) -> bool:
        scale = metres_per_unit[unit]
        return (
            PLAIN_MOTION_EXTENT_M <= extent_raw * scale <= DEMO_POSITION_LIMIT_M
            and distance_raw * scale <= DEMO_POSITION_LIMIT_M
        )

    too_small = extent_m < MIN_DEMO_EXTENT_M
    too_large = extent_m > DEMO_POSITION_LIMIT_M or distance_m > DEMO_POSITION_LIMIT_M
    if too_small or too_large:
        scale = metres_per_unit[units]
        others = [u for u in metres_per_unit if u != units and plausible(u)]
        others = [u for u in others if (metres_per_unit[u] > scale) == too_small]
        if others:
            what = (
                f"the whole motion spans {extent_m * 1e3:.3g} mm"
                if too_small
                else f"the motion spans {extent_m:.4g} m at a median {distance_m:.4g} m from the receiver"
            )
            hint = " or ".join(
                f'units = "{u}" (it then spans {extent_raw * metres_per_unit[u]:.3g} m)' for u in others
            )
            raise InputError(
                f"{source}: positions read as {units!r}: are the units right? {what}; if not, set "
                f"{hint} (the [demonstration] key)" + ("; or the tool never moved" if too_small else "")
            )

    a = np.asarray(angles_in_file, dtype=float).reshape(-1, 3)
    if angle_units is None:
        largest = float(np.max(np.abs(a))) if a.size else 0.0
        if extent_m >= PLAIN_MOTION_EXTENT_M and largest <= RADIAN_LIKE_LIMIT:
            raise InputError(
                f"{source}: the tool travels {extent_m * 1e3:.0f} mm but every angle stays within "
                f"±{largest:.3g} deg: these look like radians; set [demonstration] angle_units = "
                f'"rad" (or angle_units = "deg" if the tool really keeps its orientation within '
                f"{RADIAN_LIKE_LIMIT} deg of the receiver's axes)"
            )
    elif angle_units == "rad":
        bad = np.flatnonzero(~(np.abs(a) <= 2.0 * np.pi).all(axis=1))
        rate = _median_turn_rate_deg_s(t, to_rotations(np.degrees(a))) if not bad.size else 0.0
        if bad.size or rate > MAX_TURN_RATE_DEG_S:
            found = (
                f"an angle of {a[bad[0]][np.argmax(np.abs(a[bad[0]]))]:.6g} rad (beyond ±2π) at sample {bad[0]}"
                if bad.size
                else f"a median turning rate of {rate:.0f} deg/s (a hand turns at most {MAX_TURN_RATE_DEG_S:g} deg/s)"
            )
            raise InputError(
                f"{source}: read with angles in radians, the log has {found}: these look like degrees; "
                f'set [demonstration] angle_units = "deg"'
            )
