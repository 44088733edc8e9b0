"""The dense final clearance check of a joint path, between waypoints too.

The robot moves between two waypoints with its joints interpolated linearly,
``q(t) = q_k + t (q_{k+1} - q_k)`` for t in [0, 1], so a link can sweep through an obstacle that
neither waypoint touches.

**What is proved (``method="bound"``, the default).** For every segment counted in
``certified_segments`` and every checked pair p (link or tool against a cell object, or two of
the robot's own bodies) with margin ``m_p``:

    d_p(q(t)) >= m_p - tolerance_m   for every t in [0, 1],

where ``d_p`` is the distance between the pair's two convex shapes (the robot's link pieces, the
tool shapes, the cell objects as given). It holds for the continuous motion, not only at the
samples, provided ``m_p >= tolerance_m`` (the distances the proof uses are then non-negative),
and up to the accuracy of FCL's distances (checked against a separating plane, see
:mod:`refine.collision.distance`). Segments not certified are sampled densely (below) and reported
as such by ``certified_segments``: that happens only where a margin is broken (the path then fails
the check anyway) or where one pair needs more than
:data:`~refine.collision.advance.MAX_ADVANCE` samples inside one segment.

**How.** Per pair, a motion bound (:mod:`refine.collision.motion`): along a segment neither body
of pair p moves relative to the other further than ``S_p = Σ_j |Δq_j| R_pj``, summed only over the
joints between the two bodies (for link i against link j of an arm, the joints i+1..j; for a cell
object against link j, joints 1..j), with ``R_pj`` the largest distance of the moving body's shape
from joint j's axis. The distance of two bodies changes no faster than their relative motion, so
from a parameter where the pair's budget ``b = d_p - m_p + tolerance_m`` is known, the next
``b / S_p`` of the segment is certified. A pair is certified over a segment when the budgets at its
two ends add up to ``S_p`` at least; lower bounds on ``d_p`` serve where they suffice (the gap
between world-aligned boxes around the two bodies, or the distance to a cell mesh's convex hull),
so far pairs cost no FCL query. A pair that falls short is measured exactly at the ends, and then
advanced from the start by conservative advancement (:mod:`refine.collision.advance`), one FCL
query of that pair per step, until the span certified from the end is reached. At every waypoint
the pair with the least clearance and the pair with the least distance are measured exactly
(:meth:`CollisionModel.nearest_pairs`), for the figures and the runs.

**Dense sampling (``method="sample"``, and the fallback).** Each segment is cut into enough sub-steps that

* the TCP moves at most ``step_m`` between checks (the chord between consecutive checks; the
  segment's chord sets a first count, raised while the TCP curve makes a sub-step longer), and
* no point of any link or tool shape moves more than ``link_step_m``. That bound is taken from the
  joints: a point turning about joint j moves at most ``|dq_j| * R_j``, with ``R_j`` the largest
  distance any body downstream of joint j can have from it (:func:`joint_reach`: link offsets plus
  shape extents, a constant of the robot and tool), so a wrist flip with the TCP nearly still is
  sampled too.

At every sample the pair with the least clearance (distance minus its margin) and the pair with the
least distance are found with :meth:`CollisionModel.nearest_pairs`; where a margin is broken, every
pair below its margin is named. Dense sampling proves nothing between its samples; it finds and
names the pairs of a broken segment.

**The proof alone** (:func:`margins_proved`): the certification without the figures, for a verdict
"every margin kept" only (the optimiser's seed, the controller's line), from known bounds if given.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from refine.collision.advance import NONE, Sample, advance_pairs, pair_motion
from refine.collision.carry import (
    NEAR,
    bounds_along_normals,
    checked_bounds,
    direction_bounds,
    measure_least,
    raise_near,
    settled_pairs,
    tightener,
)
from refine.collision.figures import ClearanceRun, Figures, PathClearance
from refine.collision.model import CollisionModel
from refine.collision.native_bounds import short_of
from refine.errors import InputError
from refine.robot.kinematics import TcpKinematics
from refine.types import Array

log = logging.getLogger(__name__)

LINK_STEP_M = 0.005
"""Default largest motion of any link point between two checks [m]."""


def _sub_steps(kin: TcpKinematics, q0: Array, q1: Array, m: int, step_m: float) -> int:
    """Raise ``m`` until no TCP chord between consecutive sub-steps exceeds ``step_m``.

    The TCP runs on a curve between waypoints, so equal joint sub-steps can take it further than
    the segment's chord divided by their number.
    """
    for _ in range(4):
        t = np.linspace(0.0, 1.0, m + 1)[:, None]
        tcp = kin.poses(q0 + t * (q1 - q0))[:, :3, 3]
        longest = float(np.max(np.linalg.norm(np.diff(tcp, axis=0), axis=1)))
        if longest <= step_m:
            break
        m = math.ceil(m * longest / step_m * 1.01)
    return m


def check_path_clearance(
    model: CollisionModel,
    q_path: ArrayLike,
    kin: TcpKinematics,
    step_m: float,
    *,
    link_step_m: float = LINK_STEP_M,
    tolerance_m: float = 1e-4,
    method: str = "bound",
    prior: Array | None = None,
    directions: Array | None = None,
    every_waypoint: bool = True,
) -> PathClearance:
    """Check a joint path densely against the collision model.

    Args:
        model: the collision model (robot, tool, cell, margins).
        q_path: joints per waypoint [rad], shape (N, n).
        kin: TCP kinematics of the same robot, base and tool.
        step_m: largest TCP motion between two checks [m] (``collision.check_step_m``).
        link_step_m: largest motion of any link or tool point between two checks [m].
        tolerance_m: clearances down to ``-tolerance_m`` still count as kept [m].
        method: ``"bound"`` to certify every segment pair by pair by the motion bound and sample
            densely only segments with a broken margin, ``"sample"`` to sample every segment densely.
        prior: lower bounds (N, P) [m] on the pairs' distances at the waypoints known beforehand
            (:mod:`refine.collision.carry`): what they prove is not measured again.
        directions: unit vectors (N, P, 3), NaN for none, along which the pairs' gaps bound their
            distances at the waypoints (:func:`refine.collision.carry.direction_bounds`).
        every_waypoint: False to measure, as with ``prior`` or ``directions``, only the waypoints that
            can hold the least distance or clearance or whose margins the bounds leave unproved.

    Returns:
        The per-waypoint and per-segment figures and the runs below the margin.
    """
    q_path = np.asarray(q_path, dtype=float)
    n = model.robot.nq
    if q_path.ndim != 2 or q_path.shape[1] != n or len(q_path) == 0 or not np.all(np.isfinite(q_path)):
        raise InputError(
            f"check_path_clearance: q_path must be (N, {n}) finite joints [rad], got {q_path.shape}"
        )
    if method not in ("bound", "sample"):
        raise InputError(f"check_path_clearance: method must be 'bound' or 'sample', got {method!r}")
    for key, value in (("step_m", step_m), ("link_step_m", link_step_m)):
        if not (math.isfinite(value) and value > 0.0):
            raise InputError(f"check_path_clearance: {key} must be a number > 0 [m], got {value!r}")
    same = kin.robot is model.robot and all(  # equal arrays first: allclose costs tens of microseconds
        np.array_equal(a, b) or np.allclose(a, b)
        for a, b in ((kin.base_in_world, model.base_in_world), (kin.tcp_in_flange, model.tcp_in_flange))
    )
    if not same:
        raise InputError(
            "check_path_clearance: kin must have the collision model's robot, base_in_world and tcp_in_flange"
        )
    start, queries = time.perf_counter(), model.queries
    top_margin = max(model.margin_m, model.self_margin_m)

    def sample(q: Array, poses: Array | None = None, bounds: Array | None = None) -> Sample:
        by_distance, by_clearance = model.nearest_pairs(q, poses, bounds)
        if by_distance is None or by_clearance is None:
            return Sample(math.inf, math.inf, ("", ""), math.inf, frozenset())
        names: set[str] = set()
        if by_clearance.clearance_m < -tolerance_m:
            for c in model.contacts(q, top_margin):
                if c.clearance_m < -tolerance_m:
                    names.update((c.body, c.other))
        pair = (by_clearance.body, by_clearance.other)
        return Sample(
            by_distance.distance_m, by_clearance.clearance_m, pair, by_clearance.distance_m, frozenset(names)
        )

    points: list[Sample] = []
    given = prior is not None or directions is not None  # then, or without every_waypoint, the least only
    carry = (given or not every_waypoint) and method == "bound" and len(model.pairs) > 0
    at_waypoint = None if carry else lambda q, poses, boxes: points.append(sample(q, poses, boxes))
    normals = np.full((len(q_path), len(model.pairs), 3), np.nan) if directions is None else directions.copy()
    motion = pair_motion(model, q_path)  # per segment and pair [m], (N-1, P), once for the check
    known = {"prior": prior, "directions": directions, "out": normals, "motion": motion}
    poses, boxes, bounds, exact = _waypoint_bounds(
        model, q_path, tolerance_m, method == "bound", at_waypoint, plane=carry, **known
    )
    measured = None  # every waypoint measured, unless the check starts from known bounds:
    if carry:  # then exact where they can be the least or a margin is not proved, bounds elsewhere
        at: dict[int, Sample] = {}  # the waypoints measured

        def measure(k: int) -> tuple[float, float]:
            at[k] = sample(q_path[k], poses[k], bounds[k].copy())
            found = model.witnesses(q_path[k])
            for p, (d, n) in found.items():
                bounds[k, p], exact[k, p], normals[k, p] = d, True, n
            raise_near(model, poses, bounds, k, found)
            return at[k].distance, at[k].clearance

        measured = measure_least(
            bounds, model.pair_margins, measure, NEAR, tightener(model, poses, bounds, exact)
        )
        clear = bounds - model.pair_margins
        least = np.argmin(clear, axis=1)  # per waypoint, the pair of least clearance bound
        rows = np.arange(len(q_path))
        pairs = model.pairs
        figures = Figures(
            bounds.min(axis=1), clear[rows, least], bounds[rows, least], [pairs[p] for p in least.tolist()]
        )
        for k, found in at.items():
            figures.put(k, found)
    else:
        figures = Figures.of(points)
    sweep = np.abs(np.diff(q_path, axis=0)) @ model.joint_reach  # any body point's motion per segment [m]
    certified = np.zeros(len(sweep), dtype=bool)
    inner: dict[int, list[Sample]] = {}  # per segment, the samples the advancement took inside
    if method == "bound":
        certified, inner = advance_pairs(model, q_path, poses, bounds, exact, tolerance_m, motion=motion)
    dense = np.flatnonzero(~certified)
    sampled: dict[int, list[Sample]] = {}  # per segment sampled densely, its inner sub-steps
    steps = np.ones(len(sweep), dtype=np.int64)
    if len(dense):
        tcp = kin.poses(q_path)[:, :3, 3]
        chord = np.linalg.norm(tcp[dense + 1] - tcp[dense], axis=1)
        least = np.maximum(
            1, np.maximum(np.ceil(chord / step_m), np.ceil(sweep[dense] / link_step_m))
        ).astype(int)
        for k, m in zip(dense.tolist(), least, strict=True):
            steps[k] = _sub_steps(kin, q_path[k], q_path[k + 1], int(m), step_m)
            t = np.arange(1, steps[k])[:, None] / steps[k]  # the inner sub-steps
            sampled[k] = [sample(q) for q in q_path[k] + t * (q_path[k + 1] - q_path[k])]
    inside = {k for k, found in (*sampled.items(), *inner.items()) if found}  # segments with samples inside
    if measured is not None:
        for end in sorted({k + e for k in inside for e in (0, 1)} - set(np.flatnonzero(measured).tolist())):
            measure(end)  # a segment sampled inside takes its ends' exact figures, not bounds
            figures.put(end, at[end])
            measured[end] = True
    wp_dist, wp_clear = figures.distance, figures.clearance
    # ---- per segment: its ends' figures, and where it was sampled inside or an end is below, its samples'
    ends = np.arange(len(sweep)) + (wp_clear[1:] < wp_clear[:-1])  # the worse end: the first of a tie
    seg_dist = np.minimum(wp_dist[:-1], wp_dist[1:])
    seg_clear = wp_clear[ends]
    seg_pair = [figures.pair[k] for k in ends.tolist()]
    seg_pair_distance = figures.pair_distance[ends]
    seg_below: dict[int, frozenset[str]] = {}
    for k in sorted(inside | {k - e for k in figures.below for e in (0, 1) if 0 <= k - e < len(sweep)}):
        found = [figures.sample(k), figures.sample(k + 1), *sampled.get(k, ()), *inner.get(k, ())]
        if k not in sampled:
            steps[k] = len(inner.get(k, ())) + 1
        seg_dist[k] = min(s.distance for s in found)
        w = min(found, key=lambda s: s.clearance)  # the first of a tie
        seg_clear[k], seg_pair[k], seg_pair_distance[k] = w.clearance, w.pair, w.pair_distance
        below = frozenset().union(*(s.below for s in found))
        if below:
            seg_below[k] = below
    if len(sweep):
        runs = _runs(seg_clear, seg_pair, seg_pair_distance, seg_below, tolerance_m, single=False)
    else:
        one = figures.sample(0)
        runs = _runs(
            np.array([one.clearance]),
            [one.pair],
            np.array([one.pair_distance]),
            {0: one.below} if one.below else {},
            tolerance_m,
            single=True,
        )
    result = PathClearance(
        waypoint_distance_m=wp_dist,
        waypoint_clearance_m=wp_clear,
        segment_distance_m=seg_dist,
        segment_clearance_m=seg_clear,
        segment_pair=tuple(seg_pair),
        segment_samples=steps,
        runs=runs,
        queries=model.queries - queries,
        time_s=time.perf_counter() - start,
        tolerance_m=tolerance_m,
        certified_segments=int(certified.sum()),
        waypoint_measured=measured,
        bounds=(  # bounds and normals are the check's own, changed no more: kept, not copied
            checked_bounds(model, q_path, bounds, normals, poses, exact, copy=False)
            if method == "bound"
            else None
        ),
        inner_samples=inner,
    )
    if log.isEnabledFor(logging.INFO):  # the summary's figures only for a log that shows them
        log.info("%s", result.summary())
    return result


def joint_reach(model: CollisionModel) -> Array:
    """Per joint, the largest distance [m] of any body downstream from its axis (n,), once per moving bodies."""
    return model.joint_reach.copy()


def margins_proved(
    model: CollisionModel,
    q_path: ArrayLike,
    *,
    tolerance_m: float = 1e-4,
    prior: Array | None = None,
    directions: Array | None = None,
) -> bool:
    """True when the motion bound proves that the joint path keeps every pair's margin.

    The certification of :func:`check_path_clearance` (``method="bound"``) without its figures:
    the least-distance and least-clearance pairs are not looked up at every waypoint, and a pair
    whose box bounds fall short is first bounded by the gap along its last witness normal, so a
    clear path costs few FCL queries. True implies that the check finds every margin kept (``ok``):
    a segment certified from lower bounds on the distances is certified from the distances
    themselves, and a certified segment's ends keep their margins. False (a margin broken, a
    segment needing dense sampling, or a path of one waypoint) decides nothing: run the check.

    Args:
        model: the collision model (robot, tool, cell, margins).
        q_path: joints per waypoint [rad], shape (N, n).
        tolerance_m: clearances down to ``-tolerance_m`` still count as kept [m].
        prior: lower bounds (N, P) [m] on the pairs' distances at the waypoints, known beforehand.
        directions: unit vectors (N, P, 3) to bound the pairs' gaps along, as in the check.
    """
    q_path = np.asarray(q_path, dtype=float)
    if q_path.ndim != 2 or q_path.shape[1] != model.robot.nq or not np.all(np.isfinite(q_path)):
        raise InputError(
            f"margins_proved: q_path must be (N, {model.robot.nq}) finite joints [rad], got {q_path.shape}"
        )
    if len(q_path) < 2:
        return False
    left = None  # the segments and pairs the known bounds leave short, (N-1, P)
    motion = pair_motion(model, q_path)
    if prior is not None:
        left = short_of(prior, model.pair_margins, tolerance_m, motion)
        if not left.any():
            return True  # the known bounds certify every segment: no pose or distance is needed
    known = {"prior": prior, "directions": directions, "left": left, "motion": motion}
    poses, _, bounds, exact = _waypoint_bounds(model, q_path, tolerance_m, True, plane=True, **known)
    columns = None if left is None else np.flatnonzero(left.any(axis=0))  # the others: certified by prior
    return bool(advance_pairs(model, q_path, poses, bounds, exact, tolerance_m, columns=columns)[0].all())


def _waypoint_bounds(
    model: CollisionModel,
    q_path: Array,
    tolerance_m: float,
    by_bound: bool,
    at_waypoint: Callable[[Array, Array, Array], None] | None = None,
    *,
    plane: bool = False,
    prior: Array | None = None,
    directions: Array | None = None,
    out: Array | None = None,
    left: NDArray[np.bool_] | None = None,
    motion: Array | None = None,
) -> tuple[Array, Array | None, Array, NDArray[np.bool_]]:
    """The moving bodies' poses and each pair's distance bounds at every waypoint.

    With ``by_bound``, the pairs whose box bounds do not certify a segment next to a waypoint are
    bounded better there (:meth:`CollisionModel.pair_bound`, with ``plane`` the gap along the last
    witness normal before an FCL query). ``at_waypoint(q, poses, boxes)`` runs at each waypoint
    with the model placed there (given ``prior``, the best bounds known there); the pairs it
    measures improve the bounds. ``prior`` (N, P): lower bounds known beforehand [m];
    ``directions`` (N, P, 3): unit vectors whose gaps bound the pairs too; ``out`` (N, P, 3): where
    the witness normals of the pairs measured are written; without ``at_waypoint``, the pairs that
    ``prior`` settles keep it, unboxed (:func:`refine.collision.carry.settled_pairs`).

    ``left`` (N-1, P), for the proof alone (no ``at_waypoint``, no ``out``): the segment pairs that
    ``prior`` leaves short. Bounds only rise, so every other segment pair stays certified whatever
    else is found, and only the waypoints ending a segment left short are placed and bounded
    further, for the pairs left short somewhere: ``prior`` stands for every other bound, and the
    poses of the other waypoints are NaN (nothing reads them: every pair measured or advanced
    belongs to a segment left short). ``motion``: :func:`refine.collision.advance.pair_motion` of
    ``q_path`` if the caller has it (read only).

    Returns:
        poses (N, M, 4, 4), box bounds (N, P) [m] (None with ``left``), the better bounds (N, P)
        [m], and which of those are exact distances (N, P).
    """
    settled = None  # the pairs the known bounds leave far from the least and certified: bounded no further
    if left is None:
        poses = model.moving_poses(q_path)
        if prior is not None and at_waypoint is None:
            settled = settled_pairs(model, q_path, prior, tolerance_m, motion)
        if settled is None or not settled.any():
            boxes = model.box_bounds(poses)  # lower bounds on each pair's distance per waypoint (N, P) [m]
            bounds = boxes.copy() if prior is None else np.maximum(boxes, prior)  # and the better ones found
        else:
            boxes, bounds, columns = None, prior.copy(), np.flatnonzero(~settled)
            bounds[:, columns] = np.maximum(bounds[:, columns], model.box_bounds(poses, columns))
        rows: slice | NDArray[np.intp] = slice(None)
    else:
        assert prior is not None and at_waypoint is None and out is None
        segments = np.flatnonzero(left.any(axis=1))
        rows = np.union1d(segments, segments + 1)  # the waypoints bounded further
        columns = np.flatnonzero(left.any(axis=0))
        placed = model.moving_poses(q_path[rows])
        poses = np.full((len(q_path), *placed.shape[1:]), np.nan)
        poses[rows] = placed
        boxes = None
        bounds = prior.copy()
        cut = np.ix_(rows, columns)
        bounds[cut] = np.maximum(bounds[cut], model.box_bounds(poses[rows], columns))
    motion = pair_motion(model, q_path) if motion is None else motion  # per segment and pair [m], (N-1, P)
    if directions is not None:  # the proof alone (no figures written) bounds only the pairs left short
        columns_left = short_of(bounds, model.pair_margins, tolerance_m, motion).any(0)
        bounds[rows] = np.maximum(
            bounds[rows],
            direction_bounds(
                model,
                poses[rows],
                directions[rows],
                (None if settled is None else ~settled) if out is not None else columns_left,
            ),
        )
    exact = np.zeros(bounds.shape, dtype=bool)
    need = np.zeros(bounds.shape, dtype=bool)  # pairs to measure at each waypoint
    if by_bound and len(q_path) > 1:
        left_now = short_of(bounds, model.pair_margins, tolerance_m, motion)
        need[:-1] |= left_now
        need[1:] |= left_now
    if left is not None and need[np.setdiff1d(np.arange(len(q_path)), rows)].any():
        raise AssertionError("the proof from known bounds would read a waypoint it did not place")
    if plane and at_waypoint is None:
        bounds_along_normals(model, q_path, poses, need, bounds, exact, out)
        return poses, boxes, bounds, exact
    for k in range(len(q_path)) if at_waypoint else np.flatnonzero(need.any(axis=1)):
        q = q_path[k]
        for p in np.flatnonzero(need[k]):
            bounds[k, p], exact[k, p] = model.pair_bound(q, int(p), poses[k], plane=plane)
        if at_waypoint is not None:
            at_waypoint(q, poses[k], boxes[k] if prior is None else bounds[k].copy())
        for p, (d, n) in model.witnesses(q).items():
            bounds[k, p], exact[k, p] = d, True
            if out is not None:
                out[k, p] = n
    return poses, boxes, bounds, exact


def _runs(
    clearance: Array,
    pair: list[tuple[str, str]],
    pair_distance: Array,
    below: dict[int, frozenset[str]],
    tolerance_m: float,
    *,
    single: bool,
) -> tuple[ClearanceRun, ...]:
    """Group consecutive segments (or the single waypoint) whose worst sample breaks a margin.

    Per segment (or the waypoint): the least clearance [m], its pair and that pair's distance [m];
    ``below``: the bodies found below their margins, by segment, where there are any.
    """
    runs = []
    bad = np.flatnonzero(clearance < -tolerance_m)
    for run in np.split(bad, np.flatnonzero(np.diff(bad) > 1) + 1) if len(bad) else ():
        first, last = int(run[0]), int(run[-1])
        w = first + int(np.argmin(clearance[first : last + 1]))  # the first of a tie, as min() picks
        names = tuple(sorted(frozenset().union(*(below.get(k, NONE) for k in range(first, last + 1)))))
        end = first if single else last + 1
        runs.append(ClearanceRun(first, end, float(clearance[w]), float(pair_distance[w]), pair[w], names))
    return tuple(runs)
