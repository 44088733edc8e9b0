"""Placement repair: the smallest move of the workpiece that makes the strict problem feasible.

When the demonstration cannot be executed within the strict tolerances, bending the worker's
orientation (the slack repair of :mod:`refine.optimise.solve`) is one answer; moving the part is
often the honest other. With ``[repair] placement = { translate_m, rotate_deg }`` the engine also
searches for the smallest rigid move of the workpiece that makes the strict problem feasible, and
reports it beside the slack repair.

What moves: the CAD frame (``[frames] cad_in_world``), the demonstration recorded on the part
(``[frames] source_in_world``: the worker's tool orientations are relative to the part, so they
turn with it) and every cell object marked ``workpiece = true`` (the part and its fixture). The
robot and the other cell objects stay.

The move: a turn ``R`` (rotation vector ``r``) about ``c``, the centroid of the CAD path's
waypoints in the world frame {F} before the move, then a shift ``t`` of that point, both in {F}:
``x' = c + R (x - c) + t``. A workpiece stays on what it rests on: with ``free = "plane"`` (the
default) ``t`` lies in the support plane and ``r`` along its normal (:func:`move_basis`); the
support is the cell object beneath the workpiece, or the world z plane (:func:`support_plane`). Its size is the weighted norm
``sqrt((|t| / translate_m)² + (angle(R) / rotate_deg)²)``, each part measured against its bound;
"smallest" means the least such norm, with ``|t| <= translate_m`` and ``angle(R) <= rotate_deg``.

How it is found: one CasADi/IPOPT problem over the joints at every waypoint and the six
placement parameters together (:func:`search_placement`): the CAD points and the demonstrated
orientations become functions of the placement; the constraints are the strict ones (TCP on the
moved CAD point, the orientation cone around the moved demonstration, joint limits less the
margin, the joint step, the singularity measure at every waypoint), each kept a little inside
its bound (:data:`INSET_DEG`, :data:`SINGULARITY_INSET`), the cone elastic (a slack per waypoint
with an exact L1 penalty, :data:`ELASTIC_WEIGHT`, so the problem always has an answer and an
infeasible one says how far beyond the cone the best move leaves the path); the cost is the squared
norm plus a small multiple of the usual path cost (orientation and joint smoothness). Clearance
is part of the search in rounds (:func:`clearance_rows`), the way the refinement keeps it
(:mod:`refine.optimise.clearance`): where an answer brings a moved object near or inside another
cell object, the robot's base or a robot link at a waypoint, the signed distance linearised at the
FCL witness points (the moved point exactly as a function of the move, the link's point to first
order in the joints) becomes a row, and the search is made again from its answer. IPOPT gets CasADi's exact Hessian except the singularity rows' curvature
(:data:`SKIP_SINGULARITY_CURVATURE`): a few more iterations, each a fraction of the cost.

How it is verified (:func:`repair_by_placement`): the placement problem's answer is never the
verdict. The moved objects are checked against the rest of the cell (:func:`cell_gaps`: the
collision margin to every other object and the robot's base, distance 0 or more to the support); a
move that puts one into another is refused. The problem is moved by the placement found and run through the ordinary strict
pipeline (:func:`refine.run.solve.solve_problem` without repair: IK seed, solve, verification,
clearance rows and the dense clearance check); only an ``ok`` there makes the placement ``ok``.
When it is not, the move is enlarged along the same direction (:data:`ENLARGE`, within the bounds)
and verified again; the first enlargement that verifies is reported, with its factor.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from refine.optimise.moves import (
    Placement,
    SupportPlane,
    pose_json,
)
from refine.settings import PlacementSettings
from refine.types import Array

if TYPE_CHECKING:
    from refine.run.result import RunResult

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PlacementRepair:
    """The outcome of the placement search and its verification.

    Attributes:
        status: ``"ok"`` (a move verified by the strict pipeline), ``"infeasible"`` (no move
            within the bounds found or verified), ``"not needed"`` (every pass is ok as placed) or
            ``"not tried"`` (a pass ran out of time before a verdict).
        bounds: the ``[repair] placement`` bounds.
        placement: the move reported (the verified one when ok; the search's best otherwise), or
            None when there is none.
        scale: the factor of :data:`ENLARGE` the verified move is of the search's answer.
        reason: why it is not ok (empty when ok).
        result: the strict run of the moved problem (the last one tried), or None.
        solver_status: IPOPT's status of the placement search.
        iterations: IPOPT iterations of the search.
        timings_s: ``search`` and ``verify`` wall times [s].
        moved_frames: the problem's frames after the move.
        moved_objects: the names of the cell objects moved.
        support: the plane the workpiece rests on (:func:`support_plane`), or None when not searched.
        rounds: searches made (the first, then one per round of clearance rows).
    """

    status: str
    bounds: PlacementSettings
    placement: Placement | None = None
    scale: float = 1.0
    reason: str = ""
    result: RunResult | None = None
    solver_status: str = ""
    iterations: int = 0
    timings_s: dict[str, float] = field(default_factory=dict)
    moved_frames: dict[str, Array] = field(default_factory=dict)
    moved_objects: tuple[str, ...] = ()
    support: SupportPlane | None = None
    rounds: int = 0

    def describe(self) -> str:
        """One line for the command line's summary."""
        if self.status == "not needed":
            return "not needed: the strict problem is ok as placed"
        if self.status != "ok" or self.placement is None:
            return f"{self.status}: {self.reason}"
        head = "ok (verified by the strict run): "
        p = self.placement
        move = (
            f"move the workpiece {p.distance_m * 1e3:.1f} mm by "
            f"[{', '.join(f'{v * 1e3:.1f}' for v in p.translation_m)}] mm (world) and turn it "
            f"{p.angle_deg:.2f} deg about [{', '.join(f'{v:.3f}' for v in p.as_json()['rotation']['axis'])}] "
            f"through [{', '.join(f'{v:.3f}' for v in p.centre_m)}] m "
            f"(norm {p.norm(self.bounds):.3f} of the bounds {self.bounds.translate_m:g} m, {self.bounds.rotate_deg:g} deg"
            + (
                ""
                if self.support is None or self.bounds.free == "all"
                else f"; in {plane_text(self.support)}"
            )
            + ")"
        )
        if self.status == "ok" and self.result is not None:
            c = self.result.refinement.check
            move += (
                f"; then max orientation deviation {c.orientation_deviation_deg.max():.3f} deg, "
                f"min scaled manipulability {c.singularity.min():.4f}"
            )
            clearance = self.result.first.clearance
            if clearance is not None:
                move += f", min clearance {clearance.min_distance_m * 1e3:.1f} mm"
        return head + move

    def as_json(self) -> dict[str, Any]:
        """The ``placement`` entry of ``result.json`` (schema: ``docs/placement.schema.json``)."""
        from refine.export.result_json import aggregate_metrics, pass_metrics

        move = self.placement.as_json() if self.placement is not None else None
        verified = self.result
        return {
            "status": self.status,
            "reason": self.reason,
            "bounds": {
                "translate_m": self.bounds.translate_m,
                "rotate_deg": self.bounds.rotate_deg,
                "free": self.bounds.free,
            },
            "support": None if self.support is None else self.support.as_json(),
            "rounds": self.rounds,
            "frame": "world",
            "about_m": None if move is None else move["about_m"],
            "translation_m": None if move is None else move["translation_m"],
            "distance_m": None if move is None else move["distance_m"],
            "rotation": None if move is None else move["rotation"],
            "transform_in_world": None if move is None else move["transform_in_world"],
            "norm": None if self.placement is None else self.placement.norm(self.bounds),
            "scale": self.scale,
            "moved_frames": {name: pose_json(T) for name, T in self.moved_frames.items()},
            "moved_objects": list(self.moved_objects),
            "strict_status": None if verified is None else verified.status,
            "metrics": None
            if verified is None
            else aggregate_metrics([pass_metrics(p) for p in verified.passes]),
            "solver": {"name": "ipopt", "status": self.solver_status, "iterations": self.iterations},
            "timings_s": {k: round(v, 6) for k, v in self.timings_s.items()},
        }


# ---- the moved problem ---------------------------------------------------------------------------


# ---- where the workpiece may go ------------------------------------------------------------------


# ---- the search ----------------------------------------------------------------------------------


# ---- search and verification ---------------------------------------------------------------------


def plane_text(support: SupportPlane) -> str:
    """The support plane in words, for messages: what it is the top of, and its normal."""
    what = f"the top of {support.support!r}" if support.support else "the world z plane"
    return f"{what}, normal [{', '.join(f'{v:.3f}' for v in support.normal)}]"
