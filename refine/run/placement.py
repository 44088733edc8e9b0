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
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from refine.frames import fixed_xyz_from_matrix, matrix_from_rotvec
from refine.paths import FusedPath
from refine.settings import PlacementSettings

if TYPE_CHECKING:
    from refine.problem import Problem
    from refine.robot.model import Robot
    from refine.run.result import PassResult, RunResult

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

INSET_DEG = 0.05
"""The placement search keeps the orientation cone and the joint limits this far inside their
bounds [deg], so that the strict re-solve of the moved problem does not start on a bound's edge."""

SINGULARITY_INSET = 1.05
"""The placement search bounds the singularity measure by this factor times the margin."""

PATH_COST_WEIGHT = 1e-3
"""Weight of the usual path cost (orientation deviation in deg², joint smoothness) against the
squared placement norm: it settles the joints (a redundant arm's elbow) without moving the optimum
of the placement by more than about 1e-3 of its bounds."""

ELASTIC_WEIGHT = 1e4
"""Cost per unit of elastic cone slack (cosine units) in the placement search: 0.1 deg beyond a
3 deg cone costs about 0.9, 1 deg about 9, against a squared norm of at most 2 for the largest
move, so slack is used only where no move within the bounds avoids it (an exact L1 penalty)."""

ZERO_MOVE = 1e-3
"""A move whose norm (against the bounds) is below this is no move at all: it is within what the
small path cost (:data:`PATH_COST_WEIGHT`) may pull the answer by (0.2 mm and 0.015 deg of bounds
of 0.2 m and 15 deg)."""

SLACK_TOLERANCE_DEG = 1e-3
"""A placement search answer whose elastic slack stays below this everywhere is a feasible move [deg]."""

SKIP_SINGULARITY_CURVATURE = True
"""Leave the singularity rows' second derivatives out of the Hessian IPOPT is given: they cost
about 30 times the rest of it (a 6x6 determinant differentiated twice at every waypoint)."""

ENLARGE = (1.0, 1.1, 1.25, 1.5)
"""Factors by which the move found is scaled, in turn, until the strict pipeline verifies it."""


@dataclass(frozen=True)
class Placement:
    """A rigid move of the workpiece in the world frame {F}: ``x' = c + R (x - c) + t``.

    Attributes:
        centre_m: ``c``, the point the workpiece turns about (the CAD path's centroid) [m], (3,).
        translation_m: ``t``, the shift of ``c`` [m], (3,), in {F}.
        rotvec_rad: the turn ``R`` as a rotation vector (axis times angle) [rad], (3,), in {F}.
    """

    centre_m: Array
    translation_m: Array
    rotvec_rad: Array

    @property
    def rotation(self) -> Array:
        """The turn R (3, 3)."""
        return matrix_from_rotvec(self.rotvec_rad)

    @property
    def angle_deg(self) -> float:
        """The angle of the turn [deg]."""
        return math.degrees(float(np.linalg.norm(self.rotvec_rad)))

    @property
    def distance_m(self) -> float:
        """The length of the shift [m]."""
        return float(np.linalg.norm(self.translation_m))

    @property
    def transform(self) -> Array:
        """The move as a world transform Δ (4, 4): a point x of the workpiece goes to Δ·x."""
        T = np.eye(4)
        R = self.rotation
        T[:3, :3] = R
        T[:3, 3] = self.centre_m + self.translation_m - R @ self.centre_m
        return T

    def norm(self, bounds: PlacementSettings) -> float:
        """``sqrt((|t| / translate_m)² + (angle / rotate_deg)²)``; a part with a zero bound must be 0."""
        terms = []
        for value, bound in ((self.distance_m, bounds.translate_m), (self.angle_deg, bounds.rotate_deg)):
            terms.append(value / bound if bound > 0 else (0.0 if value < 1e-12 else math.inf))
        return math.hypot(*terms)

    def scaled(self, factor: float) -> Placement:
        """The same move scaled by ``factor`` (shift and turn angle alike)."""
        return Placement(self.centre_m, factor * self.translation_m, factor * self.rotvec_rad)

    def as_json(self) -> dict[str, Any]:
        """The move's figures for ``result.json`` (world frame {F})."""
        angle = self.angle_deg
        axis = self.rotvec_rad / np.linalg.norm(self.rotvec_rad) if angle > 0 else np.array([0.0, 0.0, 1.0])
        return {
            "frame": "world",
            "about_m": [float(v) for v in self.centre_m],
            "translation_m": [float(v) for v in self.translation_m],
            "distance_m": self.distance_m,
            "rotation": {
                "axis": [float(v) for v in axis],
                "angle_deg": angle,
                "rotvec_deg": [math.degrees(float(v)) for v in self.rotvec_rad],
                "rpy_deg": [float(v) for v in fixed_xyz_from_matrix(self.rotation)],
            },
            "transform_in_world": self.transform.tolist(),
        }


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
                else f"; in {_plane_text(self.support)}"
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
            "moved_frames": {name: _pose_json(T) for name, T in self.moved_frames.items()},
            "moved_objects": list(self.moved_objects),
            "strict_status": None if verified is None else verified.status,
            "metrics": None if verified is None else _aggregate([_pass_metrics(p) for p in verified.passes]),
            "solver": {"name": "ipopt", "status": self.solver_status, "iterations": self.iterations},
            "timings_s": {k: round(v, 6) for k, v in self.timings_s.items()},
        }


