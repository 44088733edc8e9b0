"""Approach and retract: straight TCP lines along the tool z axis, with the joints from IK along them.

A controller's linear move (MoveL, LIN, movel) keeps the orientation and moves the TCP on the
straight line. :func:`plan_line` samples that line, solves IK at every sample from the previous
one (so the joints stay on the pass's branch, starting from the pass's own end joints), and checks
the motion like the path: the joints within their limits, no joint step above
``joint_step_deg`` between samples (a branch jump), every joint within its speed limit at the
line's speed, and the clearance with margin along the continuous
joint-interpolated motion between the samples. Near a singularity the joints a straight line needs
turn ever faster: the line fails when a joint would exceed its speed limit at the line's TCP speed
(the scaled manipulability along it is reported as a figure). Between two samples the
joint-interpolated TCP
leaves the straight line by at most :attr:`Motion.line_deviation_m` (measured at the midpoints and
kept below :data:`MAX_LINE_DEVIATION_M` by refining the samples).

**A line planned again** (``previous``, the same line of an earlier run, e.g. after the part moved
a few millimetres): the IK of each sample starts from the previous line's joints at the same share
of the line, moved by the change of the anchor's joints, instead of from the anchor's. Every
check above runs as for a line planned afresh, so a line planned again is verified as fully, and
the same IK answer (within its tolerance) gives the same figures. Its clearance is proved from the
previous line's check, its bounds carried to the new samples row for row, and its least figures
measured as the dense check measures them (:func:`refine.plan.recheck.recheck`); where those
bounds do not serve, the dense check runs as for a line planned afresh.
"""

from __future__ import annotations

import math
import time

import numpy as np

from refine.plan.motion import AIR_SPEED_M_S, Motion, MotionIssue
from refine.plan.verify import MotionChecker
from refine.robot.kinematics import solve_ik_batch
from refine.types import Array

LINE_STEP_M = 0.002
"""Largest TCP travel between two IK samples of a line [m]."""

MAX_LINE_DEVIATION_M = 1e-4
"""The samples are refined until the joint-interpolated TCP stays this close to the line [m]."""

IK_TOLERANCE = 1e-8
"""Pose error [m and rad stacked] under which an IK sample counts as on the line."""


def _line_deviation(checker: MotionChecker, q: Array, start: Array, end: Array) -> tuple[float, Array]:
    """Largest distance [m] of the joint-interpolated TCP (at the midpoints) from the segment start-end.

    Also the TCP Jacobians at those midpoints ``q[k] + (q[k+1] - q[k]) / 2`` (K-1, 6, n), for the
    singularity measure between the samples.
    """
    poses, jacobians = checker.kin.poses_jacobians(q[:-1] + 0.5 * np.diff(q, axis=0))
    mid = poses[:, :3, 3]
    axis = end - start
    length = float(np.linalg.norm(axis))
    u = np.clip((mid - start) @ axis / max(length * length, 1e-300), 0.0, 1.0)
    found = float(np.max(np.linalg.norm(mid - (start + u[:, None] * axis), axis=1))) if len(mid) else 0.0
    return found, jacobians


