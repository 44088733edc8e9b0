"""Conservative advancement of the checked pairs over the segments of a joint path.

Along a segment ``q(t) = q_k + t (q_{k+1} - q_k)``, t in [0, 1], no point of either body of pair p
moves relative to the other further than ``S_p = Σ_j |Δq_j| R_pj`` (:mod:`refine.collision.motion`),
so the pair's budget ``b = d_p - m_p + tolerance_m`` (distance minus margin plus tolerance) changes
by at most ``S_p`` over the segment: a parameter where the budget is b certifies the next and the
previous ``b / S_p`` of it. A pair whose two end budgets add up to ``S_p`` is certified over the
segment outright; one that falls short is measured exactly at the ends and then advanced from the
start, one FCL query of that pair per step (:func:`advance`), until the span certified from the end
is reached (:func:`advance_pairs`). :func:`refine.collision.check.check_path_clearance` and
:func:`refine.collision.check.margins_proved` build their proofs on it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from refine.collision.model import CollisionModel
from refine.collision.native_bounds import short_of
from refine.types import Array

REACH_AHEAD = 0.75
"""Conservative advancement places its next sample this many budgets beyond the certified edge."""

MAX_ADVANCE = 200
"""Samples one pair may take inside one segment before the segment is sampled densely instead."""

NONE: frozenset[str] = frozenset()
"""No body below its margin."""


class Sample(NamedTuple):
    """What one configuration of the dense check found."""

    distance: float  # least distance over all pairs [m]
    clearance: float  # least distance minus margin [m]
    pair: tuple[str, str]  # the pair with the least clearance
    pair_distance: float  # its distance [m]
    below: frozenset[str]  # every body and object below its margin
    t: float = math.nan  # an advancement's sample: its share of the segment
    index: int = -1  # an advancement's sample: the pair's index in the model's pairs


def advance_pairs(
    model: CollisionModel,
    q_path: Array,
    poses: Array,
    bounds: Array,
    exact: NDArray[np.bool_],
    tolerance_m: float,
    proved: NDArray[np.bool_] | None = None,
    columns: NDArray[np.intp] | None = None,
    motion: Array | None = None,
) -> tuple[NDArray[np.bool_], dict[int, list[Sample]]]:
    """Certify every segment pair by pair by conservative advancement on the pair's motion bound.

    ``bounds`` (N, P) holds lower bounds on each pair's distance at the waypoints (``exact`` where
    FCL measured it), ``poses`` the moving bodies' poses there (N, M, 4, 4); both are completed in
    place where a pair is measured at an end. A pair keeps its margin over segment k when its
    budgets (distance minus margin plus tolerance) at the two ends add up to at least the pair's
    motion bound ``S`` over the segment: each end certifies ``budget / S`` of the segment. A pair
    that falls short is measured exactly at the ends, then advanced from the start
    (:func:`advance`) until the span certified from the end is reached. Segment pairs marked in
    ``proved`` (N-1, P) were proved by the caller and are neither measured nor advanced; with
    ``columns`` (C,), ascending, only those pairs are looked at (the caller proved the others).
    ``motion``: :func:`pair_motion` of ``q_path`` if the caller has it (read only).

    Returns:
        Which segments are certified (N-1,) (the others, with a broken margin or more than
        :data:`MAX_ADVANCE` samples for a pair, are to be sampled densely), and per segment where
        a pair was advanced the samples taken inside it.
    """
    names = model.pairs
    margins = model.pair_margins
    cols = np.arange(len(names)) if columns is None else np.asarray(columns, dtype=np.intp)
    if columns is None:
        margin, view = margins, bounds
        motion = pair_motion(model, q_path) if motion is None else motion
    else:  # the pairs' own columns: their bounds, margins and motion (C of P)
        margin, view = margins[cols], bounds[:, cols]
        motion = np.abs(np.diff(q_path, axis=0)) @ model.pair_motion[cols].T
        proved = None if proved is None else proved[:, cols]
    need = short_of(view, margin, tolerance_m, motion)
    if proved is not None:
        need &= ~proved
    if not need.any():  # every segment pair certified by its end bounds: nothing to measure or advance
        return np.ones(len(motion), dtype=bool), {}
    for k in np.flatnonzero(need.any(axis=1)):  # measure the pairs that fall short at the ends
        for end in (k, k + 1):
            for c in np.flatnonzero(need[k] & ~exact[end, cols]):
                p = int(cols[c])
                view[end, c] = bounds[end, p] = model.pair_distance(q_path[end], p, poses[end])
                exact[end, p] = True
    budget = view - margin + tolerance_m
    need = short(budget, motion)
    if proved is not None:
        need &= ~proved
    broken = np.zeros(len(motion), dtype=bool)
    inner: dict[int, list[Sample]] = {}

    def measure(k: int, p: int) -> Callable[[float], float]:
        found = inner.setdefault(k, [])

        def budget_at(t: float) -> float:
            d = model.pair_distance(q_path[k] + t * (q_path[k + 1] - q_path[k]), p)
            found.append(Sample(d, d - margins[p], names[p], d, NONE, t, p))
            return d - margins[p] + tolerance_m

        return budget_at

    for k, c in zip(*np.nonzero(need), strict=True):  # by segment, then by pair: the columns ascend
        if broken[k]:
            continue
        b0, b1, S = budget[k, c], budget[k + 1, c], motion[k, c]
        if b0 < 0.0 or b1 < 0.0:
            broken[k] = True
            continue
        if not advance(measure(int(k), int(cols[c])), b0, b1, S):
            broken[k] = True  # a margin broken inside, or the advance stalled: sample the segment densely
    return ~broken, inner


def advance(budget_at: Callable[[float], float], b0: float, b1: float, S: float) -> bool:
    """Conservative advancement of one pair over one segment; True when [0, 1] is certified.

    A sample at t with budget c (distance minus margin plus tolerance) certifies the window
    ``[t - c/S, t + c/S]``. The start certifies ``[0, b0/S]``, the end ``[1 - b1/S, 1]``. The next
    sample is placed :data:`REACH_AHEAD` budgets beyond the certified edge, where its window reaches
    back to the edge unless the clearance there is smaller than that share of the edge's; when it
    does not, a sample at the edge itself is taken, whose window always joins. False when a budget
    is negative (a margin broken) or after :data:`MAX_ADVANCE` samples.

    Args:
        budget_at: the pair's budget [m] at segment parameter t (one FCL query).
        b0: budget at t = 0 [m], >= 0.
        b1: budget at t = 1 [m], >= 0.
        S: the pair's motion bound over the segment [m], > 0.
    """
    edge, c_edge, end = b0 / S, b0, 1.0 - b1 / S
    for _ in range(MAX_ADVANCE):
        if edge >= end:
            return True
        t = min(edge + REACH_AHEAD * c_edge / S, end)
        c = budget_at(t)
        if c < 0.0:
            return False
        if t - c / S > edge:  # the window does not reach back: step from the edge itself
            t = edge
            c = budget_at(t)
            if c < 0.0:
                return False
        edge, c_edge = t + c / S, c
    return edge >= end


def pair_motion(model: CollisionModel, q_path: Array) -> Array:
    """Per segment and pair, the most a point of one body moves relative to the other [m], (N-1, P)."""
    return np.abs(np.diff(q_path, axis=0)) @ model.pair_motion.T


def short(budget: Array, motion: Array) -> NDArray[np.bool_]:
    """Segment pairs (N-1, P) whose end budgets (N, P) [m] do not certify the whole segment."""
    return (budget[:-1] < 0.0) | (budget[1:] < 0.0) | (budget[:-1] + budget[1:] < motion)
