"""Calibrations from robot readings: the TCP in the flange frame and the workpiece in the world.

* **TCP calibration** (``tcp_in_flange``), the four-point method of ABB and KUKA controllers: the
  robot brings the tool tip to one fixed reference point in N >= 4 flange orientations; every
  reading then obeys ``p_k + R_k t = c`` (flange pose ``R_k, p_k`` in the base frame, TCP ``t``
  in the flange frame, reference point ``c`` in the base frame), solved like a pivot by linear
  least squares inside a RANSAC when there are five or more readings. The six-point method adds
  two readings in the fourth reading's orientation with the tip moved away from the reference
  point along the wanted tool +z axis and along the wanted +x axis, which gives the TCP's
  orientation (scipy ``Rotation.align_vectors``, z exact, x as close as it can be).
* **Workpiece registration** (``cad_in_world``): the TCP touches N reference points of the CAD
  model; the TCP positions in the world (``base_in_world @ fk(q) @ tcp_in_flange``, or the
  controller's TCP positions) are registered to the CAD points by Kabsch/SVD and RANSAC.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from refine.calibrate.pivot import fixed_point_lstsq, swing_spread_deg
from refine.calibrate.result import Calibration
from refine.calibrate.rigid import check_point_geometry, kabsch, point_residuals, ransac
from refine.errors import InputError
from refine.frames import make_transform, rotation_angle_deg
from refine.types import Array

logger = logging.getLogger(__name__)

#: Default inlier threshold of robot touches [m]: a robot repeats to a few hundredths of a mm.
ROBOT_THRESHOLD_M = 0.001
#: Least RMS orientation spread of the four-point readings about two axes [deg].
MIN_TCP_SPREAD_DEG = 5.0
#: Largest orientation change allowed between the fourth reading and the two axis readings [deg].
MAX_AXIS_READING_TURN_DEG = 0.5
#: Shortest move along an axis in the six-point method [m].
MIN_AXIS_MOVE_M = 0.01


def calibrate_tcp(
    flange_poses: ArrayLike, six_point: bool = False, threshold_m: float = ROBOT_THRESHOLD_M
) -> Calibration:
    """Solve ``tcp_in_flange`` from flange poses with the tool tip on one reference point.

    Args:
        flange_poses: T_base_flange of each reading (N, 4, 4) [m]; with ``six_point`` the last
            two are the +z and +x axis readings.
        six_point: also solve the TCP orientation from the last two readings.
        threshold_m: largest residual of a good reading [m].

    Returns:
        ``tcp_in_flange`` (4, 4) (identity rotation without ``six_point``) and
        ``reference_point_in_base_m`` (3,), a residual per point reading; figures: the
        orientation spread [deg] and, for six points, the angle between the measured axes [deg].

    Raises:
        InputError: fewer than 4 point readings, too little orientation change, or axis
            readings that turn the flange or move too little.
    """
    T = np.asarray(flange_poses, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise InputError(f"tcp calibration: expected flange poses (N, 4, 4), got {T.shape}")
    points, axes = (T[:-2], T[-2:]) if six_point else (T, None)
    n = len(points)
    if n < 4:
        needed = 6 if six_point else 4
        raise InputError(
            f"tcp calibration: {len(T)} reading(s); the {needed}-point method needs at least {needed}: "
            f"4 orientations on the reference point{' and the +z and +x axis readings' if six_point else ''}"
        )
    R, p = points[:, :3, :3], points[:, :3, 3]
    first, second = swing_spread_deg(R)
    if second < MIN_TCP_SPREAD_DEG:
        raise InputError(
            f"tcp calibration: the flange orientations differ by {first:.1f} and {second:.1f} deg RMS "
            f"about their two main axes; at least {MIN_TCP_SPREAD_DEG:.0f} deg about both is needed: "
            f"tilt the tool in different directions"
        )

    def fit(idx: NDArray[np.intp]) -> tuple[Array, Array]:
        return fixed_point_lstsq(p[idx], R[idx])[:2]

    def residuals(model: tuple[Array, Array]) -> Array:
        t, c = model
        return np.linalg.norm(p + R @ t - c, axis=1)

    sample = n - 1 if n >= 5 else n
    (t, c), inliers = ransac(n, fit, residuals, sample, threshold_m)
    R_fl_tcp = np.eye(3)
    figures = {"orientation_spread_deg": first, "orientation_spread_second_axis_deg": second}
    if axes is not None:
        R_fl_tcp, between = _tool_axes(points[-1], axes)
        figures["axis_readings_angle_deg"] = between
    res = residuals((t, c))
    return Calibration(
        kind="tcp",
        values={"tcp_in_flange": make_transform(R_fl_tcp, t), "reference_point_in_base_m": c},
        residuals_m=res,
        outliers=tuple(int(i) for i in np.flatnonzero(~inliers)),
        figures=figures,
    )


def _tool_axes(T4: Array, axes: Array) -> tuple[Array, float]:
    for k, name in enumerate(("+z", "+x")):
        turn = float(rotation_angle_deg(T4[:3, :3], axes[k, :3, :3]))
        if turn > MAX_AXIS_READING_TURN_DEG:
            raise InputError(
                f"tcp calibration: the {name} axis reading turns the flange by {turn:.2f} deg from the "
                f"fourth reading; keep the orientation (at most {MAX_AXIS_READING_TURN_DEG} deg) and only move"
            )
    moves = axes[:, :3, 3] - T4[:3, 3]
    lengths = np.linalg.norm(moves, axis=1)
    if lengths.min() < MIN_AXIS_MOVE_M:
        raise InputError(
            f"tcp calibration: the axis readings move {lengths[0] * 1000:.1f} mm (+z) and "
            f"{lengths[1] * 1000:.1f} mm (+x) from the fourth reading; move at least "
            f"{MIN_AXIS_MOVE_M * 1000:.0f} mm along each axis"
        )
    in_flange = (moves / lengths[:, None]) @ T4[:3, :3]  # R^T d for each move
    between = math.degrees(math.acos(np.clip(in_flange[0] @ in_flange[1], -1.0, 1.0)))
    if not 30.0 <= between <= 150.0:
        raise InputError(
            f"tcp calibration: the +z and +x moves are {between:.1f} deg apart; they must be roughly "
            f"perpendicular (30 to 150 deg)"
        )
    rot, _ = Rotation.align_vectors(in_flange, [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], weights=[np.inf, 1.0])
    return rot.as_matrix(), between


def register_workpiece(
    tcp_positions_world: ArrayLike,
    points_cad: ArrayLike,
    threshold_m: float = ROBOT_THRESHOLD_M,
    labels: tuple[str, ...] = (),
) -> Calibration:
    """Solve ``cad_in_world`` from TCP positions touched onto points of the CAD model.

    Args:
        tcp_positions_world: where the TCP touched, in {F} [m], shape (N, 3).
        points_cad: the same points in the CAD frame [m], shape (N, 3), in the same order.
        threshold_m: largest residual of a good touch [m].
        labels: point names for the report.

    Raises:
        InputError: fewer than 3 points, collinear points, a count mismatch, or no consistent
            subset.
    """
    cad = check_point_geometry(points_cad, "workpiece registration points", 3)
    world = np.asarray(tcp_positions_world, dtype=float)
    if world.shape != cad.shape:
        raise InputError(
            f"workpiece registration: {len(cad)} points but {len(world)} robot readings; one reading "
            f"per point, in the order of the points file"
        )
    n = len(cad)

    def fit(idx: NDArray[np.intp]) -> Array:
        check_point_geometry(cad[idx], "RANSAC subset", 3)
        return kabsch(cad[idx], world[idx])

    T, inliers = ransac(n, fit, lambda M: point_residuals(M, cad, world), 3 if n >= 4 else n, threshold_m)
    return Calibration(
        kind="workpiece",
        values={"cad_in_world": T},
        residuals_m=point_residuals(T, cad, world),
        outliers=tuple(int(i) for i in np.flatnonzero(~inliers)),
        figures={"threshold_m": float(threshold_m)},
        labels=labels,
    )


def tcp_positions_world(flange_poses: ArrayLike, base_in_world: ArrayLike, tcp_in_flange: ArrayLike) -> Array:
    """TCP positions in {F} [m] (N, 3) from flange poses T_base_flange (N, 4, 4)."""
    T = np.asarray(base_in_world, dtype=float) @ np.asarray(flange_poses, dtype=float)
    return (T @ np.asarray(tcp_in_flange, dtype=float))[:, :3, 3]