def line_joints(
    checker: MotionChecker,
    q_anchor: Array,
    T_anchor: Array,
    offset_m: float,
    count: int,
    start: Array | None = None,
    jacobians_out: Array | None = None,
) -> tuple[Array, float]:
    """IK along the tool z line from ``T_anchor`` to ``offset_m`` along its z axis, ``count`` steps.

    On a seven-axis arm axis 3 (the LBR's redundancy angle E1) is held at the anchor's value, as the
    controller holds it on a linear move. ``start``: the joints (K, n) [rad] of an earlier line
    from the anchor (the anchor's first), whose rows at the same share of the line start the IK;
    None to start every sample from the anchor's joints. ``jacobians_out``: an array (count + 1,
    6, n) to receive the TCP Jacobians at the returned joints, the anchor's first; or None.

    Returns:
        joints (count + 1, n) [rad], the anchor's first; and the largest IK residual.
    """
    kin = checker.kin
    lower, upper = checker.lower.copy(), checker.upper.copy()
    if kin.robot.nq == 7:  # an LBR's linear move keeps its redundancy angle E1 (axis 3) constant
        lower[2] = upper[2] = float(q_anchor[2])
    anchor = np.asarray(q_anchor, dtype=float)
    targets = np.repeat(T_anchor[None], count, axis=0)
    u = np.arange(1, count + 1) / count
    targets[:, :3, 3] = T_anchor[:3, 3] + np.outer(u * offset_m, T_anchor[:3, 2])
    # every sample from the anchor's joints at once (the line is short); the joint-step check of
    # plan_line finds a sample that left the anchor's branch
    q, residual = solve_ik_batch(
        kin,
        targets,
        np.tile(anchor, (count, 1)) if start is None else _at_shares(start, u),
        lower,
        upper,
        damping=1e-6,
        tol=IK_TOLERANCE,
        nullspace_gain=0.0,
        max_iterations=200,
        jacobians_out=None if jacobians_out is None else jacobians_out[1:],
    )
    if jacobians_out is not None:
        jacobians_out[0] = kin.pose_jacobian(anchor)[1]
    return np.vstack([anchor, q]), float(residual.max())


def _at_shares(rows: Array, u: Array) -> Array:
    """The joints of ``rows`` (K, n), linearly interpolated at the shares ``u`` (M,) of their span, (M, n)."""
    s = np.linspace(0.0, 1.0, len(rows))
    return np.stack([np.interp(u, s, rows[:, j]) for j in range(rows.shape[1])], axis=1)


def _previous_start(previous: Motion | None, kind: str, q_anchor: Array) -> Array | None:
    """An earlier line's joints from its anchor, moved by the change of the anchor's joints; None if none.

    Only an ``ok`` line of the same kind and robot serves (a failed one may have left the branch).
    """
    if previous is None or previous.kind != kind or not previous.ok or previous.planner != "line":
        return None
    rows = np.asarray(previous.q, dtype=float)
    if rows.ndim != 2 or rows.shape[1] != len(q_anchor) or len(rows) < 2:
        return None
    if kind == "approach":  # written from the approach point onto the anchor
        rows = rows[::-1]
    return rows + (q_anchor - rows[0])


