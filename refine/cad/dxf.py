"""CAD paths from DXF drawings (read with ezdxf).

Path entities, all taken from model space and returned in world coordinates (WCS) of the drawing:

* ``POLYLINE`` (3D, and 2D with bulges and elevation) and ``LWPOLYLINE`` (bulges and elevation):
  straight segments stay straight, a bulge becomes the circular arc it encodes.
* ``SPLINE``: flattened by ezdxf's own B-spline evaluation (``Spline.flattening``).
* ``LINE`` and ``ARC``: pieces that are joined end to end into one chain.

Which entities make the path:

* With ``layer`` given, every path entity on that layer (names compare case-insensitively);
  the pieces are chained end to end, reversing pieces where needed.
* Without ``layer``, the drawing must hold exactly one ``POLYLINE``/``LWPOLYLINE``/``SPLINE``, or
  only ``LINE``/``ARC`` entities that form one chain. Anything else is an :class:`InputError`
  that lists the layers and their entities, so the user can pick a layer.

A chain runs from its loose end that belongs to the earliest entity in drawing order; a loop starts
at the first entity's start. Curves are flattened so that no chord is farther than
``flatten_tolerance_m`` from the true curve. A closed path (closed polyline or spline, or a chain
whose ends meet) is *marked closed* by returning its first point again as its last point, exactly.
The drawing's ``$INSUNITS`` is only checked against ``units`` (a mismatch is logged as a warning);
``units`` decides.

:func:`points_from_dxf` reads one path and refuses pieces that do not form one chain;
:func:`tracks_from_dxf` reads every connected chain as a track of its own (a closed entity is always
one), with the points the CAD defines (polyline vertices, line ends, the ends of arcs and splines)
marked for the resampling (:func:`refine.cad.resample.resample_track`).
"""

from __future__ import annotations

import hashlib
import logging
import math
import threading
from collections import defaultdict
from pathlib import Path
from typing import Any

import ezdxf
import numpy as np
from ezdxf.math import bulge_center
from numpy.typing import NDArray

from refine.cad.csv_ import metres_per_unit
from refine.cad.resample import FEATURE, FLATTENING, VERTEX, CadTrack
from refine.errors import InputError
from refine.plausible import CAD_COORDINATE_LIMIT_M

logger = logging.getLogger(__name__)

#: Entity types that can form a path.
PATH_TYPES = ("POLYLINE", "LWPOLYLINE", "SPLINE", "LINE", "ARC")
_WHOLE_PATH_TYPES = ("POLYLINE", "LWPOLYLINE", "SPLINE")
_INSUNITS = {1: "in", 4: "mm", 6: "m"}


def _label(e) -> str:
    return f"{e.dxftype()} #{e.dxf.handle} on layer {e.dxf.layer!r}"


def _bulged_polyline(xyb: NDArray, elevation: float, ocs, closed: bool, tol: float) -> tuple[NDArray, NDArray]:
    """Vertices (x, y, bulge) in the entity's OCS -> flattened WCS points (K, 3) and their kinds (K,)."""
    n = len(xyb)
    pts: list[NDArray] = [xyb[:1, :2]]
    kinds: list[NDArray] = [np.array([VERTEX], dtype=np.int8)]
    for i in range(n - 1 + int(closed)):
        a, b, bulge = xyb[i, :2], xyb[(i + 1) % n, :2], xyb[i, 2]
        # the bulge is tan(sweep / 4), 2 * sagitta / chord: an arc within tol of its chord is the chord
        if bulge == 0.0 or np.allclose(a, b) or abs(bulge) * float(np.linalg.norm(b - a)) / 2.0 <= tol:
            pts.append(b[None])
            kinds.append(np.array([VERTEX], dtype=np.int8))
            continue
        c = np.asarray(bulge_center(tuple(a), tuple(b), bulge))
        r = float(np.linalg.norm(a - c))
        sweep = 4.0 * math.atan(bulge)  # signed: positive is counter-clockwise
        step = 2.0 * math.acos(max(-1.0, 1.0 - tol / r)) if tol < r else math.pi / 2
        k = max(2, math.ceil(abs(sweep) / step)) if step > 0.0 else 2
        ang = math.atan2(a[1] - c[1], a[0] - c[0]) + np.linspace(0.0, sweep, k + 1)[1:]
        arc = c + r * np.column_stack([np.cos(ang), np.sin(ang)])
        arc[-1] = b
        pts.append(arc)
        kinds[-1][-1] = FEATURE  # an arc's ends are feature points
        kinds.append(np.r_[np.full(k - 1, FLATTENING), FEATURE].astype(np.int8))
    xy = np.vstack(pts)
    ocs_pts = np.column_stack([xy, np.full(len(xy), elevation)])
    wcs = np.array([tuple(v) for v in ocs.points_to_wcs(ocs_pts.tolist())], dtype=float)
    return wcs, np.concatenate(kinds)


