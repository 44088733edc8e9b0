"""What a dense check proved at its waypoints, carried to the check of a nearby path.

A re-solve after a small change (a part moved a few millimetres, another cone) gives joints close
to the previous answer's, in a cell whose objects moved little or not at all. The previous check
found, at every waypoint, a lower bound on every checked pair's distance (box gaps, gaps along a
witness normal, FCL distances: :func:`refine.collision.check.check_path_clearance`). Those bounds
still bound the new distances from below once the motion since is taken off:

    d_p(q_new, cell_new) >= d_p(q_old, cell_old) - |q_new - q_old| · R_p - δ_p,

with ``R_p`` the pair's motion bound per joint (:mod:`refine.collision.motion`: along the joint
segment from q_old to q_new no point of either body moves further relative to the other) and
``δ_p`` the largest displacement of any point of the pair's cell object (a rigid move's
displacement is affine in the point, so its norm is largest at a corner of the object's hull).
The distance between two sets changes by no more than the largest displacement of their points.

A pair keeps its bound only when both its bodies are the same shapes as before (the robot's links
and the tool on the same joints and frames, the base in the same place); a bound that is not
positive is dropped (penetration is not carried). The check of the new path then measures only
the pairs the carried bounds leave short, and the figures it reports are measured as before.

**Witness directions.** That bound loses the whole motion: a pair whose bodies slide past each
other at a constant distance keeps its distance, yet its bound drops by the sliding. The check
also keeps, where it measured a pair, the witness normal ``n`` (a unit vector from the second body
towards the first). At the new path's waypoint the gap between the two bodies along that
direction,

    g = min_{a in A, b in B} n · (a - b) = -reach_A(-n) - reach_B(n),

is a lower bound on their distance whatever ``n`` is: for every a in A and b in B,
``|a - b| >= n · (a - b) >= g`` (Cauchy-Schwarz, ``|n| = 1``), so when ``g > 0`` the bodies are
apart by at least ``g``. It is computed from the bodies as they are now (their poses at the new
joints, the cell where it is now), so nothing about the old check has to hold for it to be a
bound: the old normal only chooses the direction. Near the old configuration the gap falls short
of the distance only by the second-order turn of the normal (for most pairs micrometres, where the
displacement bound above is millimetres off; more where the nearest features change), so few
waypoints are left that can hold the least distance (:func:`direction_bounds`;
``tests/collision/test_carry.py`` compares with every pair measured at every waypoint).

**Normals that turn with a body.** Where a self pair's nearest feature is a face of its other
body, a normal fixed in the world falls behind the face as the body turns, and its gap loses the
turn at first order (a face 0.1 m across turned 1 mrad: 0.1 mm). Such a normal ``n``, found with
the other body at rotation ``R_b``, is taken elsewhere as ``R_b' R_b^T n``, a unit vector too, so
its gap is a lower bound as well (:func:`carried_directions`, :attr:`CheckedBounds.attached`). A cell
object does not turn with the joints: its pairs keep the normal as it is.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from refine.collision.advance import pair_motion
from refine.collision.model import CollisionModel
from refine.collision.motion import corners
from refine.collision.native_bounds import Shapes, carried, column_least, direction_gaps, row_least, short_of
from refine.types import Array

NEAR = 24
"""A measured waypoint's witness normals bound the pairs this many waypoints either side of it."""


@dataclass(frozen=True, eq=False)
class CheckedBounds:
    """Lower bounds on every pair's distance at a checked path's waypoints.

    Attributes:
        q: the joints checked (N, n) [rad].
        pairs: the checked pairs' labels, in the order of ``bounds``' columns.
        bounds: lower bounds on each pair's signed distance at each waypoint (N, P) [m].
        shapes: per body label, its hull's corners: in its joint's frame for a moving body (with
            the joint's index), in the world for a cell object [m].
        base_in_world: the robot base T_F_R (4, 4) of the check.
        normals: per waypoint and pair, a unit witness normal where one is known (N, P, 3), NaN
            elsewhere; None for none.
        attached: per waypoint and self pair, the normal the check measured there in the shape
            frame of the pair's other body (N, P, 3), NaN elsewhere (cell pairs too); None for none.
            Read only where its rows are those of ``normals``.
    """

    q: Array
    pairs: tuple[tuple[str, str], ...]
    bounds: Array
    shapes: dict[str, tuple[int, Array]]
    base_in_world: Array
    normals: Array | None = None
    attached: Array | None = None