def _pose_json(T: Array) -> dict[str, list[float]]:
    """A pose as the problem file writes it: ``xyz`` [m] and fixed-axis X-Y-Z ``rpy_deg``."""
    return {
        "xyz": [float(v) for v in T[:3, 3]],
        "rpy_deg": [float(v) for v in fixed_xyz_from_matrix(T[:3, :3])],
    }


# ---- the moved problem ---------------------------------------------------------------------------


def moved_problem(problem: Problem, transform: Array) -> Problem:
    """``problem`` with its workpiece moved by ``transform`` (Δ, world frame).

    What moves: the CAD frame, the tracker receiver (the demonstration was recorded on the part)
    and the cell objects marked ``workpiece``; the placement search is switched off in the copy, and
    a simulated demonstration's truth (given in {F} as placed) is left out.
    """
    D = np.asarray(transform, dtype=float)
    frames = dataclasses.replace(
        problem.frames,
        cad_in_world=D @ problem.frames.cad_in_world,
        source_in_world=D @ problem.frames.source_in_world,
    )
    cell = tuple(dataclasses.replace(o, pose=D @ o.pose) if o.workpiece else o for o in problem.cell)
    demo = problem.demonstration
    if demo is not None and demo.truth is not None:  # a simulator's truth is in {F} as placed
        demo = dataclasses.replace(demo, truth=None)
    return dataclasses.replace(
        problem,
        frames=frames,
        cell=cell,
        demonstration=demo,
        repair=dataclasses.replace(problem.repair, placement=None),
    )


def moved_path(fused: FusedPath, transform: Array) -> FusedPath:
    """The fused path moved rigidly by ``transform`` (Δ): positions and orientations in {F}."""
    D = np.asarray(transform, dtype=float)
    return dataclasses.replace(
        fused,
        positions=fused.positions @ D[:3, :3].T + D[:3, 3],
        rotations=np.einsum("ij,njk->nik", D[:3, :3], fused.rotations),
    )


# ---- where the workpiece may go ------------------------------------------------------------------

SUPPORT_GAP_M = 0.002
"""A cell object whose top lies within this of the workpiece's underside, and within this of the
workpiece itself, is what the workpiece rests on [m]."""

CONTACT_TOLERANCE_M = 1e-6
"""The moved workpiece may touch its support (distance 0), and go no deeper than this into it [m]."""

CLEARANCE_TOLERANCE_M = 1e-6
"""The final check accepts a moved object this much closer than its margin (rounding) [m]."""

LOOK_AHEAD_M = 0.03
"""A pair within its margin plus this gets a clearance row in the next search round [m]."""

BACK_OFF_M = 0.0005
"""Each clearance row asks for this much more than the margin [m]: the distance is curved where
the row is flat (as the refinement's rows, :mod:`refine.optimise.clearance`)."""

CLEARANCE_ROUNDS = 6
"""Most searches made with clearance rows added from the last answer."""


