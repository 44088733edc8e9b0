"""What a program makes the controller do along a pass: the blend zone of every target and every segment's speed.

Each writer decides its zones and speeds here (:func:`program_motion`), and ``result.json`` and
the report state the same figures, so what is reported is what is written:

* **Zones.** The zones of the path targets (:func:`refine.export.program.corner_zones`), with the
  approach and retract points as the first target's and the last target's neighbours: RAPID's
  zone (``z1`` by default), a smaller predefined zone (``z0``) or ``fine``; KRL's ``C_DIS`` with
  ``$APO.CDIS`` or an exact stop; URScript's blend radius ``r``, made as small as the tolerance
  needs; Sunrise's spline passes through every target (no zone) and blends only the approach into
  it, by ``setBlendingCart(1.0)`` (1 mm, not narrowed: its deviation is reported as it is); FANUC
  TP's ``CNT<n>`` (:func:`tp_zones`, a model of the corner distance at the programmed speed) made
  smaller, or ``FINE``, to keep the tolerance; Yaskawa INFORM's ``PL=<n>`` or ``PL=0``
  (:func:`inform_zones`). A weld's first and last targets are exact stops in every format.
* **Speeds.** The programmed speed of every segment: RAPID's ``speeddata`` levels
  (:func:`refine.export.program.speed_levels`, with ``[output] speed_share``), the rounded
  ``$VEL.CP``, ``v`` and ``setCartVelocity`` of KRL, URScript and Sunrise; TP's and INFORM's levels
  as RAPID's (TP in whole mm/sec where such levels keep the share, else in whole cm/min, else in
  tenths of an inch/min; INFORM ``V`` in 0.1 mm/s).
"""

from __future__ import annotations

import inspect
import math
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from refine.errors import InputError
from refine.export.program import (
    RAPID_ZONES_M,
    ZONE_SEGMENT_SHARE,
    Zones,
    corner_deviation,
    corner_zones,
    speed_levels,
)
from refine.paths import Trajectory
from refine.problem import Problem
from refine.types import Array

MOTION_FORMATS = ("rapid", "krl", "urscript", "sunrise", "tp", "inform")
"""The program formats whose zones and speeds :func:`program_motion` knows."""

SUNRISE_APPROACH_BLEND_M = 0.001
"""The Sunrise writer's blend of the approach move into the spline (``setBlendingCart``) [m]."""

TP_DECEL_TIME_S = 0.5
"""The time a FANUC arm is modelled to take to stop from the programmed speed [s]: the registry's
acceleration rule for industrial arms (each joint reaches full speed from rest in 0.5 s,
``refine.robot.importer.ACCELERATION_RULE``); FANUC publishes no such figure for the M-20iA."""
TP_MM_S = 1e-3
"""One mm/sec [m/s], the unit TP speeds are written in when whole numbers of it keep the share."""
TP_CM_MIN = 1.0 / 6000.0
"""One cm/min [m/s], the finer TP speed unit used where whole mm/sec would not keep the share."""
TP_TENTH_INCH_MIN = 0.1 * 0.0254 / 60.0
"""0.1 inch/min [m/s] (about 0.042 mm/s), the finest TP linear speed (``16.0inch/min``), used where
whole cm/min would not keep the share either (slow welds)."""
INFORM_PL_RADIUS_M = float("inf")
"""The radius modelled for ``PL=n`` (n >= 1) [m]: the controller's positioning zone parameters
(S1CxG033..S1CxG040) are not at hand, so no bound on them is assumed; the zone is then as large as
the controller lets it be, half the shorter neighbouring move (:data:`ZONE_SEGMENT_SHARE`)."""


