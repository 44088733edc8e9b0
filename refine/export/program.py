r"""What every robot program writer shares: passes with their repairs, home, singular runs, speeds.

* :class:`ProgramPass`: one pass to write, its timed trajectory and the segments a repair changed
  (their waypoint range, arc length, extra orientation slack and cause); a program's header lists
  them so the programmer sees what differs from the demonstration.
* :func:`home_joints`: the home joint position a program starts and ends at: ``[robot] home_deg``
  when the problem gives one, else the refined joints at the first waypoint.
* :func:`singular_runs`: the waypoints near the wrist singularity, where the wrist axis (axis 5 of
  a six-axis arm, axis 6 of a seven-axis LBR) is within :data:`WRIST_SINGULAR_DEG` of 0 or ±180 deg
  (there the axes before and after it line up). Programs hand these segments to the controller's
  wrist-singularity handling (RAPID ``SingArea \Wrist``, KRL ``$ORI_TYPE = #JOINT``) with a
  comment.
* :func:`speed_levels`: a few speeds for many segments: each segment runs at the fastest level
  not above its planned speed, and the levels are chosen (exact dynamic programme over the
  distinct rounded speeds) to add the least time to the path.
* :func:`lead_point`: where on the path a switch ``lead`` before its end falls.
* :func:`weld_start` and :func:`weld_end`: the arc start and end in the order every dialect writes
  them (gas pre-flow, arc on, wait for the arc; crater fill, arc off, gas post-flow, gas off), each
  step rendered by the dialect's own ``wait`` and ``switch``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from refine.errors import InputError
from refine.names import comment_text
from refine.optimise.verify import runs
from refine.paths import Trajectory
from refine.problem import Problem
from refine.types import Array

WRIST_SINGULAR_DEG = 10.0
"""A waypoint is near the wrist singularity when the wrist axis is this close to 0 or ±180 deg."""


@dataclass(frozen=True)
class ProgramPass:
    """One pass a program writes.

    Attributes:
        name: pass name (``"pass 1"``, ``"layer 2 pass 1"``).
        trajectory: the timed path.
        repairs: the segments a repair gave extra orientation slack, as
            :class:`refine.optimise.outcome.Repair` (waypoint indices of this pass).
        air_in: the planned air move onto this pass's approach point (the run's ``home`` or
            ``link`` motion), as the joints [rad] it moves through after its start, shape (K, n):
            its via points, then the approach joints (the last row). None: the writer's own
            approach (a program written without a run's motions).
        air_out: for the last pass, the planned ``return``: the joints [rad] after its start, via
            points then home (the last row); None: straight home.
    """

    name: str
    trajectory: Trajectory
    repairs: tuple[Any, ...] = ()
    air_in: Array | None = None
    air_out: Array | None = None


def with_motions(passes: list[ProgramPass], motions: tuple[Any, ...]) -> list[ProgramPass]:
    """The passes with the run's planned air moves (``refine.plan.motion.Motion``) to write.

    The air move into pass i is the i-th ``home``/``link`` motion, the return the ``return``
    motion; without motions (or when their count does not match) the passes are returned as given.
    """
    into = [m for m in motions if m.kind in ("home", "link")]
    back = [m for m in motions if m.kind == "return"]
    if len(into) != len(passes) or len(back) != 1:
        return passes
    out = [replace(p, air_in=np.asarray(m.q[1:], dtype=float)) for p, m in zip(passes, into, strict=True)]
    out[-1] = replace(out[-1], air_out=np.asarray(back[0].q[1:], dtype=float))
    return out


def as_passes(
    name: str, trajectory: Trajectory, passes: list[Any] | None, repairs: tuple[Any, ...] = ()
) -> list[ProgramPass]:
    """The passes to write: ``passes`` (``ProgramPass`` or ``(name, trajectory)``) or the one trajectory."""
    if passes is None:
        return [ProgramPass(name, trajectory, tuple(repairs))]
    out = [p if isinstance(p, ProgramPass) else ProgramPass(str(p[0]), p[1]) for p in passes]
    if not out:
        raise InputError("program export: passes is empty; give at least one (name, trajectory)")
    return out


def home_joints(problem: Problem, robot: Any, q_first: Array) -> Array:
    """The home joint position [rad], URDF joints, shape (n,): ``[robot] home_deg`` or the first waypoint's.

    ``home_deg`` holds the controller's joints (``RobotSpec.from_controller`` turns them into the
    URDF's for a robot with a joint coupling, such as FANUC's J2/J3).
    """
    home = problem.robot.home_deg
    if home is None:
        return np.asarray(q_first, dtype=float).copy()
    if len(home) != robot.nq:
        raise InputError(f"robot.home_deg has {len(home)} values; {robot.spec.name!r} has {robot.nq} joints")
    return np.radians(robot.spec.from_controller(np.asarray(home, dtype=float)))


def wrist_axis(robot: Any) -> int:
    """0-based index of the wrist axis whose zero is the wrist singularity (5th of 6, 6th of 7)."""
    if robot.nq == 6:
        return 4
    if robot.nq == 7:
        return 5
    raise InputError(f"wrist singularity: no rule for {robot.spec.name!r} with {robot.nq} joints")


def singular_runs(robot: Any, q: Array, threshold_deg: float = WRIST_SINGULAR_DEG) -> list[tuple[int, int]]:
    """First and last waypoint (inclusive) of each run near the wrist singularity.

    Args:
        robot: the :class:`refine.robot.model.Robot`.
        q: joints [rad], shape (N, n).
        threshold_deg: how close to 0 or ±180 deg the wrist axis must come [deg].
    """
    w = np.asarray(q, dtype=float)[:, wrist_axis(robot)]
    return [(int(a), int(b)) for a, b in runs(np.abs(np.sin(w)) < math.sin(math.radians(threshold_deg)))]


def lead_point(along: Array, lead: float) -> tuple[int, float]:
    """Where a switch ``lead`` before the path's end falls.

    Args:
        along: time [s] or arc length [m] at each waypoint, shape (N,).
        lead: how long or how far before the last waypoint, in the unit of ``along``.

    Returns:
        the waypoint k whose move (from k-1 to k) holds the switching point, and the lead from
        waypoint k to it.
    """
    to_end = along[-1] - along
    k = int(np.flatnonzero(to_end <= lead + 1e-12)[0])
    if k == 0:
        raise InputError(f"process lead {lead:g} is longer than the path ({to_end[0]:g})")
    return k, lead - float(to_end[k])


def header_notes(p: ProgramPass, robot: Any) -> list[str]:
    """Comment lines (without the comment marker) on what a pass's program differs in, and why."""
    lines, name = [], comment_text(p.name)
    for r in p.repairs:
        objs = f" ({comment_text(', '.join(r.objects))})" if getattr(r, "objects", ()) else ""
        lines.append(
            f"REPAIRED {name}: waypoints {r.index_start}-{r.index_end} "
            f"(s = {r.s_start_m * 1e3:.1f}-{r.s_end_m * 1e3:.1f} mm): {r.slack_deg:.2f} deg extra "
            f"orientation slack, cause: {r.reason}{objs}"
        )
    axis = wrist_axis(robot) + 1
    for a, b in singular_runs(robot, p.trajectory.q):
        w = np.degrees(p.trajectory.q[a : b + 1, axis - 1])
        lines.append(
            f"NEAR WRIST SINGULARITY {name}: waypoints {a}-{b}, axis {axis} at "
            f"{w.min():.1f}..{w.max():.1f} deg (within {WRIST_SINGULAR_DEG:g} deg of 0 or 180)"
        )
    return lines