@dataclass(frozen=True)
class SupportPlane:
    """The plane the workpiece rests on.

    Attributes:
        normal: unit normal (3,) in {F}, pointing away from the support into the workpiece.
        point_m: a point of the plane [m], (3,), in {F}.
        support: the cell object the workpiece rests on, or None for the world z plane.
    """

    normal: Array
    point_m: Array
    support: str | None = None

    def as_json(self) -> dict[str, Any]:
        """The ``support`` entry of the placement in ``result.json``."""
        return {
            "object": self.support,
            "normal": [float(v) for v in self.normal],
            "point_m": [float(v) for v in self.point_m],
        }


WORLD_Z = SupportPlane(np.array([0.0, 0.0, 1.0]), np.zeros(3), None)
"""The support plane when no cell object is beneath the workpiece: the world's z = 0 plane's
normal (the plane itself is put through the workpiece's lowest point by :func:`support_plane`)."""


def move_basis(support: SupportPlane, free: str) -> tuple[Array, Array]:
    """The directions the shift and the turn may take: ``t = E_t u``, ``r = E_r v``.

    ``"plane"``: two orthonormal directions in the support plane for the shift, its normal for the
    turn; ``"all"``: the identity for both.
    """
    if free == "all":
        return np.eye(3), np.eye(3)
    nrm = np.asarray(support.normal, dtype=float)
    nrm = nrm / np.linalg.norm(nrm)
    # the plane's directions: the null space of the normal (SVD), orthonormal by construction
    plane = np.linalg.svd(nrm[None, :])[2][1:].T
    return plane, nrm[:, None]


def _bodies(shapes: tuple[Any, ...]) -> list[Any]:
    from refine.collision.geometry import shape_body

    return [shape_body(o, name=o.name, kind="cell", link=None, frame_id=-1, joint=-1) for o in shapes]


def support_plane(problem: Problem) -> SupportPlane:
    """What the workpiece rests on: the highest other cell object whose top touches its underside.

    The underside is the lowest world-z point of the objects marked ``workpiece``; an object beneath
    is one that is within :data:`SUPPORT_GAP_M` of a workpiece object and whose highest point is
    within :data:`SUPPORT_GAP_M` of that underside. Its plane: for a box, the face whose outward
    normal is nearest to world +z (the table top, tilted with the box); for another shape, world z
    through its highest point. With nothing beneath, the world z plane through the underside.
    """
    from refine.collision.distance import place, signed_distance

    up = np.array([0.0, 0.0, 1.0])
    moved = [o for o in problem.cell if o.workpiece]
    if not moved:
        return WORLD_Z
    parts = _bodies(tuple(moved))
    bottom = min(-b.reach(np.asarray(o.pose, dtype=float), -up) for b, o in zip(parts, moved, strict=True))
    best: tuple[float, SupportPlane] | None = None
    for o in problem.cell:
        if o.workpiece:
            continue
        (body,) = _bodies((o,))
        T = np.asarray(o.pose, dtype=float)
        top = body.reach(T, up)
        if abs(top - bottom) > SUPPORT_GAP_M:
            continue
        place(body, T)
        near = False
        for b, w in zip(parts, moved, strict=True):
            Tw = np.asarray(w.pose, dtype=float)
            place(b, Tw)
            near = near or signed_distance(b, Tw, body, T)[0] <= SUPPORT_GAP_M
        if not near:
            continue
        normal = up
        if o.shape == "box":
            axes = np.concatenate([T[:3, :3].T, -T[:3, :3].T])  # the six face normals
            normal = axes[int(np.argmax(axes @ up))]
        plane = SupportPlane(
            normal, T[:3, 3] + normal * (body.reach(T, normal) - float(normal @ T[:3, 3])), o.name
        )
        if best is None or top > best[0]:
            best = (top, plane)
    if best is not None:
        return best[1]
    return SupportPlane(up, np.array([0.0, 0.0, bottom]), None)