_HULLS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
""":func:`hull_corners` per collision model."""


def hull_corners(model: CollisionModel) -> dict[str, tuple[int, Array]]:
    """Per body label, its joint (-1: a cell object) and corners (K, 3) [m] of a convex set holding it.

    In the joint's frame for a moving body, in the world for a cell object: what does not move with
    the joints. A moving body's corners are the same read-only array in every model of the same
    robot, base, moving bodies and self margin (:attr:`CollisionModel.kept_hulls`), so a re-solve
    compares them by identity.
    """
    known = _HULLS.get(model)
    if known is None:
        known = {}
        for body in model.bodies:
            found = model.kept_hulls.get(body.label) if body.kind != "cell" else None
            if found is None:
                T = body.link_T_shape
                if body.kind != "cell":
                    T = model.robot.model.frames[body.frame_id].placement.homogeneous @ T
                c = corners(body) @ T[:3, :3].T + T[:3, 3]
                c.flags.writeable = False
                found = (int(body.joint), c)
                if body.kind != "cell":
                    model.kept_hulls[body.label] = found
            known[body.label] = found
        _HULLS[model] = known
    return known


def checked_bounds(
    model: CollisionModel,
    q: Array,
    bounds: Array,
    normals: Array | None = None,
    poses: Array | None = None,
    exact: NDArray[np.bool_] | None = None,
    *,
    copy: bool = True,
) -> CheckedBounds:
    """The bounds ``bounds`` (N, P) [m] of a check of joints ``q`` (N, n) in ``model``, to carry.

    ``normals`` (N, P, 3): unit witness normals where the check measured a pair (NaN elsewhere);
    with the moving bodies' poses at ``q`` (N, M, 4, 4) and where the check measured a pair
    ``exact`` (N, P), the self pairs' measured normals are kept in their other body's shape frame
    too (:attr:`CheckedBounds.attached`). ``copy`` False: ``bounds`` and ``normals`` (float
    arrays the caller changes no more) are kept as they are, not copied.
    """
    attached = None
    if normals is not None and poses is not None and exact is not None:
        ks, ps = np.nonzero(exact & model.self_pairs & ~np.isnan(normals[:, :, 0]))
        if len(ks):
            attached = np.full(np.shape(normals), np.nan)
            other = {p: model.pair_bodies(p)[1] for p in set(ps.tolist())}
            R = poses[ks, [other[p] for p in ps.tolist()], :3, :3]  # the other bodies' rotations (E, 3, 3)
            attached[ks, ps] = np.einsum("kij,ki->kj", R, normals[ks, ps])  # R^T n per entry
    keep = np.array if copy else np.asarray  # copies, or the caller's arrays as they are
    return CheckedBounds(
        np.array(q, dtype=float),
        tuple(model.pairs),
        keep(bounds, dtype=float),
        dict(hull_corners(model)),
        model.base_in_world.copy(),
        None if normals is None else keep(normals, dtype=float),
        attached,
    )