def process_summary(problem: Problem, mechanism: str, out: str, gas: str = "", ok: str = "") -> str:
    """One comment line on how a program switches the process (``out``/``gas``/``ok``: the I/O as named there)."""
    pr = problem.process
    if pr.kind == "weld":
        text = (
            f"weld: gas {gas} pre-flow {pr.preflow_s:g} s, arc {out}, wait for {ok} up to {pr.arc_timeout_s:g} s "
            f"(else arc and gas off, stop), crater fill {pr.crater_fill_s:g} s, post-flow {pr.postflow_s:g} s"
        )
    else:
        how = f"{pr.lead_s:g} s" if pr.lead_m is None else f"{pr.lead_m * 1000.0:g} mm"
        text = f"{pr.kind}: {out} switched on the move by {mechanism}, {how} before the first and the last path point"
    return comment_text(text)


def speed_levels(
    speeds_m_s: Array, lengths_m: Array, count: int, resolution_m_s: float = 1e-3
) -> tuple[Array, Array]:
    """At most ``count`` speed levels for segments, adding the least time.

    Each segment runs at the fastest level not above its planned speed (rounded down to
    ``resolution_m_s``), so no segment runs faster than planned.

    Args:
        speeds_m_s: planned speed of each segment [m/s], shape (M,).
        lengths_m: length of each segment [m], shape (M,).
        count: largest number of levels.
        resolution_m_s: levels are multiples of this [m/s].

    Returns:
        the levels [m/s], ascending, shape (K,) with K <= count; and each segment's level index,
        shape (M,).
    """
    v = np.maximum(np.floor(np.asarray(speeds_m_s, dtype=float) / resolution_m_s), 1.0) * resolution_m_s
    length = np.asarray(lengths_m, dtype=float)
    if count < 1:
        raise InputError(f"speed_levels: count must be >= 1, got {count}")
    cand, inverse = np.unique(v, return_inverse=True)
    w = np.bincount(inverse, weights=length, minlength=len(cand))  # length at each distinct speed
    m = len(cand)
    k_max = min(count, m)
    # cost[i, j]: time of the candidates i..j-1 all run at level cand[i]
    cum_w = np.concatenate([[0.0], np.cumsum(w)])
    best = np.full((k_max + 1, m + 1), np.inf)
    choice = np.zeros((k_max + 1, m + 1), dtype=int)
    # best[k, j]: least time of candidates j..m-1 with k levels, the first level at cand[j]
    best[0, m] = 0.0
    # here[j, i]: the level at cand[j] covers j..i-1 (i > j); the next level starts at i (none when i == m)
    j_all, i_all = np.arange(m)[:, None], np.arange(m + 1)[None, :]
    here = np.where(i_all > j_all, (cum_w[i_all] - cum_w[j_all]) / cand[:, None], np.inf)
    for k in range(1, k_max + 1):
        total = here + best[k - 1]  # every j at once; best[k - 1] depends on the previous k only
        pick = np.argmin(total, axis=1)  # the first i of the least time, as a scan of i upwards finds
        best[k, :m] = total[np.arange(m), pick]
        choice[k, :m] = np.where(np.isinf(best[k, :m]), np.arange(1, m + 1), pick)  # none: the first i
    k = int(np.argmin(best[1:, 0])) + 1
    levels, j = [], 0
    while j < m:
        levels.append(cand[j])
        j, k = choice[k, j], k - 1
    levels_arr = np.array(levels)
    index = np.searchsorted(levels_arr, v, side="right") - 1
    return levels_arr, index