@dataclass(frozen=True)
class ClearanceRow:
    """One linearised clearance constraint of the placement search.

    ``distance_m + normal · (P(move) - moved_point_m) [+ gradient · (q_k - q)] >= bound_m``, with
    ``P(move)`` the witness point of the moved object after the move.

    Attributes:
        point_m: the witness point on the moved object, where it is as placed [m], (3,).
        moved_point_m: the same point after the move it was measured at [m], (3,).
        normal: unit vector (3,) along which moving that point increases the distance.
        distance_m: the signed distance there [m].
        bound_m: the distance the row asks for (the pair's margin plus :data:`BACK_OFF_M`) [m].
        pair: the moved object and the other body.
        waypoint: for a robot link, the waypoint k whose joints it depends on; -1 otherwise.
        gradient: d(distance)/dq of the link's point at that waypoint [m/rad], (n,).
        q: the joints it was measured at [rad], (n,).
    """

    point_m: Array
    moved_point_m: Array
    normal: Array
    distance_m: float
    bound_m: float
    pair: tuple[str, str]
    waypoint: int = -1
    gradient: Array = field(default_factory=lambda: np.zeros(0))
    q: Array = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class ObjectGap:
    """The distance of a moved object to another body, and what it must keep.

    Attributes:
        moved: the moved object (marked workpiece).
        other: the other cell object, or the robot link.
        distance_m: signed distance [m] (negative: the depth one is inside the other).
        margin_m: the least distance allowed [m]: the collision margin, 0 for the support.
        waypoint: the waypoint of a moving robot link's figure, -1 for a fixed body.
    """

    moved: str
    other: str
    distance_m: float
    margin_m: float
    waypoint: int = -1

    @property
    def kept(self) -> bool:
        """The margin is kept (within the tolerance of rounding)."""
        tolerance = CONTACT_TOLERANCE_M if self.margin_m == 0.0 else CLEARANCE_TOLERANCE_M
        return self.distance_m >= self.margin_m - tolerance

    def describe(self) -> str:
        """``'plate' 3.2 mm inside 'table'`` or ``'plate' 4.1 mm from 'post' (margin 10.0 mm)``."""
        where = f" at waypoint {self.waypoint}" if self.waypoint >= 0 else ""
        if self.distance_m < 0.0:
            return f"{self.moved!r} {-self.distance_m * 1e3:.1f} mm inside {self.other!r}{where}"
        return (
            f"{self.moved!r} {self.distance_m * 1e3:.1f} mm from {self.other!r}{where} "
            f"(margin {self.margin_m * 1e3:.1f} mm)"
        )


def _gap_rows(
    problem: Problem,
    robot: Robot,
    placement: Placement,
    q: Array | None,
    support: SupportPlane,
    reach_m: float,
) -> tuple[list[ObjectGap], list[ClearanceRow]]:
    """The moved objects' distances to the rest of the cell and the robot, and rows for the close ones.

    The other cell objects and the robot's fixed bodies (the base: the strict run does not check
    them, they cannot move) are measured once; the robot's moving links at every waypoint of ``q``
    (the pairs the collision model checks). The support is kept at distance 0 or more, the others
    at the collision margin; with ``free = "plane"`` the support is not measured in the search (a
    move in its plane keeps the contact) but it is in the final check (``q`` None).
    """
    from refine.collision import CollisionModel
    from refine.collision.distance import place, signed_distance

    bounds = problem.repair.placement
    free = "all" if bounds is None else bounds.free
    margin = problem.collision.margin_m
    D = placement.transform
    D_inv = np.linalg.inv(D)
    moved_shapes = tuple(o for o in problem.cell if o.workpiece)
    static_shapes = tuple(o for o in problem.cell if not o.workpiece)
    moved = _bodies(moved_shapes)
    moved_poses = [D @ np.asarray(o.pose, dtype=float) for o in moved_shapes]
    for b, T in zip(moved, moved_poses, strict=True):
        place(b, T)
    others: list[tuple[Any, Array, float]] = []
    for o, b in zip(static_shapes, _bodies(static_shapes), strict=True):
        is_support = o.name == support.support
        if is_support and free == "plane" and q is not None:
            continue
        T = np.asarray(o.pose, dtype=float)
        place(b, T)
        others.append((b, T, 0.0 if is_support else margin))
    model = CollisionModel.for_problem(moved_problem(problem, D), robot) if moved_shapes else None
    if model is not None and problem.collision.enabled:
        q_any = _neutral(robot) if q is None else q[0]
        poses = model.moving_poses(np.asarray(q_any, dtype=float)[None])[0]
        for b, T in zip(model.bodies[: len(poses)], poses, strict=True):
            if b.kind == "link" and b.joint == 0:  # fixed to the base
                place(b, T)
                others.append((b, T, margin))
    gaps: list[ObjectGap] = []
    rows: list[ClearanceRow] = []
    for b, T_b, own in others:
        for mb, T_m in zip(moved, moved_poses, strict=True):
            d, p_m, _, nrm = signed_distance(mb, T_m, b, T_b)
            gaps.append(ObjectGap(mb.name, b.name, float(d), own))
            if d < own + reach_m:
                point = D_inv[:3, :3] @ p_m + D_inv[:3, 3]
                rows.append(ClearanceRow(point, p_m, nrm, float(d), own + BACK_OFF_M, (mb.name, b.name)))
    if model is not None and problem.collision.enabled and q is not None:
        names = {o.name for o in moved_shapes}
        for k, qk in enumerate(np.asarray(q, dtype=float)):
            contacts = [
                c for c in model.contacts(qk, margin + reach_m) if c.other in names and not c.self_pair
            ]
            if not contacts:
                continue
            grads = model.distance_gradients(qk, contacts)
            for c, g in zip(contacts, grads, strict=True):
                gaps.append(ObjectGap(c.other, c.body, c.distance_m, c.margin_m, k))
                point = D_inv[:3, :3] @ c.point_other + D_inv[:3, 3]
                rows.append(
                    ClearanceRow(
                        point,
                        np.asarray(c.point_other),
                        -np.asarray(c.normal),
                        c.distance_m,
                        c.margin_m + BACK_OFF_M,
                        (c.other, c.body),
                        k,
                        g,
                        qk.copy(),
                    )
                )
    return gaps, rows