def carried_directions(
    model: CollisionModel, prior: CheckedBounds, q: Array, *, turned: bool = False
) -> Array | None:
    """The witness normals of ``prior`` (N, P, 3) in the order of ``model``'s pairs, for joints ``q``.

    A waypoint where ``prior`` has no normal of a pair takes the pair's normal at the nearest
    waypoint that has one (the pair was bounded there without a query); NaN for a pair ``prior``
    has no normal of. None when it has none or the paths differ in length. Any unit vector serves
    :func:`direction_bounds`, so neither the robot nor the cell need be the same.

    With ``turned``, a self pair's normal measured in ``prior`` (:attr:`CheckedBounds.attached`)
    is taken instead turned with the pair's other body to where that body is at ``q`` (as
    ``R_b' R_b^T n``, see the module notes), from the nearest waypoint where it was measured:
    near the distance where the nearest feature is a face of that body. That places the moving
    bodies at ``q`` (:meth:`CollisionModel.moving_poses`, kept for the check of ``q``).
    """
    if prior.normals is None or np.shape(q)[0] != len(prior.q):
        return None
    old = {pair: p for p, pair in enumerate(prior.pairs)}
    out = np.full((len(prior.q), len(model.pairs), 3), np.nan)
    given = ~np.isnan(prior.normals[:, :, 0])  # (N, P of prior)
    with_any = given.any(axis=0)
    cols = [(p, old[pair]) for p, pair in enumerate(model.pairs) if pair in old and with_any[old[pair]]]
    if not cols:
        return out
    mine, theirs = (np.array(c) for c in zip(*cols, strict=True))
    P0 = prior.normals.shape[1]  # gathered as whole rows of 3 from the flat (N * P0, 3) layout: one pass
    out[:, mine] = prior.normals.reshape(-1, 3).take(_nearest(given[:, theirs]) * P0 + theirs, axis=0)
    attached = prior.attached if turned else None
    if attached is None or attached.shape != prior.normals.shape:
        return out
    own = model.self_pairs[mine]
    mine, theirs = mine[own], theirs[own]
    given = ~np.isnan(attached[:, theirs, 0])  # measured self pairs' normals in their other body's frame
    some = given.any(axis=0)
    if some.any():
        mine, theirs = mine[some], theirs[some]
        local = attached[_nearest(given[:, some]), theirs]  # (N, C, 3)
        poses = model.moving_poses(np.asarray(q, dtype=float))
        for c, p in enumerate(mine.tolist()):
            out[:, p] = attached_normals(model, p, poses, local[:, c])
    return out


def _nearest(known: NDArray[np.bool_]) -> NDArray[np.intp]:
    """Per row and column of ``known`` (N, C), the nearest row known in its column (every column has one), the earlier of two as near."""
    n = len(known)
    rows = np.arange(n)[:, None]
    before = np.maximum.accumulate(np.where(known, rows, -1), axis=0)  # the last known at or before
    after = np.minimum.accumulate(np.where(known, rows, n)[::-1], axis=0)[::-1]  # the first at or after
    return np.where((before >= 0) & ((after >= n) | (rows - before <= after - rows)), before, after)


def attached_normals(model: CollisionModel, p: int, poses: Array, local: Array) -> Array:
    """Unit vectors ``local`` (K, 3) or (3,) in self pair p's other body's frame, in the world at poses (K, M, 4, 4)."""
    R = poses[:, model.pair_bodies(p)[1], :3, :3]
    return R @ local if local.ndim == 1 else np.einsum("kij,kj->ki", R, local)


def direction_bounds(
    model: CollisionModel, poses: Array, normals: Array, columns: NDArray[np.bool_] | None = None
) -> Array:
    """Lower bounds (N, P) [m] on the pairs' distances from the gaps along given directions.

    ``poses``: the moving bodies' poses at the waypoints (N, M, 4, 4) from
    :meth:`CollisionModel.moving_poses`; ``normals`` (N, P, 3): a unit direction per waypoint and
    pair, NaN where there is none. The gap between a pair's bodies along a unit direction bounds
    their distance from below (see the module notes); ``-inf`` where there is no direction, where a
    body is a mesh, or where the gap is not positive; ``columns`` (P,): the pairs to bound (all if None).
    """
    have = ~np.isnan(normals[:, :, 0])
    if columns is not None:
        have &= columns
    found = direction_gaps(shapes_of(model), poses, normals, have)
    if found is not None:
        return found
    out = np.full(normals.shape[:2], -np.inf)
    for p in np.flatnonzero(have.any(axis=0)):
        ks = np.flatnonzero(have[:, p])
        every = len(ks) == len(poses)  # then all the rows as they are, not a copy of every body's poses
        n = normals[:, p] if every else normals[ks, p]
        n = n / np.linalg.norm(n, axis=1, keepdims=True)  # unit, whatever rounding left
        gaps = model.plane_bounds(int(p), poses, n, None if every else ks)
        if gaps is not None:
            out[ks, p] = np.where(gaps > 0.0, gaps, -np.inf)
    return out


