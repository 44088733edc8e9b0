"""CAD paths from triangle meshes (STL, OBJ, PLY, read with trimesh): plane sections and boundaries.

Two ways to get a path from a mesh of a part:

* **Plane section**: the mesh cut by the plane through ``section_origin`` with normal
  ``section_normal`` (trimesh's ``Trimesh.section``), e.g. a horizontal cut through a bracket
  a few millimetres above the table gives the seam around it. Closed section loops run
  counter-clockwise about the normal (right-hand rule).
* **Open boundary**: the edges used by exactly one face, chained into loops, e.g. the edge of a
  glass pane modelled as an open surface. Loops follow the faces' winding (counter-clockwise seen
  from the side the face normals point to).

Several loops (an outer contour and holes, or several parts): the longest is taken, or with
``start_near`` the loop that passes nearest to that point. A closed loop is returned with its first
point repeated at the end; with ``start_near`` it starts at its point nearest to ``start_near``
(inserted between two vertices when it falls inside an edge). An open section chain starts at
the end nearer to ``start_near``.

Coordinates, ``section_origin`` and ``start_near`` are in the file's unit ``units``; the result is in
metres. Meshes are merged on load (trimesh's default processing), so STL files whose triangles
do not share vertices still have a boundary only where the surface really ends.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from refine.cad.csv_ import metres_per_unit
from refine.cad.resample import nearest_on_polyline, start_at_nearest
from refine.errors import InputError
from refine.lazy import on_first_use
from refine.plausible import CAD_COORDINATE_LIMIT_M, check_coordinates

if TYPE_CHECKING:
    import trimesh
else:
    trimesh = on_first_use("trimesh")  # the first mesh call imports it

logger = logging.getLogger(__name__)

#: Loop ends closer than this count as one point, relative to the mesh size [-].
CLOSED_RELATIVE_TOLERANCE = 1e-9


def _load(path: Path, source: str) -> trimesh.Trimesh:
    if not path.is_file():
        raise InputError(f"{source}: file not found")
    try:
        with np.errstate(all="ignore"):  # NaN or huge vertices are reported by the range check after
            mesh = trimesh.load(path, force="mesh")
    except Exception as e:  # trimesh raises many kinds for bad files
        raise InputError(f"{source} cannot be read as a mesh: {e}") from e
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(f"{source}: no triangles in the file")
    return mesh


def _vector(value: ArrayLike, name: str, source: str) -> NDArray:
    v = np.asarray(value, dtype=float).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise InputError(f"{source}: {name} must be 3 finite numbers, got {value!r}")
    return v


def _polyline_length(p: NDArray) -> float:
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def _boundary_loops(mesh: trimesh.Trimesh) -> list[NDArray]:
    """The open boundary as polylines in face-winding order; closed ones repeat their start."""
    edges = mesh.edges  # directed, in face winding, 3 per face
    single = trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)
    if len(single) == 0:
        return []
    outgoing: dict[int, list[int]] = {}
    for e in single:
        outgoing.setdefault(int(edges[e, 0]), []).append(int(e))
    unused = set(int(e) for e in single)
    loops = []
    for first in single:
        if int(first) not in unused:
            continue
        chain = [int(edges[first, 0])]
        e = int(first)
        while e in unused:
            unused.discard(e)
            v = int(edges[e, 1])
            chain.append(v)
            nxt = [k for k in outgoing.get(v, []) if k in unused]
            if not nxt:
                break
            e = nxt[0]
        loops.append(mesh.vertices[chain].copy())
    return loops


def _section_loops(mesh: trimesh.Trimesh, origin: NDArray, normal: NDArray) -> list[NDArray]:
    try:
        section = mesh.section(plane_origin=origin, plane_normal=normal)
    except ImportError as e:
        raise InputError(f"mesh sections need a trimesh optional dependency: {e}") from e
    if section is None:
        return []
    loops = []
    for entity in section.entities:  # .discrete would drop open chains
        p = np.asarray(entity.discrete(section.vertices), dtype=float)
        if len(p) < 2:
            continue
        if len(p) > 3 and np.allclose(p[0], p[-1]):
            area = np.cross(p[:-1] - p[0], p[1:] - p[0]).sum(axis=0)
            if float(area @ normal) < 0.0:
                p = p[::-1].copy()
        loops.append(p)
    return loops


def _pick(loops: list[NDArray], start_near_point: NDArray | None, tol: float) -> NDArray:
    lengths = [_polyline_length(p) for p in loops]
    if start_near_point is None:
        chosen = loops[int(np.argmax(lengths))].copy()
    else:
        chosen = loops[int(np.argmin([nearest_on_polyline(p, start_near_point)[0] for p in loops]))].copy()
    closed = len(chosen) > 3 and np.linalg.norm(chosen[-1] - chosen[0]) <= tol
    if closed:
        chosen[-1] = chosen[0]
    if start_near_point is None:
        return chosen
    return start_at_nearest(chosen, start_near_point, closed, tol)[0]


def points_from_mesh(
    path: str | Path,
    units: str = "mm",
    *,
    section_origin: Sequence[float] | None = None,
    section_normal: Sequence[float] | None = None,
    boundary: bool = False,
    start_near: Sequence[float] | None = None,
) -> NDArray:
    """Read a path from a mesh: a plane section or the open boundary (see the module docstring).

    Args:
        path: the mesh file (STL, OBJ, PLY or another format trimesh reads).
        units: length unit of the mesh: ``"m"``, ``"mm"`` or ``"in"``.
        section_origin: a point of the cutting plane [units], shape (3,).
        section_normal: the cutting plane's normal (any length > 0), shape (3,).
        boundary: take the open boundary instead of a section.
        start_near: pick the loop nearest to this point and start there [units], shape (3,), or
            None for the longest loop from its own first point.

    Returns:
        The path points in the mesh frame [m], shape (K, 3); a closed loop ends with its first point.

    Raises:
        InputError: unreadable file, unknown unit, neither or both of section and boundary, a
            zero normal, a plane that misses the mesh or a mesh without boundary (naming the file,
            the plane and the units).
    """
    path = Path(path)
    source = f"mesh file {str(path)!r}"
    scale = metres_per_unit(units, str(path))
    has_section = section_origin is not None or section_normal is not None
    if boundary == has_section:
        raise InputError(f"{source}: give either boundary = true or section_origin + section_normal")
    near = None if start_near is None else _vector(start_near, "start_near", source) * scale
    mesh = _load(path, source)
    vertices = np.asarray(mesh.vertices, dtype=float) * scale
    check_coordinates(vertices, CAD_COORDINATE_LIMIT_M, lambda k: f"{source}: vertex {k}", "coordinate")
    mesh = trimesh.Trimesh(vertices=vertices, faces=mesh.faces, process=False)
    size = float(np.ptp(vertices, axis=0).max()) or 1.0
    tol = CLOSED_RELATIVE_TOLERANCE * max(size, 1.0)
    if boundary:
        loops = _boundary_loops(mesh)
        if not loops:
            raise InputError(f"{source}: the mesh is closed (every edge joins two faces); no boundary")
        what = "boundary"
    else:
        if section_origin is None or section_normal is None:
            raise InputError(f"{source}: a plane section needs both section_origin and section_normal")
        origin = _vector(section_origin, "section_origin", source)
        normal = _vector(section_normal, "section_normal", source)
        if np.linalg.norm(normal) < 1e-12:
            raise InputError(f"{source}: section_normal {normal.tolist()} has zero length")
        loops = _section_loops(mesh, origin * scale, normal / np.linalg.norm(normal))
        what = f"section at {origin.tolist()} {units}, normal {normal.tolist()}"
        if not loops:
            lo, hi = np.round(mesh.bounds / scale, 6).tolist()
            raise InputError(
                f"{source}: the plane through {origin.tolist()} {units} with normal "
                f"{normal.tolist()} misses the mesh (bounds {lo} to {hi} {units})"
            )
    points = _pick(loops, near, tol)
    logger.debug("%s: %s, %d loop(s), chose %d points", source, what, len(loops), len(points))
    return points
