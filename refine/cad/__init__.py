"""The CAD/CAM stage: read the path file, bring it to the world frame, place the waypoints on it.

``read_cad_tracks`` (every track of the file) and ``read_cad_path`` (a file with one) are the entry
points; ``csv_``, ``dxf``, ``gcode`` and ``mesh`` read one format each into tracks in the CAD frame
[m], their feature points marked, and ``resample`` places the waypoints: feature points and corners
kept, the chord error against the CAD geometry within ``[cad] chord_tolerance_m``. A PathML document holds
orientations and speeds as well, so it skips this stage and the fusion:
:func:`~refine.cad.pathml_.fused_from_pathml` reads it straight into a fused path.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from refine.cad.csv_ import metres_per_unit
from refine.cad.resample import (
    FEATURE,
    VERTEX,
    CadTrack,
    resample_by_arc_length,
    resample_track,
    start_at_nearest,
)
from refine.errors import InputError
from refine.frames import check_transform, transform_points
from refine.lazy import lazy_names
from refine.paths import CadPath
from refine.settings import MAX_WAYPOINTS, CadSettings, check_waypoint_count

if TYPE_CHECKING:
    from refine.cad.csv_ import points_from_csv
    from refine.cad.dxf import points_from_dxf, tracks_from_dxf
    from refine.cad.gcode import points_from_gcode, tracks_from_gcode
    from refine.cad.mesh import points_from_mesh
    from refine.cad.pathml_ import fused_from_pathml

#: The readers, each imported on first use: a run imports only its own format's library
#: (ezdxf for DXF, trimesh for meshes).
_LAZY = {
    "points_from_csv": "refine.cad.csv_",
    "points_from_dxf": "refine.cad.dxf",
    "points_from_gcode": "refine.cad.gcode",
    "tracks_from_dxf": "refine.cad.dxf",
    "tracks_from_gcode": "refine.cad.gcode",
    "points_from_mesh": "refine.cad.mesh",
    "fused_from_pathml": "refine.cad.pathml_",
}

__all__ = [
    "CLOSED_TOLERANCE_M",
    "fused_from_pathml",
    "points_from_csv",
    "points_from_dxf",
    "points_from_gcode",
    "points_from_mesh",
    "read_cad_path",
    "read_cad_tracks",
    "resample_by_arc_length",
    "resample_track",
    "tracks_from_dxf",
    "tracks_from_gcode",
]

#: A path whose last point lies this close to its first is closed [m].
CLOSED_TOLERANCE_M = 1e-6
#: Largest distance between a curve and the polyline the DXF and G-code readers flatten it to [m].
FLATTENING_TOLERANCE_M = 1e-6

def _single(points: NDArray) -> list[CadTrack]:
    closed = bool(len(points) > 2 and np.linalg.norm(points[-1] - points[0]) <= CLOSED_TOLERANCE_M)
    return [CadTrack(points, np.full(len(points), VERTEX, dtype=np.int8), closed)]


_READERS: dict[str, Callable[[CadSettings], list[CadTrack]]] = {
    "csv": lambda c: _single(__getattr__("points_from_csv")(c.file, c.units)),
    "dxf": lambda c: __getattr__("tracks_from_dxf")(
        c.file, c.units, layer=c.layer, flatten_tolerance_m=FLATTENING_TOLERANCE_M
    ),
    "gcode": lambda c: __getattr__("tracks_from_gcode")(c.file, c.units, arc_tolerance_m=FLATTENING_TOLERANCE_M),
    "mesh": lambda c: _single(
        __getattr__("points_from_mesh")(
            c.file,
            c.units,
            section_origin=c.section_origin,
            section_normal=c.section_normal,
            boundary=c.boundary,
            start_near=c.start_near,
        )
    ),
}

__getattr__, __dir__ = lazy_names("refine.cad", _LAZY, globals())


def _chosen_tracks(tracks: list[CadTrack], settings: CadSettings) -> list[CadTrack]:
    """All tracks, or the one ``settings.track`` names (1-based, DXF and G-code)."""
    if settings.track is None:
        return tracks
    name = Path(settings.file).name
    try:
        k = int(str(settings.track).strip())
    except ValueError as e:
        raise InputError(f"cad.track = {settings.track!r}: {name} has tracks 1..{len(tracks)}; give a number") from e
    if not 1 <= k <= len(tracks):
        raise InputError(f"cad.track = {settings.track!r} does not exist: {name} has tracks 1..{len(tracks)}")
    return [tracks[k - 1]]


def _started(track: CadTrack, settings: CadSettings, closed: bool) -> tuple[NDArray, NDArray, bool, float]:
    """``start_near`` applied to one track: its points, kinds, whether reversed, and the start offset."""
    points, kinds = track.points, track.kinds
    if settings.start_near is None or settings.format == "mesh":  # the mesh reader starts there itself
        return points, kinds, False, 0.0
    near = np.asarray(settings.start_near, dtype=float) * metres_per_unit(settings.units, str(settings.file))
    moved, reversed_, offset = start_at_nearest(points, near, closed, CLOSED_TOLERANCE_M)
    kind_of = {tuple(p): int(k) for p, k in zip(points, kinds, strict=True)}
    # a start inserted between two vertices is kept as a waypoint anyway (an end)
    return moved, np.array([kind_of.get(tuple(p), FEATURE) for p in moved], dtype=np.int8), reversed_, offset


def read_cad_tracks(settings: CadSettings, cad_in_world: NDArray) -> list[CadPath]:
    """Read every track of the CAD/CAM file, each in the world frame {F} and resampled.

    Tracks: the connected pieces of a DXF drawing, the feed sequences of a G-code program (split at
    rapids, plunges and retracts along Z and closed loops); a CSV file or a mesh gives one.
    ``settings.track`` (a 1-based number) keeps one of them. Each track is read as
    :func:`read_cad_path` describes; ``reverse`` also runs the tracks in the opposite order.

    Args:
        settings: the ``[cad]`` settings.
        cad_in_world: T_F_CAD, pose of the CAD frame in the world frame {F}, shape (4, 4).

    Returns:
        The tracks in the order the program runs them, at least one.

    Raises:
        InputError: see :func:`read_cad_path`; a ``track`` that does not exist.
    """
    T_world_cad = check_transform(cad_in_world, "frames.cad_in_world")
    if T_world_cad.shape != (4, 4):
        raise InputError(f"frames.cad_in_world: expected shape (4, 4), got {T_world_cad.shape}")
    reader = _READERS.get(settings.format)
    if settings.format == "toolpath":
        raise InputError(
            f"cad.format = 'toolpath': {settings.file} holds tool axes too; read it with "
            "refine.cad.toolpath.fused_from_toolpath(file, units, spacing_m, speed_m_s, cad_in_world)"
        )
    if settings.format == "pathml":
        raise InputError(
            f"cad.format = 'pathml': {settings.file} holds orientations and speeds too; read it with "
            "refine.cad.fused_from_pathml(file, spacing_m, track), not read_cad_path"
        )
    if reader is None:
        raise InputError(f"cad.format = {settings.format!r} is not one of {', '.join(sorted(_READERS))}")
    tracks = reader(settings)
    if settings.format in ("csv", "mesh") and settings.track is not None:
        raise InputError(f"cad.track = {settings.track!r}: a {settings.format} file holds one track")
    tracks = _chosen_tracks(tracks, settings)
    if settings.reverse:
        tracks = tracks[::-1]
    name = Path(settings.file).name
    paths = []
    for number, track in enumerate(tracks, start=1):
        closed = track.closed or bool(
            len(track.points) > 2 and np.linalg.norm(track.points[-1] - track.points[0]) <= CLOSED_TOLERANCE_M
        )
        points, kinds, reversed_, offset = _started(track, settings, closed)
        if settings.reverse:
            points, kinds = points[::-1].copy(), kinds[::-1].copy()
            reversed_ = not reversed_
            if not closed:
                offset = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) - offset
        points_world = transform_points(T_world_cad, points)
        length = float(np.sum(np.linalg.norm(np.diff(points_world, axis=0), axis=1)))
        check_waypoint_count(length, settings.spacing_m, f"cad.file {name!r}")
        # against the reader's polyline, less its flattening: the exact curve is then within the tolerance
        tol = settings.chord_tolerance_m - FLATTENING_TOLERANCE_M
        s, positions, exact_s, exact = resample_track(
            points_world, settings.spacing_m, tol, kinds=kinds, closed=closed
        )
        if len(s) > MAX_WAYPOINTS:
            raise InputError(
                f"cad.file {name!r}: {len(s)} waypoints keep the chord error within cad.chord_tolerance_m = "
                f"{settings.chord_tolerance_m:g} m, more than the limit of {MAX_WAYPOINTS}; use a larger tolerance"
            )
        source = name + (f" (layer {settings.layer})" if settings.layer else "")
        if len(tracks) > 1 or settings.track is not None:
            source += f" track {settings.track if settings.track is not None else number}"
        paths.append(
            CadPath(
                s=s,
                positions=positions,
                closed=closed,
                source=source,
                reversed=reversed_,
                start_offset_m=offset,
                direction_given=settings.reverse or (settings.start_near is not None and not closed),
                start_given=settings.start_near is not None and closed,
                exact_s=exact_s,
                exact=exact,
            )
        )
    return paths


def read_cad_path(settings: CadSettings, cad_in_world: NDArray) -> CadPath:
    """Read the CAD/CAM path and return it in the world frame {F}, resampled.

    Steps: read the file in ``settings.format`` and convert ``settings.units`` to metres; a path
    whose last point is within :data:`CLOSED_TOLERANCE_M` of its first is closed; with
    ``settings.start_near`` start it at its point nearest to that (a closed path) or at its end
    nearer to it (an open path; :func:`refine.cad.resample.start_at_nearest`; the mesh reader does
    this itself); reverse it if ``settings.reverse``; map it with ``cad_in_world``; place the
    waypoints (:func:`refine.cad.resample.resample_track`): the CAD's feature points and corners
    kept, steps of at most ``settings.spacing_m``, a chord error against the CAD geometry of at
    most ``settings.chord_tolerance_m``. The result records what the problem fixed
    (``direction_given``, ``start_given``): the alignment searches the rest
    (:func:`refine.fuse.fusion.fuse`), and keeps the CAD geometry (``exact``).

    Args:
        settings: the ``[cad]`` settings (file, format, units, spacing, chord tolerance, layer,
            reverse; ``track`` the track's number for DXF and G-code; for meshes the section
            plane or ``boundary`` and ``start_near``).
        cad_in_world: T_F_CAD, pose of the CAD frame in the world frame {F}, shape (4, 4).

    Returns:
        The path in {F}: waypoints [m], their arc length [m], whether it is closed, the geometry.

    Raises:
        InputError: an unknown format (listing the known ones), ``"pathml"`` (read with
            :func:`~refine.cad.pathml_.fused_from_pathml` instead), a bad transform, a file with
            several tracks (choose one with ``track``), or anything the reader or resampler rejects.
    """
    paths = read_cad_tracks(settings, cad_in_world)
    if len(paths) > 1:
        listed = "; ".join(f"{k}: {p.length * 1e3:.3f} mm" for k, p in enumerate(paths, start=1))
        raise InputError(
            f"cad.file {Path(settings.file).name!r} has {len(paths)} tracks ({listed}); "
            'choose one with cad.track = "<number>" or read them all with read_cad_tracks'
        )
    return paths[0]


def cad_circles(settings: CadSettings, cad_in_world: NDArray) -> list[tuple[NDArray, float, NDArray]]:
    """The circles of the CAD's arcs in the world frame {F}: where a program may write circular moves.

    DXF: ``ARC`` and ``CIRCLE`` entities and polyline bulges of the entities the reader chooses;
    G-code: the planar ``G2``/``G3`` moves; the other formats hold no arcs (an empty list).

    Returns:
        ``(centre [m] (3,), radius [m], unit normal (3,))`` per arc.
    """
    T = check_transform(cad_in_world, "frames.cad_in_world")
    if settings.format == "dxf":
        from refine.cad.dxf import dxf_circles

        found = dxf_circles(settings.file, settings.units, settings.layer)
    elif settings.format == "gcode":
        from refine.cad.gcode import gcode_circles

        found = gcode_circles(settings.file, settings.units)
    else:
        return []
    return [(transform_points(T, c[None])[0], r, T[:3, :3] @ n) for c, r, n in found]
