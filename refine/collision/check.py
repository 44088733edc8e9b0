"""The dense final clearance check of a joint path, between waypoints too.

The robot moves between two waypoints with its joints interpolated linearly, so a link can sweep
through an obstacle that neither waypoint touches.

**Bounded motion (the default, ``method="bound"``).** A point turning about joint j moves at most
``|dq_j| * R_j``, with ``R_j`` the largest distance any body downstream of joint j can have from it
(:func:`joint_reach`: link offsets plus shape extents, a constant of the robot and tool, whatever
the shapes are). Along a segment no point of any link or tool shape moves more than
``S = Σ_j |Δq_j| R_j``, so between parameters t and t' two bodies approach each other by at most
``2 S |t' - t|`` (one of them may be the fixed cell). With the least clearance ``c`` over all pairs
at a sample (distance minus the pair's margin), no pair can break its margin within ``c / (2S)`` of
it. Samples are placed by this conservative advancement from the segment's start until the
certified spans from both ends meet; a segment whose clearance is too small for the bound to pay
(an advance shorter than ``link_step_m / 2``) or where a sample breaks a margin is sampled densely
as below. Guarantee: on a certified segment every checked pair keeps its margin (to
``tolerance_m``) along the whole continuous motion, not only at the samples.

**Dense sampling (``method="sample"``, and the fallback).** Each segment is cut into enough
sub-steps that

* the TCP moves at most ``step_m`` between checks (the chord between consecutive checks; the
  segment's chord sets a first count, raised while the TCP curve makes a sub-step longer), and
* no point of any link or tool shape moves more than ``link_step_m``. That bound is taken from the
  joints: a point turning about joint j moves at most ``|dq_j| * R_j``, with ``R_j`` the largest
  distance any body downstream of joint j can have from it (link offsets plus shape extents, a
  constant of the robot and tool), so a wrist flip with the TCP nearly still is sampled too.

At every sample the pair with the least clearance (distance minus its margin) and the pair with the
least distance are found with :meth:`CollisionModel.nearest_pairs`; where a margin is broken, every
pair below its margin is named.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from refine.collision.model import CollisionModel
from refine.errors import InputError
from refine.optimise.seed import TcpKinematics

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

LINK_STEP_M = 0.005
"""Default largest motion of any link point between two checks [m]."""


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
        segment_samples: sub-steps used per segment, (N-1,).
        runs: runs of segments below the margin, with the objects involved.
        queries: FCL pair queries made by the check.
        time_s: wall time of the check [s].
        tolerance_m: a clearance counts as broken below ``-tolerance_m`` [m].
        certified_segments: segments cleared by the motion bound (``method="bound"``), the rest
            were sampled densely.
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
            f"{self.min_clearance_m * 1e3:.1f} mm"
        )
        if self.ok:
            return head + "; every margin kept"
        return "\n".join(
            [head + f"; {len(self.runs)} run(s) below the margin:"] + ["  " + r.describe() for r in self.runs]
        )


class _Sample(NamedTuple):
    distance: float  # least distance over all pairs [m]
    clearance: float  # least distance minus margin [m]
    pair: tuple[str, str]  # the pair with the least clearance
    pair_distance: float  # its distance [m]
    below: frozenset[str]  # every body and object below its margin


def joint_reach(model: CollisionModel) -> Array:
    """Per joint, the largest distance [m] any body downstream of it can have from its axis, (n,).

    A bound that holds at every configuration: the joint offsets along the chain from the joint to
    the body's joint, plus the body's extent from its own joint's origin.
    """
    pm = model.robot.model
    offset = [float(np.linalg.norm(pm.jointPlacements[j].translation)) for j in range(pm.njoints)]
    reach = np.zeros(model.robot.nq)
    for body in model.bodies:
        if body.kind == "cell" or body.joint <= 0:
            continue
        jMs = pm.frames[body.frame_id].placement.homogeneous @ body.link_T_shape
        centre = jMs[:3, :3] @ body.centre + jMs[:3, 3]
        extent = float(np.linalg.norm(centre) + np.linalg.norm(body.half_extent))
        chain = list(pm.supports[body.joint])[1:]  # joints from the base to the body's joint
        for i, j in enumerate(chain):
            along = sum(offset[k] for k in chain[i + 1 :])
            v = pm.joints[j].idx_v
            reach[v] = max(reach[v], along + extent)
    return reach


def _interpolate(q0: Array, q1: Array, m: int) -> Array:
    t = np.arange(1, m)[:, None] / m
    return q0 + t * (q1 - q0)


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
) -> PathClearance:
    """Check a joint path densely against the collision model.

    Args:
        model: the collision model (robot, tool, cell, margins).
        q_path: joints per waypoint [rad], shape (N, n).
        kin: TCP kinematics of the same robot, base and tool.
        step_m: largest TCP motion between two checks [m] (``collision.check_step_m``).
        link_step_m: largest motion of any link or tool point between two checks [m].
        tolerance_m: clearances down to ``-tolerance_m`` still count as kept [m].
        method: ``"bound"`` to certify segments by the motion bound where the clearance allows
            and sample the rest densely, ``"sample"`` to sample every segment densely.

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
    same = kin.robot is model.robot and all(
        np.allclose(getattr(kin, key), getattr(model, key)) for key in ("base_in_world", "tcp_in_flange")
    )
    if not same:
        raise InputError(
            "check_path_clearance: kin must have the collision model's robot, base_in_world and tcp_in_flange"
        )
    start, queries = time.perf_counter(), model.queries
    top_margin = max(model.margin_m, model.self_margin_m)

    def sample(q: Array) -> _Sample:
        by_distance, by_clearance = model.nearest_pairs(q)
        if by_distance is None or by_clearance is None:
            return _Sample(math.inf, math.inf, ("", ""), math.inf, frozenset())
        names: set[str] = set()
        if by_clearance.clearance_m < -tolerance_m:
            for c in model.contacts(q, top_margin):
                if c.clearance_m < -tolerance_m:
                    names.update((c.body, c.other))
        pair = (by_clearance.body, by_clearance.other)
        return _Sample(
            by_distance.distance_m, by_clearance.clearance_m, pair, by_clearance.distance_m, frozenset(names)
        )

    points = [sample(q) for q in q_path]
    wp_dist = np.array([p.distance for p in points])
    wp_clear = np.array([p.clearance for p in points])
    reach = joint_reach(model)
    sweep = np.abs(np.diff(q_path, axis=0)) @ reach  # largest motion of any body point per segment [m]
    found_by_segment: list[list[_Sample] | None] = [None] * len(sweep)
    if method == "bound":
        for k, S in enumerate(sweep):
            found_by_segment[k] = _advance(
                sample, q_path[k], q_path[k + 1], points[k], points[k + 1], S, tolerance_m, link_step_m
            )
    dense = [k for k, found in enumerate(found_by_segment) if found is None]
    steps = np.ones(len(sweep), dtype=np.int64)
    if dense:
        idx = np.array(dense)
        tcp = kin.poses(q_path)[:, :3, 3]
        chord = np.linalg.norm(tcp[idx + 1] - tcp[idx], axis=1)
        least = np.maximum(1, np.maximum(np.ceil(chord / step_m), np.ceil(sweep[idx] / link_step_m))).astype(
            int
        )
        for k, m in zip(dense, least, strict=True):
            steps[k] = _sub_steps(kin, q_path[k], q_path[k + 1], int(m), step_m)
            found_by_segment[k] = [sample(q) for q in _interpolate(q_path[k], q_path[k + 1], int(steps[k]))]
    worst: list[_Sample] = []
    seg_dist = np.empty(len(sweep))
    for k, inner in enumerate(found_by_segment):
        assert inner is not None
        if k not in dense:
            steps[k] = len(inner) + 1
        found = [points[k], points[k + 1], *inner]
        seg_dist[k] = min(s.distance for s in found)
        worst.append(
            min(found, key=lambda s: s.clearance)._replace(below=frozenset().union(*(s.below for s in found)))
        )
    seg_clear = np.array([w.clearance for w in worst])
    runs = _runs(worst if len(steps) else points[:1], tolerance_m, single=len(steps) == 0)
    result = PathClearance(
        waypoint_distance_m=wp_dist,
        waypoint_clearance_m=wp_clear,
        segment_distance_m=seg_dist,
        segment_clearance_m=seg_clear,
        segment_pair=tuple(w.pair for w in worst),
        segment_samples=steps,
        runs=runs,
        queries=model.queries - queries,
        time_s=time.perf_counter() - start,
        tolerance_m=tolerance_m,
        certified_segments=len(sweep) - len(dense),
    )
    log.info("%s", result.summary())
    return result


