"""The least distance of the cell pairs and of the self pairs of a checked path, apart.

The dense check (:func:`refine.collision.check.check_path_clearance`) reports the least distance
over every pair: a robot link or tool shape against a cell object (held to the cell margin) or two
robot links or tool shapes (held to the self margin). A host comparing that one figure with the
cell margin misreads a self pair's 4.7 mm under a 10 mm cell margin as a collision, or the other
way round. :func:`kind_minima` gives each kind's own least distance:

* at the waypoints, exactly: every pair of the kind is bounded from below at every waypoint (the
  check's carried bounds of these joints where it kept them, else the gap between the bodies'
  boxes) and measured
  with FCL in the order of its bound until no bound left is below the least distance found, so far
  pairs cost nothing;
* between the waypoints, from the check's own figures: a segment whose least clearance belongs to a
  pair of the kind contributes that pair's distance there.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from refine.types import Array


@dataclass(frozen=True)
class KindMinima:
    """Each kind's least distance along a checked path [m]; None when the kind has no pair.

    Attributes:
        cell_m: least distance between the robot or tool and a cell object [m].
        self_m: least distance between robot links and tool shapes among themselves [m].
        queries: FCL distance queries made at the waypoints.
    """

    cell_m: float | None
    self_m: float | None
    queries: int = 0


def kind_minima(model: Any, q: Array, clearance: Any) -> KindMinima:
    """The cell pairs' and the self pairs' least distances of joints ``q`` (N, n) checked in ``model``.

    Args:
        model: the :class:`refine.collision.model.CollisionModel` the path was checked in.
        q: the joints checked [rad], (N, n).
        clearance: the :class:`refine.collision.PathClearance` of that check.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    kinds = {b.label: b.kind for b in model.bodies}
    is_cell = np.array([kinds.get(b) == "cell" or kinds.get(a) == "cell" for a, b in model.pairs], dtype=bool)
    if not len(is_cell):
        return KindMinima(None, None)
    poses = model.moving_poses(q)  # the check's, kept for these joints
    carried = getattr(clearance, "bounds", None)
    if (
        carried is not None
        and carried.bounds.shape == (len(q), len(model.pairs))
        and tuple(carried.pairs) == tuple(model.pairs)
        and np.array_equal(carried.q, q)
    ):
        # the check's own lower bounds at these joints: at least the box gaps wherever it boxed a
        # pair, and a proved bound elsewhere (a pair it left far and certified), so boxing the
        # pairs again would only tighten bounds that do not change the least distance found
        bounds = carried.bounds
    else:
        bounds = model.box_bounds(poses)  # (N, P), -inf where the boxes overlap
    margins = model.pair_margins
    out, queries = [], 0
    for kind in (True, False):
        columns = np.flatnonzero(is_cell == kind)
        if not len(columns):
            out.append(None)
            continue
        best = _between_waypoints(clearance, kinds, kind, float(margins[columns[0]]))
        sub = bounds[:, columns]
        for flat in ascending(sub):
            i, j = divmod(int(flat), len(columns))
            if sub[i, j] >= best:
                break  # no pair left can come closer
            best = min(best, model.pair_distance(q[i], int(columns[j]), poses[i]))
            queries += 1
        out.append(float(best))
    return KindMinima(out[0], out[1], queries)


SORTED_FIRST = 64
"""How many of the smallest bounds :func:`ascending` sorts before the rest are asked for."""


def ascending(values: Array) -> Iterator[int]:
    """The flat indices of ``values`` in ascending order, ties by index (NaN last), as a stable sort gives them.

    Lazily: the :data:`SORTED_FIRST` smallest entries are sorted first, the rest only when the
    caller asks past them (the search for the least distance usually stops within a few bounds).
    """
    flat = np.asarray(values, dtype=float).ravel()
    cut = np.partition(flat, SORTED_FIRST)[SORTED_FIRST] if flat.size > SORTED_FIRST else np.inf
    below = flat < cut  # every entry under the cut comes before every other in the sorted order
    for part in (np.flatnonzero(below), np.flatnonzero(~below)):
        yield from part[np.argsort(flat[part], kind="stable")].tolist()


def _between_waypoints(clearance: Any, kinds: dict[str, str], cell: bool, margin_m: float) -> float:
    """The least distance of a kind's pair where it held a segment's least clearance [m] (inf if none).

    Each distinct pair's kind is looked up once; a NaN clearance counts for nothing. The least
    clearance plus the margin is the least of the sums: rounding a sum keeps its order.
    """
    samples = getattr(clearance, "segment_samples", None)
    pairs = clearance.segment_pair
    if not len(pairs):
        return np.inf
    # a pair of the kind, and a pair at all (a segment without one names none)
    own = {
        p: (kinds.get(p[1]) == "cell" or kinds.get(p[0]) == "cell") == cell and bool(p[0]) for p in set(pairs)
    }
    take = np.fromiter(map(own.__getitem__, pairs), dtype=bool, count=len(pairs))
    # a segment with nothing inside has its ends' figures, which the waypoints give exactly
    if samples is not None:
        take &= np.asarray(samples) != 1
    values = np.asarray(clearance.segment_clearance_m, dtype=float)[take]
    values = values[~np.isnan(values)]
    return float(values.min()) + margin_m if len(values) else np.inf
