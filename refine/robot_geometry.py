"""Collision geometry of a robot, read from the ``<collision>`` elements of its URDF.

Only primitives are accepted (``<cylinder>``, ``<box>``, ``<sphere>``) so that FCL distance
queries stay in the microsecond range; a ``<mesh>`` is an error. URDF cylinders and FCL
cylinders share a convention (axis along the local z, centred on the origin), so a URDF
``<origin>`` is the shape pose in its link frame as it stands.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import fcl
import numpy as np
from lxml import etree
from numpy.typing import NDArray

from refine.errors import InputError
from refine.frames import make_transform, matrix_from_fixed_xyz

SUPPORTED_GEOMETRY = ("box", "cylinder", "sphere")


@dataclass(frozen=True, eq=False)
class CollisionShape:
    """One collision primitive attached to a robot link.

    Attributes:
        link: name of the link (URDF ``<link name>``) the shape moves with.
        name: the ``<collision name>`` or ``"<link>_<index>"`` when unnamed; unique per link.
        geometry: the FCL primitive (``fcl.Box``, ``fcl.Cylinder`` or ``fcl.Sphere``) [m].
        link_T_shape: pose of the shape in the link frame, (4, 4).
    """

    link: str
    name: str
    geometry: fcl.CollisionGeometry
    link_T_shape: NDArray[np.float64]

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


def _geometry(element: etree._Element, where: str) -> fcl.CollisionGeometry:
    children = [c for c in element if isinstance(c.tag, str)]
    if len(children) != 1:
        raise InputError(f"{where}: <geometry> must hold exactly one shape, got {len(children)}")
    shape = children[0]
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
        return fcl.Box(*dims)
    if shape.tag == "cylinder":
        return fcl.Cylinder(dims[0], dims[1])
    return fcl.Sphere(dims[0])


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
            shapes.append(CollisionShape(link_name, name, _geometry(geometry, where), T))
    return shapes
