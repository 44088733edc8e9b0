"""The passes of a multi-layer weld, generated from the demonstrated root pass.

The worker demonstrates the root pass only; every later pass is the root pass moved and tilted in
the seam frame, as ``[multipass]`` prescribes (layer height, lateral offsets, work-angle changes).

Seam frame, per waypoint:

* ``t``: the unit tangent of the root path (central differences of the positions in arc length).
* ``b``: the seam's bisector, pointing out of the joint. It is read from the demonstrated tool
  orientation: the torch (TCP z axis ``z``) points into the joint, so ``-(z - (z·t) t)``,
  normalised, is the torch direction with the push (travel) angle taken out. It is then smoothed
  along the path (see below).
* ``l = t × b``: the lateral direction, across the seam.

Assumption: the work angle is measured from the bisector and the demonstrated torch lies roughly
in the bisector plane (the plane through ``t`` and ``b``). A worker who tilts the torch by a few
degrees off the bisector tilts ``b`` by as much: a pass offset of ``d`` then lands ``d·sin(angle)``
off its place (0.3 mm for 4 mm and 4 deg).

Smoothing: ``b`` is expressed as an angle ``phi`` about ``t`` in a rotation-minimising (parallel
transport) frame along the path; ``phi`` is smoothed by a Gaussian of ``smoothing_m`` of arc length
(in samples of the median waypoint spacing) and ``b`` rebuilt from it. On a planar seam, where
the true bisector keeps a constant angle to that frame even through bends, the smoothing removes
tracker noise without pulling ``b`` towards the inside of a bend, as averaging the vectors would.

Pass ``(layer k, index i)``: every waypoint moves by ``(k - 1)·layer_height_m`` along ``b`` and by
``lateral_offsets_m[k-1][i-1]`` along ``l``, so it lies ``sqrt(h² + o²)`` from the root point; the
tool turns by ``work_angle_change_deg[k-1][i-1]`` about ``t`` (right-handed), which keeps the push
angle and changes the work angle alone (a positive change turns the torch's pointing direction
towards ``-l``). Speed rule: each waypoint keeps the root pass's demonstrated speed; the arc
length ``s`` is the pass's own (its polyline length), so a pass offset outward on a bend takes
slightly longer. ``t_demo`` and ``residual`` are the root's.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

from refine.errors import InputError
from refine.frames import matrix_from_rotvec
from refine.paths import FusedPath
from refine.settings import MultipassSettings
from refine.types import Array

logger = logging.getLogger(__name__)

#: Arc length [m] of the Gaussian that smooths the bisector along the path (1 sigma).
BISECTOR_SMOOTHING_M = 0.005
#: Smallest angle between the torch and the seam tangent [deg] for which a bisector exists.
MIN_TORCH_TO_TANGENT_DEG = 20.0


@dataclass(frozen=True)
class Pass:
    """One pass of a multi-layer weld.

    Attributes:
        layer: layer number, 1-based (layer 1 is the demonstrated root pass).
        index: pass number within its layer, 1-based, in the order of ``lateral_offsets_m``.
        lateral_offset_m: offset from the seam line along the lateral direction ``l = t × b`` [m].
        height_m: offset along the seam's bisector ``b``, ``(layer - 1)·layer_height_m`` [m].
        work_angle_change_deg: rotation of the tool about the seam tangent ``t`` [deg].
        path: the pass: positions [m], tool orientations, speeds [m/s] per waypoint.
    """

    layer: int
    index: int
    lateral_offset_m: float
    height_m: float
    work_angle_change_deg: float
    path: FusedPath


def _unit(v: Array) -> Array:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def path_tangents(root: FusedPath) -> Array:
    """Unit tangents of the root path [-], shape (N, 3), by central differences in arc length."""
    if len(root) < 2:
        raise InputError(f"multipass: the root pass needs at least 2 waypoints, got {len(root)}")
    return _unit(np.gradient(root.positions, root.s, axis=0))


def transported_normals(tangents: Array, first: Array) -> Array:
    """A rotation-minimising normal field along a path, shape (N, 3).

    Starting from ``first`` (made normal to the first tangent), each normal is carried to the next
    waypoint by the smallest rotation that takes one tangent to the next (parallel transport).

    Args:
        tangents: unit tangents [-], shape (N, 3).
        first: the normal at the first waypoint, shape (3,).

    Raises:
        InputError: the path turns back on itself (consecutive tangents opposite).
    """
    u = np.empty_like(tangents)
    u[0] = _unit(first - (first @ tangents[0]) * tangents[0])
    for k in range(1, len(tangents)):
        a, b, v = tangents[k - 1], tangents[k], u[k - 1]
        c = float(a @ b)
        if c <= -1.0 + 1e-9:
            raise InputError(f"multipass: the path turns back on itself at waypoint {k}")
        w = np.cross(a, b)
        v = v + np.cross(w, v) + np.cross(w, np.cross(w, v)) / (1.0 + c)
        v -= (v @ b) * b
        u[k] = v / np.linalg.norm(v)
    return u


def seam_frames(root: FusedPath, smoothing_m: float = BISECTOR_SMOOTHING_M) -> tuple[Array, Array, Array]:
    """The seam frame of the root pass: tangent, bisector and lateral direction per waypoint.

    Args:
        root: the demonstrated root pass.
        smoothing_m: 1-sigma arc length of the bisector's smoothing [m]; 0 turns it off.

    Returns:
        ``t``, ``b``, ``l = t × b``: unit vectors in {F}, shape (N, 3) each.

    Raises:
        InputError: a negative ``smoothing_m``; the torch within ``MIN_TORCH_TO_TANGENT_DEG`` of
            the tangent somewhere (naming the waypoint), where no bisector can be read.
    """
    if not (math.isfinite(smoothing_m) and smoothing_m >= 0.0):
        raise InputError(f"multipass: smoothing_m must be a finite number >= 0 m, got {smoothing_m!r}")
    t = path_tangents(root)
    z = root.rotations[:, :, 2]
    across = -(z - np.sum(z * t, axis=1, keepdims=True) * t)
    norm = np.linalg.norm(across, axis=1)
    bad = np.flatnonzero(norm < math.sin(math.radians(MIN_TORCH_TO_TANGENT_DEG)))
    if bad.size:
        k = int(bad[0])
        angle = math.degrees(math.asin(min(1.0, float(norm[k]))))
        raise InputError(
            f"multipass: at waypoint {k} (s = {root.s[k]:.4f} m) the torch is {angle:.1f} deg from "
            f"the seam tangent (at least {MIN_TORCH_TO_TANGENT_DEG:g} deg needed to read the bisector)"
        )
    b_raw = across / norm[:, None]
    u = transported_normals(t, b_raw[0])
    v = np.cross(t, u)
    phi = np.unwrap(np.arctan2(np.sum(b_raw * v, axis=1), np.sum(b_raw * u, axis=1)))
    if smoothing_m > 0.0 and len(root) > 2:
        sigma = smoothing_m / float(np.median(np.diff(root.s)))
        phi = gaussian_filter1d(phi, sigma, mode="nearest")
    b = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
    return t, b, np.cross(t, b)


def _check_settings(settings: MultipassSettings) -> tuple[tuple[float, ...], ...]:
    offsets = settings.lateral_offsets_m
    changes = settings.work_angle_change_deg
    if changes is None:
        changes = tuple(tuple(0.0 for _ in row) for row in offsets)
    if tuple(offsets[0]) != (0.0,) or tuple(changes[0]) != (0.0,):
        raise InputError(
            "multipass: layer 1 is the demonstrated root pass, so lateral_offsets_m[0] and "
            f"work_angle_change_deg[0] must be [0.0]; got {list(offsets[0])} and {list(changes[0])}"
        )
    if any(len(row) == 0 for row in offsets):
        raise InputError(f"multipass: every layer needs at least one pass, got lateral_offsets_m = {offsets}")
    return changes


def _offset_path(root: FusedPath, t: Array, shift: Array, angle_rad: float, name: str) -> FusedPath:
    positions = root.positions + shift
    steps = np.diff(positions, axis=0)
    folded = np.flatnonzero(np.sum(steps * np.diff(root.positions, axis=0), axis=1) <= 0.0)
    if folded.size:
        k = int(folded[0])
        raise InputError(
            f"multipass: {name} folds back near s = {root.s[k]:.4f} m: its offset is larger than the "
            "seam's radius of curvature there"
        )
    s = root.s[0] + np.concatenate([[0.0], np.cumsum(np.linalg.norm(steps, axis=1))])
    rotations = matrix_from_rotvec(t * angle_rad) @ root.rotations
    return FusedPath(s, positions, rotations, root.speed.copy(), root.t_demo.copy(), root.residual.copy())


def generate_passes(
    root: FusedPath, settings: MultipassSettings, *, smoothing_m: float = BISECTOR_SMOOTHING_M
) -> list[Pass]:
    """Every pass of a multi-layer weld, the demonstrated root pass first.

    Args:
        root: the demonstrated root pass (CAD positions, demonstrated orientations and speeds).
        settings: ``[multipass]``: layers, layer height, lateral offsets and work-angle changes.
        smoothing_m: 1-sigma arc length of the bisector's smoothing [m] (see :func:`seam_frames`).

    Returns:
        The passes ordered by layer, then by index; ``sum(len(row) for row in
        settings.lateral_offsets_m)`` of them. The first is ``root`` itself, unchanged.

    Raises:
        InputError: layer 1 is not the single root pass ``[0.0]``; a layer without passes; the torch
            along the seam somewhere; an offset that folds the path on a tight bend.
    """
    changes = _check_settings(settings)
    passes = [Pass(1, 1, 0.0, 0.0, 0.0, root)]
    if settings.layers == 1:
        return passes
    t, b, lateral = seam_frames(root, smoothing_m)
    for layer in range(2, settings.layers + 1):
        height = (layer - 1) * settings.layer_height_m
        row = zip(settings.lateral_offsets_m[layer - 1], changes[layer - 1], strict=True)
        for index, (offset, change) in enumerate(row, start=1):
            name = f"layer {layer} pass {index}"
            shift = height * b + offset * lateral
            path = _offset_path(root, t, shift, math.radians(change), name)
            passes.append(Pass(layer, index, float(offset), float(height), float(change), path))
    logger.info(
        "%d passes in %d layers from a root pass of %d waypoints (layer height %.4g m)",
        len(passes),
        settings.layers,
        len(root),
        settings.layer_height_m,
    )
    return passes