def _neutral(robot: Robot) -> Array:
    """The robot's neutral joints [rad] (any configuration places the fixed bodies alike)."""
    import pinocchio as pin

    return np.asarray(pin.neutral(robot.model), dtype=float)


def clearance_rows(
    problem: Problem, robot: Robot, placement: Placement, q: Array, support: SupportPlane
) -> tuple[list[ObjectGap], list[ClearanceRow]]:
    """The moved objects' gaps at a search answer and the rows for the pairs near or below their margin."""
    return _gap_rows(problem, robot, placement, q, support, LOOK_AHEAD_M)


def cell_gaps(problem: Problem, robot: Robot, placement: Placement, support: SupportPlane) -> list[ObjectGap]:
    """The final check: the moved objects' gaps to the rest of the cell and the robot's fixed bodies.

    Every other cell object (the support included, at margin 0) and the robot's base bodies, with
    the problem's collision margin; the moving links are the strict run's to check.
    """
    return _gap_rows(problem, robot, placement, None, support, 0.0)[0]


# ---- the search ----------------------------------------------------------------------------------


def _rotation(r: ca.MX) -> ca.MX:
    """Rodrigues' rotation of the rotation vector ``r`` (3,), smooth at 0 (half-angle form)."""
    theta = ca.sqrt(ca.dot(r, r) + 1e-14)
    K = ca.skew(r)
    half = theta / 2.0
    return ca.DM.eye(3) + (ca.sin(theta) / theta) * K + 0.5 * (ca.sin(half) / half) ** 2 * ca.mtimes(K, K)


@dataclass(frozen=True)
class SearchResult:
    """The placement problem's answer (not yet verified).

    Attributes:
        placement: the move found.
        q: joints at every waypoint on the moved path [rad], (N, n).
        success: IPOPT reported success.
        solver_status: IPOPT's return status.
        iterations: IPOPT iterations.
        time_s: wall time of build and solve [s].
        slack_deg: the orientation beyond the (inset) cone each waypoint still needs with this
            move [deg], (N,); all zero (below :data:`SLACK_TOLERANCE_DEG`) when the move is feasible.
        x: the solver's variables at the answer (to start the next clearance round from).
    """

    placement: Placement
    q: Array
    success: bool
    solver_status: str
    iterations: int
    time_s: float
    slack_deg: Array = field(default_factory=lambda: np.zeros(0))
    x: Array = field(default_factory=lambda: np.zeros(0))


