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
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from refine.collision.geometry import Body
from refine.collision.model import CollisionModel
from refine.collision.motion import corners
from refine.types import Array


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
    """

    q: Array
    pairs: tuple[tuple[str, str], ...]
    bounds: Array
    shapes: dict[str, tuple[int, Array]]
    base_in_world: Array


def _shape(model: CollisionModel, body: Body) -> tuple[int, Array]:
    """A body's hull corners where they do not move with the joints, and its joint (-1: the cell)."""
    c = corners(body)
    if body.kind == "cell":
        T = body.link_T_shape
        return -1, c @ T[:3, :3].T + T[:3, 3]
    T = model.robot.model.frames[body.frame_id].placement.homogeneous @ body.link_T_shape
    return int(body.joint), c @ T[:3, :3].T + T[:3, 3]


def checked_bounds(model: CollisionModel, q: Array, bounds: Array) -> CheckedBounds:
    """The bounds ``bounds`` (N, P) [m] of a check of joints ``q`` (N, n) in ``model``, to carry."""
    return CheckedBounds(
        np.array(q, dtype=float),
        tuple(model.pairs),
        np.array(bounds, dtype=float),
        {b.label: _shape(model, b) for b in model.bodies},
        model.base_in_world.copy(),
    )


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
    old = {pair: p for p, pair in enumerate(prior.pairs)}
    shift: dict[str, float] = {}  # per body: how far its points moved, inf for a changed shape
    for b in model.bodies:
        joint, now = _shape(model, b)
        before = prior.shapes.get(b.label)
        if before is None or before[0] != joint or before[1].shape != now.shape:
            shift[b.label] = np.inf
        elif joint >= 0:
            shift[b.label] = 0.0 if np.array_equal(before[1], now) else np.inf
        else:
            shift[b.label] = float(np.max(np.linalg.norm(now - before[1], axis=1)))
    motion = np.abs(q - prior.q) @ model.pair_motion.T  # (N, P) [m]
    out = np.full((len(q), len(model.pairs)), -np.inf)
    for p, (a, b) in enumerate(model.pairs):
        k = old.get((a, b))
        if k is None:
            continue
        delta = shift[a] + shift[b]
        if np.isfinite(delta):
            out[:, p] = prior.bounds[:, k] - motion[:, p] - delta
    return np.where(out > 0.0, out, -np.inf)


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
    for b in model.bodies:
        joint, now = _shape(model, b)
        before = checked.shapes.get(b.label)
        if before is None or before[0] != joint or not np.array_equal(before[1], now):
            return None
    a = np.floor(place).astype(int)
    at_waypoint = place == a
    if not np.array_equal(q[at_waypoint], checked.q[a[at_waypoint]]):
        return None
    b = np.where(at_waypoint, a, np.minimum(a + 1, N - 1))  # a waypoint keeps its own bound
    R = model.pair_motion.T  # (n, P) [m/rad]
    return np.maximum(
        checked.bounds[a] - np.abs(q - checked.q[a]) @ R, checked.bounds[b] - np.abs(q - checked.q[b]) @ R
    )


def measure_least(
    bounds: Array, margins: Array, measure: Callable[[int], tuple[float, float]]
) -> NDArray[np.bool_]:
    """Measure the waypoints that can hold the path's least distance or clearance, or break a margin.

    ``bounds`` (N, P): lower bounds [m] on every pair's distance at each waypoint (complete: no
    pair left without one, or that waypoint has ``-inf`` and is measured); ``margins`` (P,) [m].
    ``measure(k)`` measures waypoint k exactly and returns its least distance and least clearance
    [m]. Every waypoint whose bounds do not prove every margin is measured; then the waypoints in
    order of their lower bound, until the next bound is no smaller than the least measured (the
    least distance and the least clearance over the waypoints are then exact: every waypoint not
    measured is at least as far as the one measured).

    Returns:
        Which waypoints were measured, (N,).
    """
    lower_d = bounds.min(axis=1)
    lower_c = (bounds - margins).min(axis=1)
    measured = np.zeros(len(bounds), dtype=bool)
    best = [np.inf, np.inf]  # least distance, least clearance measured

    def visit(k: int) -> None:
        d, c = measure(k)
        measured[k] = True
        best[0], best[1] = min(best[0], d), min(best[1], c)

    for k in np.flatnonzero(lower_c < 0.0):
        visit(int(k))
    for which, lower in enumerate((lower_d, lower_c)):
        for k in np.argsort(lower, kind="stable"):
            if lower[k] >= best[which]:
                break
            if not measured[k]:
                visit(int(k))
    return measured