def carried_bounds(model: CollisionModel, prior: CheckedBounds, q: Array) -> Array | None:
    """Lower bounds (N, P) [m] on ``model``'s pair distances at joints ``q`` from ``prior``; None if none.

    ``-inf`` for a pair without a bound: new, with a changed moving body, or not positive once the
    motion is taken off. None when the paths differ in length or the robot or its base changed.
    """
    q = np.asarray(q, dtype=float)
    if (
        q.shape != prior.q.shape
        or model.robot.nq != q.shape[1]
        or not np.array_equal(model.base_in_world, prior.base_in_world)
    ):
        return None
    mine, theirs, delta = _carried_columns(model, prior)
    # all the carried columns at once, each as bound - motion - shift
    return carried(q, prior.q, model.pair_motion, prior.bounds, mine, theirs, delta)


_SHAPES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
""":func:`shapes_of` per collision model."""


def shapes_of(model: CollisionModel) -> Shapes:
    """The model's bodies and pairs as :func:`refine.collision.native_bounds.direction_gaps` reads them (kept per model)."""
    known = _SHAPES.get(model)
    if known is None:
        bodies = model.bodies
        fixed = np.ascontiguousarray([b.link_T_shape for b in bodies], dtype=float)  # a cell object's: final
        ends = np.array([model.pair_bodies(p) for p in range(len(model.pairs))], dtype=np.int64).reshape(
            -1, 2
        )
        bounded = np.array(
            [not (bodies[a].is_mesh or bodies[b].is_mesh) for a, b in ends.tolist()], dtype=bool
        )
        known = _SHAPES[model] = Shapes(bodies, fixed, ends[:, 0], ends[:, 1], bounded)
    return known


_COLUMNS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
""":func:`_carried_columns` per checked bounds, per model."""


def _carried_columns(
    model: CollisionModel, prior: CheckedBounds
) -> tuple[NDArray[np.intp], NDArray[np.intp], Array]:
    """The pairs ``prior`` carries into ``model``: index here (C,), index in ``prior`` (C,), shift [m] (C,).

    The shift: the largest displacement of its cell object's points (see the module notes); a pair
    with a changed body is left out. Models and checked bounds do not change: kept for each pair.
    """
    per_model = _COLUMNS.setdefault(prior, weakref.WeakKeyDictionary())
    known = per_model.get(model)
    if known is not None:
        return known
    old = {pair: p for p, pair in enumerate(prior.pairs)}
    shift: dict[str, float] = {}  # per body: how far its points moved, inf for a changed shape
    for label, (joint, now) in hull_corners(model).items():
        before = prior.shapes.get(label)
        if before is None or before[0] != joint or before[1].shape != now.shape:
            shift[label] = np.inf
        elif before[1] is now:  # the same read-only corners: a body of a model like the prior's
            shift[label] = 0.0
        elif joint >= 0:
            shift[label] = 0.0 if np.array_equal(before[1], now) else np.inf
        else:
            shift[label] = float(np.max(np.linalg.norm(now - before[1], axis=1)))
    mine, theirs, delta = [], [], []
    for p, (a, b) in enumerate(model.pairs):
        k = old.get((a, b))
        if k is not None and math.isfinite(shift[a] + shift[b]):
            mine.append(p)
            theirs.append(k)
            delta.append(shift[a] + shift[b])
    known = (np.array(mine, dtype=np.intp), np.array(theirs, dtype=np.intp), np.array(delta, dtype=float))
    for a in known:
        a.flags.writeable = False
    per_model[model] = known
    return known


def bounds_between(model: CollisionModel, checked: CheckedBounds, q: Array, place: Array) -> Array | None:
    """Lower bounds (K, P) [m] on ``model``'s pair distances along a path through a checked one's waypoints.

    ``q`` (K, n) [rad] are joints at positions ``place`` (K,) along the checked path, in segments
    (``k + t``: waypoint k at ``t = 0``, a point of the segment from waypoint k to k+1 for
    ``0 < t < 1``), e.g. the controller's line between the waypoints. At each row, every pair's
    distance is at least the checked bound at either end of its segment less the motion from that
    end's joints (``d(q) >= d(q_k) - |q - q_k| · R_p``, :mod:`refine.collision.motion`); the
    larger of the two is kept. None when the model is not the checked one's (other pairs, another
    base, a body of another shape or place) or a row at a waypoint does not hold its joints.
    """
    ends = _segment_ends(model, checked, q, place)
    if ends is None:
        return None
    q, a, b = ends
    R = model.pair_motion.T  # (n, P) [m/rad]
    out = checked.bounds.take(a, axis=0)  # (K, P), a copy: taken in place from here on
    out -= np.abs(q - checked.q.take(a, axis=0)) @ R
    other = checked.bounds.take(b, axis=0)
    other -= np.abs(q - checked.q.take(b, axis=0)) @ R
    return np.maximum(out, other, out=out)


