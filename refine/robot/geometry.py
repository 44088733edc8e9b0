"""Collision geometry of a robot, read from the ``<collision>`` elements of its URDF.

Primitives (``<cylinder>``, ``<box>``, ``<sphere>``) become FCL primitives. A ``<mesh>`` (STL,
OBJ, PLY; path relative to the URDF, ``scale`` honoured) becomes the ``fcl.Convex`` of its
convex hull: FCL distance queries stay in the microsecond range and have a depth when they
overlap. The registry's robots hold convex pieces computed from their makers' meshes (see
:mod:`refine.robot.convex`), so the hull of each file is the file. URDF cylinders and FCL
cylinders share a convention (axis along the local z, centred on the origin), so a URDF
``<origin>`` is the shape pose in its link frame as it stands.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import fcl
import numpy as np
from lxml import etree
from numpy.typing import ArrayLike, NDArray

from refine.errors import InputError
from refine.frames import make_transform, matrix_from_fixed_xyz
from refine.lazy import on_first_use
from refine.robot.convex import ConvexPiece

if TYPE_CHECKING:
    import trimesh
else:
    trimesh = on_first_use("trimesh")  # the first mesh call imports it

SUPPORTED_GEOMETRY = ("box", "cylinder", "sphere", "mesh")


@dataclass(frozen=True, eq=False)
class CollisionShape:
    """One collision primitive attached to a robot link.

    Attributes:
        link: name of the link (URDF ``<link name>``) the shape moves with.
        name: the ``<collision name>`` or ``"<link>_<index>"`` when unnamed; unique per link.
        geometry: the FCL geometry (``fcl.Box``, ``fcl.Cylinder``, ``fcl.Sphere`` or ``fcl.Convex``) [m].
        link_T_shape: pose of the shape in the link frame, (4, 4).
        convex: for a mesh, its convex hull in the shape frame [m] (the corners FCL's ``Convex``
            holds); None for primitives.
    """

    link: str
    name: str
    geometry: fcl.CollisionGeometry
    link_T_shape: NDArray[np.float64]
    convex: ConvexPiece | None = None

    def collision_object(self, T_world_link: NDArray[np.float64]) -> fcl.CollisionObject:
        """FCL object for this shape placed at a link pose (4, 4) in the world [m]."""
        T = np.asarray(T_world_link, dtype=float) @ self.link_T_shape
        return fcl.CollisionObject(self.geometry, fcl.Transform(T[:3, :3], T[:3, 3]))


def _floats(element: etree._Element, attribute: str, n: int, where: str) -> list[float]:
    text = element.get(attribute)
    if text is None:
        raise InputError(f"{where}: <{element.tag}> has no '{attribute}' attribute")
    try:
        values = [float(v) for v in text.split()]
    except ValueError as e:
        raise InputError(f"{where}: {attribute}={text!r} is not {n} numbers") from e
    if len(values) != n:
        raise InputError(f"{where}: {attribute}={text!r} has {len(values)} numbers, expected {n}")
    return values


def fcl_convex(piece: ConvexPiece) -> fcl.Convex:
    """The ``fcl.Convex`` of a convex polytope (its triangles as faces)."""
    faces = np.hstack([np.full((len(piece.faces), 1), 3), piece.faces]).ravel()
    return fcl.Convex(np.ascontiguousarray(piece.vertices), len(piece.faces), faces)


def read_mesh(path: Path, where: str) -> trimesh.Trimesh:
    """A mesh file's triangles as they stand in the file (no unit scaling of ours).

    STL, OBJ, PLY and COLLADA (``.dae``, through pycollada) are read by trimesh; a COLLADA file
    states its length unit (``<unit meter="0.001"/>``), which is applied, so its triangles come in
    metres (the unit scaling the caller applies comes on top).

    Raises:
        InputError: starting with ``where``, if the file is missing, unreadable or holds no triangles.
    """
    if not path.is_file():
        raise InputError(f"{where}: mesh file {path} not found")
    if path.suffix.lower() == ".dae":
        try:
            import collada  # noqa: F401  (trimesh reads COLLADA through pycollada)
        except ImportError as e:
            raise InputError(f"{where}: mesh {path} is COLLADA, which needs pycollada (pip install pycollada)") from e
    try:
        mesh = trimesh.load(str(path), force="mesh")
    except Exception as e:  # trimesh raises many kinds for bad files
        raise InputError(f"{where}: cannot read mesh {path}: {e}") from e
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(f"{where}: mesh {path} holds no triangles")
    if path.suffix.lower() == ".dae" and mesh.units not in (None, "meters", "m"):
        mesh.convert_units("meters")  # the file's own <unit meter="...">
    return mesh


def mesh_hull(path: str | Path, scale: ArrayLike = (1.0, 1.0, 1.0), where: str = "") -> ConvexPiece:
    """The convex hull [m] of a mesh file's vertices times ``scale`` (per axis).

    Raises:
        InputError: naming the file if it cannot be read, holds no triangles or has no volume.
    """
    mesh = read_mesh(Path(path), where)
    try:
        return ConvexPiece.hull_of(np.asarray(mesh.vertices) * np.asarray(scale, dtype=float))
    except InputError as e:
        raise InputError(f"{where}: mesh {path}: {e}") from e


def _geometry(
    element: etree._Element, where: str, folder: Path
) -> tuple[fcl.CollisionGeometry, ConvexPiece | None]:
    children = [c for c in element if isinstance(c.tag, str)]
    if len(children) != 1:
        raise InputError(f"{where}: <geometry> must hold exactly one shape, got {len(children)}")
    shape = children[0]
    if shape.tag == "mesh":
        filename = shape.get("filename")
        if not filename:
            raise InputError(f"{where}: <mesh> has no 'filename' attribute")
        if "://" in filename:
            raise InputError(
                f"{where}: mesh {filename!r}: only paths relative to the URDF's folder are supported "
                f"(no package:// or file:// URLs)"
            )
        scale = _floats(shape, "scale", 3, where) if shape.get("scale") else [1.0] * 3
        piece = mesh_hull(folder / filename, scale, where)
        return fcl_convex(piece), piece
    if shape.tag == "box":
        dims = _floats(shape, "size", 3, where)
    elif shape.tag == "cylinder":
        dims = _floats(shape, "radius", 1, where) + _floats(shape, "length", 1, where)
    elif shape.tag == "sphere":
        dims = _floats(shape, "radius", 1, where)
    else:
        raise InputError(
            f"{where}: collision geometry <{shape.tag}> is not supported; "
            f"allowed: {', '.join(SUPPORTED_GEOMETRY)}"
        )
    if min(dims) <= 0.0:
        raise InputError(f"{where}: <{shape.tag}> dimensions must be positive, got {dims}")
    if shape.tag == "box":
        return fcl.Box(*dims), None
    if shape.tag == "cylinder":
        return fcl.Cylinder(dims[0], dims[1]), None
    return fcl.Sphere(dims[0]), None


def collision_shapes_from_urdf(urdf: str | Path) -> list[CollisionShape]:
    """Read every ``<collision>`` primitive of a URDF, in document order.

    Args:
        urdf: path to the URDF file.

    Returns:
        One CollisionShape per ``<collision>`` element.

    Raises:
        InputError: if the file is not valid XML or a collision element is malformed or uses a
            geometry other than box, cylinder or sphere.
    """
    try:
        root = etree.parse(str(urdf)).getroot()
    except (OSError, etree.XMLSyntaxError) as e:
        raise InputError(f"cannot read URDF {urdf}: {e}") from e
    shapes: list[CollisionShape] = []
    for link in root.iter("link"):
        link_name = link.get("name", "")
        for k, col in enumerate(link.findall("collision")):
            name = col.get("name") or f"{link_name}_{k}"
            where = f"{Path(urdf).name}: link {link_name!r}, collision {name!r}"
            if any(s.link == link_name and s.name == name for s in shapes):
                raise InputError(f"{where}: two collision elements share this name on one link")
            geometry = col.find("geometry")
            if geometry is None:
                raise InputError(f"{where}: <collision> has no <geometry>")
            T = np.eye(4)
            origin = col.find("origin")
            if origin is not None:
                xyz = _floats(origin, "xyz", 3, where) if origin.get("xyz") else [0.0] * 3
                rpy = _floats(origin, "rpy", 3, where) if origin.get("rpy") else [0.0] * 3
                T = make_transform(matrix_from_fixed_xyz(rpy, degrees=False), xyz)
            T.setflags(write=False)
            fcl_geometry, convex = _geometry(geometry, where, Path(urdf).parent)
            shapes.append(CollisionShape(link_name, name, fcl_geometry, T, convex))
    return shapes
