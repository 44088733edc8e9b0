"""Convex collision shapes computed from a link's (or tool's) triangle mesh.

A detailed mesh is too slow for the dense clearance check and, being hollow or open, cannot tell
penetration depth. It is therefore replaced by a few convex polytopes that contain it:

1. :func:`convex_cover` cuts the mesh into slabs along one direction (only where its convex hull
   reaches too far beyond the mesh, e.g. an arm tube beside a joint housing) and takes the convex
   hull of the surface inside each slab. The hulls of the slabs cover the whole solid: a point of the
   solid inside a slab lies on a segment, parallel to the cutting planes, between two surface points
   of that slab.
2. :func:`outer_polytope` simplifies each hull to a few dozen faces from the outside: it intersects
   supporting half-spaces (every one touches the hull, so the hull stays inside), adding the plane
   that cuts off the corner farthest from the hull until every corner is within ``tolerance_m``.
   The distance to a convex set is convex, so its largest value over the polytope is at a corner:
   the polytope reaches at most ``tolerance_m`` beyond the hull.

The result contains every vertex of the mesh exactly (half-spaces are pushed out by
:data:`PAD_M`), and how far it reaches beyond the mesh is measured by :func:`overshoot`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull, HalfspaceIntersection, cKDTree

from refine.errors import InputError
from refine.lazy import on_first_use
from refine.types import Array

if TYPE_CHECKING:
    import trimesh
else:
    trimesh = on_first_use("trimesh")  # the first mesh call imports it

log = logging.getLogger(__name__)

PAD_M = 1e-6
"""Every supporting half-space is pushed out by this much [m], so rounding never uncovers a vertex."""
MERGE_M = 1e-7
"""Corners of a simplified piece closer than this are one [m]; dropping one moves no face by more than
this, far less than :data:`PAD_M`."""


@dataclass(frozen=True, eq=False)
class ConvexPiece:
    """A convex polytope given by its corners and outward-wound triangles.

    Attributes:
        vertices: corners [m], shape (V, 3).
        faces: triangles as corner indices, counter-clockwise seen from outside, shape (F, 3).
    """

    vertices: Array
    faces: NDArray[np.int64]

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=float)
        f = np.asarray(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4 or not np.all(np.isfinite(v)):
            raise InputError(f"convex piece: vertices must be (V >= 4, 3) finite values [m], got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.min() < 0 or f.max() >= len(v):
            raise InputError(f"convex piece: faces must be (F, 3) indices below {len(v)}, got {f.shape}")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)

    @classmethod
    def hull_of(cls, points: ArrayLike) -> ConvexPiece:
        """The convex hull of points [m], shape (N >= 4, 3), not all in one plane."""
        hull = _qhull(points)
        return cls(hull.vertices, hull.faces)

    @property
    def mesh(self) -> trimesh.Trimesh:
        """The polytope as a closed trimesh."""
        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    @property
    def plane_count(self) -> int:
        """Number of planar faces (coplanar triangles counted once)."""
        mesh = self.mesh
        return len(mesh.facets) + len(mesh.faces) - sum(len(f) for f in mesh.facets)

    def contains(self, points: ArrayLike, tolerance_m: float = 0.0) -> NDArray[np.bool_]:
        """Whether each point [m], shape (N, 3), is inside or within ``tolerance_m`` of a face plane."""
        return self.outside(points) <= tolerance_m

    def outside(self, points: ArrayLike) -> Array:
        """Largest face-plane excess of each point [m], shape (N,).

        It is <= 0 inside, and a lower bound on the distance outside.
        """
        p = np.atleast_2d(np.asarray(points, dtype=float))
        tri = self.vertices[self.faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        keep = np.linalg.norm(n, axis=1) > 1e-14
        n = n[keep] / np.linalg.norm(n[keep], axis=1)[:, None]
        b = np.einsum("ij,ij->i", n, tri[keep, 0])
        return np.max(p @ n.T - b, axis=1)

    def write_obj(self, path: str | Path, comment: str = "") -> None:
        """Write the polytope as a Wavefront OBJ file (metres, 9 decimals)."""
        lines = [f"# {line}" for line in comment.splitlines()]
        lines += [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in self.vertices]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in self.faces]
        Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def _qhull(points: ArrayLike) -> trimesh.Trimesh:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 4:
        raise InputError(f"convex hull: need (N >= 4, 3) points [m], got shape {p.shape}")
    try:
        hull = trimesh.convex.convex_hull(p)
        if not hull.is_watertight:
            # trimesh's repair drops sliver triangles (near-coplanar corners), opening the surface;
            # qhull's own triangles are closed: keep them all, wound outward
            hull = trimesh.convex.convex_hull(p, repair=False)
            trimesh.repair.fix_normals(hull, multibody=False)
    except Exception as e:  # qhull raises its own error types for flat or degenerate input
        raise InputError(f"convex hull of {len(p)} points failed (all in one plane?): {e}") from e
    if hull.volume <= 0.0:
        raise InputError(f"convex hull of {len(p)} points has no volume (all in one plane?)")
    return hull


def _distance_to_hull(points: Array, hull: trimesh.Trimesh) -> Array:
    """Distance [m] of points outside a convex hull to it (0 inside), shape (N,)."""
    keep = hull.area_faces > 1e-14  # qhull leaves slivers; their normals are undefined
    tri = hull.triangles[keep]
    out = np.zeros(len(points))
    n = hull.face_normals[keep]
    b = np.einsum("ij,ij->i", n, tri[:, 0])
    outside = np.max(points @ n.T - b, axis=1) > 0.0
    for i in np.flatnonzero(outside):
        closest = trimesh.triangles.closest_point(tri, np.repeat(points[i : i + 1], len(tri), axis=0))
        out[i] = float(np.min(np.linalg.norm(closest - points[i], axis=1)))
    return out


def outer_polytope(points: ArrayLike, *, tolerance_m: float = 0.005, max_planes: int = 40) -> ConvexPiece:
    """A polytope of few faces containing the convex hull of ``points`` and close to it.

    Args:
        points: the points to enclose [m], shape (N >= 4, 3), spanning a volume.
        tolerance_m: stop once no corner is farther than this from the hull [m].
        max_planes: stop adding planes at this count (the result may then be looser than
            ``tolerance_m``; it still contains every point).

    Returns:
        The polytope; every point is inside it (up to :data:`PAD_M` outward).
    """
    if not tolerance_m > 0.0 or max_planes < 6:
        raise InputError(
            f"outer polytope: tolerance_m must be > 0 [m] and max_planes >= 6, got {tolerance_m}, {max_planes}"
        )
    hull = _qhull(points)
    corners = np.asarray(hull.vertices, dtype=float)
    centre = corners.mean(axis=0)
    axes = np.linalg.svd(corners - centre, full_matrices=False)[2]  # principal directions, rows
    normals = [s * a for a in axes for s in (1.0, -1.0)]  # the principal box, then corners cut off
    while True:
        N = np.array(normals)
        b = np.max(corners @ N.T, axis=0) + PAD_M
        vertices = HalfspaceIntersection(np.hstack([N, -b[:, None]]), centre).intersections
        gaps = _distance_to_hull(vertices, hull)
        worst = int(np.argmax(gaps))
        if gaps[worst] <= tolerance_m or len(normals) >= max_planes:
            break
        # the supporting plane facing the farthest corner from its nearest point on the hull cuts it off
        tri = hull.triangles[hull.area_faces > 1e-14]
        closest = trimesh.triangles.closest_point(
            tri, np.repeat(vertices[worst : worst + 1], len(tri), axis=0)
        )
        nearest = closest[np.argmin(np.linalg.norm(closest - vertices[worst], axis=1))]
        normals.append((vertices[worst] - nearest) / gaps[worst])
    vertices = _merge_close(vertices)
    result = ConvexHull(vertices)
    piece = ConvexPiece.hull_of(vertices[result.vertices])
    log.debug(
        "outer polytope: %d corners, %d faces, %.1f mm beyond the hull",
        len(piece.vertices),
        piece.plane_count,
        gaps[worst] * 1e3,
    )
    return piece


def _merge_close(points: Array) -> Array:
    """``points`` without the later of any two closer than :data:`MERGE_M`.

    Qhull would leave a sliver face between two such corners, and the hull read back from the file
    would not be closed.
    """
    drop = {j for _, j in cKDTree(points).query_pairs(MERGE_M)}
    return points[[k for k in range(len(points)) if k not in drop]]


def overshoot(
    pieces: list[ConvexPiece], mesh: trimesh.Trimesh, *, samples: int = 2000, seed: int = 0
) -> float:
    """How far [m] the pieces reach beyond a closed mesh.

    The largest distance outside the mesh of their corners and of ``samples`` random points on each
    piece's surface (trimesh's exact signed distance; needs ``rtree``).
    """
    worst = 0.0
    for k, piece in enumerate(pieces):
        surface = piece.mesh
        pts = np.vstack([surface.vertices, trimesh.sample.sample_surface(surface, samples, seed=seed + k)[0]])
        depth = trimesh.proximity.signed_distance(mesh, pts)  # positive inside the mesh
        worst = max(worst, float(np.max(-depth)))
    return max(worst, 0.0)


class _Proxy:
    """A fast estimate of how far points lie outside a dense closed mesh, for the slab search.

    The distance to the nearest vertex, counted only when the point lies on the outer side of
    that vertex's normal; exact up to about the mesh's edge length, and thousands of times faster
    than the exact signed distance (used for the final figure, :func:`overshoot`).
    """

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        self.vertices = np.asarray(mesh.vertices, dtype=float)
        self.normals = np.asarray(mesh.vertex_normals, dtype=float)
        self.tree = cKDTree(self.vertices)

    def overshoot(self, points: Array, samples: int = 400) -> float:
        """Largest estimated distance outside the mesh of the hull of ``points`` [m]."""
        hull = _qhull(points)
        probe = np.vstack([hull.vertices, trimesh.sample.sample_surface(hull, samples, seed=0)[0]])
        d, i = self.tree.query(probe)
        outward = np.einsum("ij,ij->i", probe - self.vertices[i], self.normals[i]) > 0.0
        return float(np.max(np.where(outward, d, 0.0)))


def _slab(mesh: trimesh.Trimesh, direction: Array, lo: float, hi: float) -> Array:
    """Corners of the mesh surface clipped to the slab ``lo <= direction . x <= hi`` [m].

    They are the vertices inside and the points where edges cross the two planes.
    """
    v = np.asarray(mesh.vertices, dtype=float)
    t = v @ direction
    points = [v[(t >= lo) & (t <= hi)]]
    edges = np.asarray(mesh.edges_unique)
    ta, tb = t[edges[:, 0]], t[edges[:, 1]]
    for level in (lo, hi):
        if not np.isfinite(level):
            continue
        crossing = (np.minimum(ta, tb) < level) & (np.maximum(ta, tb) > level)
        a, b = edges[crossing, 0], edges[crossing, 1]
        s = ((level - t[a]) / (t[b] - t[a]))[:, None]
        points.append(v[a] + s * (v[b] - v[a]))
    return np.vstack(points)


def convex_cover(
    mesh: trimesh.Trimesh,
    *,
    max_overshoot_m: float = 0.02,
    max_pieces: int = 4,
    tolerance_m: float = 0.005,
    max_planes: int = 40,
    cuts: int = 12,
    mixed: bool = False,
) -> list[ConvexPiece]:
    """Few convex polytopes that together contain a link's mesh, each simplified to few faces.

    The whole mesh's hull is used when its pieces reach no more than ``max_overshoot_m`` beyond the
    mesh; otherwise the mesh is cut into up to ``max_pieces`` slabs along the direction (the mesh's
    principal axes and the frame axes are tried) that leaves the least overshoot, the slab reaching
    farthest being cut again at its best place.

    Args:
        mesh: the link's closed triangle mesh [m], in the frame the pieces are wanted in.
        max_overshoot_m: cut while the hulls reach farther than this beyond the mesh [m].
        max_pieces: most slabs (the result may stay looser than ``max_overshoot_m``).
        tolerance_m: how far each simplified piece may reach beyond its hull [m]
            (see :func:`outer_polytope`).
        max_planes: most faces of each simplified piece.
        cuts: candidate cut positions tried per slab (evenly spread quantiles).
        mixed: also try cells cut along a different direction each (:func:`_split_cells`, ranked
            by the exact overshoot: slower), for coarse meshes with large faces, where the fast
            estimate is poor, and for links whose concavities no family of parallel slabs separates.

    Returns:
        The simplified pieces; every mesh vertex lies inside at least one of them.
    """
    vertices = np.asarray(mesh.vertices, dtype=float)
    proxy = _Proxy(mesh)
    candidates = [[vertices]]
    if proxy.overshoot(vertices) > max_overshoot_m and max_pieces > 1:
        axes = np.linalg.svd(vertices - vertices.mean(axis=0), full_matrices=False)[2]
        for direction in [*axes, *np.eye(3)]:
            candidates.append(_split(mesh, proxy, direction, max_overshoot_m, max_pieces, cuts)[0])
        if mixed:
            candidates.append(_split_cells(mesh, max_overshoot_m, max_pieces, cuts))
    # the proxy ranks cuts; the exact measure picks among the directions' answers (fewest pieces on ties)
    exact = [overshoot([ConvexPiece.hull_of(p) for p in slabs], mesh, samples=500) for slabs in candidates]
    pick = min(range(len(candidates)), key=lambda k: (max(exact[k], max_overshoot_m), len(candidates[k])))
    best, best_gap = candidates[pick], exact[pick]
    log.debug("convex cover: %d slab(s), hulls %.1f mm beyond the mesh", len(best), best_gap * 1e3)
    return [outer_polytope(points, tolerance_m=tolerance_m, max_planes=max_planes) for points in best]


def _split(
    mesh: trimesh.Trimesh, proxy: _Proxy, direction: Array, max_overshoot_m: float, max_pieces: int, cuts: int
) -> tuple[list[Array], float]:
    """Slabs along ``direction``, cutting the loosest slab at its best place; their hulls' overshoot."""
    t = np.asarray(mesh.vertices, dtype=float) @ direction
    bounds = [-np.inf, np.inf]
    gaps = [proxy.overshoot(np.asarray(mesh.vertices, dtype=float))]
    while max(gaps) > max_overshoot_m and len(gaps) < max_pieces:
        k = int(np.argmax(gaps))
        lo, hi = bounds[k], bounds[k + 1]
        inside = t[(t > lo) & (t < hi)]
        choice: tuple[float, float, float] | None = None
        for cut in np.quantile(inside, np.linspace(0.0, 1.0, cuts + 2)[1:-1]):
            pair = []
            for a, b in ((lo, cut), (cut, hi)):
                pts = _slab(mesh, direction, a, b)
                if len(pts) < 4 or np.linalg.matrix_rank(pts - pts.mean(axis=0), tol=1e-6) < 3:
                    break
                pair.append(proxy.overshoot(pts))
            if len(pair) == 2 and (choice is None or max(pair) < max(choice[1:])):
                choice = (float(cut), pair[0], pair[1])
        if choice is None or max(choice[1:]) >= gaps[k]:
            break
        bounds.insert(k + 1, choice[0])
        gaps[k : k + 1] = [choice[1], choice[2]]
    slabs = [_slab(mesh, direction, bounds[i], bounds[i + 1]) for i in range(len(gaps))]
    return slabs, max(gaps)


