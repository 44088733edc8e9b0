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
  distinct rounded speeds) to add the least time to the path; with a ``share``, as many more
  levels as it takes for every segment to run within that share of its planned speed.
* :func:`corner_zones`: the blend zone of every path target and the largest deviation from the
  programmed path it allows (:func:`corner_deviation`), the zone made smaller or an exact stop
  where the deviation would exceed ``[process] path_tolerance_m``.
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

        air_in_s, air_out_s: the time [s] of each joint move of ``air_in`` and ``air_out`` (one per
            row) at ``[output] air_speed_share`` (:func:`refine.plan.motion.air_limits`); None
            without planned motions.
    """

    name: str
    trajectory: Trajectory
    repairs: tuple[Any, ...] = ()
    air_in: Array | None = None
    air_out: Array | None = None
    air_in_s: tuple[float, ...] | None = None
    air_out_s: tuple[float, ...] | None = None


def fixed_decimals(value: float, decimals: int) -> str:
    """``value`` with exactly ``decimals`` decimals, a rounded-off negative zero written as zero."""
    text = f"{value:.{decimals}f}"
    return f"{0.0:.{decimals}f}" if float(text) == 0.0 else text


def with_motions(passes: list[ProgramPass], motions: tuple[Any, ...]) -> list[ProgramPass]:
    """The passes with the run's planned air moves (``refine.plan.motion.Motion``) to write.

    The air move into pass i is the i-th ``home``/``link`` motion, the return the ``return``
    motion; without motions (or when their count does not match) the passes are returned as given.
    """
    into = [m for m in motions if m.kind in ("home", "link")]
    back = [m for m in motions if m.kind == "return"]
    if len(into) != len(passes) or len(back) != 1:
        return passes
    out = [
        replace(p, air_in=np.asarray(m.q[1:], dtype=float), air_in_s=tuple(m.move_s) or None)
        for p, m in zip(passes, into, strict=True)
    ]
    out[-1] = replace(out[-1], air_out=np.asarray(back[0].q[1:], dtype=float), air_out_s=tuple(back[0].move_s) or None)
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
    speeds_m_s: Array,
    lengths_m: Array,
    count: int,
    resolution_m_s: float = 1e-3,
    share: float | None = None,
) -> tuple[Array, Array]:
    """At most ``count`` speed levels for segments, adding the least time (more where ``share`` needs them).

    Each segment runs at the fastest level not above its planned speed (rounded down to
    ``resolution_m_s``), so no segment runs faster than planned. With ``share``, no segment may
    run slower than ``(1 - share)`` times its planned speed: the levels are then the fewest that
    allow it when ``count`` does not (the least number by covering the sorted speeds from the
    slowest up), chosen for the least added time among those that keep every segment within it.
    A segment the resolution cannot keep within the share (its planned speed rounded down falls
    below it) gets that rounded speed as a level of its own.

    Args:
        speeds_m_s: planned speed of each segment [m/s], shape (M,).
        lengths_m: length of each segment [m], shape (M,).
        count: largest number of levels (raised when ``share`` needs more).
        resolution_m_s: levels are multiples of this [m/s].
        share: largest shortfall of a segment's level below its planned speed, as a share of it
            [-] in (0, 1); None for no such bound.

    Returns:
        the levels [m/s], ascending, shape (K,); and each segment's level index, shape (M,).
    """
    planned = np.asarray(speeds_m_s, dtype=float)
    v = np.maximum(np.floor(planned / resolution_m_s), 1.0) * resolution_m_s
    length = np.asarray(lengths_m, dtype=float)
    if count < 1:
        raise InputError(f"speed_levels: count must be >= 1, got {count}")
    if share is not None and not 0.0 < share < 1.0:
        raise InputError(f"speed_levels: share must be in (0, 1), got {share}")
    cand, inverse = np.unique(v, return_inverse=True)
    w = np.bincount(inverse, weights=length, minlength=len(cand))  # length at each distinct speed
    m = len(cand)
    fastest = np.zeros(m)  # the fastest planned speed of each candidate's segments
    np.maximum.at(fastest, inverse, planned)
    k_max = min(count, m)
    if share is not None:
        need, j = 0, 0
        while j < m:  # a level at cand[j] serves every candidate whose segments it keeps within the share
            need += 1
            # (at least itself: a candidate rounded below its own segments' share serves them alone)
            j = max(j + 1, int(np.searchsorted(fastest * (1.0 - share), cand[j], side="right")))
        k_max = max(k_max, need)
    # cost[i, j]: time of the candidates i..j-1 all run at level cand[i]
    cum_w = np.concatenate([[0.0], np.cumsum(w)])
    best = np.full((k_max + 1, m + 1), np.inf)
    choice = np.zeros((k_max + 1, m + 1), dtype=int)
    # best[k, j]: least time of candidates j..m-1 with k levels, the first level at cand[j]
    best[0, m] = 0.0
    # here[j, i]: the level at cand[j] covers j..i-1 (i > j); the next level starts at i (none when i == m)
    j_all, i_all = np.arange(m)[:, None], np.arange(m + 1)[None, :]
    here = np.where(i_all > j_all, (cum_w[i_all] - cum_w[j_all]) / cand[:, None], np.inf)
    if (
        share is not None
    ):  # the level at cand[j] must keep the fastest segment of cand[i - 1] within the share
        slowest_kept = np.concatenate([[0.0], fastest * (1.0 - share)])[i_all]
        kept = (slowest_kept <= cand[:, None] * (1.0 + 1e-12)) | (i_all == j_all + 1)
        here = np.where(kept, here, np.inf)
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


RAPID_ZONES_M = {"z0": 0.0003, "z1": 0.001, "z5": 0.005, "z10": 0.01, "z15": 0.015, "z20": 0.02}
"""``pzone_tcp`` of RAPID's predefined zones [m] (RAPID reference, data type ``zonedata``)."""

