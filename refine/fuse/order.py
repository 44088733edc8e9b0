"""Which way round and from where: the worker's direction and start on the CAD path.

Which way round and from where: the direction of travel and, on a closed contour, the start point
of a demonstration on the CAD path, found by a coarse match both ways (cyclic on a closed path);
the CAD waypoints reordered to the worker's direction and start (:func:`reorder`). A clearly
better direction is taken (its coarse distance at most 1/:data:`DIRECTION_RATIO` of the other's);
otherwise the run stops naming both. ``[cad] reverse`` and ``start_near`` override the search.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import uniform_filter1d
from scipy.spatial.distance import cdist

from refine.errors import InputError
from refine.frames import check_transform, invert_transform, transform_points
from refine.fuse.align import (
    MAX_RESIDUAL_M,
    PRE_MOTION_S,
    monotone_dtw,
    refine_start,
    resample_in_time,
    start_position,
)
from refine.paths import CadPath, Demonstration, PathOrder
from refine.types import Array

logger = logging.getLogger(__name__)

SEARCH_MAX_POINTS = 240  # CAD points of the direction and start search at most


DIRECTION_RATIO = 2.0  # the other direction's coarse residual must be this many times the chosen one's


DIRECTIONS = ("as_cad", "reversed")


SEARCH_ROUNDS = 2  # coarse matches per direction, the demo moved by the matched mean offset between them


def cyclic_dtw(cost: Array) -> tuple[NDArray[np.intp], int]:
    """Monotone DTW once round a closed path, from any start: the column matched to each row.

    The columns are the K points of a closed path (the closing point not repeated). Row 0 may be
    matched to any column j0; each row advances by 0, 1 or 2 columns, modulo K; the last row is
    matched to j0 again, one lap later.

    Args:
        cost: matching cost, shape (M, K).

    Returns:
        The unwrapped column per row (M,), from j0 to j0 + K, non-decreasing, and j0.

    Raises:
        InputError: when M rows cannot go once round (M < K / 2 + 1).
    """
    m, k = cost.shape
    ext = np.concatenate([cost, cost, cost[:, :1]], axis=1)  # columns 0 .. 2K (2K is column 0 again)
    n = 2 * k + 1
    D = np.full(n, np.inf)
    D[:k] = ext[0, :k]
    start = np.arange(n)
    step = np.zeros((m, n), dtype=np.int8)  # columns advanced into each cell
    for i in range(1, m):
        best, src, arg = D.copy(), start.copy(), step[i]
        for d in (1, 2):
            better = D[:-d] < best[d:]
            np.copyto(best[d:], D[:-d], where=better)
            np.copyto(src[d:], start[:-d], where=better)
            np.copyto(arg[d:], d, where=better)
        D, start = best + ext[i], src
    end = np.arange(k, n)  # a full lap: end column = start column + K
    ok = start[end] == end - k
    if not np.any(ok & np.isfinite(D[end])):
        raise InputError(f"DTW: {m} demo rows cannot go once round {k} path points (need >= {k // 2 + 1})")
    j = int(end[ok][np.argmin(np.where(np.isfinite(D[end[ok]]), D[end[ok]], np.inf))])
    cols = np.empty(m, dtype=np.intp)
    cols[-1] = j
    for i in range(m - 1, 0, -1):
        j -= int(step[i, j])
        cols[i - 1] = j
    return cols, int(cols[0])


def _ring(points: Array, closed: bool, reverse: bool) -> Array:
    """Search points in the order of one direction; a closed path's (without its closing point) keeps its first."""
    if not closed or not reverse:
        return points[::-1] if reverse else points
    return np.concatenate([points[:1], points[:0:-1]])