def tp_zones(
    points: Array,
    speeds_m_s: Array,
    tolerance_m: float,
    cnt: int,
    ends: tuple[bool, bool],
    decel_time_s: float = TP_DECEL_TIME_S,
    segment_share: float = 0.5,
) -> Zones:
    """The ``CNT`` of every path target: the largest ``n <= cnt`` whose corner keeps ``tolerance_m``, else ``FINE``.

    The model of ``CNT n`` (FANUC: the number is how much of the deceleration into the target is
    overlapped by the next move; 100 keeps the speed through the corner): the corner path starts
    ``d(n) = (n / 100) · v · T / 2`` before the target, where ``v · T / 2`` is what a move at speed
    ``v`` covers while it stops in ``T`` = ``decel_time_s`` (a linear ramp), ``v`` the faster of
    the two moves, and ``d`` at most ``segment_share`` of either move. Overlapping the last share
    ``n / 100`` of the deceleration covers ``(n / 100)^2 · v · T / 2``; ``d(n)`` bounds that. With the
    two moves' profiles alike, the corner path is a weighted mean of the two corner points and the
    target (:func:`refine.export.program.corner_deviation`): it deviates at most ``d · sin(θ/2)``.

    Args:
        points: the approach point, the N targets and the retract point [m], (N + 2, 3).
        speeds_m_s: the programmed speed of the N + 1 moves between them [m/s].
        tolerance_m: ``[process] path_tolerance_m`` [m].
        cnt: the program's ``CNT`` (1..100).
        ends: whether the first and the last target are blended.
        decel_time_s: ``T`` [s].
        segment_share: the largest share of a neighbouring move the corner may take.
    """
    n_targets = len(points) - 2
    radius, deviation, labels, narrowed = np.zeros(n_targets), np.zeros(n_targets), [], []
    for k in range(n_targets):
        if (k == 0 and not ends[0]) or (k == n_targets - 1 and not ends[1]):
            labels.append("FINE")
            continue
        before, corner, after = points[k], points[k + 1], points[k + 2]
        full = max(speeds_m_s[k], speeds_m_s[k + 1]) * decel_time_s / 2.0  # d(100) [m]
        n = cnt
        r, dev = corner_deviation(before, corner, after, full * n / 100.0, segment_share)
        if dev > tolerance_m:  # d(n) is linear in n below the segment cap, which this breach is below
            n = int(np.floor(100.0 * tolerance_m / (dev / r * full)))
            r, dev = corner_deviation(before, corner, after, full * n / 100.0, segment_share)
        if n < 1:
            r, dev, label = 0.0, 0.0, "FINE"
        else:
            label = f"CNT{n}"
        if n != cnt:
            narrowed.append(k)
        labels.append(label)
        radius[k], deviation[k] = r, dev
    return Zones(radius, deviation, tuple(labels), tolerance_m, tuple(narrowed))


def _tp_levels(planned: Array, lengths: Array, count: int, share: float) -> Array:
    """Each segment's TP speed [m/s]: levels in the coarsest unit that keeps ``share``.

    Whole mm/sec, else whole cm/min, else tenths of an inch/min (the finest).
    """
    steps = (TP_MM_S, TP_CM_MIN, TP_TENTH_INCH_MIN)
    for step in steps:
        levels, level_of = speed_levels(planned, lengths, count, step, share=share)
        programmed = levels[level_of]
        if step == steps[-1] or np.all(programmed >= (1.0 - share) * planned * (1.0 - 1e-12)):
            return programmed
    raise AssertionError("unreachable")


def segment_speeds(trajectory: Trajectory) -> Array:
    """Planned speed of each segment k -> k+1 [m/s], shape (N-1,): mean of its end speeds."""
    return 0.5 * (trajectory.speed[:-1] + trajectory.speed[1:])


@dataclass(frozen=True)
class ProgramMotion:
    """The zones and speeds a program writes for one pass.

    Attributes:
        kind: the program format, one of :data:`MOTION_FORMATS`.
        zones: the zone of every target and the deviation it allows.
        planned_m_s: the planned speed of every segment [m/s], (N-1,).
        programmed_m_s: the speed the program writes for it [m/s], (N-1,).
        lengths_m: every segment's length [m], (N-1,).
        share: ``[output] speed_share``, the shortfall below the planned speed a segment may have [-].
        levels: the program's distinct speeds for the path (RAPID's ``speeddata``) [m/s].
    """

    kind: str
    zones: Zones
    planned_m_s: Array
    programmed_m_s: Array
    lengths_m: Array
    share: float
    levels: Array

    @property
    def difference_rel(self) -> Array:
        """Each segment's programmed speed less its planned speed, as a share of the planned [-], (N-1,)."""
        return (self.programmed_m_s - self.planned_m_s) / self.planned_m_s

    @property
    def beyond_share(self) -> list[int]:
        """The segments that run slower than the planned speed by more than ``share``."""
        return np.flatnonzero(-self.difference_rel > self.share * (1.0 + 1e-9)).tolist()

    @property
    def extra_time_s(self) -> float:
        """The time the programmed speeds add to the planned path [s]."""
        return float(np.sum(self.lengths_m / self.programmed_m_s) - np.sum(self.lengths_m / self.planned_m_s))

    def as_json(self) -> dict:
        """The figures ``result.json`` writes (``passes[i].programs.<kind>``)."""
        diff = self.difference_rel
        return {
            "zones": list(self.zones.label),
            "zone_radius_m": self.zones.radius_m.tolist(),
            "zone_deviation_m": self.zones.deviation_m.tolist(),
            "path_tolerance_m": self.zones.tolerance_m,
            "largest_zone_deviation_m": self.zones.largest_deviation_m,
            "narrowed_zones": len(self.zones.narrowed),
            "speed_share": self.share,
            "speed_levels": len(self.levels),
            "speed_difference_rel": diff.tolist(),
            "largest_speed_shortfall_rel": float(max(0.0, -diff.min(initial=0.0))),
            "segments_beyond_share": len(self.beyond_share),
            "segments_below_plan": int(np.count_nonzero(diff < -1e-9)),
            "extra_time_s": self.extra_time_s,
        }


