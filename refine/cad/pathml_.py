"""A PathML track as the input of a refinement: positions, orientations and speeds in one file.

A PathML document (from refine or another tool, read with
:func:`refine.cad.pathml_read.read_pathml`) already holds what the CAD and demonstration
stages produce together: TCP positions in the world frame {F} [m], tool orientations R_F_TCP and
speeds. :func:`fused_from_pathml` turns one of its tracks into a :class:`~refine.paths.FusedPath`
at the waypoint spacing of the problem, so it can go straight to the optimiser:

* The track's points, consecutive duplicates dropped, form a polyline; waypoints are placed on it
  as on a CAD path (:func:`refine.cad.resample.resample_track`): its corners (points where it
  turns by more than 5 deg) kept, steps of at most ``spacing_m``, the polyline within
  ``chord_tolerance_m`` of the straight moves; the polyline is kept as the path's geometry.
  Arc length is measured along the points, not taken from their ``arcLength`` values.
* Orientations are interpolated by Slerp at the waypoints' arc lengths, speeds linearly; speeds
  below :data:`MIN_SPEED_M_S` (a trajectory that starts or ends at rest has speed 0 there) are
  raised to it, because a fused path's speed is a cap that must be > 0.
* ``t_demo`` is the time to travel the waypoints at those speeds (trapezoidal in 1/v); the
  ``residual`` (demo-to-CAD distance) is zero, as there is no separate demonstration.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation, Slerp

from refine.cad.pathml_read import PathMLTrack, read_pathml
from refine.cad.resample import DUPLICATE_TOLERANCE_M, resample_track
from refine.errors import InputError
from refine.paths import FusedPath
from refine.plausible import CAD_COORDINATE_LIMIT_M, CAD_SPEED_LIMIT_M_S, check_coordinates
from refine.settings import check_waypoint_count

logger = logging.getLogger(__name__)

#: Smallest speed a waypoint gets [m/s] (1 mm/s).
MIN_SPEED_M_S = 1e-3


def _select_track(path: Path, tracks: list[tuple[str, PathMLTrack]], track: str | None) -> PathMLTrack:
    names = [name for name, _ in tracks]
    if not tracks:
        raise InputError(f"PathML {path}: no tracks in the document")
    if track is None:
        if len(tracks) > 1:
            logger.info("PathML %s: %d tracks (%s); reading the first", path, len(tracks), ", ".join(names))
        return tracks[0][1]
    if "/" in track:
        hits = [t for name, t in tracks if name == track]
    else:
        hits = [t for name, t in tracks if name.split("/", 1)[1] == track]
    if len(hits) != 1:
        why = "is not in" if not hits else "names several tracks of"
        raise InputError(
            f"PathML {path}: track {track!r} {why} the document; give one of {', '.join(names)} "
            '(as "layer/track")'
        )
    return hits[0]


def fused_from_pathml(
    path: str | Path,
    spacing_m: float,
    track: str | None = None,
    *,
    reverse: bool = False,
    start_near: ArrayLike | None = None,
    chord_tolerance_m: float = 1e-4,
) -> FusedPath:
    """Read one PathML track as a fused path resampled by arc length (see the module docstring).

    Args:
        path: the PathML (``.aml``) document.
        spacing_m: largest waypoint spacing along the path [m], > 0.
        track: ``"layer/track"`` (or a track name that is unique in the document), or None for
            the first track of the first layer.
        reverse: run the track against the order of its points (``[cad] reverse``); each point
            keeps its orientation and speed.
        start_near: start a closed track (its last point repeats its first) at its point nearest
            to this, an open one at its end nearer to it [m], shape (3,) (``[cad] start_near``);
            applied before ``reverse``.
        chord_tolerance_m: largest distance of the track's polyline from the straight moves
            between waypoints [m] (``[cad] chord_tolerance_m``).

    Returns:
        The fused path in {F}: arc length [m], positions [m], orientations R_F_TCP, speeds
        [m/s] (>= :data:`MIN_SPEED_M_S`), times [s] from 0 and zero residuals, shape (N, ...).

    Raises:
        InputError: anything :func:`read_pathml` rejects, an unknown track (listing the tracks),
            a track with missing or non-finite speeds or fewer than two distinct points.
    """
    path = Path(path)
    doc = read_pathml(path)
    tracks = [(f"{layer.name}/{t.name}", t) for layer in doc.layers for t in layer.tracks]
    tr = _select_track(path, tracks, track)
    if not np.all(np.isfinite(tr.speed)):
        k = int(np.flatnonzero(~np.isfinite(tr.speed))[0])
        raise InputError(f"PathML {path}: track {tr.name!r} point {k} has no valid speed [m/s]")

    def where(k: int) -> str:
        return f"PathML {path}: track {tr.name!r} point {k}"

    check_coordinates(tr.positions, CAD_COORDINATE_LIMIT_M, where, "position")
    fast = np.flatnonzero(~(np.abs(tr.speed) <= CAD_SPEED_LIMIT_M_S))
    if fast.size:
        k = int(fast[0])
        raise InputError(
            f"{where(k)}: speed {tr.speed[k]:.6g} m/s is outside the plausible range 0..{CAD_SPEED_LIMIT_M_S:g} m/s"
        )

    keep = np.zeros(len(tr.positions), dtype=bool)
    keep[0] = True
    last = tr.positions[0]
    for k in range(1, len(tr.positions)):
        if np.linalg.norm(tr.positions[k] - last) > DUPLICATE_TOLERANCE_M:
            keep[k], last = True, tr.positions[k]
    points, rotations, speed = tr.positions[keep], tr.rotations[keep], tr.speed[keep]
    if len(points) < 2:
        raise InputError(f"PathML {path}: track {tr.name!r} needs at least 2 distinct points")
    order = np.arange(len(points))
    closed = len(points) > 2 and np.linalg.norm(points[-1] - points[0]) <= DUPLICATE_TOLERANCE_M
    if start_near is not None:
        near = np.asarray(start_near, dtype=float).reshape(3)
        if closed:
            ring = order[:-1]
            k = int(np.argmin(np.linalg.norm(points[ring] - near, axis=1)))
            order = np.r_[np.roll(ring, -k), ring[k]]
        elif np.linalg.norm(points[-1] - near) < np.linalg.norm(points[0] - near):
            order = order[::-1]
    if reverse:
        order = order[::-1]
    points, rotations, speed = points[order], rotations[order], speed[order]
    s_points = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])

    check_waypoint_count(
        float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1))),
        spacing_m,
        f"cad.file {Path(path).name!r}",
    )
    s, positions, exact_s, exact = resample_track(points, spacing_m, chord_tolerance_m)
    s = np.clip(s, 0.0, s_points[-1])
    R = Slerp(s_points, Rotation.from_matrix(rotations))(s).as_matrix()
    v = np.interp(s, s_points, speed)
    low = v < MIN_SPEED_M_S
    if low.any():
        logger.info(
            "PathML %s: %d waypoint speed(s) below %g m/s raised to it", path, int(low.sum()), MIN_SPEED_M_S
        )
        v = np.maximum(v, MIN_SPEED_M_S)
    t = np.concatenate([[0.0], np.cumsum(np.diff(s) / (0.5 * (v[1:] + v[:-1])))])
    logger.debug("PathML %s: track %r, %d points -> %d waypoints", path, tr.name, len(points), len(s))
    return FusedPath(
        s=s,
        positions=positions,
        rotations=R,
        speed=v,
        t_demo=t,
        residual=np.zeros(len(s)),
        exact_s=exact_s,
        exact=exact,
    )