def _search_order(
    rows: Array, cad_s: Array, cad: Array, closed: bool, directions: tuple[bool, ...], search_start: bool
) -> dict[bool, tuple[float, float, Array]]:
    """Coarse match of demo rows for each direction (and, on a closed path, every start).

    ``SEARCH_ROUNDS`` matches: after each, the demo rows are moved by the mean offset to their
    matched points (a rigid tracker offset would otherwise blur the comparison on a small path).

    Args:
        rows: demo TCP positions on a time grid, from the start pause on [m], (M, 3).
        cad_s: arc length of the waypoints [m], (N,).
        cad: waypoints in the demo's frame [m], (N, 3).
        closed: the path is closed (its last waypoint repeats its first).
        directions: the directions to try (False as the waypoints run, True reversed).
        search_start: try every start of a closed path.

    Returns:
        Per direction: the larger of the median row-to-path and the median path-to-row distance
        of the last match [m], the arc length of
        the start found, along the waypoints' order from the first one [m], and the offset the
        rows were moved by [m], (3,).
    """
    n = len(cad_s) - int(closed)
    idx = np.arange(0, n, -(-n // SEARCH_MAX_POINTS))
    if not closed:
        idx = np.unique(np.r_[idx, n - 1])
    pts, sc = cad[idx], cad_s[idx]
    k = len(idx)
    rows = rows[:: max(1, len(rows) // (2 * k))]
    out = {}
    for reverse in directions:
        ring = _ring(pts, closed, reverse)
        cyclic = closed and search_start
        if closed and not cyclic:
            ring = np.vstack([ring, ring[:1]])
        shift, j0 = np.zeros(3), 0
        for _ in range(SEARCH_ROUNDS):  # match, move the demo by the matched mean offset, match again
            moved = rows + shift
            cost = cdist(moved, ring)
            if cyclic:
                unwrapped, j0 = cyclic_dtw(cost)
            else:
                unwrapped = monotone_dtw(cost)
            cols = unwrapped % len(ring)
            d_demo = cost[np.arange(len(rows)), cols]
            # each path point to the first row matched at or past it: a demo that stays on part
            # of the path is near the path, but the path is not near it
            j = np.arange(j0, j0 + len(ring))
            first = np.minimum(np.searchsorted(unwrapped, j), len(rows) - 1)
            d_path = np.linalg.norm(ring[j % len(ring)] - moved[first], axis=1)
            shift = shift + np.mean(ring[cols] - moved, axis=0)
        j0 = (0 if j0 == 0 else k - j0) if reverse else j0  # index into pts
        out[reverse] = (max(float(np.median(d_demo)), float(np.median(d_path))), float(sc[j0]), shift)
    return out


def reorder(cad: CadPath, reverse: bool, start: int) -> CadPath:
    """The same waypoints run the other way and/or from another waypoint of a closed path.

    Args:
        cad: the path.
        reverse: run it the other way (a closed path keeps its first point).
        start: index, in the new direction, of the waypoint to start from (closed paths only).

    Returns:
        The path with its ``s`` restarted at 0, and ``reversed`` / ``start_offset_m`` updated.
    """
    if not reverse and not start:
        return cad
    p, ds = cad.positions, np.diff(cad.s)
    L = cad.length
    if reverse:
        p, ds = p[::-1], ds[::-1]
    first = (len(p) - 1 - start) % (len(p) - 1) if reverse else start  # index in cad of the new start
    sigma_run = float(np.sum(ds[:start])) if cad.closed and start else 0.0  # new start along the run
    exact_s, exact = cad.reordered_exact(reverse, sigma_run)
    if cad.closed and start:
        ring = np.roll(p[:-1], -start, axis=0)
        p, ds = np.vstack([ring, ring[:1]]), np.roll(ds, -start)
    sigma = float(cad.s[first]) if cad.closed else (L if reverse else 0.0)
    offset = cad.start_offset_m - sigma if cad.reversed else cad.start_offset_m + sigma
    if cad.closed:
        offset %= L
    return replace(
        cad,
        s=np.r_[0.0, np.cumsum(ds)],
        positions=np.ascontiguousarray(p),
        reversed=cad.reversed != reverse,
        start_offset_m=float(offset),
        exact_s=exact_s,
        exact=exact,
    )


def orient(
    cad: CadPath, demo: Demonstration, source_in_world: ArrayLike, sensor_in_tcp: ArrayLike
) -> tuple[bool, int, PathOrder]:
    """The CAD path turned to the worker's direction and, when closed, started where the worker started.

    The demo TCP positions from ``PRE_MOTION_S`` before ``motion_start`` (box-averaged on a time
    grid of about four rows per search point) are matched by DTW to the waypoints, thinned to at
    most ``SEARCH_MAX_POINTS``, once as drawn and once reversed; on a closed path by
    :func:`cyclic_dtw`, which also finds the start; ``SEARCH_ROUNDS`` times, the rows moved by
    their mean offset to the matched points in between. A direction's distance is the larger of
    the median row-to-path and the median path-to-row distance; the smaller wins when the
    other's is at least ``DIRECTION_RATIO`` times it. The
    start is then refined to the path point nearest to the demo's start position (its mean over
    the first ``START_WINDOW_S``, not past ``motion_start``), within two search steps of the
    coarse start, and rounded to the nearest waypoint.
    What the problem fixed (``cad.direction_given``, ``cad.start_given``) is kept, not searched.

    Args:
        cad: the CAD path in {F}.
        demo: the cleaned demonstration.
        source_in_world: receiver pose in the world, T_F_S, shape (4, 4).
        sensor_in_tcp: sensor pose in the tool frame, T_TCP_E, shape (4, 4).

    Returns:
        Whether to reverse the path, the waypoint to start from in that direction (the arguments
        of :func:`reorder`), and what was chosen.

    Raises:
        InputError: neither direction clearly better (naming both distances [mm]).
    """
    open_path = not cad.closed
    if cad.direction_given and (cad.start_given or open_path):
        d = "reversed" if cad.reversed else "as_cad"
        start = "open path" if open_path else "problem"
        return False, 0, PathOrder(d, cad.start_offset_m, "problem", start)
    T_S_F = invert_transform(check_transform(source_in_world, "source_in_world"))
    T_E_TCP = invert_transform(check_transform(sensor_in_tcp, "sensor_in_tcp"))
    i0 = int(np.searchsorted(demo.t, demo.t[demo.motion_start] - PRE_MOTION_S))
    t = demo.t[i0:]
    p = demo.positions[i0:] + np.einsum("mij,j->mi", demo.rotations[i0:], T_E_TCP[:3, 3])
    cad_S = transform_points(T_S_F, cad.positions)
    n_search = min(SEARCH_MAX_POINTS, len(cad.s))
    dt_grid = max((t[-1] - t[0]) / (2 * n_search), float(np.median(np.diff(t))))
    tg = np.linspace(t[0], t[-1], int(np.ceil((t[-1] - t[0]) / dt_grid)) + 1)
    pg = resample_in_time(
        t, uniform_filter1d(p, max(1, round(dt_grid / float(np.median(np.diff(t))))), axis=0), tg
    )
    directions = (False,) if cad.direction_given else (False, True)
    found = _search_order(pg, cad.s, cad_S, cad.closed, directions, not cad.start_given)
    reverse = min(found, key=lambda r: found[r][0])
    tried = ", ".join(f"{v[0] * 1e3:.0f} mm {'reversed' if r else 'as drawn'}" for r, v in found.items())
    if found[reverse][0] > MAX_RESIDUAL_M:
        raise InputError(
            f"demo {demo.source!r} does not follow the CAD path {cad.source!r}: median distance "
            f"{tried} before alignment (limit {MAX_RESIDUAL_M * 1e3:.0f} mm); check frames and units"
        )
    if len(found) == 2 and found[not reverse][0] < DIRECTION_RATIO * found[reverse][0]:
        raise InputError(
            f"demo {demo.source!r}: cannot tell which way round the CAD path {cad.source!r} it runs: "
            f"median distance {found[False][0] * 1e3:.1f} mm as drawn, {found[True][0] * 1e3:.1f} mm "
            f"reversed (the better must be under 1/{DIRECTION_RATIO:g} of the other); does it cover the "
            "whole path once? set [cad] reverse to choose"
        )
    # as the file runs, and against it (cad may already run against the file: [cad] reverse)
    residuals = (found[cad.reversed][0], found[not cad.reversed][0]) if len(found) == 2 else (None, None)
    start = 0
    if cad.closed and not cad.start_given:
        s0 = found[reverse][1]
        if reverse:  # the search's start is along the waypoints' order; measure it along the reversed run
            s0 = (cad.length - s0) % cad.length
        ring_s = cad.s if not reverse else np.r_[0.0, np.cumsum(np.diff(cad.s)[::-1])]
        ring = cad_S if not reverse else cad_S[::-1]
        # the demo's start moved by the offset the search found, then onto the path
        p_start = start_position(t, p, float(demo.t[demo.motion_start])) + found[reverse][2]
        h_search = cad.length / n_search
        s_start = refine_start(p_start, ring_s, ring, s0, 2.0 * h_search)
        start = int(np.argmin(np.abs(ring_s - s_start))) % (len(ring_s) - 1)
    out = reorder(cad, reverse, start)
    order = PathOrder(
        "reversed" if out.reversed else "as_cad",
        out.start_offset_m,
        "problem" if cad.direction_given else "alignment",
        "open path" if open_path else "problem" if cad.start_given else "alignment",
        *residuals,
    )
    logger.info(
        "path order: %s from %.3f m (coarse median distance %s)",
        order.direction,
        order.start_offset_m,
        ", ".join(f"{DIRECTIONS[int(r)]} {v[0] * 1e3:.1f} mm" for r, v in found.items()),
    )
    return reverse, start, order