ZONE_SEGMENT_SHARE = {"rapid": 0.5, "krl": 0.5, "urscript": 0.4, "sunrise": 0.5, "tp": 0.5, "inform": 0.5}
"""A zone reaches at most this share of each neighbouring segment: ABB and KUKA halve a zone that
is larger than half a move; the URScript writer caps ``r`` at 40 % of the shorter segment; FANUC's
and Yaskawa's corners are modelled as ABB's and KUKA's (neither maker's manual at hand says)."""


def corner_deviation(
    before: Array, corner: Array, after: Array, radius_m: float, segment_share: float
) -> tuple[float, float]:
    """The zone a corner gets and the largest deviation from the programmed path it allows.

    The corner path starts on the incoming move ``r`` before the target and ends on the outgoing
    move ``r`` after it, with ``r = min(radius_m, share * |incoming|, share * |outgoing|)``, and
    lies inside the triangle of those two points and the target (true of a corner path that is a
    weighted mean of them, as the parabolic and Bezier blends of the controllers are). With
    ``theta`` the angle the direction turns through, every point of that triangle is within
    ``r sin(theta/2) cos(theta/2)`` of the two moves, and the path passes within
    ``r sin(theta/2)`` of the target (it crosses the bisector between the target and the chord's
    midpoint); ``r sin(theta/2)`` bounds both.

    Args:
        before: the previous target [m], (3,).
        corner: this target [m], (3,).
        after: the next target [m], (3,).
        radius_m: the zone's radius [m] (0 for an exact stop).
        segment_share: the largest share of a neighbouring move the zone may take.

    Returns:
        the zone's radius as the controller applies it [m] and the deviation bound [m].
    """
    d_in, d_out = np.asarray(corner) - np.asarray(before), np.asarray(after) - np.asarray(corner)
    l_in, l_out = float(np.linalg.norm(d_in)), float(np.linalg.norm(d_out))
    if radius_m <= 0.0 or l_in == 0.0 or l_out == 0.0:
        return 0.0, 0.0
    r = min(radius_m, segment_share * l_in, segment_share * l_out)
    cos_turn = float(np.clip(np.dot(d_in, d_out) / (l_in * l_out), -1.0, 1.0))
    return r, r * math.sqrt(max(0.0, 0.5 * (1.0 - cos_turn)))  # sin(theta/2) = sqrt((1 - cos theta)/2)


