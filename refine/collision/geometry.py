"""Collision bodies: FCL objects with the bounds and support functions the queries need.

A :class:`Body` is one FCL object of the collision model: a robot link primitive, a tool shape on
the flange, or a cell object. Next to the FCL object it keeps what FCL does not offer in a usable
form: a box bounding the shape in its own frame (for the broad phase); its support function (the
point furthest along a direction: it certifies FCL's answers against a separating plane and
measures how far a body reaches through a mesh face); and for meshes the triangles, outward face
normals and convex hull (FCL's mesh witness points are repaired with them, and the hull gives a
cheap lower bound; see :mod:`refine.collision.distance`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import fcl
import numpy as np
from numpy.typing import NDArray

from refine.errors import InputError
from refine.lazy import on_first_use
from refine.robot.convex import ConvexPiece
from refine.robot.geometry import CollisionShape, fcl_convex, read_mesh
from refine.settings import Shape
from refine.types import Array

if TYPE_CHECKING:
    import trimesh
else:
    trimesh = on_first_use("trimesh")  # the first mesh call imports it

log = logging.getLogger(__name__)

UNIT_SCALE = {"m": 1.0, "mm": 1e-3, "in": 0.0254}
"""Metres per unit of a mesh file."""


@dataclass(eq=False)
class Body:
    """One collision object and what the queries need to know about it.

    Attributes:
        name: the name contacts report: the robot link, ``"tool:<shape>"`` or the cell object.
        shape: the shape's own name (URDF collision name, tool or cell shape name).
        kind: ``"link"``, ``"tool"`` or ``"cell"``.
        link: the URDF link (Pinocchio frame) the body moves with; None for cell objects.
        frame_id: Pinocchio frame index of ``link`` (-1 for cell objects).
        joint: Pinocchio joint that moves ``link`` (0: fixed to the base; -1 for cell objects).
        link_T_shape: pose of the shape in its link frame, or in the world for cell objects, (4, 4).
        geometry: the FCL geometry, in the shape frame [m].
        obj: the FCL object placed in the world.
        kind_params: ``("box", half sizes)``, ``("cylinder", radius, half length)``,
            ``("sphere", radius)``, ``("convex", corners (C, 3))`` (an ``fcl.Convex``, measured
            like the primitives) or ``("mesh",)``.
        half_extent: half sizes of a box bounding the shape, centred on ``centre`` [m], (3,).
        centre: centre of that box in the shape frame [m], (3,).
        vertices: mesh vertices in the shape frame [m], (V, 3), or None.
        faces: mesh triangles as vertex indices, (F, 3), or None.
        face_normals: outward unit normals of the triangles in the shape frame, (F, 3), or None.
        vertex_faces: per vertex, the triangles using it, padded with -1, (V, k), or None.
        hull: the mesh's convex hull as an FCL object placed like the body, or None.
        hull_vertices: the hull's corners in the shape frame [m], (H, 3), or None.
        workpiece: a cell object the process touches by design (the tool is not checked against it).
        triangles: single world-frame triangles of a cell mesh as (FCL object, geometry, corners),
            built on demand.
        convex_piece: the polytope of a ``"convex"`` body, in the shape frame; None otherwise.
    """

    name: str
    shape: str
    kind: str
    link: str | None
    frame_id: int
    joint: int
    link_T_shape: Array
    geometry: fcl.CollisionGeometry
    obj: fcl.CollisionObject
    kind_params: tuple
    half_extent: Array
    centre: Array
    vertices: Array | None = None
    faces: NDArray[np.int64] | None = None
    face_normals: Array | None = None
    vertex_faces: NDArray[np.int64] | None = None
    hull: fcl.CollisionObject | None = None
    hull_vertices: Array | None = None
    workpiece: bool = False
    triangles: dict[int, tuple] = field(default_factory=dict)
    convex_piece: ConvexPiece | None = None

    @property
    def label(self) -> str:
        """``name`` for tool shapes and cell objects, ``"<link>/<shape>"`` for link shapes."""
        return f"{self.name}/{self.shape}" if self.kind == "link" else self.name

    @property
    def is_mesh(self) -> bool:
        """True for a triangle mesh (an FCL BVHModel)."""
        return self.vertices is not None

    def ring(self, index: int) -> NDArray[np.int64]:
        """The triangle ``index`` of a mesh and every triangle sharing a corner with it."""
        assert self.vertex_faces is not None and self.faces is not None
        near = np.unique(self.vertex_faces[self.faces[index]])
        return near[near >= 0]

    def outside_distance(self, T: Array, point: Array) -> float:
        """Distance [m] from a world point to the body placed at T (4, 4); zero inside."""
        x = T[:3, :3].T @ (np.asarray(point, dtype=float) - T[:3, 3])
        tag = self.kind_params[0]
        if tag == "sphere":
            return max(float(np.linalg.norm(x)) - self.kind_params[1], 0.0)
        if tag == "box":
            return float(np.linalg.norm(np.maximum(np.abs(x) - self.kind_params[1], 0.0)))
        if tag == "cylinder":
            radial = max(float(np.hypot(x[0], x[1])) - self.kind_params[1], 0.0)
            return float(np.hypot(radial, max(abs(float(x[2])) - self.kind_params[2], 0.0)))
        if tag == "convex" and self.convex_piece is not None and self.convex_piece.outside(x)[0] <= 0.0:
            return 0.0
        probe = fcl.CollisionObject(fcl.Sphere(1e-9), fcl.Transform(np.eye(3), np.asarray(point, float)))
        return max(float(fcl.distance(probe, self.obj, fcl.DistanceRequest())), 0.0)

    def reach(self, T: Array, direction: Array) -> float:
        """Largest ``direction . x`` [m] over the points x of the body placed at T (4, 4)."""
        lifted = direction @ T[:3, :]  # d . [R | t] at once: the direction in the shape frame, and d . t
        base, local = float(lifted[3]), lifted[:3]
        if self.vertices is not None:
            return base + float((self.vertices @ local).max())
        tag, *dims = self.kind_params
        if tag == "convex":
            return base + float((dims[0] @ local).max())
        ux, uy, uz = local.tolist()
        if tag == "sphere":
            return base + dims[0] * math.sqrt(ux * ux + uy * uy + uz * uz)
        if tag == "box":
            hx, hy, hz = dims[0].tolist()
            return base + hx * abs(ux) + hy * abs(uy) + hz * abs(uz)
        return base + dims[1] * abs(uz) + dims[0] * math.hypot(ux, uy)

    def reach_many(self, Ts: Array, direction: Array) -> Array:
        """:meth:`reach` at every pose of ``Ts`` (K, 4, 4), (K,) [m].

        ``direction``: one (3,) for every pose, or one per pose (K, 3).
        """
        d = np.asarray(direction, dtype=float)
        # d . [R | t] at once: the direction in each shape frame (K, 3) and d . t (K,), one pass over the poses
        lifted = np.einsum("ki,kij->kj", d, Ts[:, :3, :]) if d.ndim == 2 else d @ Ts[:, :3, :]
        local, base = lifted[:, :3], lifted[:, 3]
        if self.vertices is not None:
            return base + (local @ self.vertices.T).max(axis=1)
        tag, *dims = self.kind_params
        if tag == "convex":
            return base + (local @ dims[0].T).max(axis=1)
        if tag == "sphere":
            return base + dims[0] * np.linalg.norm(d, axis=-1)
        if tag == "box":
            return base + np.abs(local) @ dims[0]
        return base + dims[1] * np.abs(local[:, 2]) + dims[0] * np.hypot(local[:, 0], local[:, 1])

    def support(self, T: Array, direction: Array) -> Array:
        """The point of the body placed at T (4, 4) furthest along ``direction`` (3,), world [m]."""
        R, c = T[:3, :3], T[:3, 3]
        u = R.T @ direction
        tag = self.kind_params[0]
        if tag == "sphere":
            return c + self.kind_params[1] * direction / np.linalg.norm(direction)
        if tag == "box":
            return c + R @ (np.sign(u) * self.kind_params[1])
        if tag == "cylinder":
            radius, half_length = self.kind_params[1], self.kind_params[2]
            local = np.array([0.0, 0.0, np.sign(u[2]) * half_length])
            radial = np.hypot(u[0], u[1])
            if radial > 1e-12:
                local[:2] = radius * u[:2] / radial
            return c + R @ local
        if tag == "convex":
            corners = self.kind_params[1]
            return c + R @ corners[int(np.argmax(corners @ u))]
        assert self.vertices is not None
        return c + R @ self.vertices[int(np.argmax(self.vertices @ u))]


def fcl_geometry(shape: Shape) -> fcl.CollisionGeometry:
    """The FCL box, cylinder (along z, centred) or sphere of a primitive :class:`Shape`."""
    if shape.shape == "box":
        return fcl.Box(*shape.size_m)
    if shape.shape == "cylinder":
        return fcl.Cylinder(float(shape.radius_m), float(shape.length_m))  # type: ignore[arg-type]
    if shape.shape == "sphere":
        return fcl.Sphere(float(shape.radius_m))  # type: ignore[arg-type]
    raise InputError(f"shape {shape.name!r}: {shape.shape} is not a primitive (box, cylinder, sphere)")


def _primitive(shape: Shape) -> tuple[fcl.CollisionGeometry, tuple, Array]:
    geometry = fcl_geometry(shape)
    params, half = primitive_from_fcl(geometry, f"shape {shape.name!r}")
    return geometry, params, half


def primitive_from_fcl(geometry: fcl.CollisionGeometry, where: str) -> tuple[tuple, Array]:
    """Support parameters and half extents [m] of an FCL box, cylinder or sphere."""
    if isinstance(geometry, fcl.Box):
        half = np.asarray(geometry.side, dtype=float) / 2.0
        return ("box", half), half
    if isinstance(geometry, fcl.Cylinder):
        r, h = float(geometry.radius), float(geometry.lz) / 2.0
        return ("cylinder", r, h), np.array([r, r, h])
    if isinstance(geometry, fcl.Sphere):
        r = float(geometry.radius)
        return ("sphere", r), np.full(3, r)
    raise InputError(f"{where}: collision geometry {type(geometry).__name__} is not supported")


def convex_parts(piece: ConvexPiece, geometry: fcl.Convex | None = None) -> dict:
    """Support parameters, bounding box and FCL geometry of a convex :class:`Body`."""
    lo, hi = piece.vertices.min(axis=0), piece.vertices.max(axis=0)
    return {
        "geometry": fcl_convex(piece) if geometry is None else geometry,
        "kind_params": ("convex", piece.vertices),
        "half_extent": (hi - lo) / 2.0,
        "centre": (hi + lo) / 2.0,
        "convex_piece": piece,
    }


def link_body(shape: CollisionShape, frame_id: int, joint: int, where: str) -> Body:
    """A :class:`Body` for a robot link shape from the URDF (its FCL geometry is shared)."""
    if shape.convex is not None:
        parts = convex_parts(shape.convex, shape.geometry)
    else:
        params, half = primitive_from_fcl(shape.geometry, f"{where} link {shape.link!r}")
        parts = {
            "geometry": shape.geometry,
            "kind_params": params,
            "half_extent": half,
            "centre": np.zeros(3),
        }
    return Body(
        name=shape.link,
        shape=shape.name,
        kind="link",
        link=shape.link,
        frame_id=frame_id,
        joint=joint,
        link_T_shape=np.array(shape.link_T_shape),
        obj=fcl.CollisionObject(shape.geometry),
        **parts,
    )


def load_mesh(shape: Shape) -> trimesh.Trimesh:
    """Read a shape's mesh file in metres, with outward normals when the mesh is closed.

    Raises:
        InputError: naming the shape and file if it cannot be read or holds no triangles.
    """
    path = Path(shape.file) if shape.file is not None else None
    if path is None:
        raise InputError(f"shape {shape.name!r}: mesh file None not found")
    mesh = read_mesh(path, f"shape {shape.name!r}")
    mesh.apply_scale(UNIT_SCALE[shape.units])
    if mesh.is_watertight and mesh.volume < 0.0:
        mesh.invert()
    if not mesh.is_watertight:
        log.warning(
            "mesh %r (%s) is not closed: penetration into it is measured against its faces' "
            "planes as wound in the file",
            shape.name,
            path,
        )
    return mesh


def mesh_body_parts(mesh: trimesh.Trimesh) -> dict:
    """FCL BVH (OBBRSS) geometry and the mesh arrays of a :class:`Body`."""
    vertices = np.ascontiguousarray(mesh.vertices, dtype=float)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    geometry = fcl.BVHModel()
    geometry.beginModel(len(vertices), len(faces))
    geometry.addSubModel(vertices, faces.astype(np.int32))
    geometry.endModel()
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    return {
        "geometry": geometry,
        "kind_params": ("mesh",),
        "half_extent": (hi - lo) / 2.0,
        "centre": (hi + lo) / 2.0,
        "vertices": vertices,
        "faces": faces,
        "face_normals": np.asarray(mesh.face_normals, dtype=float),
        "vertex_faces": np.asarray(mesh.vertex_faces, dtype=np.int64),
        **_hull(mesh),
    }


def _hull(mesh: trimesh.Trimesh) -> dict:
    try:
        hull = mesh.convex_hull
    except Exception as e:  # qhull fails on flat or degenerate meshes; the bound is only a speed-up
        log.debug("no convex hull for a mesh (%s): its pairs are bounded by boxes only", e)
        return {}
    corners = np.ascontiguousarray(hull.vertices, dtype=float)
    faces = np.hstack([np.full((len(hull.faces), 1), 3), hull.faces]).ravel()
    return {
        "hull": fcl.CollisionObject(fcl.Convex(corners, len(hull.faces), faces)),
        "hull_vertices": corners,
    }


def tool_hull(shape: Shape) -> ConvexPiece:
    """The convex hull [m] of a tool shape's mesh file, in the shape frame.

    Raises:
        InputError: naming the shape if the file is missing, unreadable, or flat.
    """
    where = f"tool shape {shape.name!r}"
    if shape.file is None:
        raise InputError(f"{where}: a mesh shape needs a file")
    mesh = read_mesh(Path(shape.file), where)
    try:
        return ConvexPiece.hull_of(np.asarray(mesh.vertices) * UNIT_SCALE[shape.units])
    except InputError as e:
        raise InputError(f"{where}: {e}") from e


def shape_body(shape: Shape, *, name: str, kind: str, link: str | None, frame_id: int, joint: int) -> Body:
    """A :class:`Body` for a tool shape (pose in the flange frame) or a cell object (world)."""
    pose = np.array(shape.pose, dtype=float)
    if shape.shape == "mesh" and kind == "tool":  # a torch or gun model: its hull, measured like a primitive
        parts = convex_parts(tool_hull(shape))
    elif shape.shape == "mesh":
        parts = mesh_body_parts(load_mesh(shape))
    else:
        geometry, params, half = _primitive(shape)
        parts = {"geometry": geometry, "kind_params": params, "half_extent": half, "centre": np.zeros(3)}
    obj = fcl.CollisionObject(parts["geometry"], fcl.Transform(pose[:3, :3], pose[:3, 3]))
    if parts.get("hull") is not None:
        parts["hull"].setTransform(fcl.Transform(pose[:3, :3], pose[:3, 3]))
    return Body(
        name=name,
        shape=shape.name,
        kind=kind,
        link=link,
        frame_id=frame_id,
        joint=joint,
        link_T_shape=pose,
        obj=obj,
        workpiece=bool(shape.workpiece) and kind == "cell",
        **parts,
    )


def check_body_names(bodies: list[Body]) -> None:
    """Reject a tool shape or cell object named as another body or a robot link (InputError)."""
    links = {b.name for b in bodies if b.kind == "link"}
    seen: set[str] = set()
    for b in bodies:
        if b.kind == "link":
            continue
        if b.name in seen or b.name in links:
            raise InputError(
                f"collision model: the name {b.name!r} is used twice (tool shapes, cell objects and "
                f"robot links {sorted(links)} must all have distinct names)"
            )
        seen.add(b.name)


def world_aabb(T: Array, centre: Array, half: Array) -> tuple[Array, Array]:
    """Axis-aligned box (centre, half sizes) [m] around a shape box placed at T (..., 4, 4)."""
    R = T[..., :3, :3]
    c = T[..., :3, 3] + (R @ centre[..., None])[..., 0]
    h = (np.abs(R) @ half[..., None])[..., 0]
    return c, h