def _rounded(speeds: Array, step: float) -> Array:
    return np.maximum(np.round(speeds / step), 1.0) * step


def zone_points(trajectory: Trajectory, retract_m: float) -> Array:
    """The approach point, the targets and the retract point [m], (N + 2, 3): ``retract_m`` behind the ends along tool z."""
    poses = trajectory.poses
    back = np.array([0.0, 0.0, -retract_m])
    return np.vstack(
        [
            poses[0, :3, :3] @ back + poses[0, :3, 3],
            poses[:, :3, 3],
            poses[-1, :3, :3] @ back + poses[-1, :3, 3],
        ]
    )


_RECENT: list[tuple[str, Trajectory, Problem, tuple, ProgramMotion]] = []
"""The last few answers of :func:`program_motion`, with the objects they were computed for."""
_RECENT_LOCK = threading.Lock()
RECENT_MOTIONS = 8
"""Answers :func:`program_motion` keeps: the writers and ``result.json`` (twice: the file and the
report) ask for the same pass's motion, which is computed once."""


def program_motion(kind: str, trajectory: Trajectory, problem: Problem, **options: Any) -> ProgramMotion:
    """The zones and speeds program ``kind`` writes for ``trajectory`` (:func:`compute_program_motion`).

    The answer for the same trajectory and problem objects and options is the one computed
    before (the last :data:`RECENT_MOTIONS` kept), its arrays read-only.
    """
    bound = inspect.signature(compute_program_motion).bind(kind, trajectory, problem, **options)
    bound.apply_defaults()  # an option given as its default is the same answer
    key = tuple(sorted((k, v) for k, v in bound.arguments.items() if k not in ("kind", "trajectory", "problem")))
    with _RECENT_LOCK:
        for k, tr, pr, opts, motion in _RECENT:
            if k == kind and tr is trajectory and pr is problem and opts == key:
                return motion
    motion = compute_program_motion(kind, trajectory, problem, **options)
    zones = motion.zones
    for array in (zones.radius_m, zones.deviation_m, motion.planned_m_s, motion.programmed_m_s, motion.lengths_m):
        array.flags.writeable = False
    motion.levels.flags.writeable = False
    with _RECENT_LOCK:
        _RECENT.append((kind, trajectory, problem, key, motion))
        del _RECENT[:-RECENT_MOTIONS]
    return motion