def plan_line(
    checker: MotionChecker,
    kind: str,
    name: str,
    q_anchor: Array,
    T_anchor: Array,
    *,
    retract_m: float,
    speed_m_s: float = AIR_SPEED_M_S,
    previous: Motion | None = None,
) -> Motion:
    """The approach onto (``kind="approach"``) or the retract from (``"retract"``) a pass's end waypoint.

    Args:
        checker: what the motion is checked against.
        kind: ``"approach"`` (from ``retract_m`` behind the waypoint onto it) or ``"retract"``
            (from the waypoint back by ``retract_m``).
        name: the motion's name.
        q_anchor: the pass's joints at the waypoint [rad], shape (n,).
        T_anchor: the TCP pose at the waypoint, world frame (4, 4).
        retract_m: the line's length along -z of the tool [m].
        speed_m_s: the TCP speed of the line [m/s] (its duration is ``retract_m / speed_m_s``).
        previous: the same line of an earlier run, to start the IK from (module notes); None to
            plan it afresh.
    """
    t0 = time.perf_counter()
    q_anchor = np.asarray(q_anchor, dtype=float)
    count = max(1, math.ceil(retract_m / LINE_STEP_M))
    end = T_anchor[:3, 3] - retract_m * T_anchor[:3, 2]
    start = _previous_start(previous, kind, q_anchor)
    for _ in range(4):
        jacobians = np.empty((count + 1, 6, len(q_anchor)))
        q, residual = line_joints(checker, q_anchor, T_anchor, -retract_m, count, start, jacobians)
        deviation, between = _line_deviation(checker, q, T_anchor[:3, 3], end)
        if deviation <= MAX_LINE_DEVIATION_M or residual > IK_TOLERANCE * 10:
            break
        count *= 2
    issues: list[MotionIssue] = []
    wanted = T_anchor[:3, 3] + np.outer(np.linspace(0.0, 1.0, len(q)), end - T_anchor[:3, 3])
    if kind == "approach":  # from the approach point onto the waypoint: every figure in that order
        q, wanted, jacobians, between = q[::-1].copy(), wanted[::-1], jacobians[::-1], between[::-1]
    poses = checker.kin.poses(q)
    if residual > IK_TOLERANCE * 10:
        k = int(np.argmax(np.linalg.norm(poses[:, :3, 3] - wanted, axis=1)))
        issues.append(
            MotionIssue(
                "unreachable",
                f"IK along the line leaves it by {residual:.2e} (position [m] and angle [rad] stacked) within "
                "the joint limits",
                fraction=k / max(len(q) - 1, 1),
                tcp_m=poses[k, :3, 3],
            )
        )
    step = np.degrees(np.max(np.abs(np.diff(q, axis=0)), axis=1))
    if step.size and step.max() > checker.tolerances.joint_step_deg:
        k = int(np.argmax(step))
        issues.append(
            MotionIssue(
                "singularity",
                f"the joints jump by {step.max():.1f} deg between two samples {LINE_STEP_M * 1e3:g} mm apart "
                f"(joint step bound {checker.tolerances.joint_step_deg:g} deg): a branch change on the line",
                fraction=k / max(len(q) - 1, 1),
                tcp_m=poses[k, :3, 3],
            )
        )
    issues += checker.limit_issues(q, 0.0)  # the controller's limits (the margin is the optimiser's)
    # the singularity measure is the figure; what a singularity breaks is the speed:
    _, least = checker.singularity_issues(q, jacobians, between)
    dt = (retract_m / (len(q) - 1)) / speed_m_s
    rate = np.abs(np.diff(q, axis=0)) / dt / checker.kin.robot.spec.velocity  # share of each joint's limit
    if rate.size and rate.max() > 1.0:
        k, j = np.unravel_index(int(np.argmax(rate)), rate.shape)
        issues.append(
            MotionIssue(
                "singularity",
                f"joint {j + 1} would turn at {rate.max():.1f} times its speed limit "
                f"({math.degrees(checker.kin.robot.spec.velocity[j]):.0f} deg/s) to keep the TCP on the line at "
                f"{speed_m_s:g} m/s (scaled manipulability down to {least:.4f})",
                fraction=k / max(len(q) - 1, 1),
                tcp_m=poses[k, :3, 3],
            )
        )
    check = checker.clearance_again(q, None if start is None else previous.check)  # type: ignore[union-attr]
    issues += checker.clearance_issues(q, check)
    return Motion(
        kind=kind,
        name=name,
        q=q,
        start_pose=poses[0],
        end_pose=poses[-1],
        duration_s=retract_m / speed_m_s,
        planner="line",
        planner_time_s=time.perf_counter() - t0,
        status="failed" if issues else "ok",
        min_distance_m=None if check is None else check.min_distance_m,
        min_clearance_m=None if check is None else check.min_clearance_m,
        closest=_closest(check),
        min_joint_margin_rad=float(checker.joint_margin(q).min()),
        min_singularity=least,
        line_deviation_m=deviation,
        issues=tuple(issues),
        check=check,
    )


def _closest(check) -> tuple[str, str]:  # noqa: ANN001 - PathClearance or None
    if check is None or not len(check.segment_clearance_m):
        return ("", "")
    return tuple(check.segment_pair[int(np.argmin(check.segment_clearance_m))])  # type: ignore[return-value]
