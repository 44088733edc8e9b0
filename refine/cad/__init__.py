"""The CAD/CAM stage: read the path file, bring it to the world frame, resample it by arc length.

``read_cad_path`` is the entry point; ``csv_``, ``dxf``, ``gcode`` and ``mesh`` read one format each
into points in the CAD frame [m], and ``resample`` places the waypoints. A PathML document holds
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
from refine.cad.resample import resample_by_arc_length, start_at_nearest
from refine.errors import InputError
from refine.frames import check_transform, transform_points
from refine.lazy import lazy_names
from refine.paths import CadPath
from refine.settings import CadSettings, check_waypoint_count

if TYPE_CHECKING:
    from refine.cad.csv_ import points_from_csv
    from refine.cad.dxf import points_from_dxf
    from refine.cad.gcode import points_from_gcode
    from refine.cad.mesh import points_from_mesh
    from refine.cad.pathml_ import fused_from_pathml

#: The readers, each imported on first use: a run imports only its own format's library
#: (ezdxf for DXF, trimesh for meshes).
_LAZY = {
    "points_from_csv": "refine.cad.csv_",
    "points_from_dxf": "refine.cad.dxf",
    "points_from_gcode": "refine.cad.gcode",
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
    "resample_by_arc_length",
]

#: A path whose last point lies this close to its first is closed [m].
CLOSED_TOLERANCE_M = 1e-6

_READERS: dict[str, Callable[[CadSettings], NDArray]] = {
    "csv": lambda c: __getattr__("points_from_csv")(c.file, c.units),
    "dxf": lambda c: __getattr__("points_from_dxf")(c.file, c.units, layer=c.layer),
    "gcode": lambda c: __getattr__("points_from_gcode")(c.file, c.units, program=c.track),
    "mesh": lambda c: __getattr__("points_from_mesh")(
        c.file,
        c.units,
        section_origin=c.section_origin,
        section_normal=c.section_normal,
        boundary=c.boundary,
        start_near=c.start_near,
    ),
}

__getattr__, __dir__ = lazy_names("refine.cad", _LAZY, globals())


def read_cad_path(settings: CadSettings, cad_in_world: NDArray) -> CadPath:
    """Read the CAD/CAM path and return it in the world frame {F}, resampled by arc length.

    Steps: read the file in ``settings.format`` and convert ``settings.units`` to metres; a path
    whose last point is within :data:`CLOSED_TOLERANCE_M` of its first is closed; with
    ``settings.start_near`` start it at its point nearest to that (a closed path) or at its end
    nearer to it (an open path; :func:`refine.cad.resample.start_at_nearest`; the mesh reader does
    this itself); reverse it if ``settings.reverse``; map it with ``cad_in_world``; resample it
    every ``settings.spacing_m`` or a little less (see
    :func:`refine.cad.resample.resample_by_arc_length`). The result records what the problem
    fixed (``direction_given``, ``start_given``): the alignment searches the rest
    (:func:`refine.fuse.fusion.fuse`).

    Args:
        settings: the ``[cad]`` settings (file, format, units, spacing, layer, reverse; for
            G-code ``track`` is the feed sequence number; for meshes the section plane or
            ``boundary`` and ``start_near``).
        cad_in_world: T_F_CAD, pose of the CAD frame in the world frame {F}, shape (4, 4).

    Returns:
        The path in {F}: waypoints [m], their arc length [m] and whether it is closed.

    Raises:
        InputError: an unknown format (listing the known ones), ``"pathml"`` (read with
            :func:`~refine.cad.pathml_.fused_from_pathml` instead), a bad transform, or anything
            the reader or resampler rejects.
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
    points = reader(settings)
    closed = bool(len(points) > 2 and np.linalg.norm(points[-1] - points[0]) <= CLOSED_TOLERANCE_M)
    reversed_, offset = False, 0.0
    if settings.start_near is not None and settings.format != "mesh":  # the mesh reader starts there itself
        near = np.asarray(settings.start_near, dtype=float) * metres_per_unit(
            settings.units, str(settings.file)
        )
        points, reversed_, offset = start_at_nearest(points, near, closed, CLOSED_TOLERANCE_M)
    if settings.reverse:
        points = points[::-1].copy()
        reversed_ = not reversed_
        if not closed:
            offset = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) - offset
    points_world = transform_points(T_world_cad, points)
    length = float(np.sum(np.linalg.norm(np.diff(points_world, axis=0), axis=1)))
    check_waypoint_count(length, settings.spacing_m, f"cad.file {Path(settings.file).name!r}")
    s, positions = resample_by_arc_length(points_world, settings.spacing_m, closed=closed)
    source = Path(settings.file).name + (f" (layer {settings.layer})" if settings.layer else "")
    return CadPath(
        s=s,
        positions=positions,
        closed=closed,
        source=source,
        reversed=reversed_,
        start_offset_m=offset,
        direction_given=settings.reverse or (settings.start_near is not None and not closed),
        start_given=settings.start_near is not None and closed,
    )
