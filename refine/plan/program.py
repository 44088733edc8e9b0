"""The whole program as a sequence of verified motions.

:func:`plan_program` builds every motion a robot program makes, in the order it makes them::

    home -> approach 1 -> pass 1 -> retract 1 -> link -> approach 2 -> pass 2 -> ... -> retract n -> return

``home`` and ``link`` and ``return`` are air moves (:func:`refine.plan.air.plan_air`), ``approach``
and ``retract`` straight TCP lines of :data:`refine.plan.motion.RETRACT_M` along the tool z axis
(:func:`refine.plan.line.plan_line`), each pass the refined path as it was verified. The program
writers write these motions (their via points and approach joints), so what was verified is what
is written.

A program planned again (``previous``: the motions of an earlier run, after a small change such
as the part moved a few millimetres) plans each motion from the earlier one of the same kind and
name (a line's IK from its joints, :func:`refine.plan.line.plan_line`; an air move planned around
the cell tries its via points again, :func:`refine.plan.air.plan_air`), and verifies each as fully
as a motion planned afresh.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from refine.plan.air import TIME_LIMIT_S, plan_air
from refine.plan.line import plan_line
from refine.plan.motion import RETRACT_M, Motion
from refine.plan.verify import MotionChecker
from refine.types import Array


@dataclass(frozen=True)
class PlannedPass:
    """A refined pass as the motion plan needs it.

    Attributes:
        name: the pass's name.
        q: its joints per waypoint [rad], shape (N, n).
        poses: its TCP poses per waypoint, world frame, shape (N, 4, 4) (the first and last are used).
        duration_s: its timed duration [s].
        clearance: its dense clearance check (``PathClearance`` of ``q``), or None.
        min_joint_margin_rad: least joint margin along it [rad].
        min_singularity: least scaled manipulability along it [-].
    """

    name: str
    q: Array
    poses: Array
    duration_s: float
    clearance: Any = None
    min_joint_margin_rad: float = float("inf")
    min_singularity: float | None = None


def plan_program(
    checker: MotionChecker,
    passes: list[PlannedPass],
    home: Array | None,
    *,
    velocity: Array,
    acceleration: Array,
    retract_m: float = RETRACT_M,
    time_limit_s: float = TIME_LIMIT_S,
    previous: Sequence[Motion] = (),
) -> tuple[Motion, ...]:
    """Every motion of the program, each verified (see the module notes).

    Args:
        checker: limits, collision model with the margins, tolerances.
        passes: the refined passes in program order (at least one).
        home: the home joints [rad] (n,); None to start and end at the first pass's first waypoint.
        velocity: joint speed limits of the air moves [rad/s], shape (n,).
        acceleration: joint acceleration limits of the air moves [rad/s^2], shape (n,).
        retract_m: approach and retract distance along the tool z axis [m].
        time_limit_s: wall time of one planner attempt per air move [s].
        previous: the motions of an earlier run of the same robot to plan from (module notes),
            matched by kind and name; () to plan afresh.
    """
    q_home = np.asarray(passes[0].q[0] if home is None else home, dtype=float)
    air = {"velocity": velocity, "acceleration": acceleration, "time_limit_s": time_limit_s}
    earlier = {(m.kind, m.name): m for m in previous}
    motions: list[Motion] = []
    here, where = q_home, "home"
    for k, p in enumerate(passes):
        name = f"approach {p.name}"
        approach = plan_line(
            checker,
            "approach",
            name,
            p.q[0],
            p.poses[0],
            retract_m=retract_m,
            previous=earlier.get(("approach", name)),
        )
        kind, name = ("home" if k == 0 else "link"), f"{where} -> {p.name}"
        motions.append(
            plan_air(checker, kind, name, here, approach.q[0], previous=earlier.get((kind, name)), **air)
        )
        motions.append(approach)
        motions.append(_path_motion(p))
        name = f"retract {p.name}"
        retract = plan_line(
            checker,
            "retract",
            name,
            p.q[-1],
            p.poses[-1],
            retract_m=retract_m,
            previous=earlier.get(("retract", name)),
        )
        motions.append(retract)
        here, where = retract.q[-1], p.name
    name = f"{where} -> home"
    motions.append(
        plan_air(checker, "return", name, here, q_home, previous=earlier.get(("return", name)), **air)
    )
    return tuple(motions)


def _path_motion(p: PlannedPass) -> Motion:
    c = p.clearance
    closest: tuple[str, str] = ("", "")
    if c is not None and len(c.segment_clearance_m):
        closest = tuple(c.segment_pair[int(np.argmin(c.segment_clearance_m))])  # type: ignore[assignment]
    return Motion(
        kind="path",
        name=p.name,
        q=np.asarray(p.q, dtype=float),
        start_pose=p.poses[0],
        end_pose=p.poses[-1],
        duration_s=float(p.duration_s),
        planner="refinement",
        planner_time_s=0.0,
        status="ok",
        min_distance_m=None if c is None else c.min_distance_m,
        min_clearance_m=None if c is None else c.min_clearance_m,
        closest=closest,
        min_joint_margin_rad=p.min_joint_margin_rad,
        min_singularity=p.min_singularity,
    )
