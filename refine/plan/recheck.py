"""A motion planned again, its clearance proved from its earlier check's bounds.

A re-solve after a small change (the part moved a few millimetres, another cone) plans the same
motions with joints close to the earlier ones, row for row: a line's IK samples at the same shares
of the line, a direct joint move's two ends. The earlier check of the motion
(:func:`refine.collision.check_path_clearance`) ended with a lower bound on every pair's distance
at each of its rows (:class:`refine.collision.carry.CheckedBounds`); carried to the new rows they
still bound the distances from below,

    d_p(q_new) >= d_p(q_old) - |q_new - q_old| · R_p - δ_p

(:func:`refine.collision.carry.carried_bounds`: ``R_p`` the pair's motion bound per joint, ``δ_p``
the largest displacement of its cell object). :func:`recheck` proves every margin along the new
motion from them as the dense check proves it from its own bounds: a pair whose budgets (bound
minus margin plus tolerance) at a segment's two ends add up to the pair's motion over the segment
keeps its margin over the whole segment (:mod:`refine.collision.advance`); a pair that falls short
is measured exactly at the ends and advanced by FCL queries (:func:`refine.collision.advance.advance_pairs`),
as in the dense check, unless the earlier check's samples of it inside the segment, carried the same
way, prove its margin and lie above the segment's least figures (:func:`_samples_carried`). The least distance and clearance are then measured exactly: at every row
whose bounds could hold them (:func:`refine.collision.carry.measure_least`, with the gaps along
the witness normals found, :func:`refine.collision.carry.raise_near`), and the samples the
advancement took inside a segment count with their segment's ends measured, as in the dense check.

What it skips is the dense check's own bounding of every pair at every row (boxes, gaps along the
last normals) and the check's set-up; what it finds is what the dense check finds from the same
exact distances (to FCL's accuracy): the same pairs advanced (those the exact distances at a
segment's ends leave short, whatever lower bounds came first), hence the same samples inside, and
the same least figures and pair. A row measured exactly is kept with its collision model (the
last :data:`MEASURED_ROWS`): motions planned one after the other share their ends (the home move
ends on the approach's first row), and the later takes the row's figures and witnesses as they
were, leaving the model the witness normals the measurement left
(:meth:`CollisionModel.take_witnesses`). When the carried bounds cannot serve (no earlier check,
other rows, another robot, base or body, a pair without a bound at more than :data:`UNBOUND_ROWS`
rows, a margin broken or a segment the advancement gives up on) it returns None and the caller runs
the dense check, which finds and names what is broken.
"""

from __future__ import annotations

import math
import threading
import time
import weakref
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from refine.collision import CollisionModel, PathClearance
from refine.collision.advance import NONE, Sample, advance_pairs, pair_motion, short
from refine.collision.carry import (
    NEAR,
    CheckedBounds,
    carried_bounds,
    checked_bounds,
    hull_corners,
    measure_least,
    raise_near,
    tightener,
)
from refine.native import BoundedCache
from refine.types import Array

UNBOUND_ROWS = 2
"""Rows with a pair the earlier bounds leave unbounded that :func:`recheck` measures; more: None."""

MEASURED_ROWS = 16
"""Rows measured exactly that :func:`recheck` keeps per collision model for the next motions."""


