"""Resampling a polyline at equal arc-length steps.

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
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from refine.errors import InputError

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