def _advance(
    sample,
    q0: Array,
    q1: Array,
    first: _Sample,
    last: _Sample,
    sweep_m: float,
    tolerance_m: float,
    link_step_m: float,
) -> list[_Sample] | None:
    """Samples inside one segment placed by conservative advancement, or None to sample it densely.

    From the start, each sample's least clearance ``c`` (plus the tolerance) certifies the next
    ``c / (2 sweep_m)`` of the segment; the end certifies the last ``c_end / (2 sweep_m)``. None when
    a clearance is broken (the dense sampling then finds and names the pairs) or too small for an
    advance of at least ``link_step_m / 2``.
    """
    if sweep_m <= 0.0:
        return [] if min(first.clearance, last.clearance) >= -tolerance_m else None
    end = 1.0 - (last.clearance + tolerance_m) / (2.0 * sweep_m)
    t, c = 0.0, first.clearance + tolerance_m
    found: list[_Sample] = []
    while True:
        if c < 0.0 or last.clearance + tolerance_m < 0.0:
            return None
        advance = c / (2.0 * sweep_m)
        if t + advance >= end:
            return found
        if advance * sweep_m < 0.5 * link_step_m:
            return None
        t += advance
        s = sample(q0 + t * (q1 - q0))
        found.append(s)
        c = s.clearance + tolerance_m


def _runs(worst: list[_Sample], tolerance_m: float, *, single: bool) -> tuple[ClearanceRun, ...]:
    """Group consecutive segments (or the single waypoint) whose worst sample breaks a margin."""
    runs = []
    k = 0
    while k < len(worst):
        if worst[k].clearance >= -tolerance_m:
            k += 1
            continue
        first = k
        while k < len(worst) and worst[k].clearance < -tolerance_m:
            k += 1
        w = min(worst[first:k], key=lambda s: s.clearance)
        names = tuple(sorted(frozenset().union(*(s.below for s in worst[first:k]))))
        end = first if single else k
        runs.append(ClearanceRun(first, end, w.clearance, w.pair_distance, w.pair, names))
    return tuple(runs)