def proved_between(
    model: CollisionModel, checked: CheckedBounds, q: Array, place: Array, tolerance_m: float = 1e-4
) -> bool:
    """True when the bounds of :func:`bounds_between` prove every margin along the rows ``q`` (K, n).

    True implies that :func:`refine.collision.check.margins_proved` of ``q`` with
    ``prior=bounds_between(model, checked, q, place)`` is True (and so that the dense check finds
    every margin kept); False decides nothing. Most pairs are far from their margins everywhere:
    a pair p is proved on every segment of ``q`` at once when, with ``B_p`` its least checked bound
    over the path, ``U`` (n,) the largest |q - q_k| per joint over the rows (k the row's segment
    start, whose bound :func:`bounds_between` never goes below), and ``V`` (n,) the largest joint
    step between consecutive rows, the budget ``b_p = B_p - U · R_p - m_p + tolerance_m`` keeps
    ``b_p >= ε`` and ``2 b_p >= V · R_p + ε`` (each row's budget there is at least ``b_p``, each
    segment's motion at most ``V · R_p``; ``ε = 1e-9`` m covers the rounding of both sums). Only
    the other pairs' bounds are formed row by row, as :func:`bounds_between` forms them, and
    tested as ``margins_proved`` tests its known bounds.
    """
    ends = _segment_ends(model, checked, q, place)
    if ends is None or len(q) < 2 or not np.all(np.isfinite(ends[0])):
        return False
    q, a, b = ends
    R = model.pair_motion.T  # (n, P) [m/rad]
    margins = model.pair_margins
    from_start = np.abs(q - checked.q.take(a, axis=0))  # (K, n) [rad]
    moves = np.abs(q[1:] - q[:-1])  # (K-1, n) [rad]
    # the largest per joint, reduced along rows laid out contiguously (a strided reduction costs 10x)
    reach = np.ascontiguousarray(from_start.T).max(axis=1) @ R  # (P,) [m]: no row moved further
    step = np.ascontiguousarray(moves.T).max(axis=1) @ R  # (P,) [m]: no segment moves further
    budget = np.ascontiguousarray(checked.bounds.T).min(axis=1) - reach - margins + tolerance_m
    rest = np.flatnonzero(~((budget >= _SLACK_M) & (2.0 * budget >= step + _SLACK_M)))
    if len(rest) == 0:
        return True
    R = R[:, rest]
    kept = checked.bounds[:, rest]
    low = kept.take(a, axis=0)  # copies: taken in place from here on, as bounds_between forms them
    low -= from_start @ R
    other = kept.take(b, axis=0)
    other -= np.abs(q - checked.q.take(b, axis=0)) @ R
    np.maximum(low, other, out=low)
    return not short_of(low, margins[rest], tolerance_m, moves @ R).any()


_SLACK_M = 1e-9  # [m], far above the rounding of sums of a few metres, far below any margin


def _segment_ends(
    model: CollisionModel, checked: CheckedBounds, q: Array, place: Array
) -> tuple[Array, NDArray[np.intp], NDArray[np.intp]] | None:
    """The rows ``q`` as floats and each row's segment ends in ``checked``, (K,) and (K,).

    None as in :func:`bounds_between` (another model, or a row at a waypoint without its joints).
    """
    q = np.asarray(q, dtype=float)
    place = np.asarray(place, dtype=float)
    N = len(checked.q)
    if (
        tuple(model.pairs) != checked.pairs
        or not np.array_equal(model.base_in_world, checked.base_in_world)
        or q.ndim != 2
        or q.shape[1] != checked.q.shape[1]
        or len(place) != len(q)
        or not np.all((place >= 0.0) & (place <= N - 1))
    ):
        return None
    for label, (joint, now) in hull_corners(model).items():
        before = checked.shapes.get(label)
        if before is None or before[0] != joint or not (before[1] is now or np.array_equal(before[1], now)):
            return None
    a = np.floor(place).astype(int)
    at_waypoint = place == a
    if not np.array_equal(q[at_waypoint], checked.q[a[at_waypoint]]):
        return None
    b = np.where(at_waypoint, a, np.minimum(a + 1, N - 1))  # a waypoint keeps its own bound
    return q, a, b


