"""A workpiece move and what it must keep: its support plane and its clearance.

A workpiece move and what it must keep: :class:`Placement` (a rigid move of the part and its
fixtures), the support plane the part rests on and the directions a move may take in it, the moved
problem and path, and the clearance rows of the moved objects against the rest of the cell,
linearised at FCL's witness points.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from refine.frames import fixed_xyz_from_matrix, matrix_from_rotvec
from refine.paths import FusedPath
from refine.settings import PlacementSettings
from refine.types import Array

if TYPE_CHECKING:
    from refine.problem import Problem
    from refine.robot.model import Robot
if TYPE_CHECKING:
    from refine.robot.model import Robot

if TYPE_CHECKING:
    from refine.problem import Problem
    from refine.robot.model import Robot

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


def fcl_bodies(shapes: tuple[Any, ...]) -> list[Any]:
    """FCL bodies of cell shapes, in the world, named after the shapes."""
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
    parts = fcl_bodies(tuple(moved))
    bottom = min(-b.reach(np.asarray(o.pose, dtype=float), -up) for b, o in zip(parts, moved, strict=True))
    best: tuple[float, SupportPlane] | None = None
    for o in problem.cell:
        if o.workpiece:
            continue
        (body,) = fcl_bodies((o,))
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
    moved = fcl_bodies(moved_shapes)
    moved_poses = [D @ np.asarray(o.pose, dtype=float) for o in moved_shapes]
    for b, T in zip(moved, moved_poses, strict=True):
        place(b, T)
    others: list[tuple[Any, Array, float]] = []
    for o, b in zip(static_shapes, fcl_bodies(static_shapes), strict=True):
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


def pose_json(T: Array) -> dict[str, list[float]]:
    """A pose as the problem file writes it: ``xyz`` [m] and fixed-axis X-Y-Z ``rpy_deg``."""
    return {
        "xyz": [float(v) for v in T[:3, 3]],
        "rpy_deg": [float(v) for v in fixed_xyz_from_matrix(T[:3, :3])],
    }


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
        exact=None if fused.exact is None else fused.exact @ D[:3, :3].T + D[:3, 3],
        demo_positions=None
        if fused.demo_positions is None
        else fused.demo_positions @ D[:3, :3].T + D[:3, 3],
    )
