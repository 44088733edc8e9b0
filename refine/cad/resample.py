"""Resampling a polyline: at equal arc-length steps, or keeping its feature points within a chord tolerance.

The CAD readers return the path as a dense polyline: every vertex of the drawing plus the points
that flatten its arcs and splines. The optimiser wants waypoints at a fixed spacing instead.
:func:`resample_by_arc_length` places them exactly on that polyline, so resampling never moves the
path; it only chooses where along it the waypoints sit.

The rule, precisely:

* Consecutive input points closer than :data:`DUPLICATE_TOLERANCE_M` are duplicates; the later one
  is dropped (zero-length segments have no direction and would stall the arc-length map).
* A closed path is closed explicitly first: if its last point is not its first, the first point is
  appended, so the closing segment belongs to the length.
* With total length ``L`` and requested spacing ``h``, the path gets ``n = ceil(L / h)`` equal steps
  of ``L / n <= h``; that is ``n + 1`` waypoints including both ends.
* Waypoint ``i`` is the point at arc length ``s_i = i L / n`` on the polyline, by linear
  interpolation inside the segment that contains it. The first and last waypoints are copied from the
  input exactly (for a closed path the last waypoint *is* the first point).

Corners of the input polyline are not kept as waypoints unless they happen to fall on a step: a
waypoint grid that hits every corner would need uneven spacing. Between two waypoints the robot
path therefore cuts a corner by at most ``h / 2`` along each leg; choose ``h`` accordingly.

The CAD stage places its waypoints with :func:`resample_track` instead: the readers' feature
points and corners are kept exactly, the spacing is even only between two of them, and it shrinks
until the chord error against the reader's polyline is within a tolerance. The polyline and the
waypoints together are kept with the path as its geometry, to measure the chord error against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from refine.errors import InputError
from refine.paths import chord_errors

#: Consecutive input points closer than this are treated as one point [m].
DUPLICATE_TOLERANCE_M = 1e-9


def drop_duplicate_points(points: ArrayLike, tol: float = DUPLICATE_TOLERANCE_M) -> NDArray:
    """Remove points that repeat their predecessor within ``tol``.

    Args:
        points: polyline vertices [m], shape (K, 3).
        tol: distance under which two consecutive points count as one [m].

    Returns:
        The vertices without consecutive duplicates [m], shape (K', 3), K' <= K; the first point
        is always kept.
    """
    points = np.asarray(points, dtype=float)
    if len(points) == 0:
        return points.reshape(0, 3)
    keep = np.ones(len(points), dtype=bool)
    last = points[0]
    for k in range(1, len(points)):  # a chain of tiny steps must not add up unnoticed
        if np.linalg.norm(points[k] - last) <= tol:
            keep[k] = False
        else:
            last = points[k]
    return points[keep]


def resample_by_arc_length(
    points: ArrayLike, spacing_m: float, closed: bool = False
) -> tuple[NDArray, NDArray]:
    """Waypoints on a polyline at equal arc-length steps no longer than ``spacing_m``.

    See the module docstring for the exact rule.

    Args:
        points: polyline vertices [m], shape (K, 3), K >= 2 distinct points.
        spacing_m: largest allowed step between waypoints [m], > 0.
        closed: the path returns to its first point; the closing segment is added if missing.

    Returns:
        ``(s, positions)``: arc length of each waypoint [m], shape (N,), ``s[0] = 0`` and
        ``s[-1]`` the polyline length; the waypoints [m], shape (N, 3), N >= 2.

    Raises:
        InputError: bad shape, non-finite values, a non-positive spacing, or fewer than two
            distinct points.
    """
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"resample: points must have shape (K, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise InputError("resample: points contain NaN or infinite values")
    if not (math.isfinite(spacing_m) and spacing_m > 0.0):
        raise InputError(f"resample: spacing_m must be a finite number > 0 m, got {spacing_m!r}")
    points = drop_duplicate_points(points)
    if closed and len(points) >= 2:
        if np.linalg.norm(points[-1] - points[0]) <= DUPLICATE_TOLERANCE_M:
            points[-1] = points[0]
        else:
            points = np.vstack([points, points[:1]])
    if len(points) < 2 or (closed and len(points) < 3):
        raise InputError(
            f"resample: the path needs at least 2 distinct points, got {len(points)} "
            f"(duplicates within {DUPLICATE_TOLERANCE_M} m removed)"
        )

    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    length = float(cum[-1])
    n = max(1, math.ceil(length / spacing_m))
    while length / n > spacing_m:  # guard against rounding in the division above
        n += 1
    s = np.linspace(0.0, length, n + 1)
    s[-1] = length

    # segment j holds s in [cum[j], cum[j+1]); the last waypoint is pinned below
    j = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    frac = (s - cum[j]) / seg[j]
    positions = points[j] + frac[:, None] * (points[j + 1] - points[j])
    positions[0] = points[0]
    positions[-1] = points[-1]
    return s, positions


def nearest_on_polyline(points: NDArray, q: NDArray) -> tuple[float, int, NDArray]:
    """Distance from ``q`` to the polyline ``points`` (K, 3), the segment index and the nearest point.

    Args:
        points: polyline vertices, shape (K, 3), K >= 2, in the unit of ``q``.
        q: the point, shape (3,).

    Returns:
        ``(distance, j, foot)``: the distance, the index of the segment ``points[j] -> points[j + 1]``
        that holds the nearest point, and that point, shape (3,).
    """
    a, b = points[:-1], points[1:]
    ab = b - a
    denom = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", q - a, ab) / np.where(denom > 0, denom, 1.0), 0.0, 1.0)
    foot = a + t[:, None] * ab
    d = np.linalg.norm(foot - q, axis=1)
    j = int(np.argmin(d))
    return float(d[j]), j, foot[j]


def start_at_nearest(points: NDArray, near: NDArray, closed: bool, tol: float) -> tuple[NDArray, bool, float]:
    """The polyline started at its point nearest to ``near`` (``[cad] start_near``).

    A closed polyline (its last point repeats its first) is rotated to start, and end, at its point
    nearest to ``near``, inserted between two vertices when it falls inside a segment; its direction
    is kept. An open polyline starts at the end nearer to ``near``: it is reversed when that is its
    last point.

    Args:
        points: polyline vertices, shape (K, 3), K >= 2.
        near: the point to start near, shape (3,), in the unit of ``points``.
        closed: whether the polyline is closed.
        tol: vertices closer than this count as one point, in the unit of ``points``.

    Returns:
        ``(points, reversed, offset)``: the reordered vertices (a closed one ends with its first
        point), whether they were reversed, and the arc length along the input from its first
        point to the new first point, in the unit of ``points`` (for a reversed open polyline
        its length).
    """
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    if not closed:
        ends = np.linalg.norm(points[[0, -1]] - near, axis=1)
        if ends[1] < ends[0]:
            return points[::-1].copy(), True, float(seg.sum())
        return points, False, 0.0
    chosen = points.copy()
    chosen[-1] = chosen[0]
    _, j, foot = nearest_on_polyline(chosen, near)
    offset = float(seg[:j].sum() + np.linalg.norm(foot - chosen[j]))
    ring = chosen[:-1]
    if np.linalg.norm(foot - chosen[j + 1]) <= tol:
        j, foot = j + 1, chosen[j + 1]
    if np.linalg.norm(foot - ring[j % len(ring)]) <= tol:
        ring = np.roll(ring, -(j % len(ring)), axis=0)
    else:
        ring = np.vstack([foot, ring[j + 1 :], ring[: j + 1]])
    return np.vstack([ring, ring[:1]]), False, offset % float(seg.sum())


#: What a point of a reader's polyline is (:class:`CadTrack` ``kinds``): a point that only flattens
#: a curve, a vertex of the CAD (kept as a waypoint where the path turns there by more than
#: :data:`CORNER_ANGLE_DEG`), or a feature point (always kept as a waypoint).
FLATTENING, VERTEX, FEATURE = 0, 1, 2

#: A vertex where the path turns by more than this is a corner and becomes a waypoint [deg].
CORNER_ANGLE_DEG = 5.0


@dataclass(frozen=True)
class CadTrack:
    """One track of a CAD/CAM file as its reader evaluates it: a dense polyline and its feature points.

    Attributes:
        points: the polyline [m], shape (K, 3): every vertex of the CAD and the points that
            flatten its arcs and splines (within the reader's flattening tolerance, 1 µm for DXF and
            G-code); a closed track repeats its first point at the end.
        kinds: what each point is, shape (K,): :data:`FLATTENING`, :data:`VERTEX` or
            :data:`FEATURE`.
        closed: the track returns to its first point.
        label: where it comes from in the file (entities, lines), for messages.
    """

    points: NDArray
    kinds: NDArray
    closed: bool = False
    label: str = ""


def turn_angles_deg(points: NDArray, closed: bool) -> NDArray:
    """The angle the polyline turns by at each point [deg], shape (K,); 0 at the ends of an open one.

    Args:
        points: polyline vertices without consecutive duplicates, shape (K, 3), K >= 2; a closed
            one repeats its first point at the end (both ends then get the turn at the start).
        closed: whether the polyline is closed.
    """
    d = np.diff(points, axis=0)
    u = d / np.linalg.norm(d, axis=1, keepdims=True)
    turn = np.zeros(len(points))
    turn[1:-1] = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", u[:-1], u[1:]), -1.0, 1.0)))
    if closed and len(u) > 1:
        turn[0] = turn[-1] = math.degrees(math.acos(float(np.clip(u[-1] @ u[0], -1.0, 1.0))))
    return turn


def _span_grid(
    points: NDArray, cum: NDArray, lo: int, hi: int, spacing_m: float, tol: float
) -> tuple[NDArray, NDArray]:
    """Equal steps from point ``lo`` to point ``hi`` of the polyline, fine enough for ``tol``."""
    length = float(cum[hi] - cum[lo])
    n = max(1, math.ceil(length / spacing_m * (1.0 - 1e-12)))  # 40 mm at 5 mm is 8 steps despite rounding
    while length / n > spacing_m * (1.0 + 1e-12):
        n += 1
    inner = points[lo + 1 : hi]
    seg = np.diff(cum)
    while True:
        s = np.linspace(cum[lo], cum[hi], n + 1)
        k = np.clip(np.searchsorted(cum, s, side="right") - 1, lo, hi - 1)
        pos = points[k] + ((s - cum[k]) / seg[k])[:, None] * (points[k + 1] - points[k])
        pos[0], pos[-1] = points[lo], points[hi]
        if len(inner) == 0:
            return s, pos
        j = np.clip(np.searchsorted(s, cum[lo + 1 : hi], side="right") - 1, 0, n - 1)
        err = float(chord_errors(inner, j, pos).max())
        if err <= tol:
            return s, pos
        # a chord's sagitta grows with the square of its length: aim straight at the tolerance
        n = max(n + 1, math.ceil(n * math.sqrt(err / tol)))
        if n > MAX_SPAN_STEPS:
            raise InputError(
                f"resample: more than {MAX_SPAN_STEPS} waypoints on {length * 1e3:.3f} mm of path to keep "
                f"the chord error within {tol * 1e3:.4g} mm; use a larger cad.chord_tolerance_m"
            )


#: Most waypoints between two kept points of one track (a guard against a chord tolerance that
#: the polyline's own flattening cannot meet).
MAX_SPAN_STEPS = 20_000


def resample_track(
    points: ArrayLike,
    spacing_m: float,
    chord_tolerance_m: float,
    *,
    kinds: ArrayLike | None = None,
    closed: bool = False,
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Waypoints on a polyline that keep its feature points and corners and follow it within a tolerance.

    The rule:

    * Duplicates are dropped and a closed polyline is closed as in :func:`resample_by_arc_length`.
    * Kept exactly as waypoints: both ends, every :data:`FEATURE` point and every :data:`VERTEX`
      where the polyline turns by more than :data:`CORNER_ANGLE_DEG` (a corner).
    * Between two kept points the waypoints are equally spaced along the polyline, as few as give
      steps of at most ``spacing_m`` and a chord error of at most ``chord_tolerance_m``: no point
      of the polyline between two waypoints lies farther than that from the straight move
      between them.

    Args:
        points: the reader's polyline [m], shape (K, 3), K >= 2 distinct points.
        spacing_m: largest step between waypoints [m], > 0.
        chord_tolerance_m: largest distance of the polyline from the straight moves [m], > 0.
        kinds: what each point is (:data:`FLATTENING`, :data:`VERTEX`, :data:`FEATURE`), shape (K,);
            None treats every point as a vertex.
        closed: the polyline returns to its first point.

    Returns:
        ``(s, positions, exact_s, exact)``: the waypoints' arc length [m], shape (N,), and
        positions [m], shape (N, 3); the polyline's points together with the waypoints, ordered by
        arc length (``exact_s`` [m], shape (M,); ``exact`` [m], shape (M, 3)): the geometry the
        chord error is measured against.

    Raises:
        InputError: what :func:`resample_by_arc_length` rejects, a non-positive tolerance, or a
            tolerance that needs more than :data:`MAX_SPAN_STEPS` steps between two kept points.
    """
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"resample: points must have shape (K, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise InputError("resample: points contain NaN or infinite values")
    if not (math.isfinite(spacing_m) and spacing_m > 0.0):
        raise InputError(f"resample: spacing_m must be a finite number > 0 m, got {spacing_m!r}")
    if not (math.isfinite(chord_tolerance_m) and chord_tolerance_m > 0.0):
        raise InputError(f"resample: chord_tolerance_m must be a finite number > 0 m, got {chord_tolerance_m!r}")
    kinds = np.full(len(points), VERTEX, dtype=np.int8) if kinds is None else np.asarray(kinds, dtype=np.int8)
    if kinds.shape != (len(points),):
        raise InputError(f"resample: kinds must have shape ({len(points)},), got {kinds.shape}")
    keep = np.ones(len(points), dtype=bool)
    last = 0
    for k in range(1, len(points)):
        if np.linalg.norm(points[k] - points[last]) <= DUPLICATE_TOLERANCE_M:
            keep[k] = False
            kinds[last] = max(kinds[last], kinds[k])
        else:
            last = k
    points, kinds = points[keep], kinds[keep]
    if closed and len(points) >= 2:
        if np.linalg.norm(points[-1] - points[0]) <= DUPLICATE_TOLERANCE_M:
            points[-1] = points[0]
        else:
            points, kinds = np.vstack([points, points[:1]]), np.r_[kinds, kinds[:1]]
    if len(points) < 2 or (closed and len(points) < 3):
        raise InputError(
            f"resample: the path needs at least 2 distinct points, got {len(points)} "
            f"(duplicates within {DUPLICATE_TOLERANCE_M} m removed)"
        )
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    turn = turn_angles_deg(points, closed)
    kept = (kinds == FEATURE) | ((kinds == VERTEX) & (turn > CORNER_ANGLE_DEG))
    kept[0] = kept[-1] = True
    ends = np.flatnonzero(kept)
    s_parts, p_parts = [np.zeros(1)], [points[:1]]
    for lo, hi in zip(ends[:-1], ends[1:], strict=True):
        s, pos = _span_grid(points, cum, int(lo), int(hi), spacing_m, chord_tolerance_m)
        s_parts.append(s[1:])
        p_parts.append(pos[1:])
    s, positions = np.concatenate(s_parts), np.vstack(p_parts)
    s[-1] = cum[-1]
    order = np.argsort(np.concatenate([cum, s]), kind="stable")
    exact_s = np.concatenate([cum, s])[order]
    exact = np.vstack([points, positions])[order]
    return s, positions, exact_s, exact