def _defining_values(e) -> NDArray:
    """The numbers that place an entity (points, radius, elevation) in drawing units, flat."""
    kind = e.dxftype()
    if kind == "LINE":
        values = [*e.dxf.start, *e.dxf.end]
    elif kind == "ARC":
        values = [*e.dxf.center, e.dxf.radius]
    elif kind == "SPLINE":
        values = [c for v in (*e.control_points, *e.fit_points) for c in v]
    elif kind == "LWPOLYLINE":
        values = [c for v in e.get_points("xy") for c in v] + [e.dxf.elevation]
    else:
        values = [c for v in e.vertices for c in v.dxf.location]
    return np.asarray(values, dtype=float)


def _xyb(e) -> NDArray | None:
    """Vertices (x, y, bulge) in the OCS of a 2D polyline, shape (K, 3); None for other entities."""
    if e.dxftype() == "LWPOLYLINE":
        return np.array(e.get_points("xyb"), dtype=float).reshape(-1, 3)
    if e.dxftype() == "POLYLINE" and not e.is_3d_polyline:
        return np.array([(*v.dxf.location.xy, v.dxf.bulge) for v in e.vertices], dtype=float).reshape(-1, 3)
    return None


def _check_extent(e, scale: float, units: str, source: str, tol: float) -> None:
    """Stop before flattening an entity whose defining numbers are beyond the plausible range.

    The numbers are its points, radius and elevation, and for a 2D polyline the radius of each arc
    segment that leaves its chord by more than ``tol`` [drawing units] (from the bulge).
    """
    values = _defining_values(e)
    bad = np.flatnonzero(~(np.abs(values * scale) <= CAD_COORDINATE_LIMIT_M))
    if bad.size:
        v = values[bad[0]]
        raise InputError(
            f"{source}: {_label(e)} has the value {v:.6g} {units} ({v * scale:.6g} m), outside the "
            f"plausible range ±{CAD_COORDINATE_LIMIT_M:g} m (a value in the wrong unit, or garbage)"
        )
    xyb = _xyb(e)
    if xyb is None or len(xyb) < 2:
        return
    n = len(xyb)
    for i in range(n - 1 + int(_is_closed(e))):
        bulge = float(xyb[i, 2])
        if not math.isfinite(bulge):
            raise InputError(
                f"{source}: {_label(e)} vertex {i} has the bulge {bulge!r}; a bulge is a finite number"
            )
        chord = float(np.linalg.norm(xyb[(i + 1) % n, :2] - xyb[i, :2]))
        if bulge == 0.0 or abs(bulge) * chord / 2.0 <= tol:
            continue
        radius = chord / 4.0 * (1.0 / abs(bulge) + abs(bulge))
        if not radius * scale <= CAD_COORDINATE_LIMIT_M:
            raise InputError(
                f"{source}: {_label(e)} vertex {i}: the bulge {bulge:.6g} makes an arc of radius "
                f"{radius * scale:.6g} m, outside the plausible range {CAD_COORDINATE_LIMIT_M:g} m"
            )


