"""Receiver registration: the tracker receiver in the world frame (``source_in_world``).

Two measurements give it:

* **touched points** (:func:`register_receiver`): the tip of the pivot-calibrated hand tool rests
  on N points of known world coordinates, one after the other, each for a dwell of at least
  ``min_dwell_s``; :func:`find_dwells` finds the dwells in the log. The rigid transform comes from
  Kabsch/SVD (:mod:`refine.calibrate.rigid`), refined together with the tracker's z error
  (:mod:`refine.calibrate.zfield`) by least squares, inside a RANSAC that rejects a wrongly
  touched point.
* **a trace along the CAD path** (:func:`register_receiver_to_path`): a short demonstration with
  the tip on the path; ICP matches every tip position to its nearest path point (scipy
  ``cKDTree``) and refines the transform and the z error, from a first guess.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from refine.calibrate import zfield
from refine.calibrate.result import Calibration
from refine.calibrate.rigid import check_point_geometry, kabsch, ransac
from refine.demo.filters import hampel, smooth_positions, speed_along_track
from refine.errors import InputError
from refine.frames import invert_transform, make_transform
from refine.paths import TrackerLog
from refine.types import Array

logger = logging.getLogger(__name__)

#: Tip speed under which the tool counts as resting on a point [m/s].
DWELL_SPEED_M_S = 0.02
#: Still runs separated by less than this are one dwell [s] (noise lifts the speed for a moment).
DWELL_GAP_S = 0.15
#: Smoothing of the tip track before its speed is taken [s].
DWELL_SMOOTHING_S = 0.05
#: Default inlier threshold of the point registration [m].
RECEIVER_THRESHOLD_M = 0.002
#: Farthest a Liberty-class tracker reads [m]; farther positions mean wrong units.
MAX_TRACKER_RANGE_M = 3.0


@dataclass(frozen=True)
class Dwell:
    """One rest of the tip on a point.

    Attributes:
        start: first sample index.
        stop: one past the last sample index.
        sensor_position: median sensor position in {S} over the dwell [m], shape (3,).
        sensor_rotation: mean sensor orientation R_S_E over the dwell, shape (3, 3).
        duration_s: length of the dwell [s].
    """

    start: int
    stop: int
    sensor_position: Array
    sensor_rotation: Array
    duration_s: float


def check_tracker_range(log: TrackerLog) -> None:
    """Raise InputError when the log's positions are beyond any tracker's range (wrong units)."""
    far = float(np.max(np.linalg.norm(log.positions, axis=1)))
    if far > MAX_TRACKER_RANGE_M:
        raise InputError(
            f"tracker log {log.source!r}: positions reach {far:.1f} m from the receiver, beyond a "
            f"tracker's {MAX_TRACKER_RANGE_M:.0f} m: are the units right (--units)?"
        )


def find_dwells(log: TrackerLog, tip_in_sensor: ArrayLike, min_dwell_s: float = 0.5) -> list[Dwell]:
    """The rests of the tool tip in a log, in time order.

    The tip track ``p + R t`` is cleaned of spikes in position or orientation (Hampel filter on the
    tip), smoothed over
    :data:`DWELL_SMOOTHING_S` and differentiated; runs where the tip moves slower than
    :data:`DWELL_SPEED_M_S` (joined across gaps shorter than :data:`DWELL_GAP_S`) for at least
    ``min_dwell_s`` (less twice the smoothing, which shortens a rest at both ends) are dwells.
    Each dwell's sensor pose is the median position and the mean orientation of the spike-free
    samples of its middle 80 %.
    """
    t = np.asarray(tip_in_sensor, dtype=float)
    tip, spikes = hampel(log.positions + log.rotations @ t, 7, 4.0, min_deviation=0.003)
    speed = speed_along_track(log.t, smooth_positions(log.t, tip, DWELL_SMOOTHING_S))
    still = speed < DWELL_SPEED_M_S
    moving_runs = np.flatnonzero(np.diff(np.concatenate([[1], still.astype(int), [1]])))
    for a, b in zip(moving_runs[::2], moving_runs[1::2], strict=True):
        if 0 < a and b < len(still) and log.t[b - 1] - log.t[a] < DWELL_GAP_S:
            still[a:b] = True
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(int), [0]])))
    dwells = []
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        duration = float(log.t[stop - 1] - log.t[start])
        if duration < min_dwell_s - 2.0 * DWELL_SMOOTHING_S:  # the smoothing shortens a rest at both ends
            continue
        trim = (stop - start) // 10
        a, b = start + trim, stop - trim
        good = ~spikes.any(axis=1)[a:b]
        rot = Rotation.from_matrix(log.rotations[a:b][good]).mean()
        dwells.append(
            Dwell(
                start=int(start),
                stop=int(stop),
                sensor_position=np.median(log.positions[a:b][good], axis=0),
                sensor_rotation=rot.as_matrix(),
                duration_s=duration,
            )
        )
    return dwells


# ---- touched points ----------------------------------------------------------------------------


def unpack_frame(x: Array) -> tuple[Array, Array]:
    """The frame T (4, 4) and z-error coefficients (2,) of a parameter vector (rotation vector, translation, z)."""
    return make_transform(Rotation.from_rotvec(x[:3]).as_matrix(), x[3:6]), x[6:8]


def pack_frame(T: Array, coeffs: Array) -> Array:
    """The parameter vector (8,) of a frame T (4, 4) and z-error coefficients (2,): the inverse of :func:`unpack_frame`."""
    return np.concatenate([Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3], coeffs])


def _touch_residuals(x: Array, p: Array, R: Array, tip: Array, world: Array, fit_z: bool) -> Array:
    """Measured minus predicted sensor positions in {S} [m], shape (N, 3)."""
    T_F_S, coeffs = unpack_frame(x)
    if not fit_z:
        coeffs = np.zeros(zfield.N_COEFFS)
    T_S_F = invert_transform(T_F_S)
    tip_in_source = world @ T_S_F[:3, :3].T + T_S_F[:3, 3]
    return p - zfield.distort(tip_in_source - R @ tip, coeffs)


def register_receiver(
    sensor_positions: ArrayLike,
    sensor_rotations: ArrayLike,
    tip_in_sensor: ArrayLike,
    points_world: ArrayLike,
    fit_z: bool = True,
    threshold_m: float = RECEIVER_THRESHOLD_M,
    labels: tuple[str, ...] = (),
) -> Calibration:
    """Solve ``source_in_world`` from the tool tip resting on points of known world position.

    Args:
        sensor_positions: sensor position in {S} at each point [m], shape (N, 3).
        sensor_rotations: sensor orientation R_S_E at each point, shape (N, 3, 3).
        tip_in_sensor: the tip offset in {E} [m], shape (3,).
        points_world: the touched points in {F} [m], shape (N, 3), in the same order.
        fit_z: consider the tracker's z error (needs at least 4 points): the rigid fit and the
            fit with the z error are both made (each inside its RANSAC), and the z error is kept
            only when it explains more points, or when, left out one at a time, the points
            (at least 5 both fits keep) are predicted better with it (leave-one-out RMS).
        threshold_m: largest residual of a point that counts as touched right [m].
            With the z model, RANSAC fits subsets of at least 5 points, so finding a wrongly
            touched point takes at least 6 points; without it, subsets of 3 and 4 points do.
        labels: point names for the report.

    Returns:
        ``source_in_world`` (4, 4), a residual per point (outliers included) and the rejected
        points; figures: the leave-one-out RMS of both fits (``loo_rms_rigid_m``,
        ``loo_rms_z_model_m``, left out when it cannot be taken), ``z_model_used`` (1 or 0), the
        z error coefficients used and its range over the points.

    Raises:
        InputError: fewer points than the model needs, collinear points, or no consistent subset.
    """
    world = check_point_geometry(points_world, "receiver registration points", 4 if fit_z else 3)
    p = np.asarray(sensor_positions, dtype=float)
    R = np.asarray(sensor_rotations, dtype=float)
    tip = np.asarray(tip_in_sensor, dtype=float)
    n = len(world)
    if p.shape != (n, 3) or R.shape != (n, 3, 3):
        raise InputError(
            f"receiver registration: {n} points but {len(p)} dwells in the log; touch the points in "
            f"the order of the points file, resting at least the dwell time on each"
        )

    def fitter(with_z: bool):  # noqa: ANN202 - the fit of one model
        def fit(idx: NDArray[np.intp]) -> Array:
            check_point_geometry(world[idx], "RANSAC subset", 3)
            T0 = kabsch(p[idx] + R[idx] @ tip, world[idx])
            x0 = pack_frame(T0, np.zeros(zfield.N_COEFFS))
            sol = least_squares(
                lambda x: _touch_residuals(x, p[idx], R[idx], tip, world[idx], with_z).ravel(),
                x0,
                x_scale="jac",
            )
            return sol.x

        return fit

    def residuals_of(with_z: bool):  # noqa: ANN202 - the residuals of one model
        return lambda x: np.linalg.norm(_touch_residuals(x, p, R, tip, world, with_z), axis=1)

    figures: dict[str, float] = {"threshold_m": float(threshold_m)}
    if not fit_z:
        x, inliers = ransac(n, fitter(False), residuals_of(False), 3, threshold_m)
        use_z = False
    else:
        sample = max(5, n - max(1, n // 4)) if n >= 6 else n
        x_z, inliers_z = ransac(n, fitter(True), residuals_of(True), sample, threshold_m)
        try:
            x_rigid, inliers_rigid = ransac(n, fitter(False), residuals_of(False), 3, threshold_m)
        except InputError:  # a z error so large that no rigid fit agrees with three points
            x_rigid, inliers_rigid = x_z, np.zeros(n, dtype=bool)
        # the z model enters only when it predicts left-out points better than the rigid fit, or
        # when it explains more points
        common = np.flatnonzero(inliers_rigid & inliers_z)
        loo = {False: np.inf, True: np.inf}
        if len(common) >= 5:
            for with_z in (False, True):
                errors = [residuals_of(with_z)(fitter(with_z)(np.setdiff1d(common, [i])))[i] for i in common]
                loo[with_z] = float(np.sqrt(np.mean(np.square(errors))))
        use_z = bool(loo[True] < loo[False] or inliers_z.sum() > inliers_rigid.sum())
        x, inliers = (x_z, inliers_z) if use_z else (x_rigid, inliers_rigid)
        if np.isfinite(loo[False]) and np.isfinite(loo[True]):
            figures["loo_rms_rigid_m"] = loo[False]
            figures["loo_rms_z_model_m"] = loo[True]
    figures["z_model_used"] = float(use_z)
    T_F_S, coeffs = unpack_frame(x)
    if not use_z:
        coeffs = np.zeros(zfield.N_COEFFS)
    res = residuals_of(use_z)(x)
    dz_min, dz_max = zfield.z_error_range_m(p, coeffs)
    return Calibration(
        kind="receiver",
        values={"source_in_world": T_F_S},
        residuals_m=res,
        outliers=tuple(int(i) for i in np.flatnonzero(~inliers)),
        figures={
            **figures,
            "z_coeffs_c2_per_m": float(coeffs[0]),
            "z_coeffs_c3_per_m2": float(coeffs[1]),
            "z_error_min_m": dz_min,
            "z_error_max_m": dz_max,
        },
        labels=labels,
    )


def register_receiver_from_log(
    log: TrackerLog,
    tip_in_sensor: ArrayLike,
    points_world: ArrayLike,
    min_dwell_s: float = 0.5,
    fit_z: bool = True,
    threshold_m: float = RECEIVER_THRESHOLD_M,
    labels: tuple[str, ...] = (),
) -> Calibration:
    """:func:`register_receiver` on the dwells :func:`find_dwells` finds in a log.

    Raises:
        InputError: a log beyond the tracker's range (units), or a number of dwells different
            from the number of points (listing the dwells found).
    """
    check_tracker_range(log)
    world = np.asarray(points_world, dtype=float)
    dwells = find_dwells(log, tip_in_sensor, min_dwell_s)
    if len(dwells) != len(world):
        found = ", ".join(f"{log.t[d.start]:.1f}-{log.t[d.stop - 1]:.1f} s" for d in dwells) or "none"
        raise InputError(
            f"tracker log {log.source!r}: {len(dwells)} dwell(s) of at least {min_dwell_s} s found "
            f"({found}) but {len(world)} points given; rest the tip on every point, in the order of "
            f"the points file"
        )
    cal = register_receiver(
        np.array([d.sensor_position for d in dwells]),
        np.array([d.sensor_rotation for d in dwells]),
        tip_in_sensor,
        world,
        fit_z=fit_z,
        threshold_m=threshold_m,
        labels=labels,
    )
    cal.figures["n_dwells"] = float(len(dwells))
    return cal


# ---- trace along the CAD path ------------------------------------------------------------------
