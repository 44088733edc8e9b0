"""Signed distance and witness points of one pair of bodies, with python-fcl's pitfalls worked around.

What python-fcl 0.7 gives, measured (``tests/collision/test_distance.py`` keeps it honest):

* Primitive pairs (box, cylinder, sphere) with ``enable_signed_distance``: the distance is signed
  (negative = penetration depth, from libccd's EPA) and the nearest points are in world coordinates,
  on the two surfaces. These are used as they are.
* Mesh (BVH) against a primitive: the distance is right, but the nearest points are not usable:
  against a box or cylinder they come back as [mesh point, shape point] whatever the argument order,
  against a sphere in the two objects' *local* frames. The distance query is therefore only used for
  the distance and the index of the nearest triangle; the witness points come from a second query
  between that one triangle (an ``fcl.Convex``) and the other body, which is exact and in world
  coordinates.
* Mesh pairs in contact: FCL returns -1 and no depth (BVH models have no signed distance), and the
  collision contacts' depths and normals are per triangle, often pointing sideways. The penetration
  is measured instead against the planes of the triangles in contact: the depth of a face is how far
  the other body reaches behind it along the outward normal, and the face needing the smallest push
  wins (the exact answer for a convex mesh, an estimate otherwise). A body wholly inside a mesh
  touches no triangle and reads as separated; keep margins larger than the thinnest body.
"""

from __future__ import annotations

import math

import fcl
import numpy as np
from numpy.typing import NDArray

from refine.collision.geometry import Body

Array = NDArray[np.float64]

MAX_MESH_CONTACTS = 64
"""Triangles in contact examined when a body penetrates a mesh."""

_SIGNED = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=True)
_CONTACTS = fcl.CollisionRequest(num_max_contacts=MAX_MESH_CONTACTS, enable_contact=True)
_TRIANGLE_FACES = np.array([3, 0, 1, 2])
_EPS = 1e-9


def place(body: Body, T: Array) -> None:
    """Move a body's FCL object to the world pose T (4, 4) of its shape frame."""
    body.obj.setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))


def signed_distance(a: Body, T_a: Array, b: Body, T_b: Array) -> tuple[float, Array, Array, Array]:
    """Signed distance between two placed bodies and its witness points.

    Args:
        a: the first body, already placed at ``T_a`` (see :func:`place`).
        T_a: world pose of ``a``'s shape frame, (4, 4).
        b: the second body, placed at ``T_b``.
        T_b: world pose of ``b``'s shape frame, (4, 4).

    Returns:
        distance [m] (negative = penetration depth), the witness point on ``a`` and on ``b``
        (world [m], (3,) each), and the unit normal (3,) along which moving ``a`` increases the
        distance (from ``b`` towards ``a`` when they are apart).
    """
    if not (a.is_mesh or b.is_mesh):
        res = fcl.DistanceResult()
        d = float(fcl.distance(a.obj, b.obj, _SIGNED, res))
        p_a, p_b = np.asarray(res.nearest_points[0]), np.asarray(res.nearest_points[1])
        return d, p_a, p_b, _normal(d, p_a, p_b, a, T_a, b, T_b)
    swap = not a.is_mesh  # FCL handles BVH-first pairs natively; keep the mesh as the first object
    m, T_m, o, T_o = (b, T_b, a, T_a) if swap else (a, T_a, b, T_b)
    d, p_m, p_o, n_m = _mesh_distance(m, T_m, o, T_o)
    if swap:
        return d, p_o, p_m, -n_m
    return d, p_m, p_o, n_m


def _normal(d: float, p_a: Array, p_b: Array, a: Body, T_a: Array, b: Body, T_b: Array) -> Array:
    gap = p_a - p_b
    length = math.sqrt(float(gap @ gap))
    if length > _EPS:
        return gap / length if d >= 0.0 else -gap / length
    res = fcl.CollisionResult()
    fcl.collide(a.obj, b.obj, fcl.CollisionRequest(num_max_contacts=1, enable_contact=True), res)
    if res.contacts:
        n = -np.asarray(res.contacts[0].normal, dtype=float)  # FCL's normal points from o1 to o2
    else:
        n = (T_a[:3, :3] @ a.centre + T_a[:3, 3]) - (T_b[:3, :3] @ b.centre + T_b[:3, 3])
    length = float(np.linalg.norm(n))
    return n / length if length > _EPS else np.array([0.0, 0.0, 1.0])


def _triangle(body: Body, T: Array, index: int) -> fcl.CollisionObject:
    assert body.vertices is not None and body.faces is not None
    corners = body.vertices[body.faces[index]] @ T[:3, :3].T + T[:3, 3]
    return fcl.CollisionObject(fcl.Convex(corners, 1, _TRIANGLE_FACES), fcl.Transform())


def _mesh_distance(m: Body, T_m: Array, o: Body, T_o: Array) -> tuple[float, Array, Array, Array]:
    """Distance, points on m and o, and the normal along which moving m increases the distance."""
    res = fcl.DistanceResult()
    d = float(fcl.distance(m.obj, o.obj, _SIGNED, res))
    if d > _EPS and res.b1 >= 0:
        tri_m = _triangle(m, T_m, int(res.b1))
        other = _triangle(o, T_o, int(res.b2)) if o.is_mesh and res.b2 >= 0 else o.obj
        exact = fcl.DistanceResult()
        d_tri = float(fcl.distance(tri_m, other, _SIGNED, exact))
        if d_tri > 0.0:
            p_m, p_o = np.asarray(exact.nearest_points[0]), np.asarray(exact.nearest_points[1])
            return d_tri, p_m, p_o, (p_m - p_o) / max(float(np.linalg.norm(p_m - p_o)), _EPS)
    return _mesh_penetration(m, T_m, o, T_o)


def _mesh_penetration(m: Body, T_m: Array, o: Body, T_o: Array) -> tuple[float, Array, Array, Array]:
    """Penetration of o into mesh m measured against the planes of m's triangles in contact."""
    res = fcl.CollisionResult()
    fcl.collide(m.obj, o.obj, _CONTACTS, res)
    assert m.faces is not None and m.vertices is not None and m.face_normals is not None
    best: tuple[float, Array, Array, Array] | None = None
    for index in sorted({int(c.b1) for c in res.contacts if c.b1 >= 0}):
        n = T_m[:3, :3] @ m.face_normals[index]
        corner = T_m[:3, :3] @ m.vertices[m.faces[index][0]] + T_m[:3, 3]
        p_o = o.support(T_o, -n)
        depth = max(float(n @ (corner - p_o)), 0.0)
        if best is None or depth < best[0]:
            best = (depth, p_o + depth * n, p_o, -n)  # m leaves o by moving against its face normal
    if best is None:  # touching without a reported contact: distance zero, on o towards m
        n_m = _normal(0.0, np.zeros(3), np.zeros(3), m, T_m, o, T_o)
        p = o.support(T_o, n_m)
        return 0.0, p, p.copy(), n_m
    depth, p_m, p_o, n_m = best
    return -depth, p_m, p_o, n_m
