"""What the dense clearance check reports: per waypoint and segment its figures, the runs below the margin.

:class:`PathClearance` is :func:`refine.collision.check.check_path_clearance`'s answer,
:class:`ClearanceRun` one run of segments below the margin in it, :class:`Figures` the per-waypoint
figures the check fills as it measures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from refine.collision.advance import NONE, Sample
from refine.collision.carry import CheckedBounds
from refine.types import Array


@dataclass(frozen=True)
class ClearanceRun:
    """Consecutive segments where some pair is closer than its margin.

    Attributes:
        index_start: first waypoint of the run.
        index_end: last waypoint of the run (inclusive); the run covers the segments between.
        min_clearance_m: the least clearance (distance minus margin) inside [m], negative.
        min_distance_m: the signed distance of that worst pair there [m].
        worst_pair: (body, other) names of the worst pair.
        objects: every body and object found below its margin inside the run, sorted.
    """

    index_start: int
    index_end: int
    min_clearance_m: float
    min_distance_m: float
    worst_pair: tuple[str, str]
    objects: tuple[str, ...]

    def describe(self) -> str:
        """One line for messages and reports."""
        return (
            f"waypoints {self.index_start}-{self.index_end}: {self.worst_pair[0]} vs {self.worst_pair[1]} "
            f"at {self.min_distance_m * 1e3:.1f} mm ({-self.min_clearance_m * 1e3:.1f} mm inside the "
            f"margin); below margin: {', '.join(self.objects)}"
        )


@dataclass(frozen=True, eq=False)
class PathClearance:
    """Result of :func:`check_path_clearance`.

    Attributes:
        waypoint_distance_m: least signed distance over all checked pairs per waypoint [m], (N,).
        waypoint_clearance_m: least distance minus the pair's margin per waypoint [m], (N,).
        segment_distance_m: least distance per segment, waypoints and sub-steps [m], (N-1,).
        segment_clearance_m: least clearance per segment [m], (N-1,).
        segment_pair: per segment, (body, other) of the pair with the least clearance.
        segment_samples: sub-steps per segment, one more than the configurations sampled inside it, (N-1,).
        runs: runs of segments below the margin, with the objects involved.
        queries: FCL pair queries made by the check.
        time_s: wall time of the check [s].
        tolerance_m: a clearance counts as broken below ``-tolerance_m`` [m].
        certified_segments: segments proved clear along their whole motion by the per-pair
            motion bound (``method="bound"``; see the module notes); the rest were sampled densely.
        waypoint_measured: None when every waypoint is measured; else (``prior``, ``every_waypoint=False``)
            those measured (N,): that can hold the least distance or clearance, whose margins the bounds
            leave unproved, or that end a segment sampled inside. The others' figures, and those of a
            segment with one sub-step ending at one, are lower bounds; the least figures are exact.
        bounds, inner_samples: every pair's distance bounds at the waypoints (None for ``"sample"``), and
            per segment the advancement's samples (``Sample.t``, ``.index``), to re-check a nearby path.
    """

    waypoint_distance_m: Array
    waypoint_clearance_m: Array
    segment_distance_m: Array
    segment_clearance_m: Array
    segment_pair: tuple[tuple[str, str], ...]
    segment_samples: NDArray[np.int64]
    runs: tuple[ClearanceRun, ...]
    queries: int
    time_s: float
    tolerance_m: float
    certified_segments: int = 0
    waypoint_measured: NDArray[np.bool_] | None = None
    bounds: CheckedBounds | None = None
    inner_samples: dict[int, list[Sample]] | None = None

    @property
    def ok(self) -> bool:
        """True when no pair breaks its margin anywhere along the path."""
        return not self.runs

    @property
    def min_distance_m(self) -> float:
        """The least signed distance along the whole path [m]."""
        return float(np.min(np.concatenate([self.waypoint_distance_m, self.segment_distance_m])))

    @property
    def min_clearance_m(self) -> float:
        """The least clearance (distance minus margin) along the whole path [m]."""
        return float(np.min(np.concatenate([self.waypoint_clearance_m, self.segment_clearance_m])))

    def summary(self) -> str:
        """A few lines for logs and reports."""
        head = (
            f"clearance check: {len(self.waypoint_distance_m)} waypoints, "
            f"{int(self.segment_samples.sum())} sub-steps, {self.queries} distance queries in "
            f"{self.time_s:.3f} s; least distance {self.min_distance_m * 1e3:.1f} mm, least clearance "
            f"{self.min_clearance_m * 1e3:.1f} mm; {self.certified_segments} of "
            f"{len(self.segment_samples)} segments proved clear by the motion bound"
        )
        if self.ok:
            return head + "; every margin kept"
        return "\n".join(
            [head + f"; {len(self.runs)} run(s) below the margin:"] + ["  " + r.describe() for r in self.runs]
        )


class Figures:
    """Per waypoint of a check, its figures.

    The least distance and clearance [m], the pair of least clearance and its distance [m] (arrays
    (N,) and a list), and the bodies below their margins where there are any.
    """

    def __init__(self, distance: Array, clearance: Array, pair_distance: Array, pair: list[tuple[str, str]]):
        self.distance = np.array(distance, dtype=float)
        self.clearance = np.array(clearance, dtype=float)
        self.pair_distance = np.array(pair_distance, dtype=float)
        self.pair = pair
        self.below: dict[int, frozenset[str]] = {}

    @classmethod
    def of(cls, samples: list[Sample]) -> Figures:
        """The figures of one sample per waypoint."""
        figures = cls(
            [s.distance for s in samples],
            [s.clearance for s in samples],
            [s.pair_distance for s in samples],
            [s.pair for s in samples],
        )
        figures.below = {k: s.below for k, s in enumerate(samples) if s.below}
        return figures

    def put(self, k: int, s: Sample) -> None:
        """Waypoint k's figures are those of sample ``s``."""
        self.distance[k], self.clearance[k], self.pair[k], self.pair_distance[k] = (
            s.distance,
            s.clearance,
            s.pair,
            s.pair_distance,
        )
        if s.below:
            self.below[k] = s.below
        else:
            self.below.pop(k, None)

    def sample(self, k: int) -> Sample:
        """Waypoint k's figures as a sample."""
        return Sample(
            float(self.distance[k]),
            float(self.clearance[k]),
            self.pair[k],
            float(self.pair_distance[k]),
            self.below.get(k, NONE),
        )