@dataclass(frozen=True)
class Zones:
    """The blend zone of every path target of a pass as a program writes it.

    Attributes:
        radius_m: the zone's radius as the controller applies it, per target [m], (N,); 0 for an
            exact stop.
        deviation_m: the largest deviation from the programmed path the zone allows
            (:func:`corner_deviation`), per target [m], (N,).
        label: the zone as the program names it (``"z1"``, ``"fine"``, ``"C_DIS"``, ``"r=0.0008"``).
        tolerance_m: ``[process] path_tolerance_m`` [m].
        narrowed: targets whose zone was made smaller or an exact stop to keep the tolerance.
    """

    radius_m: Array
    deviation_m: Array
    label: tuple[str, ...]
    tolerance_m: float
    narrowed: tuple[int, ...]

    @property
    def largest_deviation_m(self) -> float:
        """The largest deviation any zone of the pass allows [m]."""
        return float(self.deviation_m.max(initial=0.0))


def corner_zones(
    points: Array,
    choices: list[tuple[str, float]],
    tolerance_m: float,
    segment_share: float,
    exact: tuple[str, float] = ("fine", 0.0),
    ends: tuple[bool, bool] = (True, True),
    continuous: bool = False,
) -> Zones:
    """The zone of every target: the first of ``choices`` whose deviation keeps ``tolerance_m``.

    Args:
        points: the approach point, the N path targets and the retract point [m], (N + 2, 3).
        choices: (label, radius [m]) from the largest zone down; the first is the program's zone.
        tolerance_m: largest deviation a zone may allow [m].
        segment_share: the share of a neighbouring move a zone may take (:data:`ZONE_SEGMENT_SHARE`).
        exact: label and radius of an exact stop, used where no choice keeps the tolerance.
        ends: whether the first and the last target are blended (False: they are exact stops).
        continuous: the radius may take any value (URScript ``r``): where the first choice breaks
            the tolerance, the largest radius that keeps it, labelled ``r=<radius>``.

    Returns:
        the zones of the N targets.
    """
    points = np.asarray(points, dtype=float)
    n = len(points) - 2
    radius, deviation, labels, narrowed = np.zeros(n), np.zeros(n), [], []
    for k in range(n):
        if (k == 0 and not ends[0]) or (k == n - 1 and not ends[1]):
            labels.append(exact[0])
            continue
        before, corner, after = points[k], points[k + 1], points[k + 2]
        chosen = None
        for label, r in choices:
            r_eff, dev = corner_deviation(before, corner, after, r, segment_share)
            if dev <= tolerance_m:
                chosen = (label, r_eff, dev)
                break
        if chosen is None and continuous:
            r_eff, dev = corner_deviation(before, corner, after, choices[0][1], segment_share)
            r_eff *= tolerance_m / dev  # the deviation is proportional to the radius
            chosen = (f"r={r_eff:.6g}", r_eff, tolerance_m)
        if chosen is None:
            chosen = (exact[0], exact[1], 0.0)
        if chosen[0] != choices[0][0]:
            narrowed.append(k)
        labels.append(chosen[0])
        radius[k], deviation[k] = chosen[1], chosen[2]
    return Zones(radius, deviation, tuple(labels), tolerance_m, tuple(narrowed))


def circular_pieces(
    tr: Trajectory, *marks: dict[int, str] | int | None
) -> list[Any]:
    """The trajectory's verified circular moves a program writes (``Trajectory.arcs``).

    A piece is left to straight moves where the program switches something on one of its
    segments: a segment number of ``marks`` (the keys of a dict, or an int; None for nothing) in
    ``start + 1 .. end`` (the wrist handling on or off, the process output's switch point).
    """
    taken: set[int] = set()
    for m in marks:
        if isinstance(m, dict):
            taken.update(m)
        elif m is not None:
            taken.add(int(m))
    return [a for a in getattr(tr, "arcs", ()) if not any(a.start < k <= a.end for k in taken)]


def circular_note(count: int, model: str) -> list[str]:
    """Header lines on the ``count`` circular moves a program writes (none when there are none)."""
    if not count:
        return []
    return [f"{count} circular move(s) on the CAD's arcs, checked with the controller's {model} orientation model"]