def recheck(
    model: CollisionModel, q: Array, previous: object, tolerance_m: float = 1e-4
) -> PathClearance | None:
    """The clearance check of the joint-interpolated rows ``q`` (K, n) from ``previous``'s bounds, or None.

    Args:
        model: the collision model (with the run's margins).
        q: joints [rad], (K, n), K >= 2, row for row the motion ``previous`` checked, moved a little.
        previous: the earlier check of the motion (``PathClearance`` with ``bounds``), or None.
        tolerance_m: clearances down to ``-tolerance_m`` still count as kept [m].

    Returns:
        A ``PathClearance`` as :func:`refine.collision.check_path_clearance` with
        ``every_waypoint=False`` gives it (every segment certified, no run below the margin; the
        least figures exact, a row's other figures lower bounds), or None (module notes).
    """
    checked = getattr(previous, "bounds", None)
    q = np.asarray(q, dtype=float)
    if checked is None or q.ndim != 2 or len(q) < 2 or checked.q.shape != q.shape:
        return None
    start, queries = time.perf_counter(), model.queries
    carried = _carried(model, checked, q)  # (K, P) lower bounds [m], -inf where none is carried
    if carried is None:
        return None
    bounds, delta = carried
    poses = model.moving_poses(q)
    unbound = ~np.isfinite(bounds)
    if unbound.any():  # the boxes bound those pairs where they are apart
        bounds = np.maximum(bounds, model.box_bounds(poses))
        if np.count_nonzero((~np.isfinite(bounds)).any(axis=1)) > UNBOUND_ROWS:
            return None
    margins = model.pair_margins
    exact = np.zeros(bounds.shape, dtype=bool)
    normals = np.full((*bounds.shape, 3), np.nan)
    at: dict[int, Sample] = {}

    def measure(k: int) -> tuple[float, float]:
        key = q[k].tobytes() + poses[k].tobytes()
        known = _measured_row(model, key)
        if known is None:
            by_distance, by_clearance = model.nearest_pairs(q[k], poses[k], bounds[k].copy())
            if by_distance is None or by_clearance is None:
                at[k] = Sample(math.inf, math.inf, ("", ""), math.inf, NONE)
            else:
                pair = (by_clearance.body, by_clearance.other)
                at[k] = Sample(
                    by_distance.distance_m, by_clearance.clearance_m, pair, by_clearance.distance_m, NONE
                )
            found = model.witnesses(q[k])
            _keep_row(model, key, (at[k], found))
        else:
            at[k], found = known
            model.take_witnesses(found)  # the last normals the measurement would have left
        for p, (d, n) in found.items():
            bounds[k, p], exact[k, p], normals[k, p] = d, True, n
        raise_near(model, poses, bounds, k, found)
        return at[k].distance, at[k].clearance

    measured = measure_least(bounds, margins, measure, NEAR, tightener(model, poses, bounds, exact))
    proved, kept = _samples_carried(model, previous, checked, q, bounds, delta, tolerance_m, at, measure)
    measured[list(at)] = True
    certified, inner = advance_pairs(model, q, poses, bounds, exact, tolerance_m, proved)
    if not certified.all():
        return None  # a margin broken or a segment given up: the dense check samples and names it
    for k in sorted({k + e for k, found in inner.items() if found for e in (0, 1)} - set(at)):
        measure(k)  # a segment sampled inside takes its ends' exact figures, as in the dense check
        measured[k] = True
    # ---- per row: the exact figures where measured, the bounds elsewhere
    clear = bounds - margins
    least = np.argmin(clear, axis=1)
    rows = np.arange(len(q))
    wp_dist, wp_clear = bounds.min(axis=1), clear[rows, least]
    wp_pair = [model.pairs[p] for p in least.tolist()]
    for k, s in at.items():
        wp_dist[k], wp_clear[k], wp_pair[k] = s.distance, s.clearance, s.pair
    # ---- per segment: its ends' figures, and where the advancement sampled inside, its samples'
    ends = np.arange(len(q) - 1) + (wp_clear[1:] < wp_clear[:-1])  # the worse end: the first of a tie
    seg_dist = np.minimum(wp_dist[:-1], wp_dist[1:])
    seg_clear = wp_clear[ends]
    seg_pair = [wp_pair[k] for k in ends.tolist()]
    steps = np.ones(len(q) - 1, dtype=np.int64)
    for k, samples in inner.items():
        if not samples:
            continue
        found = [at[k], at[k + 1], *samples]
        steps[k] = len(samples) + 1
        seg_dist[k] = min(s.distance for s in found)
        w = min(found, key=lambda s: s.clearance)  # the first of a tie
        seg_clear[k], seg_pair[k] = w.clearance, w.pair
    return PathClearance(
        waypoint_distance_m=wp_dist,
        waypoint_clearance_m=wp_clear,
        segment_distance_m=seg_dist,
        segment_clearance_m=seg_clear,
        segment_pair=tuple(seg_pair),
        segment_samples=steps,
        runs=(),
        queries=model.queries - queries,
        time_s=time.perf_counter() - start,
        tolerance_m=tolerance_m,
        certified_segments=len(q) - 1,
        waypoint_measured=measured,
        bounds=checked_bounds(model, q, bounds, normals),
        inner_samples={k: [*kept.get(k, ()), *inner.get(k, ())] for k in {*kept, *inner}},
    )