def bounds_along_normals(
    model: CollisionModel,
    q_path: Array,
    poses: Array,
    need: NDArray[np.bool_],
    bounds: Array,
    exact: NDArray[np.bool_],
    out: Array | None = None,
) -> None:
    """Bound the pairs ``need`` (N, P) marks, pair by pair along the path, into ``bounds`` and ``exact``.

    What :meth:`CollisionModel.pair_bound` with ``plane`` gives waypoint by waypoint, with the gaps
    along a pair's last witness normal taken at all its waypoints at once
    (:meth:`CollisionModel.plane_bounds`): up to the first waypoint where the gap does not keep
    the pair's margin, which is then measured (and gives the next normal). A pair without a normal
    yet, or with a mesh, is bounded one waypoint at a time. A bound already in ``bounds`` is kept
    where it is larger. ``out`` (N, P, 3): where the witness normals of the pairs measured are written.
    """
    margins = model.pair_margins
    for p in np.flatnonzero(need.any(axis=0)):
        p = int(p)
        ks = np.flatnonzero(need[:, p])
        i = 0
        while i < len(ks):
            gaps = model.plane_bounds(p, poses, rows=ks[i:])
            if gaps is not None:
                short = np.flatnonzero(gaps <= margins[p])
                stop = int(short[0]) if short.size else len(gaps)
                rows = ks[i : i + stop]
                bounds[rows, p] = np.maximum(bounds[rows, p], gaps[:stop])
                i += stop
            if i < len(ks):
                k = ks[i]
                if gaps is not None:  # the gap there leaves the margin unproved: measure it
                    bounds[k, p], exact[k, p] = model.pair_distance(q_path[k], p, poses[k]), True
                else:
                    bounds[k, p], exact[k, p] = model.pair_bound(q_path[k], p, poses[k], plane=True)
                if exact[k, p] and out is not None:
                    out[k, p] = model.witnesses(q_path[k])[p][1]
                i += 1


def raise_near(
    model: CollisionModel, poses: Array, bounds: Array, k: int, found: dict[int, tuple[float, Array]]
) -> None:
    """Raise the bounds (N, P) [m] of the waypoints within :data:`NEAR` of waypoint k, in place.

    ``found``: the pairs measured at k, by pair index, with their unit witness normals
    (:meth:`CollisionModel.witnesses`); ``poses`` (N, M, 4, 4): the moving bodies at every waypoint.
    Each pair's gap along its normal at k bounds its distance at the other waypoints from below
    (any unit direction does, see the module notes); near k the joints, hence the normal, have
    turned little, so the gap is close to the distance there. Waypoint k keeps its own figures.
    """
    lo, hi = max(k - NEAR, 0), min(k + NEAR + 1, len(bounds))
    near = np.arange(lo, hi) != k  # of the rows lo..hi-1, a view of the poses (no copy)
    for p, (_, n) in found.items():
        gaps = model.plane_bounds(p, poses[lo:hi], n)
        if gaps is not None:
            rows = bounds[lo:hi, p]
            rows[near] = np.maximum(rows[near], np.where(gaps[near] > 0.0, gaps[near], -np.inf))


def tightener(
    model: CollisionModel, poses: Array, bounds: Array, exact: NDArray[np.bool_]
) -> Callable[[int], bool]:
    """A ``tighten(k)`` for :func:`measure_least`: raise the bounds that hold waypoint k's lower bound.

    The pairs holding waypoint k's least distance bound and least clearance bound, if not measured
    there, are bounded at every waypoint by their gap along the pair's last witness normal
    (:meth:`CollisionModel.plane_bounds`, a lower bound whatever the normal, see the module notes),
    each pair once per check; ``bounds`` (N, P) [m] is raised in place where that gap is larger,
    ``exact`` (N, P) entries are kept. ``tighten(k)`` is True when it tried a pair (finitely often).
    """
    tried = np.zeros(bounds.shape[1], dtype=bool)
    margins = model.pair_margins

    def tighten(k: int) -> bool:
        pairs = {int(np.argmin(bounds[k])), int(np.argmin(bounds[k] - margins))}
        pairs = {p for p in pairs if not (tried[p] or exact[k, p])}
        for p in pairs:
            tried[p] = True
            gaps = model.plane_bounds(p, poses)
            if gaps is not None:
                raised = np.maximum(bounds[:, p], np.where(gaps > 0.0, gaps, -np.inf))
                bounds[:, p] = np.where(exact[:, p], bounds[:, p], raised)
        return bool(pairs)

    return tighten


