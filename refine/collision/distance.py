"""Signed distance and witness points of one pair of bodies, with python-fcl's pitfalls worked around.

What python-fcl 0.7 gives, measured (``tests/collision/test_distance.py`` keeps it honest):

* Primitive pairs (box, cylinder, sphere): the nearest points are in world coordinates, on the two
  surfaces. The plain (unsigned) query is used first: with ``enable_signed_distance`` separated
  pairs with a sphere go through GJK and lose up to 0.5 mm, while the plain query solves them in
  closed form. Only when it reports contact (-1) is the signed query asked for the penetration
  depth (libccd's EPA, accurate to about a micrometre). Two spheres are solved here in closed
  form: FCL's signed sphere-sphere query never returns when the centres are within ~0.1 mm.
* GJK (libccd) now and then stops early on cylinders and reports a distance too large, by up to
  9 cm in one pose met in testing (forearm against upper arm). Every separated result is therefore
  checked against the separating plane through its witness points and repeated when that fails
  (:func:`_separation`).
* Mesh (BVH) against a primitive: the distance is right, but the nearest points are not usable:
  against a box or cylinder they come back as [mesh point, shape point] whatever the argument order,
  against a sphere in the two objects' *local* frames. The mesh query is therefore only used to find
  the nearest triangle; distance and witness points come from queries between single triangles (an
  ``fcl.Convex`` each) and the other body, which are right and in world coordinates. The triangle
  FCL names is now and then a neighbour of the nearest one (off by up to 0.3 mm, seen with
  cylinders), so every triangle sharing a corner with it is queried and the nearest kept.
* Mesh pairs in contact: FCL returns -1 and no depth (BVH models have no signed distance), and the
  collision contacts' depths and normals are per triangle, often pointing sideways. The penetration
  is measured instead against the planes of the triangles in contact: the depth of a face is how far
  the other body reaches behind it along the outward normal, and the face needing the smallest push
  wins (the exact answer for a convex mesh, an estimate otherwise). A body wholly inside a mesh
  touches no triangle and reads as separated; keep margins larger than the thinnest body.
"""

from __future__ import annotations

import logging
import math
from typing import NamedTuple

import fcl
import numpy as np
from scipy.spatial.transform import Rotation

from refine.collision.geometry import Body
from refine.types import Array

log = logging.getLogger(__name__)

MAX_MESH_CONTACTS = 64
"""Triangles in contact examined when a body penetrates a mesh."""

GAP_TOLERANCE_M = 5e-5
"""A separated result is accepted when its witness points are this close to a separating plane [m]."""

_UNSIGNED = fcl.DistanceRequest(enable_nearest_points=True)
_SIGNED = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=True)
_CONTACTS = fcl.CollisionRequest(num_max_contacts=MAX_MESH_CONTACTS, enable_contact=True)
_TRIANGLE_FACES = np.array([3, 0, 1, 2])
_EPS = 1e-9
_IDENTITY = np.eye(4)
_IDENTITY.flags.writeable = False
_RETRY_TURNS = tuple(
    Rotation.from_rotvec(v).as_matrix() for v in ([0.7, 0.3, -0.5], [-0.4, 0.9, 0.2], [0.3, -0.6, 1.1])
)


class _Part(NamedTuple):
    """Something FCL can measure: a placed body (``corners`` None) or one world-frame triangle."""

    obj: fcl.CollisionObject
    geometry: fcl.CollisionGeometry
    T: Array
    body: Body
    corners: Array | None  # a triangle's corners, world [m] (3, 3)
    index: int = -1  # a triangle's index in its mesh

    def reach(self, n: Array) -> float:
        """The largest ``n . x`` over the part's points x for a world direction n (3,) [m]."""
        if self.corners is None:
            return self.body.reach(self.T, n)
        return max((self.corners @ n).tolist())

    @property
    def label(self) -> str:
        """The body's label, and the triangle's index for a triangle (for the log)."""
        return self.body.label if self.corners is None else f"{self.body.label} triangle {self.index}"


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
    if a.kind_params[0] == "sphere" and b.kind_params[0] == "sphere":
        return _sphere_sphere(a, T_a, b, T_b)
    if not (a.is_mesh or b.is_mesh):
        d, p_a, p_b = _separation(_body_part(a, T_a), _body_part(b, T_b))
        if d <= 0.0:  # in contact: FCL's plain query says -1; ask for the penetration depth
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


def hull_bound(a: Body, T_a: Array, m: Body, T_m: Array) -> float:
    """A lower bound [m] on the distance from a placed primitive body to a mesh, from its convex hull.

    Taken from the separating plane through FCL's witness points (so an early GJK stop cannot make
    it too large); ``-inf`` when the body may touch the hull or the mesh has none.
    """
    if m.hull is None or m.hull_vertices is None or a.is_mesh:
        return -math.inf
    res = fcl.DistanceResult()
    if fcl.distance(a.obj, m.hull, _UNSIGNED, res) <= 0.0:
        return -math.inf
    n = np.asarray(res.nearest_points[0]) - np.asarray(res.nearest_points[1])
    n /= max(float(np.linalg.norm(n)), _EPS)
    reach = float(np.max(m.hull_vertices @ (n @ T_m[:3, :3]))) + float(n @ T_m[:3, 3])
    return -a.reach(T_a, -n) - reach


