"""The rules each contender keeps by construction, stated once for the report and the CSV.

refine's verification (:func:`refine.bench.contenders.verify`) checks every answer against all of
:data:`RULES`, whoever made it; this module says which of them a contender *poses* (so an answer
that breaks a rule it does not pose is no surprise). The statements follow how each contender is
posed in :mod:`refine.bench.contenders` and :mod:`refine.bench.peers`. A plug-in contender may
state its own as a ``rules_kept`` attribute (an iterable of names from :data:`RULES`); one that
states none is ``unstated``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from refine.errors import InputError

RULES: dict[str, str] = {
    "position": "the TCP on the demonstrated point within the position tolerance",
    "cone": "the tool orientation within the cone of the demonstrated orientation",
    "joint-margin": "the joints inside their limits less the joint margin",
    "joint-step": "each joint's step between waypoints within the joint-step bound",
    "singularity": "the manipulability above the singularity margin",
    "clearance-waypoints": "the cell clearance with its margin at each waypoint",
    "clearance-between": "the cell clearance with its margin between waypoints (dense or continuous)",
    "self-clearance": "the self-collision margin between the robot's own links",
}
"""refine's rules, by short name, each with what it asks (the verification checks all of them)."""

_REFINE = tuple(RULES)

KEPT: dict[str, tuple[str, ...]] = {
    "refine": _REFINE,
    "refine-casadi-ad": _REFINE,
    "refine-fatrop": _REFINE,
    "greedy-ik": ("position", "cone", "joint-margin"),
    "drake-ik": ("position", "cone", "joint-margin"),
    "trajopt": ("position", "cone", "joint-margin", "clearance-waypoints", "clearance-between"),
    "descartes": ("position", "cone", "joint-margin", "clearance-waypoints"),
}
"""The rules each built-in contender poses (docs/bench.md, "Rules kept").

- refine: all of them; repaired answers keep the cone only with their stated slack.
- greedy-ik: the IK of the demonstrated pose inside the narrowed limits; no step bound, no
  singularity margin, no collision.
- drake-ik: Drake's IK with the position, the cone and the narrowed limits; its cost (the joint
  change) keeps steps small but bounds none; no singularity margin, no collision.
- trajopt: the position exactly, the orientation in a box inside the cone, the narrowed limits,
  collision with the cell margin at and between waypoints (its continuous check); no step bound,
  no singularity margin, self collision only at the cell margin.
- descartes: the position, samples about the tool axis (inside the cone), the narrowed limits,
  collision with the cell margin at the waypoints only; no step bound, no singularity margin.
"""

UNSTATED = "unstated"
"""The rules column of a contender that states none."""


def kept(name: str, function: Callable[..., Any] | None = None) -> tuple[str, ...] | None:
    """The rules ``name`` poses: its function's ``rules_kept`` attribute, else :data:`KEPT`, else None."""
    stated: Iterable[str] | None = getattr(function, "rules_kept", None)
    if stated is None:
        stated = KEPT.get(name)
    if stated is None:
        return None
    stated = tuple(stated)
    unknown = [r for r in stated if r not in RULES]
    if unknown:
        raise InputError(
            f"contender {name!r} states rules {unknown} that refine does not name",
            key="rules_kept",
            value=unknown,
            expected=f"names from {sorted(RULES)}",
        )
    return stated


def columns(name: str, function: Callable[..., Any] | None = None) -> dict[str, str]:
    """The CSV's ``rules_kept`` and ``rules_not_kept`` of contender ``name`` (names joined by ``;``)."""
    stated = kept(name, function)
    if stated is None:
        return {"rules_kept": UNSTATED, "rules_not_kept": UNSTATED}
    return {
        "rules_kept": ";".join(r for r in RULES if r in stated),
        "rules_not_kept": ";".join(r for r in RULES if r not in stated),
    }