_MEASURED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""Per collision model: the rows it measured exactly (joints' and moving poses' bytes -> what was found),
the last :data:`MEASURED_ROWS` used (a :class:`refine.native.BoundedCache`, which holds its own lock)."""
_MEASURED_LOCK = threading.Lock()  # held while _MEASURED itself is read or changed

Measured = tuple[Sample, dict[int, tuple[float, Array]]]
"""A row measured exactly: its least figures and the pairs measured there, by pair index, with their
distances [m] and unit witness normals (:meth:`CollisionModel.witnesses`)."""


def _measured_row(model: CollisionModel, key: bytes) -> Measured | None:
    """What ``model`` found at the row ``key`` (the joints' and the moving bodies' poses' bytes), or None.

    A model's cell, tool, base and margins are fixed for its life (as
    :func:`refine.collision.carry.hull_corners` keeps them), so the model and the row's joints and
    poses to the bit fix every distance measured there: a row two motions planned one after the
    other share (a line's first row, the direct move ending on it) is measured once.
    """
    with _MEASURED_LOCK:
        rows = _MEASURED.get(model)
    return None if rows is None else rows.get(key)


def _keep_row(model: CollisionModel, key: bytes, found: Measured) -> None:
    """Keep ``found`` at the row ``key`` of ``model`` (past :data:`MEASURED_ROWS`, the oldest used goes)."""
    with _MEASURED_LOCK:
        rows = _MEASURED.get(model)
        if rows is None:
            rows = _MEASURED[model] = BoundedCache(MEASURED_ROWS)
    rows.put(key, found)


_SHIFTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""Per collision model: its bodies' labels, each pair's two label indices, and the shifts found so far."""


def _carried(model: CollisionModel, checked: CheckedBounds, q: Array) -> tuple[Array, Array | None] | None:
    """:func:`refine.collision.carry.carried_bounds` of ``checked`` at joints ``q`` (K, n), (K, P) [m] or None.

    With the bounds, each pair's shift ``δ_p`` [m] (P,), or None where ``carried_bounds`` formed them.

    For a check of the same pairs in the same order (a motion of the run before) the bounds are
    formed as there, ``bound - |q - q_checked| · R_p - δ_p`` kept where positive, with each body's
    shift ``δ`` (0 for the same shape on the same joint, the largest corner displacement of a cell
    object, inf for a changed shape) kept per model and earlier hull; other pairs go to
    ``carried_bounds`` itself.
    """
    if checked.pairs != model.pairs:
        out = carried_bounds(model, checked, q)
        return None if out is None else (out, None)
    if (
        q.shape != checked.q.shape
        or q.shape[1] != model.robot.nq
        or not np.array_equal(model.base_in_world, checked.base_in_world)
    ):
        return None
    hulls = hull_corners(model)
    kept = _SHIFTS.get(model)
    if kept is None:
        labels = {label: i for i, label in enumerate(hulls)}
        a = np.array([labels[x] for x, _ in model.pairs], dtype=int)
        b = np.array([labels[y] for _, y in model.pairs], dtype=int)
        kept = _SHIFTS[model] = (a, b, {})
    a, b, found = kept
    shift = np.empty(len(hulls))
    for i, (label, (joint, now)) in enumerate(hulls.items()):
        before = checked.shapes.get(label)
        memo = found.get(label)
        if memo is None or memo[0] is not before:
            memo = found[label] = (before, _shift(before, joint, now))
        shift[i] = memo[1]
    delta = shift[a] + shift[b]  # (P,) [m], inf for a pair with a changed body
    out = checked.bounds - np.abs(q - checked.q) @ model.pair_motion.T - delta
    return np.where(out > 0.0, out, -np.inf), delta


def _samples_carried(
    model: CollisionModel,
    previous: object,
    checked: CheckedBounds,
    q: Array,
    bounds: Array,
    delta: Array | None,
    tolerance_m: float,
    at: dict[int, Sample],
    measure: Callable[[int], tuple[float, float]],
) -> tuple[NDArray[np.bool_], dict[int, list[Sample]]]:
    """The segment pairs (K-1, P) the earlier check's samples inside prove, and those samples carried.

    A sample of pair p at share t of segment k, distance ``d`` at the earlier rows' ``q_old(t)``,
    bounds the pair at the new rows' ``q(t)`` from below by ``b = d - |q(t) - q_old(t)| · R_p - δ_p``
    (``q(t) - q_old(t)`` is the rows' change interpolated at t). Along the segment, with these and the
    ends' bounds at shares ``0 = t_0 < … < t_m = 1`` and the pair's motion ``S`` over the segment,
    the pair's distance anywhere between ``t_i`` and ``t_i+1`` is at least
    ``L = (b_i + b_i+1 - S (t_i+1 - t_i)) / 2``. When the least ``L`` keeps the margin
    (``L >= m_p - tolerance_m``) and lies above the segment's ends' exact least distance and its
    clearance above theirs (``L - m_p``), the pair keeps its margin over the segment, and any sample
    the advancement would take of it counts in neither least figure nor names its pair: the segment's
    figures are its ends', measured here as for a segment sampled inside. Otherwise the pair is
    advanced as before.
    """
    proved = np.zeros((len(q) - 1, len(model.pairs)), dtype=bool)
    kept: dict[int, list[Sample]] = {}
    samples = getattr(previous, "inner_samples", None)
    if not samples or delta is None:
        return proved, kept
    margin = model.pair_margins
    motion = pair_motion(model, q)
    need = short(bounds - margin + tolerance_m, motion)
    for k, found in samples.items():
        index = np.array([s.index for s in found])
        t = np.array([s.t for s in found])
        moved = (1.0 - t)[:, None] * (q[k] - checked.q[k]) + t[:, None] * (q[k + 1] - checked.q[k + 1])
        carried = (
            np.array([s.distance for s in found])
            - np.einsum("ij,ij->i", np.abs(moved), model.pair_motion[index])
            - delta[index]
        )
        carried = np.where(carried > 0.0, carried, -np.inf)
        for p in np.unique(index).tolist():
            if not need[k, p] or not math.isfinite(delta[p]):
                continue
            mine = np.flatnonzero(index == p)
            mine = mine[np.argsort(t[mine], kind="stable")]
            share = np.diff(np.concatenate(([0.0], t[mine], [1.0]))) * motion[k, p]
            low = _least(bounds[k, p], carried[mine], bounds[k + 1, p], share)
            if low < margin[p] - tolerance_m:
                continue
            if k in at and k + 1 in at:  # the ends' figures known: the samples must lie above them
                if low <= min(at[k].distance, at[k + 1].distance) or low - margin[p] <= min(
                    at[k].clearance, at[k + 1].clearance
                ):
                    continue
            for end in (k, k + 1):
                if end not in at:
                    measure(end)
            low = _least(bounds[k, p], carried[mine], bounds[k + 1, p], share)  # the ends measured
            if (
                low >= margin[p] - tolerance_m
                and low > min(at[k].distance, at[k + 1].distance)
                and low - margin[p] > min(at[k].clearance, at[k + 1].clearance)
            ):
                proved[k, p] = True
                kept.setdefault(k, []).extend(
                    found[i]._replace(distance=v, clearance=v - margin[p], pair_distance=v)
                    for i, v in zip(mine.tolist(), carried[mine].tolist(), strict=True)
                )
    return proved, kept


def _least(start: float, inside: Array, end: float, motion: Array) -> float:
    """The least distance [m] the bounds ``start``, ``inside`` (m,), ``end`` [m] allow along a segment.

    ``motion`` (m+1,) [m] is the pair's motion bound over each stretch between them; over a stretch
    with bounds ``a``, ``b`` the distance is at least ``(a + b - motion) / 2``.
    """
    chain = np.concatenate(([start], inside, [end]))
    return float(np.min(chain[:-1] + chain[1:] - motion)) / 2.0


def _shift(before: tuple[int, Array] | None, joint: int, now: Array) -> float:
    """How far a body's points moved since ``before`` (its joint and hull corners then) [m]; inf if changed."""
    if before is None or before[0] != joint or before[1].shape != now.shape:
        return math.inf
    if before[1] is now:
        return 0.0
    if joint >= 0:
        return 0.0 if np.array_equal(before[1], now) else math.inf
    return float(np.max(np.linalg.norm(now - before[1], axis=1)))