Wait = Callable[[float, str], str]
"""A dialect's pause: ``wait(seconds, comment)`` is one program line (``comment`` may be empty)."""
Switch = Callable[[str, bool, str], str]
"""A dialect's digital output: ``switch(role, on, comment)``, ``role`` ``"out"`` (arc) or ``"gas"``."""


def weld_start(problem: Problem, wait: Wait, switch: Switch, arc_wait: list[str]) -> list[str]:
    """The arc start: gas on, pre-flow, arc on, then ``arc_wait``.

    ``arc_wait`` is the dialect's wait for the arc-ok input; it switches off with :func:`arc_abort`
    and stops the program when the arc does not come within ``process.arc_timeout_s``.
    """
    return [
        switch("gas", True, "gas pre-flow"),
        wait(problem.process.preflow_s, ""),
        switch("out", True, "arc on"),
        *arc_wait,
    ]


def arc_abort(switch: Switch, indent: str) -> list[str]:
    """What a failed arc start switches off before the program stops: the arc, then the gas."""
    return [indent + switch("out", False, ""), indent + switch("gas", False, "")]


def weld_end(problem: Problem, wait: Wait, switch: Switch) -> list[str]:
    """The arc end: crater fill, arc off, gas post-flow, gas off."""
    pr = problem.process
    return [
        wait(pr.crater_fill_s, "crater fill"),
        switch("out", False, "arc off"),
        wait(pr.postflow_s, "gas post-flow"),
        switch("gas", False, ""),
    ]


def controller_base(robot: Any) -> Array:
    """``T_root_controller`` (4, 4) [m]: the controller's position frame in the URDF's root link.

    The frame is ``spec.controller_frame`` (ROS-Industrial's ``base``), which must be fixed to the
    root; the identity when the robot names none.
    """
    name = getattr(robot.spec, "controller_frame", "")
    if not name:
        return np.eye(4)
    fid = robot.frame_id(name)
    if robot.model.frames[fid].parentJoint != 0:
        raise InputError(
            f"robot {robot.spec.name!r}: controller_frame {name!r} moves with a joint; it must be fixed to the base"
        )
    return robot.frame_pose(np.zeros(robot.nq), name)


def arm_configuration(robot: Any, q: Array) -> tuple[Array, Array]:
    """Which side of axis 1 the wrist is on and where the elbow is, for joint vectors ``q`` [rad] (N, 6).

    The geometry comes from the model (link frames parallel to the base at zero, as in ``robots/``):
    the wrist centre is the origin of joint 5, the shoulder of joint 2, the elbow of joint 3; the
    frame of joint 1 turns with axis 1 and the arm points along its x axis at zero.

    Returns:
        ``behind`` (N,) bool: the wrist centre has a negative x in the frame of joint 1 (behind
        axis 1); ``elbow_up`` (N,) bool: the elbow lies above the line from the shoulder to the
        wrist centre, "above" along the axis of joint 1's frame z (up for a floor-mounted arm).
    """
    qs = np.atleast_2d(np.asarray(q, dtype=float))
    if qs.shape[1] != 6 or robot.nq != 6:
        raise InputError(
            f"arm configuration needs a six-axis robot, got {robot.spec.name!r} with q {qs.shape}"
        )
    import pinocchio as pin

    behind = np.zeros(len(qs), dtype=bool)
    elbow_up = np.zeros(len(qs), dtype=bool)
    for k, qk in enumerate(qs):
        pin.forwardKinematics(robot.model, robot.data, qk)
        a1 = robot.data.oMi[1]
        p2, p3, wrist = (robot.data.oMi[i].translation for i in (2, 3, 5))
        behind[k] = float((a1.rotation.T @ (wrist - a1.translation))[0]) < 0.0
        line = (wrist - p2) / max(float(np.linalg.norm(wrist - p2)), 1e-12)
        up = a1.rotation[:, 2] - float(np.dot(a1.rotation[:, 2], line)) * line
        elbow_up[k] = float(np.dot(p3 - p2, up)) > 0.0
    return behind, elbow_up