def compute_program_motion(
    kind: str,
    trajectory: Trajectory,
    problem: Problem,
    *,
    zone: str = "z1",
    approximation_m: float = 0.001,
    blend_m: float = 0.001,
    retract_m: float = 0.1,
    speed_resolution_m_s: float = 1e-4,
    cnt: int = 100,
    approach_m_s: float = 0.25,
    decel_time_s: float = TP_DECEL_TIME_S,
    pl: int = 1,
) -> ProgramMotion:
    """The zones and speeds program ``kind`` writes for ``trajectory`` (the writers' defaults as theirs).

    Args:
        kind: one of :data:`MOTION_FORMATS`.
        trajectory: the pass's timed path.
        problem: ``[process]`` (kind, ``path_tolerance_m``) and ``[output]`` (``speed_levels``,
            ``speed_share``).
        zone: RAPID's zone between path targets (``"z0"``, ``"z1"``, ...).
        approximation_m: KRL's ``$APO.CDIS`` [m].
        blend_m: URScript's blend radius [m].
        retract_m: approach and retract distance along the tool z axis [m].
        speed_resolution_m_s: speeds are multiples of this [m/s] (not TP: whole mm/sec or cm/min).
        cnt: TP's largest ``CNT`` (1..100).
        approach_m_s: TP's speed onto the first and off the last target [m/s].
        decel_time_s: TP's modelled stopping time (:func:`tp_zones`) [s].
        pl: INFORM's position level of the path moves (0..8).
    """
    weld = problem.process.kind == "weld"
    tolerance = float(problem.process.path_tolerance_m or 0.0)
    points = zone_points(trajectory, retract_m)
    ends = (not weld, not weld)
    share = problem.output.speed_share
    planned = segment_speeds(trajectory)
    lengths = np.linalg.norm(np.diff(trajectory.poses[:, :3, 3], axis=0), axis=1)
    segment_share = ZONE_SEGMENT_SHARE.get(kind, 0.5)
    if kind == "rapid":
        if zone not in RAPID_ZONES_M:
            raise InputError(f"RAPID zone must be one of {', '.join(RAPID_ZONES_M)}, got {zone!r}")
        top = RAPID_ZONES_M[zone]
        choices = [(name, r) for name, r in sorted(RAPID_ZONES_M.items(), key=lambda kv: -kv[1]) if r <= top]
        zones = corner_zones(points, choices, tolerance, segment_share, ("fine", 0.0), ends)
        levels, level_of = speed_levels(
            planned, lengths, problem.output.speed_levels, speed_resolution_m_s, share=share
        )
        programmed = levels[level_of]
    elif kind in ("krl", "urscript", "sunrise"):
        if kind == "krl":
            zones = corner_zones(
                points, [("C_DIS", approximation_m)], tolerance, segment_share, ("exact", 0.0), ends
            )
        elif kind == "urscript":
            zones = corner_zones(
                points, [("r", blend_m)], tolerance, segment_share, ("r=0", 0.0), ends, continuous=True
            )
            label = tuple(f"r={r:.6g}" for r in zones.radius_m)
            zones = Zones(zones.radius_m, zones.deviation_m, label, zones.tolerance_m, zones.narrowed)
        else:  # the spline passes through every target; only the approach blends into it, by 1 mm always
            n = len(trajectory)
            radius, deviation = np.zeros(n), np.zeros(n)
            label = ["spline"] * n
            if not weld:
                radius[0], deviation[0] = corner_deviation(
                    points[0], points[1], points[2], SUNRISE_APPROACH_BLEND_M, segment_share
                )
                label[0] = f"blend {SUNRISE_APPROACH_BLEND_M * 1e3:g} mm"
            zones = Zones(radius, deviation, tuple(label), tolerance, ())
        programmed = _rounded(planned, speed_resolution_m_s)
        levels = np.unique(programmed)
    elif kind == "tp":
        if not 1 <= cnt <= 100:
            raise InputError(f"TP: cnt must be 1..100, got {cnt}")
        programmed = _tp_levels(planned, lengths, problem.output.speed_levels, share)
        moves = np.concatenate([[approach_m_s], programmed, [approach_m_s]])
        zones = tp_zones(points, moves, tolerance, cnt, ends, decel_time_s, segment_share)
        levels = np.unique(programmed)
    elif kind == "inform":
        if not 0 <= pl <= 8:
            raise InputError(f"INFORM: pl must be 0..8, got {pl}")
        if pl == 0:
            n = len(trajectory)
            zones = Zones(np.zeros(n), np.zeros(n), ("PL=0",) * n, tolerance, ())
        else:
            choices = [(f"PL={pl}", INFORM_PL_RADIUS_M)]
            zones = corner_zones(points, choices, tolerance, segment_share, ("PL=0", 0.0), ends)
        levels, level_of = speed_levels(
            planned, lengths, problem.output.speed_levels, max(speed_resolution_m_s, 1e-4), share=share
        )
        programmed = levels[level_of]
    else:
        raise InputError(f"program_motion: no zone and speed rules for program format {kind!r}")
    if kind != "sunrise":  # a circular move runs its segments at one speed (RAPID: its own speeddata)
        programmed = programmed.copy()
        for arc in getattr(trajectory, "arcs", ()):
            steps = max(math.floor(arc.speed_m_s / speed_resolution_m_s + 1e-9), 1)
            programmed[arc.start : arc.end] = steps * speed_resolution_m_s
    return ProgramMotion(kind, zones, planned, programmed, lengths, share, levels)