def _is_closed(e) -> bool:
    return bool(e.closed) if e.dxftype() == "LWPOLYLINE" else bool(e.is_closed)


def _entity_points(e, tol: float) -> tuple[NDArray, bool]:
    """One path entity -> (points (K, 3) in drawing units, closed)."""
    pts, _, closed = _entity_polyline(e, tol)
    return pts, closed


def _curve_kinds(n: int) -> NDArray:
    """Kinds of the points of a flattened curve: its ends are feature points."""
    kinds = np.full(n, FLATTENING, dtype=np.int8)
    kinds[[0, -1]] = FEATURE
    return kinds


def _entity_polyline(e, tol: float) -> tuple[NDArray, NDArray, bool]:
    """One path entity -> (points (K, 3) in drawing units, their kinds (K,), closed)."""
    kind = e.dxftype()
    if kind == "LINE":
        return np.array([tuple(e.dxf.start), tuple(e.dxf.end)], dtype=float), np.full(2, VERTEX, np.int8), False
    if kind in ("ARC", "SPLINE"):
        pts = np.array([tuple(v) for v in e.flattening(tol)], dtype=float)
        return pts, _curve_kinds(len(pts)), kind == "SPLINE" and bool(e.closed)
    if kind == "LWPOLYLINE":
        pts, kinds = _bulged_polyline(_xyb(e), e.dxf.elevation, e.ocs(), e.closed, tol)
        return pts, kinds, bool(e.closed)
    # POLYLINE
    if e.is_3d_polyline:
        pts = np.array([tuple(v) for v in e.points_in_wcs()], dtype=float)
        return pts, np.full(len(pts), VERTEX, np.int8), bool(e.is_closed)
    elevation = e.dxf.elevation.z
    pts, kinds = _bulged_polyline(_xyb(e), elevation, e.ocs(), e.is_closed, tol)
    return pts, kinds, bool(e.is_closed)


def _chain(pieces: list[NDArray], labels: list[str], tol: float, source: str) -> NDArray:
    """Join open pieces end to end; see the module docstring for the start rule."""
    if len(pieces) == 1:
        return pieces[0]
    ends = np.array([[p[0], p[-1]] for p in pieces])  # (n, 2, 3)

    def touching(point: NDArray, exclude: set[int]) -> list[tuple[int, int]]:
        d = np.linalg.norm(ends - point, axis=2)
        hits = np.argwhere(d <= tol)
        return [(int(i), int(j)) for i, j in hits if i not in exclude]

    loose = [(i, j) for i in range(len(pieces)) for j in (0, 1) if not touching(ends[i, j], {i})]
    if len(loose) not in (0, 2):
        listed = "; ".join(f"{labels[i]} at {np.round(ends[i, j], 6).tolist()}" for i, j in loose)
        raise InputError(
            f"{source}: the path entities do not form one chain ({len(loose)} loose ends: "
            f"{listed}); choose one path with cad.layer"
        )
    first, end = loose[0] if loose else (0, 0)
    out = [pieces[first] if end == 0 else pieces[first][::-1]]
    used, last = {first}, first
    while len(used) < len(pieces):
        nxt = touching(out[-1][-1], used)
        if len(nxt) != 1:
            why = "a gap" if not nxt else "a branch"
            raise InputError(
                f"{source}: {why} in the chain after {labels[last]} at "
                f"{np.round(out[-1][-1], 6).tolist()}; choose one path with cad.layer"
            )
        i, j = nxt[0]
        used.add(i)
        last = i
        out.append((pieces[i] if j == 0 else pieces[i][::-1])[1:])
    return np.vstack(out)