def measure_least(
    bounds: Array,
    margins: Array,
    measure: Callable[[int], tuple[float, float]],
    window: int = 0,
    tighten: Callable[[int], bool] | None = None,
) -> NDArray[np.bool_]:
    """Measure the waypoints that can hold the path's least distance or clearance, or break a margin.

    ``bounds`` (N, P): lower bounds [m] on every pair's distance at each waypoint (complete: no
    pair left without one, or that waypoint has ``-inf`` and is measured); ``margins`` (P,) [m].
    ``measure(k)`` measures waypoint k exactly and returns its least distance and least clearance
    [m]; it may raise the bounds of the waypoints within ``window`` of k in ``bounds`` (lower
    bounds still), which are read again after it. ``tighten(k)``, tried before waypoint k is
    measured, may raise any bounds (lower bounds still); it returns True when it did something,
    which it may do only finitely often. Every waypoint whose bounds do not prove every margin is
    measured; then, for the distance and then the clearance, the waypoint of least lower bound not
    yet measured, until that bound is no smaller than the least measured. The least distance and
    the least clearance over the waypoints are then exact: every waypoint not measured has a lower
    bound, hence a value, at least the least measured.

    Returns:
        Which waypoints were measured, (N,).
    """
    N = len(bounds)
    measured = np.zeros(N, dtype=bool)

    def read(rows: slice) -> None:
        row_least(bounds, margins, measured, rows, lower[0], lower[1])

    lower = [np.empty(N), np.empty(N)]  # per waypoint not measured: distance, clearance bounds
    read(slice(None))
    best = [np.inf, np.inf]  # least distance, least clearance measured

    def visit(k: int) -> None:
        d, c = measure(k)
        measured[k] = True
        best[0], best[1] = min(best[0], d), min(best[1], c)
        read(slice(max(k - window, 0), k + window + 1))

    for k in np.flatnonzero(lower[1] < 0.0):
        visit(int(k))
    for which in (0, 1):
        while True:
            k = int(np.argmin(lower[which]))
            if lower[which][k] >= best[which]:
                break
            if tighten is not None and tighten(k):
                read(slice(None))
                continue
            visit(k)
    return measured


SETTLED_M = 0.05
"""A pair whose known bounds stay this far above the path's least known bound [m] is not bounded further."""


def settled_pairs(
    model: CollisionModel, q_path: Array, prior: Array, tolerance_m: float, motion: Array | None = None
) -> NDArray[np.bool_]:
    """The pairs (P,) whose known lower bounds ``prior`` (N, P) [m] leave nothing to find along ``q_path``.

    Settled: its known bounds certify every segment of ``q_path`` (N, n) by the motion bound
    (:func:`refine.collision.advance.short`) and stay :data:`SETTLED_M` above the least known bound
    of any pair, in distance and in clearance. Bounds only rise, so it stays certified whatever else
    is found; where it holds a waypoint's least bound, that waypoint is measured if it can matter
    (:func:`measure_least` needs lower bounds, not close ones). Its box and direction bounds are not
    computed: the check finds the same, only the lower-bound figures of waypoints it does not
    measure (and the bounds it carries on) keep such a pair's known bound where a box gives more.
    ``motion``: :func:`refine.collision.advance.pair_motion` of ``q_path`` if the caller has it.
    """
    least, clear, finite = column_least(prior, model.pair_margins)  # per pair (P,)
    if not finite.any():
        return finite
    motion = pair_motion(model, q_path) if motion is None else motion
    certified = ~short_of(prior, model.pair_margins, tolerance_m, motion).any(axis=0)
    far = (least >= least[finite].min() + SETTLED_M) & (clear >= clear[finite].min() + SETTLED_M)
    return finite & certified & far