def _clip(triangles: Array, normal: Array, offset: float) -> Array:
    """The parts of triangles (T, 3, 3) [m] on the side ``normal . x <= offset``, as triangles."""
    if len(triangles) == 0:
        return triangles
    d = triangles @ normal - offset  # (T, 3): <= 0 inside
    inside = d <= 0.0
    count = inside.sum(axis=1)
    out = [triangles[count == 3]]
    for n_in in (1, 2):
        sel = count == n_in
        if not np.any(sel):
            continue
        tri, dd, ins = triangles[sel], d[sel], inside[sel]
        # rotate each triangle so that its lone vertex (the one inside for 1, outside for 2) comes first
        lone = np.argmax(ins if n_in == 1 else ~ins, axis=1)
        order = (lone[:, None] + np.arange(3)[None, :]) % 3
        rows = np.arange(len(tri))[:, None]
        tri, dd = tri[rows, order], dd[rows, order]
        a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
        ab = a + (dd[:, 0] / (dd[:, 0] - dd[:, 1]))[:, None] * (b - a)
        ac = a + (dd[:, 0] / (dd[:, 0] - dd[:, 2]))[:, None] * (c - a)
        if n_in == 1:
            out.append(np.stack([a, ab, ac], axis=1))
        else:  # the quad ab, b, c, ac
            out.append(np.stack([ab, b, c], axis=1))
            out.append(np.stack([ab, c, ac], axis=1))
    return np.concatenate(out, axis=0)


