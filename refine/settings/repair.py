"""The tables of repair, placement, multi-pass welds and a problem's expected outcome.

The tables of what happens when the strict problem has no answer (``[repair]``, with its
``placement`` search), the passes of a multi-layer weld (``[multipass]``), and a problem's
expected outcome (``[expect]``).
"""

from __future__ import annotations

from dataclasses import dataclass

from refine.errors import InputError
from refine.settings.limits import CAUSES, in_range, one_of

MAX_PLACEMENT_TRANSLATE_M = 1.0
"""Largest workpiece shift the placement repair may search [m]: beyond it the cell is laid out anew."""


MAX_PLACEMENT_ROTATE_DEG = 45.0
"""Largest workpiece turn the placement repair may search [deg]."""


PLACEMENT_FREEDOMS = ("plane", "all")
"""``[repair] placement.free``: in the support plane only, or any rigid move."""


@dataclass(frozen=True)
class PlacementSettings:
    """``[repair] placement``: the bounds of the workpiece move the placement repair may propose.

    The move is a rigid transform of the workpiece (the CAD frame, the demonstration recorded on it
    and the cell objects marked ``workpiece``): a turn about the path's centroid and a shift, both
    in the world frame {F}. The smallest move is the one with the least
    ``sqrt((|t| / translate_m)² + (angle / rotate_deg)²)`` (see :mod:`refine.run.placement`).

    Attributes:
        translate_m: largest shift of the workpiece [m] (0: no shift).
        rotate_deg: largest turn of the workpiece about the path's centroid [deg] (0: no turn).
        free: ``"plane"``: the workpiece only slides in the plane it rests on and turns about that
            plane's normal; ``"all"``: any rigid move (kept out of the cell's other objects).
    """

    translate_m: float = 0.0
    rotate_deg: float = 0.0
    free: str = "plane"

    def __post_init__(self) -> None:
        in_range("repair.placement", "translate_m", self.translate_m, 0.0, MAX_PLACEMENT_TRANSLATE_M, "m")
        in_range("repair.placement", "rotate_deg", self.rotate_deg, 0.0, MAX_PLACEMENT_ROTATE_DEG, "deg")
        if self.translate_m == 0.0 and self.rotate_deg == 0.0:
            raise InputError(
                "repair.placement needs translate_m > 0 m or rotate_deg > 0 deg "
                "(leave placement out to search no workpiece move)"
            )
        if self.free not in PLACEMENT_FREEDOMS:
            raise InputError(
                f"repair.placement.free must be one of {', '.join(map(repr, PLACEMENT_FREEDOMS))}, got {self.free!r}"
            )


@dataclass(frozen=True)
class RepairSettings:
    """``[repair]``: what to do when the strict problem is infeasible.

    Attributes:
        enabled: look for the smallest extra orientation slack per waypoint that makes it feasible.
        max_slack_deg: the largest extra slack [deg] on top of the orientation tolerance.
        time_limit_s: wall-time budget of one pass's refinement (IK seed, solves, repair) [s];
            when it runs out before a verdict the pass is ``infeasible`` and says so.
        placement: the bounds of a workpiece move to search when the strict problem has no
            answer (:mod:`refine.run.placement`), or None for no placement search.
    """

    enabled: bool = True
    max_slack_deg: float = 15.0
    time_limit_s: float = 120.0
    placement: PlacementSettings | None = None

    def __post_init__(self) -> None:
        in_range("repair", "max_slack_deg", self.max_slack_deg, 0.0, 90.0, "deg")
        in_range("repair", "time_limit_s", self.time_limit_s, 0.1, 86400.0, "s")


@dataclass(frozen=True)
class MultipassSettings:
    """``[multipass]``: the passes of a multi-layer weld, generated from the demonstrated first pass.

    Attributes:
        layers: number of layers (the first is the demonstrated root pass).
        layer_height_m: height of each layer above the previous, along the seam's bisector [m].
        lateral_offsets_m: per layer, the lateral offset of each pass from the seam line [m];
            layer 1 must be ``[0.0]``.
        work_angle_change_deg: per layer and pass, the change of the work angle (tilt about the
            seam tangent) from the demonstrated one [deg]; zeros when absent.
    """

    layers: int = 1
    layer_height_m: float = 0.0
    lateral_offsets_m: tuple[tuple[float, ...], ...] = ((0.0,),)
    work_angle_change_deg: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        in_range("multipass", "layers", self.layers, 1, 50)
        in_range("multipass", "layer_height_m", self.layer_height_m, 0.0, 0.1, "m")
        for key, bound, unit in (("lateral_offsets_m", 0.2, "m"), ("work_angle_change_deg", 90.0, "deg")):
            for row in getattr(self, key) or ():
                for v in row:
                    in_range("multipass", f"{key}[][]", v, -bound, bound, unit)
        if len(self.lateral_offsets_m) != self.layers:
            raise InputError(
                f"multipass.lateral_offsets_m needs one list per layer ({self.layers}), got {len(self.lateral_offsets_m)}"
            )
        if self.work_angle_change_deg is not None and [len(x) for x in self.work_angle_change_deg] != [
            len(x) for x in self.lateral_offsets_m
        ]:
            raise InputError("multipass.work_angle_change_deg must have the shape of lateral_offsets_m")


@dataclass(frozen=True)
class ExpectedOutcome:
    """``[expected]``: what a test problem is built to produce (checked by the test suite).

    Attributes:
        status: ``"ok"``, ``"repaired"`` or ``"infeasible"``.
        reason: a text the repair or infeasibility reason must contain (e.g. ``"joint limit"``).
        max_slack_deg: for a repaired problem, the largest slack it may use [deg].
        s_range_m: arc-length range [m] the reported segment must overlap, or None.
        cause: the cause the diagnosis must name first for that segment (``"reach"``,
            ``"joint limit"``, ``"joint wrap"``, ``"singularity"``, ``"collision"``,
            ``"self-collision"``, ``"orientation"``), or ``""`` for no check.
    """

    status: str
    reason: str = ""
    max_slack_deg: float | None = None
    s_range_m: tuple[float, float] | None = None
    cause: str = ""

    def __post_init__(self) -> None:
        one_of("expected", "status", self.status, ("ok", "repaired", "infeasible", "timeout"))
        if self.cause:
            one_of("expected", "cause", self.cause, CAUSES)