def _select(entities: list, layer: str | None, source: str) -> list:
    by_layer: dict[str, list[str]] = defaultdict(list)
    for e in entities:
        by_layer[e.dxf.layer].append(f"{e.dxftype()} #{e.dxf.handle}")
    listing = "; ".join(f"layer {k!r}: {', '.join(v)}" for k, v in sorted(by_layer.items()))
    if not entities:
        raise InputError(f"{source}: no path entities ({', '.join(PATH_TYPES)}) in model space")
    if layer is not None:
        chosen = [e for e in entities if e.dxf.layer.casefold() == layer.casefold()]
        if not chosen:
            raise InputError(f"{source}: no path entities on layer {layer!r}; found {listing}")
        return chosen
    whole = [e for e in entities if e.dxftype() in _WHOLE_PATH_TYPES]
    if whole and len(entities) > 1:
        raise InputError(
            f"{source}: {len(entities)} path entities and no cad.layer to choose from: {listing}"
        )
    return entities


def _read_pieces(
    path: Path, units: str, layer: str | None, flatten_tolerance_m: float
) -> tuple[list[tuple[NDArray, NDArray, bool, str]], float, str]:
    """The chosen path entities as (points [drawing units], kinds, closed, label), the scale and the source."""
    doc, source, scale = _open(path, units)
    insunits = _INSUNITS.get(doc.header.get("$INSUNITS", 0))
    if insunits is not None and insunits != units:
        logger.warning("%s says $INSUNITS=%s but cad.units=%s; using %s", source, insunits, units, units)
    entities = [
        e
        for e in doc.modelspace()
        if e.dxftype() in PATH_TYPES
        and not (e.dxftype() == "POLYLINE" and (e.is_poly_face_mesh or e.is_polygon_mesh))
    ]
    chosen = _select(entities, layer, source)
    tol = flatten_tolerance_m / scale
    pieces = []
    for e in chosen:
        _check_extent(e, scale, units, source, tol)
        pts, kinds, is_closed = _entity_polyline(e, tol)
        if len(pts) < 2:
            raise InputError(f"{source}: {_label(e)} has fewer than 2 points")
        pieces.append((pts, kinds, is_closed, _label(e)))
    return pieces, scale, source


def points_from_dxf(
    path: str | Path, units: str = "mm", layer: str | None = None, flatten_tolerance_m: float = 1e-6
) -> NDArray:
    """Read one path from a DXF drawing (see the module docstring for which one and how).

    Args:
        path: the DXF file.
        units: length unit of the drawing: ``"m"``, ``"mm"`` or ``"in"``.
        layer: layer holding the path, or None when the drawing holds a single path.
        flatten_tolerance_m: largest distance between a curve and its chords [m].

    Returns:
        The path points in the CAD frame [m], shape (K, 3); for a closed path the last point
        equals the first.

    Raises:
        InputError: unreadable file, no or ambiguous path entities (listing layers and entities),
            pieces that do not chain (naming the entity and point).
    """
    path = Path(path)
    found, scale, source = _read_pieces(path, units, layer, flatten_tolerance_m)
    pieces = [f[0] for f in found]
    labels = [f[3] for f in found]
    closed = [f[2] for f in found]
    extent = float(np.ptp(np.vstack(pieces), axis=0).max())
    join_tol = 1e-6 * max(extent, 1.0)
    if len(pieces) > 1 and any(closed):
        shut = [lb for lb, c in zip(labels, closed, strict=True) if c]
        raise InputError(f"{source}: closed {', '.join(shut)} cannot be chained with other entities")
    points = _chain(pieces, labels, join_tol, source)
    if closed[0] or (len(points) > 2 and np.linalg.norm(points[-1] - points[0]) <= join_tol):
        if np.linalg.norm(points[-1] - points[0]) <= join_tol:
            points[-1] = points[0]
        else:
            points = np.vstack([points, points[:1]])
    logger.debug("%s: %d points from %s", source, len(points), ", ".join(labels))
    return points * scale