def _cell_gap(mesh: trimesh.Trimesh, points: Array) -> float:
    """How far [m] the hull of ``points`` reaches beyond the mesh (300 surface samples)."""
    return overshoot([ConvexPiece.hull_of(points)], mesh, samples=300)


def _split_cells(mesh: trimesh.Trimesh, max_overshoot_m: float, max_pieces: int, cuts: int) -> list[Array]:
    """Convex cells of the mesh surface, each cut along its own best direction; their corners.

    The loosest cell is cut in two by the plane (its principal axes and the frame axes, ``cuts``
    quantile positions each) that leaves the smaller of the two hulls' overshoots, until
    every cell is within ``max_overshoot_m``, ``max_pieces`` is reached or no cut helps. A cell
    holds the surface triangles clipped to it (Sutherland-Hodgman), so the hull of its corners
    holds every point of the solid inside the cell: a segment through such a point, clipped to
    the cell, ends on the clipped surface or on a cut face whose outline is clipped surface.
    """
    triangles = np.asarray(mesh.triangles, dtype=float)
    cells = [triangles]
    gaps = [_cell_gap(mesh, triangles.reshape(-1, 3))]
    done = [False]
    while len(cells) < max_pieces:
        open_cells = [k for k in range(len(cells)) if not done[k] and gaps[k] > max_overshoot_m]
        if not open_cells:
            break
        k = max(open_cells, key=lambda i: gaps[i])
        tri = cells[k]
        points = tri.reshape(-1, 3)
        axes = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)[2]
        best: tuple[list[float], Array, Array] | None = None
        for direction in [*axes, *np.eye(3)]:
            t = points @ direction
            for cut in np.quantile(t, np.linspace(0.0, 1.0, cuts + 2)[1:-1]):
                parts = [_clip(tri, direction, cut), _clip(tri, -direction, -cut)]
                halves = [p.reshape(-1, 3) for p in parts]
                if any(len(h) < 4 or np.linalg.matrix_rank(h - h.mean(axis=0), tol=1e-6) < 3 for h in halves):
                    continue
                pair = sorted((_cell_gap(mesh, h) for h in halves), reverse=True)  # larger gap first
                if best is None or pair < best[0]:
                    best = (pair, parts[0], parts[1])
        # a cut that only tightens one half may still free the other for the next cut
        if best is None or best[0][1] >= gaps[k]:
            done[k] = True
            continue
        cells[k : k + 1] = [best[1], best[2]]
        gaps[k : k + 1] = [_cell_gap(mesh, best[1].reshape(-1, 3)), _cell_gap(mesh, best[2].reshape(-1, 3))]
        done[k : k + 1] = [False, False]
    return [np.unique(c.reshape(-1, 3), axis=0) for c in cells]
