"""One motion of a robot program, verified: what it is, what it passes through and what was found.

A program is a sequence of motions (:func:`refine.plan.program.plan_program`): ``home`` (from the
home joints to the first approach pose), ``approach`` (a straight TCP line along the tool z axis
onto the first waypoint), ``path`` (a refined pass), ``retract`` (a straight TCP line back along
the tool z axis), ``link`` (from one retract to the next approach) and ``return`` (from the last
retract to home). Air moves (home, link, return) are joint-interpolated between their via points;
approach and retract are straight TCP lines with the joints from IK along them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from refine.types import Array

KINDS = ("home", "approach", "path", "retract", "link", "return")
"""The kinds of motion, in the order a single-pass program runs them."""

AIR_KINDS = ("home", "link", "return")
"""The motions joint-interpolated between via points (planned around the cell when needed)."""

LINE_KINDS = ("approach", "retract")
"""The motions along a straight TCP line."""

RETRACT_M = 0.1
"""Approach and retract distance along the tool z axis [m] (the programs' ``retract_m``)."""

AIR_SPEED_M_S = 0.25
"""TCP speed of the approach and retract lines [m/s] (the programs' ``approach_speed_m_s``)."""


@dataclass(frozen=True)
class MotionIssue:
    """Where a motion fails: what broke, between which objects, where.

    Attributes:
        cause: ``"collision"``, ``"self-collision"``, ``"joint limit"``, ``"singularity"``,
            ``"unreachable"`` or ``"no path found"``.
        detail: one sentence with the figures and units.
        objects: the bodies and cell objects below their margin (sorted), empty for other causes.
        fraction: where along the motion (0 at its start, 1 at its end) the worst point lies.
        tcp_m: the TCP position there, world frame [m], shape (3,).
        distance_m: the signed distance of the worst pair there [m] (clearance causes), else None.
    """

    cause: str
    detail: str
    objects: tuple[str, ...] = ()
    fraction: float = 0.0
    tcp_m: Array = field(default_factory=lambda: np.zeros(3))
    distance_m: float | None = None

    def describe(self) -> str:
        """One line for messages and reports."""
        where = ", ".join(f"{v * 1e3:.1f}" for v in self.tcp_m)
        return f"{self.cause} at {self.fraction:.0%} of the motion (TCP at [{where}] mm): {self.detail}"

    def as_json(self) -> dict[str, Any]:
        """The issue as ``result.json`` writes it (``motions[i].issues[j]``)."""
        return {
            "cause": self.cause,
            "detail": self.detail,
            "objects": list(self.objects),
            "fraction": float(self.fraction),
            "tcp_m": [float(v) for v in self.tcp_m],
            "distance_m": None if self.distance_m is None else float(self.distance_m),
        }


@dataclass(frozen=True)
class Motion:
    """One verified motion of the program.

    Attributes:
        kind: one of :data:`KINDS`.
        name: what it joins (``"home -> pass 1"``, ``"pass 1"``).
        q: joints [rad] it passes through, start first and end last, shape (K, n): an air move's
            start, via points and end (joint-interpolated between them), a line's IK samples, or a
            pass's waypoints.
        start_pose: TCP pose at the start, world frame, (4, 4).
        end_pose: TCP pose at the end, world frame, (4, 4).
        duration_s: the motion's time [s] (see :func:`joint_move_time`, or the line at
            :data:`AIR_SPEED_M_S`, or the pass's timed trajectory).
        planner: ``"joint move"`` (the direct joint move was clear), ``"RRT-Connect"`` (via points
            from OMPL), ``"line"`` (a straight TCP line) or ``"refinement"`` (a pass).
        planner_time_s: wall time of planning and verifying it [s].
        status: ``"ok"`` when every check passed, else ``"failed"``.
        min_distance_m: least signed distance to the cell or between the robot's bodies along the
            whole continuous motion [m]; None without a collision model.
        min_clearance_m: least distance minus the pair's margin [m]; None without a collision model.
        closest: (body, other) of the pair with the least clearance.
        min_joint_margin_rad: least distance of any joint to its limit along the motion [rad].
        min_singularity: least scaled manipulability along a line (None for air moves) [-].
        line_deviation_m: a line's largest TCP distance from the straight line between its IK
            samples (joint-interpolated) [m]; None for other kinds.
        issues: why it failed (empty when ``ok``).
        direct_issues: for an air move planned around the cell, what the direct joint move hit.
        move_s: an air move's time per joint move between its rows [s], (K-1,) (what the programs
            command for each: RAPID's time argument ``T``, URScript's ``t``); () for other kinds.
        check: the motion's continuous clearance check (``PathClearance`` of ``q``), whose
            distance bounds a later plan of the same motion starts from
            (:class:`refine.plan.verify.Known`); None without a collision model.
    """

    kind: str
    name: str
    q: Array
    start_pose: Array
    end_pose: Array
    duration_s: float
    planner: str
    planner_time_s: float
    status: str
    min_distance_m: float | None = None
    min_clearance_m: float | None = None
    closest: tuple[str, str] = ("", "")
    min_joint_margin_rad: float = math.inf
    min_singularity: float | None = None
    line_deviation_m: float | None = None
    issues: tuple[MotionIssue, ...] = ()
    direct_issues: tuple[MotionIssue, ...] = ()
    move_s: tuple[float, ...] = ()
    check: Any = field(default=None, compare=False, repr=False)

    @property
    def ok(self) -> bool:
        """True when the motion passed every check."""
        return self.status == "ok"

    @property
    def via(self) -> Array:
        """An air move's via points [rad], shape (V, n): its joint rows between start and end."""
        if self.kind not in AIR_KINDS:
            return np.zeros((0, self.q.shape[1]))
        return self.q[1:-1]

    @property
    def reason(self) -> str:
        """The failure in one line (empty when ``ok``)."""
        return "; ".join(f"{self.name}: {i.describe()}" for i in self.issues)

    def as_json(self, shown: Callable[[Array], Array] = lambda q: q) -> dict[str, Any]:
        """The motion as ``result.json`` writes it (``motions[i]``, see docs/outputs.md).

        Args:
            shown: URDF joints -> the joints as the controller shows them (``RobotSpec.to_controller``).
        """

        def end(q: Array, T: Array) -> dict[str, Any]:
            return {
                "joints_deg": [float(v) for v in np.degrees(shown(q))],
                "tcp_position_m": [float(v) for v in T[:3, 3]],
                "tcp_rotation": [[float(v) for v in row] for row in T[:3, :3]],
            }

        def num(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "kind": self.kind,
            "name": self.name,
            "status": self.status,
            "start": end(self.q[0], self.start_pose),
            "end": end(self.q[-1], self.end_pose),
            "duration_s": float(self.duration_s),
            "planner": self.planner,
            "planner_time_s": float(self.planner_time_s),
            "via_points": int(len(self.via)),
            "via_points_deg": [[float(v) for v in np.degrees(shown(row))] for row in self.via],
            "min_distance_m": num(self.min_distance_m),
            "min_clearance_m": num(self.min_clearance_m),
            "closest_pair": list(self.closest) if self.closest[0] else None,
            "min_joint_margin_deg": num(math.degrees(self.min_joint_margin_rad)),
            "min_singularity_measure": num(self.min_singularity),
            "line_deviation_m": num(self.line_deviation_m),
            "issues": [i.as_json() for i in self.issues],
            "direct_move_issues": [i.as_json() for i in self.direct_issues],
        }


def joint_move_times(q: Array, velocity: Array, acceleration: Array) -> Array:
    """Time [s] of each joint-interpolated move between consecutive rows of ``q`` (K, n), stopping at each row, (K-1,).

    Each move is one synchronised joint move: every joint's trapezoidal (or triangular) speed
    profile at its velocity and acceleration limit, the slowest joint setting the move's time
    (how a controller's joint move, PTP, ``MoveAbsJ``, ``movej``, times its axes).

    Args:
        q: joints [rad], start first, shape (K, n).
        velocity: joint speeds [rad/s], shape (n,) (:func:`air_limits`).
        acceleration: joint accelerations [rad/s^2], shape (n,).
    """
    v, a = np.asarray(velocity, dtype=float), np.asarray(acceleration, dtype=float)
    dq = np.abs(np.diff(np.asarray(q, dtype=float), axis=0))
    ramp = v * v / a  # the distance of a full ramp up and down [rad]
    t = np.where(dq >= ramp, dq / v + v / a, 2.0 * np.sqrt(dq / a))
    return t.max(axis=1) if t.size else np.zeros(len(dq))


def joint_move_time(q: Array, velocity: Array, acceleration: Array) -> float:
    """Time [s] of a joint-interpolated move through the rows of ``q`` (K, n), stopping at each row.

    The sum of :func:`joint_move_times`.
    """
    return float(np.sum(joint_move_times(q, velocity, acceleration)))


def air_limits(problem: Any, robot: Any) -> tuple[Array, Array]:
    """The joint speeds and accelerations the programs' air moves run at [rad/s], [rad/s^2], (n,) each.

    The speed: ``[output] air_speed_share`` of each joint's maximum (the share the writers command:
    RAPID ``MoveAbsJ`` with the move's time argument ``T``, URScript ``movej`` with ``t``, KRL
    ``BAS (#VEL_PTP, %)``, FANUC ``J ... %``, INFORM ``VJ``, Sunrise ``setJointVelocityRel``); the
    acceleration: the run's (``[robot] joint_acceleration_deg_s2`` or the robot's limits).
    """
    spec = robot.spec
    accel = spec.acceleration
    if problem.robot.joint_acceleration_deg_s2 is not None:
        accel = np.radians(problem.robot.joint_acceleration_deg_s2)
    return np.asarray(spec.velocity, dtype=float) * problem.output.air_speed_share, np.asarray(
        accel, dtype=float
    )


TABLE_COLUMNS = (
    "kind",
    "name",
    "status",
    "planner",
    "duration_s",
    "via_points",
    "min_distance_mm",
    "closest",
    "planner_time_s",
    "issue",
)
"""The columns of the motions table (``motions.csv`` and the report)."""


def table_rows(motions: tuple[Motion, ...]) -> list[dict[str, str]]:
    """One row of :data:`TABLE_COLUMNS` per motion, as text (distances in mm, times in s)."""
    rows = []
    for m in motions:
        rows.append(
            {
                "kind": m.kind,
                "name": m.name,
                "status": m.status,
                "planner": m.planner,
                "duration_s": f"{m.duration_s:.3f}",
                "via_points": str(len(m.via)),
                "min_distance_mm": "" if m.min_distance_m is None else f"{m.min_distance_m * 1e3:.1f}",
                "closest": " / ".join(m.closest) if m.closest[0] else "",
                "planner_time_s": f"{m.planner_time_s:.3f}",
                "issue": "; ".join(i.describe() for i in m.issues),
            }
        )
    return rows