def _components(
    pieces: list[tuple[NDArray, NDArray, bool, str]], tol: float, source: str
) -> list[tuple[NDArray, NDArray, list[str]]]:
    """The open pieces chained end to end into connected chains, each closed piece alone.

    A chain runs from its loose end that belongs to the earlier entity in drawing order (a loop
    from its first entity's start); the chains are ordered by their first entity. Returns
    (points, kinds, labels) per chain.
    """
    ends = np.array([[p[0][0], p[0][-1]] for p in pieces])  # (n, 2, 3)
    shut = {i for i, p in enumerate(pieces) if p[2]}
    used: set[int] = set()

    def follow(point: NDArray) -> tuple[int, int] | None:
        d = np.linalg.norm(ends - point, axis=2)
        hits = [(int(i), int(j)) for i, j in np.argwhere(d <= tol) if i not in used and i not in shut]
        if len(hits) > 1:
            raise InputError(
                f"{source}: a branch in the chain at {np.round(point, 6).tolist()} "
                f"({', '.join(pieces[i][3] for i, _ in hits)}); choose one path with cad.layer"
            )
        return hits[0] if hits else None

    out = []
    for first in range(len(pieces)):
        if first in used:
            continue
        used.add(first)
        if first in shut:
            out.append((pieces[first][0], pieces[first][1], [pieces[first][3]]))
            continue
        chain = [(first, False)]  # (piece, run against its drawing order)
        for forward in (True, False):
            point = ends[first, 1 if forward else 0]
            while (hit := follow(point)) is not None:
                i, j = hit
                used.add(i)
                point = ends[i, 1 - j]
                if forward:
                    chain.append((i, j == 1))
                else:
                    chain.insert(0, (i, j == 0))
        if chain[-1][0] < chain[0][0]:
            chain = [(i, not r) for i, r in reversed(chain)]
        p_parts, k_parts, labels = [], [], []
        for n, (i, against) in enumerate(chain):
            pts, kinds = pieces[i][0], pieces[i][1]
            if against:
                pts, kinds = pts[::-1], kinds[::-1]
            if n:
                k_parts[-1] = k_parts[-1].copy()
                k_parts[-1][-1] = max(k_parts[-1][-1], kinds[0])
                pts, kinds = pts[1:], kinds[1:]
            p_parts.append(pts)
            k_parts.append(kinds)
            labels.append(pieces[i][3])
        out.append((np.vstack(p_parts), np.concatenate(k_parts), labels))
    return out


def _close(points: NDArray, kinds: NDArray, tol: float) -> tuple[NDArray, NDArray]:
    """A closed entity's points ending with its first point, exactly."""
    if np.linalg.norm(points[-1] - points[0]) <= tol:
        points = points.copy()
        points[-1] = points[0]
        return points, kinds
    return np.vstack([points, points[:1]]), np.r_[kinds, kinds[:1]]


def tracks_from_dxf(
    path: str | Path, units: str = "mm", layer: str | None = None, flatten_tolerance_m: float = 1e-6
) -> list[CadTrack]:
    """Every track of a DXF drawing: its path entities chained into connected pieces.

    The entities are chosen as by :func:`points_from_dxf`; pieces that touch end to end form one
    track, a disconnected piece (or a closed entity) is a track of its own. Tracks are ordered by
    their first entity in drawing order. Feature points (:class:`~refine.cad.resample.CadTrack`
    ``kinds``): the ends of arcs, bulges and splines; vertices: polyline vertices and line ends.

    Args:
        path: the DXF file.
        units: length unit of the drawing: ``"m"``, ``"mm"`` or ``"in"``.
        layer: layer holding the path, or None when the drawing holds a single path or only lines
            and arcs.
        flatten_tolerance_m: largest distance between a curve and its chords [m].

    Returns:
        The tracks in the CAD frame [m]; a closed one ends with its first point.

    Raises:
        InputError: unreadable file, no or ambiguous path entities (listing layers and entities),
            a branch (three pieces meeting at a point).
    """
    path = Path(path)
    found, scale, source = _read_pieces(path, units, layer, flatten_tolerance_m)
    extent = float(np.ptp(np.vstack([f[0] for f in found]), axis=0).max())
    join_tol = 1e-6 * max(extent, 1.0)
    tracks = []
    shut = {f[3] for f in found if f[2]}
    for points, kinds, labels in _components(found, join_tol, source):
        closed = labels[0] in shut or (len(points) > 2 and np.linalg.norm(points[-1] - points[0]) <= join_tol)
        if closed:
            points, kinds = _close(points, kinds, join_tol)
        tracks.append(CadTrack(points * scale, kinds, bool(closed), ", ".join(labels)))
    logger.debug("%s: %d track(s)", source, len(tracks))
    return tracks


