"""The constraints that bind at an answer: what holds a repaired segment where it is.

The diagnosis (:mod:`refine.optimise.diagnosis`) measures each cause at the demonstrated
orientation: a joint beyond its limit there, a pair inside its margin there. A segment can need
slack although no single limit is broken at the demonstrated orientation: several constraints
together hold the answer back (a clearance pair at its margin, a joint at its limit, a joint step at
its bound, the manipulability at its margin), and the orientation gives way. Those are read off the
answer itself (:func:`binding_at`): each constraint of the refinement within a small distance of
its bound, at the segment's waypoints, with the bound, the figure and the runs of waypoints where
it is at its bound.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from refine.optimise.verify import runs, singularity_measures
from refine.robot.kinematics import TcpKinematics
from refine.settings import Tolerances
from refine.types import Array

BIND_CLEARANCE_M = 0.001
"""A pair counts as binding within this distance above its margin [m] (the clearance rows ask
for half a millimetre more than the margin, :data:`refine.optimise.clearance.BACK_OFF_M`)."""

BIND_JOINT_RAD = 1e-4
"""A joint, or a joint step, counts as binding within this of its bound [rad] (0.006 deg)."""

BIND_SINGULARITY = 1e-3
"""The scaled manipulability counts as binding below its margin times (1 + this)."""


def binding_at(
    kin: TcpKinematics,
    q: Array,
    a: int,
    b: int,
    tolerances: Tolerances,
    lower: Array,
    upper: Array,
    model: Any = None,
    cell: set[str] | frozenset[str] = frozenset(),
) -> list[dict[str, Any]]:
    """The constraints at their bounds in waypoints ``a``..``b`` of the answer ``q`` (N, n) [rad].

    Args:
        kin: TCP kinematics of the refinement.
        q: the answer's joints (N, n) [rad].
        a: first waypoint of the segment.
        b: last waypoint of the segment (inclusive).
        tolerances: the refinement's tolerances (joint step, singularity margin).
        lower: lower joint bounds (the limits less the margin) [rad] (n,).
        upper: upper joint bounds [rad] (n,).
        model: the collision model (:class:`refine.collision.CollisionModel`), or None.
        cell: the names of the cell's objects (any other body is the robot's or the tool's).

    Returns:
        One entry per binding constraint (pair, joint, or the singularity), the closest to its bound
        in the segment: the fields of a :class:`refine.optimise.diagnosis.Cause` (``cause``,
        ``figure``, ``limit``, ``unit``, ``objects``, ``joint``, ``suggestion``, ``waypoints``: the
        runs (first, last inclusive) of the path's waypoints where it is at its bound; a joint step
        is at its bound over the two waypoints of the step).
    """
    seg = q[a : b + 1]
    out: list[dict[str, Any]] = []

    def waypoints(mask: Array, first: int = a) -> tuple[tuple[int, int], ...]:
        return tuple((first + i, first + j) for i, j in runs(mask))

    if model is not None:
        reach = max(model.margin_m, model.self_margin_m) + BIND_CLEARANCE_M
        pairs: dict[tuple[str, str], Any] = {}
        where: dict[tuple[str, str], Array] = {}
        for i, qk in enumerate(seg):
            for c in model.contacts(qk, reach):
                if c.distance_m < c.margin_m + BIND_CLEARANCE_M:
                    key = (c.body, c.other)
                    where.setdefault(key, np.zeros(len(seg), dtype=bool))[i] = True
                    if key not in pairs or c.distance_m < pairs[key].distance_m:
                        pairs[key] = c
        for (body, other), c in sorted(pairs.items(), key=lambda item: item[1].distance_m):
            own_self = other not in cell
            out.append(
                {
                    "cause": "self-collision" if own_self else "collision",
                    "figure": c.distance_m,
                    "limit": c.margin_m,
                    "unit": "m",
                    "objects": (body, other),
                    "joint": None,
                    "suggestion": (
                        f"{body} and {other} held at {c.distance_m * 1e3:.1f} mm by the "
                        f"{'self' if own_self else 'cell'} margin {c.margin_m * 1e3:g} mm in the answer"
                        + ("" if own_self else f"; more room round {other} frees the orientation")
                    ),
                    "waypoints": waypoints(where[(body, other)]),
                }
            )
    for j in range(q.shape[1]):
        low = float(seg[:, j].min() - lower[j])
        high = float(upper[j] - seg[:, j].max())
        if min(low, high) <= BIND_JOINT_RAD:
            bound = lower[j] if low <= high else upper[j]
            at = np.abs(seg[:, j] - bound) <= BIND_JOINT_RAD
            value = float(seg[:, j].min() if low <= high else seg[:, j].max())
            out.append(
                {
                    "cause": "joint limit",
                    "figure": math.degrees(value),
                    "limit": math.degrees(bound),
                    "unit": "deg",
                    "objects": (),
                    "joint": j + 1,
                    "suggestion": (
                        f"joint {j + 1} held at {math.degrees(bound):.1f} deg (its limit less the "
                        f"{tolerances.joint_margin_deg:g} deg margin) in the answer"
                    ),
                    "waypoints": waypoints(at),
                }
            )
    step = math.radians(tolerances.joint_step_deg)
    lo, hi = max(a - 1, 0), min(b + 1, len(q) - 1)  # the steps into and out of the segment too
    steps = np.abs(np.diff(q[lo : hi + 1], axis=0))
    for j in np.flatnonzero(steps.max(axis=0, initial=0.0) >= step - BIND_JOINT_RAD) if len(steps) else []:
        at = np.zeros(hi - lo + 1, dtype=bool)
        for i in np.flatnonzero(steps[:, j] >= step - BIND_JOINT_RAD):
            at[i : i + 2] = True  # a step binds the two waypoints it joins
        out.append(
            {
                "cause": "joint step",
                "figure": math.degrees(float(steps[:, j].max())),
                "limit": tolerances.joint_step_deg,
                "unit": "deg",
                "objects": (),
                "joint": int(j) + 1,
                "suggestion": (
                    f"joint {int(j) + 1} moves the whole joint-step bound of {tolerances.joint_step_deg:g} "
                    "deg between two waypoints in the answer; a denser path or a larger bound frees it"
                ),
                "waypoints": waypoints(at, lo),
            }
        )
    margin = tolerances.singularity_margin
    if margin > 0:
        w, _ = singularity_measures(kin, seg)
        at = w <= margin * (1.0 + BIND_SINGULARITY)
        if at.any():
            out.append(
                {
                    "cause": "singularity",
                    "figure": float(w.min()),
                    "limit": margin,
                    "unit": "-",
                    "objects": (),
                    "joint": None,
                    "suggestion": f"the scaled manipulability held at its margin {margin:g} in the answer",
                    "waypoints": waypoints(at),
                }
            )
    return out


def waypoint_runs(spans: tuple[tuple[int, int], ...]) -> str:
    """``" over waypoints 120-164, 170"`` for runs (first, last inclusive); empty for none."""
    if not spans:
        return ""
    text = ", ".join(f"{i}" if i == j else f"{i}-{j}" for i, j in spans)
    single = len(spans) == 1 and spans[0][0] == spans[0][1]
    return f" over waypoint{'' if single else 's'} {text}"


def bound_text(cause: Any) -> str:
    """A constraint at its bound in the answer (a :class:`refine.optimise.diagnosis.Cause`), in words.

    Its object, its bound, its figure and its waypoints, e.g. ``"clearance part<->grinder at its 5 mm
    margin (5.4 mm) over waypoints 120-164"``, ``"joint 2 at its limit -118.0 deg (less the margin)
    over waypoint 7"``.
    """
    c = cause
    if c.cause in ("collision", "self-collision"):
        kind = "self-clearance" if c.cause == "self-collision" else "clearance"
        what = f"{kind} {'<->'.join(c.objects)} at its {c.limit * 1e3:g} mm margin ({c.figure * 1e3:.1f} mm)"
    elif c.cause == "joint limit":
        what = f"joint {c.joint} at its limit {c.limit:.1f} deg (less the margin)"
    elif c.cause == "joint step":
        what = f"joint {c.joint} step at its {c.limit:g} deg bound ({c.figure:.2f} deg)"
    elif c.cause == "singularity":
        what = f"scaled manipulability at its margin {c.limit:g} ({c.figure:.4f})"
    else:
        what = c.label + (f" ({', '.join(c.objects)})" if c.objects else "")
    return what + waypoint_runs(c.waypoints)