def search_placement(
    robot: Robot,
    fused: FusedPath,
    base_in_world: Array,
    tcp_in_flange: Array,
    tolerances: Any,
    bounds: PlacementSettings,
    q0: Array,
    *,
    axisymmetric: bool = False,
    weights: Any = None,
    time_limit_s: float = 120.0,
    support: SupportPlane | None = None,
    rows: tuple[ClearanceRow, ...] = (),
    start: SearchResult | None = None,
) -> SearchResult:
    """The smallest move of the workpiece for which the joints meet the strict constraints.

    Args:
        robot: the robot.
        fused: the path as placed (N waypoints).
        base_in_world: T_F_R (4, 4).
        tcp_in_flange: T_flange_TCP (4, 4).
        tolerances: the strict tolerances (:class:`refine.settings.Tolerances`).
        bounds: the largest shift [m] and turn [deg], and what may move (``free``).
        q0: joints to start from (N, n) [rad], e.g. the slack repair's or the IK seed.
        axisymmetric: only the tool axis counts in the cone.
        weights: the path cost weights (:class:`refine.optimise.problem.Weights`), or None.
        time_limit_s: IPOPT's wall-time limit [s].
        support: the plane the workpiece rests on; with ``bounds.free == "plane"`` the shift stays
            in it and the turn is about its normal. None: the world z plane.
        rows: clearance rows of the moved objects (:func:`clearance_rows`), kept as constraints.
        start: an earlier answer to start from (the previous clearance round), or None.
    """
    from refine.optimise.derivatives import smoothness_matrix
    from refine.optimise.problem import Weights, joint_bounds, singularity_function, waypoint_function

    t0 = time.perf_counter()
    weights = weights or Weights()
    N, n = len(fused), robot.nq
    centre = fused.positions.mean(axis=0)
    T_max, A_max = bounds.translate_m, math.radians(bounds.rotate_deg)

    # decision variables: joints, the shift and the rotation vector scaled by their bounds, and an
    # elastic slack per waypoint on the cone (cosine units), so that the problem always has an
    # answer: with the slack zero the move is feasible; otherwise it says how far from it the largest
    # move within the bounds leaves the path
    E_t, E_r = move_basis(support or WORLD_Z, bounds.free)
    m_t, m_r = E_t.shape[1], E_r.shape[1]
    m = m_t + m_r
    x = ca.MX.sym("x", N * n + m + N)
    Q = ca.reshape(x[: N * n], n, N)
    u, v, sigma = x[N * n : N * n + m_t], x[N * n + m_t : N * n + m], x[N * n + m :]
    t, r = T_max * ca.mtimes(ca.DM(E_t), u), A_max * ca.mtimes(ca.DM(E_r), v)
    R = _rotation(r)
    P = ca.DM(fused.positions.T)  # (3, N)
    c = ca.DM(centre)
    P_moved = ca.mtimes(R, P - ca.repmat(c, 1, N)) + ca.repmat(c + t, 1, N)
    R_demo = ca.DM(np.concatenate(list(fused.rotations), axis=1))  # (3, 3N): R_0 | R_1 | ...
    R_moved = ca.reshape(ca.mtimes(R, R_demo), 9, N)  # column k: R·R_k, column-major

    G, cost = waypoint_function(robot, base_in_world, tcp_in_flange, axisymmetric).map(N)(Q, P_moved, R_moved)
    cos_theta = G[3, :]
    clearance = rows
    rows = [ca.vec(ca.vertcat(G[:3, :], cos_theta + sigma.T)), ca.vec(Q[:, 1:] - Q[:, :-1])]
    inset = math.radians(INSET_DEG)
    cone = math.radians(tolerances.orientation_deg) - inset
    step = math.radians(tolerances.joint_step_deg)
    lbg = [np.tile([0.0, 0.0, 0.0, math.cos(cone)], N)]
    ubg = [np.tile([0.0, 0.0, 0.0, np.inf], N)]
    lbg.append(np.full(n * (N - 1), -step + inset))
    ubg.append(np.full(n * (N - 1), step - inset))
    if tolerances.singularity_margin > 0:
        rows.append(ca.vec(singularity_function(robot, base_in_world, tcp_in_flange).map(N)(Q)))
        lbg.append(np.full(N, SINGULARITY_INSET * tolerances.singularity_margin))
        ubg.append(np.full(N, np.inf))
    rows.append(ca.vertcat(ca.dot(u, u), ca.dot(v, v)))
    lbg.append(np.array([-np.inf, -np.inf]))
    ubg.append(np.array([1.0, 1.0]))
    for row in clearance:
        # the signed distance linearised at its witness points: the moved object's point follows
        # the move exactly, a robot link's point the joints to first order
        moved = c + ca.mtimes(R, ca.DM(row.point_m - centre)) + t
        d = row.distance_m + ca.dot(ca.DM(row.normal), moved - ca.DM(row.moved_point_m))
        if row.waypoint >= 0:
            d += ca.dot(ca.DM(row.gradient), Q[:, row.waypoint] - ca.DM(row.q))
        rows.append(d)
        lbg.append(np.array([row.bound_m]))
        ubg.append(np.array([np.inf]))

    spec = robot.spec
    h = float(np.mean(np.diff(fused.s)))
    half = 0.5 * (spec.upper - spec.lower)
    K = smoothness_matrix(n, N, h, weights.velocity, weights.acceleration, 0.0, half) / N
    qv = x[: N * n]
    path_cost = weights.orientation * (180.0 / math.pi) ** 2 * 2.0 * ca.sum2(cost) / N + 0.5 * ca.dot(
        qv, ca.mtimes(ca.DM(K), qv)
    )
    f = ca.dot(u, u) + ca.dot(v, v) + PATH_COST_WEIGHT * path_cost + ELASTIC_WEIGHT * ca.sum1(sigma)

    lower, upper = joint_bounds(robot, tolerances)
    lower, upper = lower + inset, upper - inset
    free_t, free_r = float(T_max > 0), float(A_max > 0)  # a part with a zero bound stays at 0
    lbx = np.concatenate([np.tile(lower, N), np.full(m_t, -free_t), np.full(m_r, -free_r), np.zeros(N)])
    ubx = np.concatenate([np.tile(upper, N), np.full(m_t, free_t), np.full(m_r, free_r), np.full(N, 2.0)])
    options = {
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "print_time": False,
        "ipopt.tol": 1e-8,
        "ipopt.constr_viol_tol": 1e-9,
        "ipopt.max_iter": 300,
        "ipopt.mu_strategy": "adaptive",
        "ipopt.max_wall_time": float(time_limit_s),
    }
    g = ca.vertcat(*rows)
    if SKIP_SINGULARITY_CURVATURE and tolerances.singularity_margin > 0:
        # the Hessian of the Lagrangian without the singularity rows' curvature (their λ·∇²w)
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.size1())
        first = 4 * N + n * (N - 1)
        keep = ca.vertcat(lam_g[:first], ca.MX(N, 1), lam_g[first + N :])
        H = ca.triu(ca.hessian(lam_f * f + ca.dot(keep, g), x)[0])
        p_empty = ca.MX.sym("p", 0)
        options["hess_lag"] = ca.Function(
            "hess_lag", [x, p_empty, lam_f, lam_g], [H], ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"]
        )
    solver = ca.nlpsol("placement", "ipopt", {"x": x, "f": f, "g": g}, options)
    if start is not None and start.x.size == x.size1():
        x0 = np.clip(start.x, lbx, ubx)
    else:
        q_start = np.clip(np.asarray(q0, dtype=float), lower, upper).ravel()
        start_cos = ca.Function("cos_theta", [x], [cos_theta])(np.concatenate([q_start, np.zeros(m + N)]))
        sigma0 = np.clip(math.cos(cone) - np.asarray(start_cos).ravel(), 0.0, 2.0)  # what the start needs
        x0 = np.concatenate([q_start, np.zeros(m), sigma0])
    sol = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=np.concatenate(lbg), ubg=np.concatenate(ubg))
    stats = solver.stats()
    log.debug("placement search timings: %s", {k: v for k, v in stats.items() if k.startswith("t_wall")})
    xs = np.asarray(sol["x"]).ravel()
    placement = Placement(
        centre, T_max * (E_t @ xs[N * n : N * n + m_t]), A_max * (E_r @ xs[N * n + m_t : N * n + m])
    )
    slack = np.clip(xs[N * n + m :], 0.0, None)
    slack_deg = np.degrees(np.arccos(np.clip(math.cos(cone) - slack, -1.0, 1.0)) - cone)
    return SearchResult(
        placement,
        xs[: N * n].reshape(N, n),
        bool(stats.get("success", False)) and float(slack_deg.max()) <= SLACK_TOLERANCE_DEG,
        str(stats.get("return_status", "unknown")),
        int(stats.get("iter_count", 0)),
        time.perf_counter() - t0,
        slack_deg,
        xs,
    )


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
        plane = "" if bounds.free == "all" else f" in the support plane ({_plane_text(support)})"
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


def _plane_text(support: SupportPlane) -> str:
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
