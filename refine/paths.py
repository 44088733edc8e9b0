"""The values that flow between pipeline stages.

``cad`` makes a :class:`CadPath`, ``demo`` a :class:`TrackerLog` and then a :class:`Demonstration`,
``fuse`` a :class:`FusedPath`; ``optimise`` and ``timing`` produce the joint path and its timing,
gathered in a :class:`Trajectory` that every exporter reads. All arrays are float64 numpy arrays,
SI units, frames named in each field.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from refine.errors import InputError
from refine.types import Array


def _check_exact(owner: str, exact_s: Array | None, exact: Array | None) -> None:
    if (exact_s is None) != (exact is None):
        raise InputError(f"{owner}: exact_s and exact go together")
    if exact_s is not None and exact is not None:
        _check_rows(f"{owner}.exact_s", exact_s, len(exact_s), ())
        _check_rows(f"{owner}.exact", exact, len(exact_s), (3,))


def _check_rows(name: str, arr: Array, n: int, tail: tuple[int, ...]) -> None:
    if arr.shape != (n, *tail):
        raise InputError(f"{name}: expected shape {(n, *tail)}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: contains NaN or infinite values")


def chord_errors(points: Array, j: Array, positions: Array) -> Array:
    """Distance of each point of a curve to the straight move that passes it [m], shape (K,).

    Args:
        points: points of the curve, shape (K, 3).
        j: for each point, the index of the move ``positions[j] -> positions[j + 1]`` whose
            arc-length interval holds it, shape (K,).
        positions: the waypoints, shape (N, 3).
    """
    a, b = positions[j], positions[j + 1]
    ab = b - a
    denom = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", points - a, ab) / np.where(denom > 0.0, denom, 1.0), 0.0, 1.0)
    return np.linalg.norm(a + t[:, None] * ab - points, axis=1)


@dataclass(frozen=True)
class ChordError:
    """The largest distance between a CAD curve and the straight moves through reached points.

    Attributes:
        max_m: the largest distance [m].
        segment: index ``i`` of the move from waypoint ``i`` to ``i + 1`` where it is.
        s_m: arc length of the CAD point that is farthest [m].
        point: that CAD point in {F} [m], shape (3,).
    """

    max_m: float
    segment: int
    s_m: float
    point: Array


def chord_error(
    exact_s: Array, exact: Array, s: Array, positions: Array, targets: Array | None = None
) -> ChordError:
    """How far the CAD geometry lies from the straight moves between ``positions``.

    Every point of the geometry whose arc length falls in ``[s[i], s[i + 1]]`` is measured against
    the straight segment ``positions[i] -> positions[i + 1]``; with ``targets`` (the waypoints on
    the geometry), each reached point is also measured against its own target, so a reached
    point off its target counts in full.

    Args:
        exact_s: arc length of each geometry point [m], shape (M,), non-decreasing, in the
            waypoints' arc length.
        exact: the geometry [m], shape (M, 3).
        s: arc length of the waypoints [m], shape (N,).
        positions: the points the moves run through [m], shape (N, 3) (targets or reached).
        targets: the waypoints' targets on the geometry [m], shape (N, 3), or None.
    """
    j = np.clip(np.searchsorted(s, exact_s, side="right") - 1, 0, len(s) - 2)
    err = chord_errors(exact, j, positions)
    k = int(np.argmax(err))
    worst = ChordError(float(err[k]), int(j[k]), float(exact_s[k]), exact[k].copy())
    if targets is not None:
        off = np.linalg.norm(positions - targets, axis=1)
        i = int(np.argmax(off))
        if off[i] > worst.max_m:
            worst = ChordError(float(off[i]), min(i, len(s) - 2), float(s[i]), targets[i].copy())
    return worst


def _reorder_exact(
    exact_s: Array, exact: Array, length: float, reverse: bool, sigma: float, closed: bool
) -> tuple[Array, Array]:
    """The geometry of a path run the other way and/or from arc length ``sigma`` (closed paths)."""
    if reverse:
        exact_s, exact = length - exact_s[::-1], exact[::-1]
    if closed and sigma > 0.0:
        head = exact_s >= sigma
        tail = (exact_s > 0.0) & (exact_s <= sigma)
        exact_s = np.r_[exact_s[head] - sigma, exact_s[tail] + length - sigma]
        exact = np.vstack([exact[head], exact[tail]])
    return np.clip(exact_s, 0.0, length), np.ascontiguousarray(exact)


@dataclass(frozen=True)
class CadPath:
    """A CAD/CAM path in the world frame {F}, resampled by arc length.

    Attributes:
        s: arc length from the first point [m], shape (N,), s[0] = 0, strictly increasing.
        positions: path points in {F} [m], shape (N, 3).
        closed: whether the path returns to its start (the last point equals the first).
        source: where it came from (file name and entity), for messages.
        reversed: the waypoints run against the order of the file (``[cad] reverse``, or
            ``start_near`` at the last point of an open path).
        start_offset_m: arc length along the file's order from its first point to the first
            waypoint [m] (0 unless ``start_near`` moved the start, and 0 for a mesh, whose reader
            starts its loop there itself; the length for a reversed open path).
        direction_given: the problem fixed the direction (``[cad] reverse``, or ``start_near`` on
            an open path); the alignment keeps it instead of searching both.
        start_given: the problem fixed the start of a closed path (``[cad] start_near``); the
            alignment keeps it instead of searching every start.
        exact_s: arc length of each point of the CAD geometry, in the waypoints' arc length [m],
            shape (M,), or None when the path has none (given as points only).
        exact: the CAD geometry as the reader evaluates it, in {F} [m], shape (M, 3): every vertex
            and the points of its curves within the reader's flattening tolerance, and the
            waypoints; what the chord error is measured against.
    """

    s: Array
    positions: Array
    closed: bool = False
    source: str = ""
    reversed: bool = False
    start_offset_m: float = 0.0
    direction_given: bool = False
    start_given: bool = False
    exact_s: Array | None = None
    exact: Array | None = None

    def __post_init__(self) -> None:
        n = len(self.s)
        if n < 2:
            raise InputError(f"CadPath from {self.source!r}: needs at least 2 points, got {n}")
        _check_rows("CadPath.s", self.s, n, ())
        _check_rows("CadPath.positions", self.positions, n, (3,))
        if np.any(np.diff(self.s) <= 0.0):
            raise InputError(f"CadPath from {self.source!r}: arc length must strictly increase")
        _check_exact("CadPath", self.exact_s, self.exact)

    def reordered_exact(self, reverse: bool, sigma: float) -> tuple[Array | None, Array | None]:
        """The geometry run the other way (``reverse``) and then from arc length ``sigma`` [m] (closed)."""
        if self.exact_s is None or self.exact is None:
            return None, None
        return _reorder_exact(self.exact_s, self.exact, self.length, reverse, sigma, self.closed)

    @property
    def length(self) -> float:
        """Total arc length [m]."""
        return float(self.s[-1])

    @property
    def tangents(self) -> Array:
        """Unit tangents [-], shape (N, 3), by central differences in arc length."""
        d = np.gradient(self.positions, self.s, axis=0)
        return d / np.linalg.norm(d, axis=1, keepdims=True)


@dataclass(frozen=True)
class TrackerLog:
    """Raw tracker samples as read from a log: the sensor {E} pose in the receiver frame {S}.

    Attributes:
        t: sample times [s], shape (M,), non-decreasing, t[0] = 0.
        positions: sensor origin in {S} [m], shape (M, 3).
        rotations: sensor orientation R_S_E, shape (M, 3, 3).
        station: tracker station (sensor) number the samples belong to.
        source: file name, for messages.
        device_error: the device's error indicator per sample (character code, 0 for none),
            shape (M,), or None when the device reported no error.
    """

    t: Array
    positions: Array
    rotations: Array
    station: int = 1
    source: str = ""
    device_error: NDArray[np.int16] | None = None

    def __post_init__(self) -> None:
        m = len(self.t)
        if m < 2:
            raise InputError(f"tracker log {self.source!r}: needs at least 2 samples, got {m}")
        _check_rows("TrackerLog.t", self.t, m, ())
        _check_rows("TrackerLog.positions", self.positions, m, (3,))
        _check_rows("TrackerLog.rotations", self.rotations, m, (3, 3))
        if self.device_error is not None and np.shape(self.device_error) != (m,):
            raise InputError(
                f"TrackerLog.device_error: expected shape ({m},), got {np.shape(self.device_error)}"
            )


@dataclass(frozen=True)
class Demonstration:
    """A cleaned demonstration: outliers replaced, poses smoothed, the start pause located.

    Attributes:
        t: sample times [s], shape (M,).
        positions: smoothed sensor origin in {S} [m], shape (M, 3).
        rotations: smoothed sensor orientation R_S_E (smoothed on SO(3)), shape (M, 3, 3).
        speed: sensor speed along its own track [m/s], shape (M,).
        motion_start: index of the first sample after the static pause at the start.
        n_outliers: number of samples the outlier filter replaced.
        source: file name, for messages.
    """

    t: Array
    positions: Array
    rotations: Array
    speed: Array
    motion_start: int = 0
    n_outliers: int = 0
    source: str = ""

    def __post_init__(self) -> None:
        m = len(self.t)
        _check_rows("Demonstration.positions", self.positions, m, (3,))
        _check_rows("Demonstration.rotations", self.rotations, m, (3, 3))
        _check_rows("Demonstration.speed", self.speed, m, ())
        if not 0 <= self.motion_start < m:
            raise InputError(f"Demonstration.motion_start {self.motion_start} outside [0, {m})")


@dataclass(frozen=True)
class PathOrder:
    """Which way round, and from where, the run follows the CAD path: the worker's way.

    Attributes:
        direction: ``"as_cad"`` (the order of the CAD file) or ``"reversed"`` (against it).
        start_offset_m: arc length along the CAD file's order from its first point to the run's
            first waypoint [m]; 0 for an open path run as drawn, its length when reversed.
        direction_source: ``"alignment"`` (both directions tried) or ``"problem"`` (``[cad]
            reverse`` or ``start_near`` fixed it).
        start_source: ``"alignment"`` (every start of a closed path tried), ``"problem"``
            (``[cad] start_near``) or ``"open path"`` (an open path starts at an end).
        residual_as_cad_m: distance of the coarse match run as drawn [m]: the larger of the
            median demo-to-path and path-to-demo distances, no distortion correction
            (:func:`refine.fuse.order.orient`); None when not tried.
        residual_reversed_m: the same run reversed [m]; None when not tried.
    """

    direction: str = "as_cad"
    start_offset_m: float = 0.0
    direction_source: str = "alignment"
    start_source: str = "alignment"
    residual_as_cad_m: float | None = None
    residual_reversed_m: float | None = None

    def as_json(self) -> dict[str, object]:
        """Plain values for ``result.json`` (``demo_quality``)."""
        return {
            "direction": self.direction,
            "start_offset_m": self.start_offset_m,
            "direction_source": self.direction_source,
            "start_source": self.start_source,
            "direction_residual_as_cad_m": self.residual_as_cad_m,
            "direction_residual_reversed_m": self.residual_reversed_m,
        }


@dataclass(frozen=True)
class FusedPath:
    """CAD positions fused with demonstrated tool orientations and speeds, per waypoint.

    Attributes:
        s: arc length along the CAD path [m], shape (N,).
        positions: TCP targets from the CAD path in {F} [m], shape (N, 3).
        rotations: demonstrated tool (TCP) orientation in {F}, R_F_TCP, shape (N, 3, 3).
        speed: demonstrated TCP speed along the CAD path [m/s], shape (N,), > 0.
        t_demo: demonstration time matched to each waypoint [s], shape (N,), increasing.
        residual: distance between the aligned demonstration and the CAD point [m], shape (N,).
        order: which way round and from where the run follows the CAD path (the worker's way),
            None for a path that was not aligned to a demonstration (PathML).
        exact_s: arc length of each point of the CAD geometry, in ``s`` [m], shape (M,), or None
            (a path without CAD geometry: arrays, the later passes of a multi-pass weld; a PathML
            track's geometry is its polyline).
        exact: the CAD geometry in {F} [m], shape (M, 3) (see :class:`CadPath`).
        demo_positions: the demonstrated TCP at ``t_demo`` after the fusion's tracker position
            correction, in {F} [m], shape (N, 3): the demonstration as the fusion matched it (its
            distance to ``positions`` is ``residual``), or None (a path not aligned to a
            demonstration: arrays, PathML, the later passes of a multi-pass weld).
    """

    s: Array
    positions: Array
    rotations: Array
    speed: Array
    t_demo: Array
    residual: Array
    order: PathOrder | None = None
    exact_s: Array | None = None
    exact: Array | None = None
    demo_positions: Array | None = None

    def __post_init__(self) -> None:
        n = len(self.s)
        _check_exact("FusedPath", self.exact_s, self.exact)
        _check_rows("FusedPath.positions", self.positions, n, (3,))
        _check_rows("FusedPath.rotations", self.rotations, n, (3, 3))
        _check_rows("FusedPath.speed", self.speed, n, ())
        _check_rows("FusedPath.t_demo", self.t_demo, n, ())
        _check_rows("FusedPath.residual", self.residual, n, ())
        if self.demo_positions is not None:
            _check_rows("FusedPath.demo_positions", self.demo_positions, n, (3,))
        if np.any(self.speed <= 0.0):
            raise InputError("FusedPath.speed: every demonstrated speed must be > 0 m/s")

    def __len__(self) -> int:
        return len(self.s)


@dataclass(frozen=True)
class Trajectory:
    """The refined and timed path: what every exporter reads.

    Attributes:
        t: time of each waypoint [s], shape (N,), t[0] = 0.
        s: arc length along the CAD path [m], shape (N,).
        q: joint positions [rad], shape (N, n_joints).
        positions_ref: CAD target of each waypoint in {F} [m], shape (N, 3).
        poses: TCP pose reached, T_F_TCP, shape (N, 4, 4) (verified with Pinocchio).
        rotations_demo: fused demonstrated orientation R_F_TCP, shape (N, 3, 3).
        speed: planned TCP speed [m/s], shape (N,).
        arcs: the circular moves the programs write on the CAD's arcs, verified
            (:class:`refine.optimise.controller_arc.ArcPiece`, ``[output] circular_moves``); empty
            for straight moves everywhere.
    """

    t: Array
    s: Array
    q: Array
    positions_ref: Array
    poses: Array
    rotations_demo: Array
    speed: Array
    arcs: tuple = ()

    def __post_init__(self) -> None:
        n = len(self.t)
        _check_rows("Trajectory.s", self.s, n, ())
        _check_rows("Trajectory.q", self.q, n, (self.q.shape[1] if self.q.ndim == 2 else -1,))
        _check_rows("Trajectory.positions_ref", self.positions_ref, n, (3,))
        _check_rows("Trajectory.poses", self.poses, n, (4, 4))
        _check_rows("Trajectory.rotations_demo", self.rotations_demo, n, (3, 3))
        _check_rows("Trajectory.speed", self.speed, n, ())

    def __len__(self) -> int:
        return len(self.t)