def dxf_circles(path: str | Path, units: str = "mm", layer: str | None = None) -> list:
    """The circles of the drawing's arcs: ``ARC`` and ``CIRCLE`` entities and polyline bulges.

    The entities are those the reader chooses (the path entities, on ``layer`` when given).

    Returns:
        ``(centre [m] (3,), radius [m], unit normal (3,))`` per arc, in the drawing's frame.
    """
    doc, source, scale = _open(Path(path), units)
    entities = [e for e in doc.modelspace() if e.dxftype() in PATH_TYPES]
    circles = []
    for e in _select(entities, layer, source):
        ocs = e.ocs()
        normal = np.asarray(ocs.uz, dtype=float)
        if e.dxftype() in ("ARC", "CIRCLE"):
            centre = np.asarray(ocs.to_wcs(e.dxf.center), dtype=float)
            circles.append((centre * scale, float(e.dxf.radius) * scale, normal))
            continue
        xyb = _xyb(e)
        if xyb is None:
            continue
        elevation = float(e.dxf.elevation) if e.dxftype() == "LWPOLYLINE" else float(e.dxf.elevation.z)
        n = len(xyb)
        for i in range(n if _is_closed(e) else n - 1):
            a, b, bulge = xyb[i, :2], xyb[(i + 1) % n, :2], xyb[i, 2]
            if bulge == 0.0 or np.allclose(a, b):
                continue
            c = bulge_center(tuple(a), tuple(b), bulge)
            radius = float(np.linalg.norm(b - a)) / 4.0 * (1.0 / abs(bulge) + abs(bulge))
            centre = np.asarray(ocs.to_wcs((c[0], c[1], elevation)), dtype=float)
            circles.append((centre * scale, radius * scale, normal))
    return circles


_LAST = threading.local()
"""Per thread, the last drawing read (``drawing``) and its key (``key``): the resolved path and the
SHA-256 of the file's bytes."""


def _open(path: Path, units: str) -> tuple[Any, str, float]:
    """The drawing read by ezdxf, its name for messages and the metres per drawing unit.

    Each thread keeps the last drawing it read, keyed by the file's resolved path and the SHA-256
    of its bytes: the path and the arcs of one run, or a problem solved again, read the file's
    bytes once more but parse them once. A file whose bytes changed is parsed again. The drawing
    is only read, never changed, by this module.
    """
    source = f"DXF file {str(path)!r}"
    scale = metres_per_unit(units, str(path))
    try:
        key = (str(path.resolve()), hashlib.sha256(path.read_bytes()).digest())
        if getattr(_LAST, "key", None) == key:
            return _LAST.drawing, source, scale
        drawing = ezdxf.readfile(path)
        if hashlib.sha256(path.read_bytes()).digest() == key[1]:  # not written to while it was parsed
            _LAST.key, _LAST.drawing = key, drawing
        return drawing, source, scale
    except (OSError, ezdxf.DXFError) as e:
        raise InputError(f"{source} cannot be read: {e}") from e