def _body_part(body: Body, T: Array) -> _Part:
    return _Part(body.obj, body.geometry, T, body, None)


def _triangle_part(body: Body, T: Array, index: int) -> _Part:
    cached = body.triangles.get(index)
    if cached is None:
        assert body.vertices is not None and body.faces is not None
        corners = body.vertices[body.faces[index]] @ T[:3, :3].T + T[:3, 3]
        geometry = fcl.Convex(corners, 1, _TRIANGLE_FACES)
        cached = (fcl.CollisionObject(geometry, fcl.Transform()), geometry, corners)
        if body.kind == "cell":  # cell objects do not move: keep the world-frame triangle
            body.triangles[index] = cached
    obj, geometry, corners = cached
    return _Part(obj, geometry, _IDENTITY, body, corners, index)


def _query(first: _Part, second: _Part, turn: Array | None) -> tuple[float, Array, Array]:
    o1, o2 = first.obj, second.obj
    if turn is not None:  # the same pair turned as a whole: FCL's GJK starts from another direction
        o1, o2 = (
            fcl.CollisionObject(p.geometry, fcl.Transform(turn @ p.T[:3, :3], turn @ p.T[:3, 3]))
            for p in (first, second)
        )
    res = fcl.DistanceResult()
    d = float(fcl.distance(o1, o2, _UNSIGNED, res))
    p1, p2 = np.asarray(res.nearest_points[0]), np.asarray(res.nearest_points[1])
    return (d, p1, p2) if turn is None else (d, turn.T @ p1, turn.T @ p2)


def _separation(a: _Part, b: _Part) -> tuple[float, Array, Array]:
    """Distance of two separated parts and witness points, checked against a separating plane.

    Witness points are right when the plane through them normal to their offset separates the
    parts (neither part reaches past it along that normal), up to :data:`GAP_TOLERANCE_M`. When
    that check fails the query is repeated with the arguments swapped and then with the pair turned
    as a whole (GJK starts from another direction), and the smallest distance found is kept: every
    one is an upper bound, being the length between two points of the parts. In random cylinder
    pairs about 1.5 % of the results fail the check; the retries leave at most ~0.3 mm.
    """
    d, p_a, p_b = _query(a, b, None)  # the first attempt, which almost always stands
    if d <= 0.0 or _gap(d, p_a, p_b, a, b) <= GAP_TOLERANCE_M:
        return d, p_a, p_b
    best = (d, p_a, p_b)
    gap = math.inf
    for first, second, turn in ((b, a, None), *((a, b, turn) for turn in _RETRY_TURNS)):
        d, p1, p2 = _query(first, second, turn)
        p_a, p_b = (p2, p1) if first is b else (p1, p2)
        if d <= 0.0:
            return d, p_a, p_b
        gap = _gap(d, p_a, p_b, a, b)
        if d < best[0]:
            best = (d, p_a, p_b)
        if gap <= GAP_TOLERANCE_M:
            break
    else:
        log.debug(
            "%s vs %s: FCL's distance not confirmed (%.2g m from a separating plane)", a.label, b.label, gap
        )
    return best


def _gap(d: float, p_a: Array, p_b: Array, a: _Part, b: _Part) -> float:
    """``d`` less the width of the gap between the parts along the unit offset of their witness points [m]."""
    offset = p_a - p_b
    n = offset / max(math.sqrt(float(offset @ offset)), _EPS)
    return d + a.reach(-n) + b.reach(n)


def _sphere_sphere(a: Body, T_a: Array, b: Body, T_b: Array) -> tuple[float, Array, Array, Array]:
    """Closed form: FCL's signed sphere-sphere query never returns for centres within ~0.1 mm."""
    r_a, r_b = a.kind_params[1], b.kind_params[1]
    c_a, c_b = T_a[:3, 3], T_b[:3, 3]
    u = c_a - c_b
    length = math.sqrt(float(u @ u))
    n = u / length if length > _EPS else np.array([0.0, 0.0, 1.0])
    return length - r_a - r_b, c_a - r_a * n, c_b + r_b * n, n


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


def _mesh_distance(m: Body, T_m: Array, o: Body, T_o: Array) -> tuple[float, Array, Array, Array]:
    """Distance, points on m and o, and the normal along which moving m increases the distance."""
    res = fcl.DistanceResult()
    d = float(fcl.distance(m.obj, o.obj, _UNSIGNED, res))
    if d > _EPS and res.b1 >= 0:
        other = _triangle_part(o, T_o, int(res.b2)) if o.is_mesh and res.b2 >= 0 else _body_part(o, T_o)
        best: tuple[float, Array, Array] | None = None
        for index in m.ring(int(res.b1)):  # FCL's triangle is now and then a neighbour of the nearest
            found = _separation(_triangle_part(m, T_m, int(index)), other)
            if found[0] > 0.0 and (best is None or found[0] < best[0]):
                best = found
        if best is not None:
            d_tri, p_m, p_o = best
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
