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
pipeline (:func:`refine.run.stages.solve_problem` without repair: IK seed, solve, verification,
clearance rows and the dense clearance check); only an ``ok`` there makes the placement ``ok``.
When it is not, the move is enlarged along the same direction (:data:`ENLARGE`, within the bounds)
and verified again; the first enlargement that verifies is reported, with its factor.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from refine.optimise.moves import (
    CLEARANCE_ROUNDS,
    ClearanceRow,
    ObjectGap,
    Placement,
    SupportPlane,
    cell_gaps,
    clearance_rows,
    moved_path,
    moved_problem,
    pose_json,
    support_plane,
)
from refine.optimise.placement import SLACK_TOLERANCE_DEG, ZERO_MOVE, SearchResult, search_placement
from refine.paths import FusedPath
from refine.settings import PlacementSettings

if TYPE_CHECKING:
    from refine.problem import Problem
    from refine.robot.model import Robot
    from refine.run.result import PassResult, RunResult

log = logging.getLogger(__name__)

Array = NDArray[np.float64]


ENLARGE = (1.0, 1.1, 1.25, 1.5)
"""Factors by which the move found is scaled, in turn, until the strict pipeline verifies it."""


@dataclass(frozen=True)
class PlacementRepair:
    """The outcome of the placement search and its verification.

    Attributes:
        status: ``"ok"`` (a move verified by the strict pipeline), ``"infeasible"`` (no move
            within the bounds found or verified) or ``"not needed"`` (every pass is ok as placed).
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
        from refine.export.result_json import _aggregate, _pass_metrics

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
            "metrics": None if verified is None else _aggregate([_pass_metrics(p) for p in verified.passes]),
            "solver": {"name": "ipopt", "status": self.solver_status, "iterations": self.iterations},
            "timings_s": {k: round(v, 6) for k, v in self.timings_s.items()},
        }


# ---- the moved problem ---------------------------------------------------------------------------


# ---- where the workpiece may go ------------------------------------------------------------------


# ---- the search ----------------------------------------------------------------------------------


# ---- search and verification ---------------------------------------------------------------------


def placement_repair(
    problem: Problem, robot: Robot, passes: tuple[PassResult, ...] | list[PassResult]
) -> PlacementRepair:
    """The placement repair of a run.

    ``not needed`` when every pass is ok as placed, else :func:`repair_by_placement` on the first
    (demonstrated) pass; its verification runs every pass.
    """
    bounds = problem.repair.placement
    assert bounds is not None
    if all(p.refinement.status == "ok" for p in passes):
        return PlacementRepair("not needed", bounds)
    return repair_by_placement(problem, robot, passes[0])


def verify_placement(problem: Problem, robot: Robot, fused: FusedPath, placement: Placement) -> RunResult:
    """The ordinary strict pipeline on ``problem`` with its workpiece moved by ``placement``.

    The slack repair is off, so the run is ``ok`` only when the strict tolerances hold (clearance
    included, checked densely); ``fused`` is the problem's fused path as placed, moved rigidly (the
    same as fusing the moved problem's files: fusion depends only on the CAD path and the
    demonstration relative to each other).
    """
    from refine.run.stages import solve_problem

    moved = moved_problem(problem, placement.transform)
    strict = dataclasses.replace(moved, repair=dataclasses.replace(moved.repair, enabled=False))
    return solve_problem(strict, robot=robot, fused=moved_path(fused, placement.transform))


def repair_by_placement(problem: Problem, robot: Robot, first: PassResult) -> PlacementRepair:
    """Search the smallest workpiece move that makes the strict problem feasible, and verify it.

    The search is repeated with clearance rows (:func:`clearance_rows`) from its last answer until
    the moved objects keep their margins to the rest of the cell and to the robot, for at most
    :data:`CLEARANCE_ROUNDS` rounds.

    Args:
        problem: the problem as placed, with ``[repair] placement``.
        robot: the robot.
        first: the first pass's result as placed (its path, and its joints as the search's start).

    Returns:
        The outcome; ``status`` is ``ok`` only when the moved problem's strict run is ``ok`` and the
        moved objects keep their margins to the rest of the cell (:func:`cell_gaps`).
    """
    from refine.run.stages import weights_for

    bounds = problem.repair.placement
    assert bounds is not None
    timings: dict[str, float] = {}
    fused = first.fused
    support = support_plane(problem)
    rows: list[ClearanceRow] = []
    found: SearchResult | None = None
    gaps: list[ObjectGap] = []
    blocked: tuple[Placement, list[ObjectGap]] | None = None  # the last answer that broke a margin
    rounds = 0
    t0 = time.perf_counter()
    for rounds in range(1, CLEARANCE_ROUNDS + 1):
        found = search_placement(
            robot,
            fused,
            problem.robot.base_in_world,
            problem.tool.tcp_in_flange,
            problem.tolerances,
            bounds,
            first.refinement.q,
            axisymmetric=problem.tool.axisymmetric,
            weights=weights_for(problem, robot),
            time_limit_s=problem.repair.time_limit_s,
            support=support,
            rows=tuple(rows),
            start=found,
        )
        log.info(
            "placement search round %d: %s after %d iterations, shift %.4f m, turn %.3f deg, %d clearance rows",
            rounds,
            found.solver_status,
            found.iterations,
            found.placement.distance_m,
            found.placement.angle_deg,
            len(rows),
        )
        if not found.success:
            break
        gaps, more = clearance_rows(problem, robot, found.placement, found.q, support)
        if all(g.kept for g in gaps):
            break
        blocked = (found.placement, [g for g in gaps if not g.kept])
        rows += more
    assert found is not None
    timings["search"] = time.perf_counter() - t0
    common = {
        "bounds": bounds,
        "solver_status": found.solver_status,
        "iterations": found.iterations,
        "support": support,
        "rounds": rounds,
    }
    # the gaps measured at the last answer found; a failed search's point is no answer
    broken = (
        sorted((g for g in gaps if not g.kept), key=lambda g: g.distance_m - g.margin_m)
        if found.success
        else []
    )
    near = sorted({f"{a!r} / {b!r}" for a, b in (r.pair for r in rows)})
    if not found.success or broken:
        short = ""
        if not rows and found.slack_deg.size and found.slack_deg.max() > SLACK_TOLERANCE_DEG:
            worst = int(np.argmax(found.slack_deg))
            s = fused.s
            short = (
                f": the best move (shift {found.placement.distance_m:.4f} m, turn "
                f"{found.placement.angle_deg:.3f} deg) still leaves the orientation up to "
                f"{found.slack_deg.max():.2f} deg beyond the cone, at waypoint {worst} (s = {s[worst]:.3f} m)"
            )
        solver = (
            ""
            if found.solver_status == "Solve_Succeeded"
            else f" (placement search: IPOPT {found.solver_status})"
        )
        keeps = "the strict tolerances"
        if rows:
            keeps += f" and the clearance of the moved objects ({', '.join(near)})"
        if broken:
            short += f": after {rounds} clearance rounds the best move still puts " + "; ".join(
                g.describe() for g in broken[:3]
            )
        elif blocked is not None:
            p, why = blocked
            short += (
                f"; the move that keeps the strict tolerances without them (shift {p.distance_m * 1e3:.1f} mm, "
                f"turn {p.angle_deg:.2f} deg) puts " + "; ".join(g.describe() for g in why[:3])
            )
        plane = "" if bounds.free == "all" else f" in the support plane ({plane_text(support)})"
        return PlacementRepair(
            "infeasible",
            reason=(
                f"no workpiece move within {bounds.translate_m:g} m and {bounds.rotate_deg:g} deg{plane} "
                f"found that keeps {keeps}{solver}{short}"
            ),
            timings_s=timings,
            **common,
        )
    base_norm = found.placement.norm(bounds)
    if base_norm < ZERO_MOVE:
        return PlacementRepair(
            "infeasible",
            reason=(
                "the placement search meets the strict tolerances without moving the workpiece, so what "
                "fails as placed is what it leaves out: the robot's clearance between waypoints (or an IK "
                "branch the strict solve did not find); no workpiece move is proposed (see the diagnosis)"
            ),
            timings_s=timings,
            **common,
        )
    t0 = time.perf_counter()
    result = None
    tried = []
    for factor in ENLARGE:
        if factor > 1.0 and not _within(found.placement.scaled(factor), bounds):
            break
        candidate = found.placement.scaled(factor)
        collided = [g for g in cell_gaps(problem, robot, candidate, support) if not g.kept]
        if collided:  # one object put into (or too near) another: refused before any run
            tried.append(f"x{factor:g}: refused, it puts {'; '.join(g.describe() for g in collided)}")
            continue
        result = verify_placement(problem, robot, fused, candidate)
        tried.append(f"x{factor:g}: {result.status}")
        if result.status == "ok":
            timings["verify"] = time.perf_counter() - t0
            return PlacementRepair(
                "ok",
                placement=candidate,
                scale=factor,
                result=result,
                timings_s=timings,
                **common,
                **_moved(problem, candidate),
            )
    timings["verify"] = time.perf_counter() - t0
    why = f": {result.refinement.reason}" if result is not None else ""
    return PlacementRepair(
        "infeasible",
        placement=found.placement,
        reason=(
            f"the move found (shift {found.placement.distance_m:.4f} m, turn {found.placement.angle_deg:.3f} deg) "
            f"and its enlargements within the bounds are not verified ({'; '.join(tried)}; the placement "
            f"search checks the robot's clearance at the waypoints only){why}"
        ),
        result=result,
        timings_s=timings,
        **common,
        **_moved(problem, found.placement),
    )


def plane_text(support: SupportPlane) -> str:
    what = f"the top of {support.support!r}" if support.support else "the world z plane"
    return f"{what}, normal [{', '.join(f'{v:.3f}' for v in support.normal)}]"


def _moved(problem: Problem, placement: Placement) -> dict[str, Any]:
    """The moved frames (``cad_in_world``, ``source_in_world``) and the names of the objects moved."""
    moved = moved_problem(problem, placement.transform)
    return {
        "moved_frames": {
            "cad_in_world": moved.frames.cad_in_world,
            "source_in_world": moved.frames.source_in_world,
        },
        "moved_objects": tuple(o.name for o in problem.cell if o.workpiece),
    }


def _within(placement: Placement, bounds: PlacementSettings) -> bool:
    return (
        placement.distance_m <= bounds.translate_m + 1e-12 and placement.angle_deg <= bounds.rotate_deg + 1e-9
    )
