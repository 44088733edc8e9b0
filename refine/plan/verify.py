"""The checks every motion passes: joint limits, clearance along the continuous motion, singularity.

:class:`MotionChecker` holds the robot, its kinematics, the collision model (with the run's
margins) and the tolerances. Clearance is the path's dense check
(:func:`refine.collision.check_path_clearance`, ``method="bound"``): between two rows the joints
move linearly, and the motion bound certifies every pair's margin along that continuous motion,
not only at samples. A broken margin becomes a :class:`refine.plan.motion.MotionIssue` naming the
objects, the share of the motion and the TCP position where the worst pair is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from refine.collision import CollisionModel, PathClearance, check_path_clearance
from refine.optimise.verify import segment_singularity, singularity_measures
from refine.plan.motion import MotionIssue
from refine.robot.kinematics import TcpKinematics
from refine.settings import Tolerances
from refine.types import Array

LOCATE_SAMPLES = 21
"""Samples along the worst segment of a broken margin that locate its worst point for the diagnosis."""


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

    def clearance(self, q: Array) -> PathClearance | None:
        """The continuous clearance check of the joint-interpolated rows ``q`` (K, n); None without a model.

        Its least distance and clearance are exact; a row's own figures are exact only where they
        can be those (elsewhere lower bounds: a motion reports its least only).
        """
        if self.model is None:
            return None
        return check_path_clearance(
            self.model, np.atleast_2d(q), self.kin, self.check_step_m, every_waypoint=False
        )

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

    def singularity_issues(self, q: Array) -> tuple[list[MotionIssue], float]:
        """The scaled manipulability along the rows of ``q`` (K, n) below the margin, and its least value."""
        q = np.atleast_2d(q)
        at, _ = singularity_measures(self.kin, q, smallest=False)
        between = segment_singularity(self.kin, q)[0] if len(q) > 1 else np.zeros(0)
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
