"""The demonstration stage: read the tracker log and clean it into a :class:`Demonstration`.

``read_tracker_log`` dispatches on the log format (``liberty``, ``liberty_binary`` and ``csv_`` hold
the readers);
``clean_demonstration`` removes outliers, smooths positions and orientations, computes the speed
and finds the end of the start pause, with the pieces from ``filters``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation, Slerp

from refine.demo.csv_ import read_demo_csv
from refine.demo.filters import (
    check_times,
    find_motion_start,
    hampel,
    rotation_outliers,
    smooth_positions,
    smooth_rotations,
    speed_along_track,
)
from refine.demo.liberty import read_liberty_ascii, write_liberty_ascii
from refine.demo.liberty_binary import read_liberty_binary, write_liberty_binary
from refine.errors import InputError
from refine.paths import Demonstration, TrackerLog
from refine.settings import DemoSettings

__all__ = [
    "ANGLE_OUTLIER_FLOOR_DEG",
    "MOTION_START_SMOOTHING_S",
    "POSITION_OUTLIER_FLOOR_M",
    "clean_demonstration",
    "fill_positions",
    "fill_rotations",
    "read_demo_csv",
    "read_liberty_ascii",
    "read_liberty_binary",
    "read_tracker_log",
    "write_liberty_ascii",
    "write_liberty_binary",
]

logger = logging.getLogger(__name__)

#: Deviations from the running median below this are never outliers [m] (tracker noise and
#: quantisation stay well under it; magnetic-distortion spikes are centimetres).
POSITION_OUTLIER_FLOOR_M = 1e-3
#: The same floor for orientations [deg].
ANGLE_OUTLIER_FLOOR_DEG = 0.5
#: Smoothing [s] of the positions used to find the motion start, whatever
#: ``smoothing_s`` is: heavier smoothing spreads the start of the motion over +-2 sigma and finds
#: it too early; none leaves tracker noise to look like motion.
MOTION_START_SMOOTHING_S = 0.05

_READERS: dict[str, Callable[[DemoSettings], TrackerLog]] = {
    "liberty_ascii": lambda d: read_liberty_ascii(
        d.file, units=d.units, station=d.station, rate_hz=d.rate_hz
    ),
    "liberty_binary": lambda d: read_liberty_binary(
        d.file, station=d.station, rate_hz=d.rate_hz, units=d.units
    ),
    "csv": lambda d: read_demo_csv(d.file, units=d.units, angle_units=d.angle_units),
}


def fill_positions(t: ArrayLike, positions: ArrayLike, mask: ArrayLike) -> NDArray:
    """Replace masked samples (M,) of positions (M, 3) by linear interpolation in time ``t`` [s]."""
    t, p, mask = np.asarray(t, float), np.array(positions, float), np.asarray(mask, bool)
    good = ~mask
    if mask.any() and good.any():
        for axis in range(p.shape[1]):
            p[mask, axis] = np.interp(t[mask], t[good], p[good, axis])
    return p


def fill_rotations(t: ArrayLike, rotations: ArrayLike, mask: ArrayLike) -> NDArray:
    """Replace masked samples of rotations (M, 3, 3) by Slerp between the good neighbours.

    Masked samples before the first or after the last good sample take that sample's rotation.
    """
    t, R, mask = np.asarray(t, float), np.array(rotations, float), np.asarray(mask, bool)
    good = np.flatnonzero(~mask)
    if not mask.any() or len(good) == 0:
        return R
    if len(good) == 1:
        R[mask] = R[good[0]]
        return R
    slerp = Slerp(t[good], Rotation.from_matrix(R[good]))
    R[mask] = slerp(np.clip(t[mask], t[good[0]], t[good[-1]])).as_matrix()
    return R


def read_tracker_log(settings: DemoSettings) -> TrackerLog:
    """Read the raw tracker log named by ``settings`` (format, units, station, rate).

    Raises:
        InputError: an unknown format (listing the known ones) or anything the reader rejects.
    """
    reader = _READERS.get(settings.format)
    if reader is None:
        raise InputError(
            f"demonstration.format = {settings.format!r} is not one of {', '.join(sorted(_READERS))}"
        )
    return reader(settings)


def clean_demonstration(log: TrackerLog, settings: DemoSettings) -> Demonstration:
    """Turn a raw tracker log into a cleaned demonstration.

    Steps:

    1. Position outliers: :func:`~refine.demo.filters.hampel` on each axis (half window
       ``settings.hampel_window``, threshold ``settings.hampel_sigmas``, floor
       :data:`POSITION_OUTLIER_FLOOR_M`); a sample flagged on any axis is replaced on all three
       by linear interpolation between its good neighbours in time.
    2. Orientation outliers: :func:`~refine.demo.filters.rotation_outliers` (residual to the
       running median rotation, floor :data:`ANGLE_OUTLIER_FLOOR_DEG`), replaced by Slerp
       between the good neighbours.
    3. Gaussian smoothing of positions and of orientations (on SO(3)) with standard deviation
       ``settings.smoothing_s``.
    4. Speed along the smoothed track, and the end of the start pause
       (:func:`~refine.demo.filters.find_motion_start` with ``settings.pause_speed_m_s``) on the
       positions smoothed with :data:`MOTION_START_SMOOTHING_S`.

    Args:
        log: the raw samples; times must strictly increase.
        settings: the ``[demonstration]`` settings.

    Returns:
        The cleaned demonstration; ``n_outliers`` counts samples replaced in position or
        orientation (or both).

    Raises:
        InputError: times that do not increase, or a log in which the tool never moves.
    """
    check_times(log.t)
    h, n_sigmas = settings.hampel_window, settings.hampel_sigmas
    _, pos_mask = hampel(log.positions, h, n_sigmas, min_deviation=POSITION_OUTLIER_FLOOR_M)
    pos_bad = pos_mask.any(axis=1)
    rot_bad = rotation_outliers(log.rotations, h, n_sigmas, min_angle_deg=ANGLE_OUTLIER_FLOOR_DEG)
    positions = fill_positions(log.t, log.positions, pos_bad)
    rotations = fill_rotations(log.t, log.rotations, rot_bad)
    n_outliers = int((pos_bad | rot_bad).sum())
    logger.info(
        "%s: replaced %d outlier sample(s) of %d (%d in position, %d in orientation)",
        log.source or "tracker log",
        n_outliers,
        len(log.t),
        int(pos_bad.sum()),
        int(rot_bad.sum()),
    )

    start = find_motion_start(
        log.t, smooth_positions(log.t, positions, MOTION_START_SMOOTHING_S), settings.pause_speed_m_s
    )
    positions = smooth_positions(log.t, positions, settings.smoothing_s)
    rotations = smooth_rotations(log.t, rotations, settings.smoothing_s)
    speed = speed_along_track(log.t, positions)
    logger.info(
        "%s: motion starts at sample %d (t = %.3f s); peak speed %.3f m/s",
        log.source or "tracker log",
        start,
        log.t[start],
        float(speed.max()),
    )
    return Demonstration(
        t=log.t.copy(),
        positions=positions,
        rotations=rotations,
        speed=speed,
        motion_start=start,
        n_outliers=n_outliers,
        source=log.source,
    )
