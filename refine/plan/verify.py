"""The checks every motion passes: joint limits, clearance along the continuous motion, singularity.

:class:`MotionChecker` holds the robot, its kinematics, the collision model (with the run's
margins) and the tolerances. Clearance is the path's dense check
(:func:`refine.collision.check_path_clearance`, ``method="bound"``): between two rows the joints
move linearly, and the motion bound certifies every pair's margin along that continuous motion,
not only at samples. A broken margin becomes a :class:`refine.plan.motion.MotionIssue` naming the
objects, the share of the motion and the TCP position where the worst pair is.

A check may start from what an earlier check proved (:class:`Known`: a previous run's check of the
same motion, its distance bounds less the motion since, :func:`refine.collision.carry.carried_bounds`):
a pair those bounds prove is not measured again, and the least figures are measured as without
them. An air move's kept via points are checked so (:func:`refine.plan.air.plan_air`). A line or a
direct move planned again is checked by :meth:`MotionChecker.clearance_again`: its earlier check's
bounds prove it where they can, with no bounding of every pair at every row
(:func:`refine.plan.recheck.recheck`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from refine.collision import CollisionModel, PathClearance, check_path_clearance, margins_proved
from refine.collision.carry import CheckedBounds, carried_bounds, carried_directions
from refine.optimise.verify import segment_singularity, singularity_measures
from refine.plan.motion import MotionIssue
from refine.plan.recheck import recheck
from refine.robot.kinematics import TcpKinematics
from refine.settings import Tolerances
from refine.types import Array

LOCATE_SAMPLES = 21
"""Samples along the worst segment of a broken margin that locate its worst point for the diagnosis."""


@dataclass(frozen=True)
class Known:
    """Distance bounds an earlier check proved, for rows of a motion about to be checked.

    Attributes:
        bounds: the earlier check's bounds (``PathClearance.bounds``).
        rows: the rows of the earlier check to take, (R,).
        at: the rows of the new motion they bound, (R,): each bound is carried from the earlier
            check's joints and cell to the new row's (:func:`refine.collision.carry.carried_bounds`:
            unchanged at the same joints in the same cell, less the motion since elsewhere).
    """

    bounds: CheckedBounds
    rows: tuple[int, ...]
    at: tuple[int, ...]

    @staticmethod
    def of(check: PathClearance | None, rows: Sequence[int], at: Sequence[int]) -> Known | None:
        """``check``'s bounds at its ``rows`` for the new motion's rows ``at``; None without them."""
        bounds = getattr(check, "bounds", None)
        if bounds is None:
            return None
        n = len(bounds.q)
        if not all(-n <= r < n for r in rows):
            return None
        return Known(bounds, tuple(int(r) % n for r in rows), tuple(int(a) for a in at))


@dataclass
class MotionChecker:
    """What the motions are checked against.

    Attributes:
        kin: TCP kinematics of the robot, base and tool (world frame).
        model: the collision model with the run's margins; None when collision is off.
        tolerances: the problem's tolerances (joint margin, singularity margin, joint step).
        check_step_m: largest TCP travel between two poses of the dense clearance check [m].
    """

    kin: TcpKinematics
    model: CollisionModel | None
    tolerances: Tolerances
    check_step_m: float

    @property
    def lower(self) -> Array:
        """Joint lower limits [rad]."""
        return self.kin.robot.spec.lower

    @property
    def upper(self) -> Array:
        """Joint upper limits [rad]."""
        return self.kin.robot.spec.upper

    def joint_margin(self, q: Array) -> Array:
        """Per row of ``q`` (K, n), the least distance of any joint to its limit [rad] (negative outside)."""
        q = np.atleast_2d(q)
        return np.min(np.minimum(q - self.lower, self.upper - q), axis=1)

    def clearance_at(self, q: Array) -> tuple[float, float, tuple[str, str]]:
        """Least clearance (distance minus margin) [m], its distance [m] and pair at one configuration."""
        if self.model is None:
            return math.inf, math.inf, ("", "")
        _, worst = self.model.nearest_pairs(np.asarray(q, dtype=float))
        if worst is None:
            return math.inf, math.inf, ("", "")
        return worst.clearance_m, worst.distance_m, (worst.body, worst.other)

    def clearance(self, q: Array, known: Sequence[Known | None] = ()) -> PathClearance | None:
        """The continuous clearance check of the joint-interpolated rows ``q`` (K, n); None without a model.

        Its least distance and clearance are exact; a row's own figures are exact only where they
        can be those (elsewhere lower bounds: a motion reports its least only). ``known``: bounds
        earlier checks proved at rows of ``q`` (:class:`Known`); the larger bound of a pair holds.
        """
        if self.model is None:
            return None
        q = np.atleast_2d(np.asarray(q, dtype=float))
        prior, directions = self.carried(q, known)
        return check_path_clearance(
            self.model,
            q,
            self.kin,
            self.check_step_m,
            every_waypoint=False,
            prior=prior,
            directions=directions,
        )

    def clearance_again(self, q: Array, previous: PathClearance | None) -> PathClearance | None:
        """The continuous clearance check of the rows ``q`` (K, n) of a motion planned again; None without a model.

        ``previous``: the earlier check of the same motion, row for row (or None). Its bounds,
        carried to ``q``, prove the margins and bound the least figures where they can
        (:func:`refine.plan.recheck.recheck`); where they cannot, the check of :meth:`clearance`.
        """
        if self.model is None:
            return None
        found = None if previous is None else recheck(self.model, q, previous)
        return self.clearance(q) if found is None else found

    def proved(self, q: Array, known: Sequence[Known | None] = ()) -> bool:
        """True when the motion bound proves every margin along the rows ``q`` (K, n) (without a model too).

        :func:`refine.collision.margins_proved` from the bounds ``known``; False decides nothing.
        """
        if self.model is None:
            return True
        q = np.atleast_2d(np.asarray(q, dtype=float))
        prior, directions = self.carried(q, known)
        return margins_proved(self.model, q, prior=prior, directions=directions)

    def carried(self, q: Array, known: Sequence[Known | None]) -> tuple[Array | None, Array | None]:
        """Lower bounds (K, P) [m] and witness directions (K, P, 3) at the rows ``q`` (K, n) from ``known``.

        None for either when no bound applies: another robot or base, or no earlier check. A row
        without a bound has ``-inf`` (directions NaN).
        """
        assert self.model is not None
        bounds: Array | None = None
        directions: Array | None = None
        for k in known:
            if k is None or not k.at:
                continue
            at, rows = list(k.at), list(k.rows)
            part = replace(
                k.bounds,
                q=k.bounds.q[rows],
                bounds=k.bounds.bounds[rows],
                normals=None if k.bounds.normals is None else k.bounds.normals[rows],
            )
            found = carried_bounds(self.model, part, q[at])
            if found is None:
                continue
            if bounds is None:
                bounds = np.full((len(q), len(self.model.pairs)), -np.inf)
            bounds[at] = np.maximum(bounds[at], found)
            towards = carried_directions(self.model, part, q[at])
            if towards is not None:
                if directions is None:
                    directions = np.full((len(q), len(self.model.pairs), 3), np.nan)
                free = np.isnan(directions[at, :, :1])
                directions[at] = np.where(free, towards, directions[at])
        return bounds, directions

    def limit_issues(self, q: Array, margin_rad: float) -> list[MotionIssue]:
        """A joint outside [lower + margin, upper - margin] anywhere in the rows of ``q`` (K, n).

        Between rows the joints move linearly, so the rows bound the whole motion.
        """
        margins = self.joint_margin(q)
        k = int(np.argmin(margins))
        if margins[k] >= margin_rad - 1e-9:
            return []
        row = np.atleast_2d(q)[k]
        j = int(np.argmin(np.minimum(row - self.lower, self.upper - row)))
        return [
            MotionIssue(
                "joint limit",
                f"joint {j + 1} at {math.degrees(row[j]):.2f} deg, {math.degrees(margins[k]):.2f} deg from its "
                f"limit [{math.degrees(self.lower[j]):.1f}, {math.degrees(self.upper[j]):.1f}] deg "
                f"(margin {math.degrees(margin_rad):.2f} deg)",
                fraction=k / max(len(margins) - 1, 1),
                tcp_m=self.kin.pose(row)[:3, 3],
            )
        ]

    def clearance_issues(self, q: Array, check: PathClearance | None) -> list[MotionIssue]:
        """Every run of ``check`` below the margin, as issues naming the objects and where."""
        if check is None:
            return []
        q = np.atleast_2d(q)
        cell = set() if self.model is None else {b.name for b in self.model.bodies if b.kind == "cell"}
        out = []
        for run in check.runs:
            segs = range(run.index_start, max(run.index_end, run.index_start + 1))
            k = min(
                segs,
                key=lambda i: check.segment_clearance_m[i] if i < len(check.segment_clearance_m) else 0.0,
            )
            where = float(k)
            if k + 1 < len(q):  # where inside the segment: the worst of a few samples along it
                u = np.linspace(0.0, 1.0, LOCATE_SAMPLES)
                worst = min(u, key=lambda t: self.clearance_at(q[k] + t * (q[k + 1] - q[k]))[0])
                where = k + float(worst)
            at = q[k] + (where - k) * (q[min(k + 1, len(q) - 1)] - q[k])
            cause = "self-collision" if run.worst_pair[1] not in cell else "collision"
            out.append(
                MotionIssue(
                    cause,
                    f"{run.worst_pair[0]} vs {run.worst_pair[1]} at {run.min_distance_m * 1e3:.1f} mm "
                    f"({-run.min_clearance_m * 1e3:.1f} mm inside the margin); below margin: "
                    f"{', '.join(run.objects)}",
                    objects=run.objects,
                    fraction=where / max(len(q) - 1, 1),
                    tcp_m=self.kin.pose(at)[:3, 3],
                    distance_m=run.min_distance_m,
                )
            )
        return out

    def singularity_issues(
        self, q: Array, jacobians: Array | None = None, midpoint_jacobians: Array | None = None
    ) -> tuple[list[MotionIssue], float]:
        """The scaled manipulability along the rows of ``q`` (K, n) below the margin, and its least value.

        ``jacobians``: the TCP Jacobians (K, 6, n) at the rows when the caller has them, else None;
        ``midpoint_jacobians`` (K-1, 6, n): those at the segments' midpoints
        (:func:`refine.optimise.verify.segment_singularity`), or None.
        """
        q = np.atleast_2d(q)
        at, _ = singularity_measures(self.kin, q, smallest=False, jacobians=jacobians)
        between = (
            segment_singularity(self.kin, q, midpoint_jacobians=midpoint_jacobians)[0]
            if len(q) > 1
            else np.zeros(0)
        )
        least = float(min(at.min(), between.min() if between.size else math.inf))
        limit = self.tolerances.singularity_margin
        if least >= limit - 1e-9:
            return [], least
        k = int(np.argmin(at))
        return [
            MotionIssue(
                "singularity",
                f"scaled manipulability {least:.4f} below the margin {limit:g}",
                fraction=k / max(len(q) - 1, 1),
                tcp_m=self.kin.pose(q[k])[:3, 3],
            )
        ], least
