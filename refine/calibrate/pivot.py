"""Pivot calibration of the hand tool: where the tip is in the tracker sensor frame.

The worker holds the tool's tip in a divot and swings the tool about it. Every sample then obeys
``p_k + R_k t = c``: the sensor position ``p_k`` and orientation ``R_k`` (in the receiver frame
{S}) carry the tip offset ``t`` (in the sensor frame {E}) to the fixed pivot ``c`` (in {S}).

The solution takes three steps: the linear least-squares answer of the stacked equations
``[R_k  -I] [t; c] = -p_k``; a robust nonlinear fit (scipy ``least_squares``, soft-L1 loss) that
also estimates the tracker's distance-dependent z error (:mod:`refine.calibrate.zfield`); and a
final fit without the samples whose residual exceeds the outlier threshold.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import lstsq
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from refine.calibrate import zfield
from refine.calibrate.result import Calibration
from refine.errors import InputError
from refine.types import Array

logger = logging.getLogger(__name__)

#: Least RMS swing about the tool's second principal axis [deg]: a swing about one axis only
#: leaves the tip's component along that axis undetermined.
MIN_SWING_DEG = 8.0
#: Residuals below this are never outliers [m].
OUTLIER_FLOOR_M = 0.003
#: Outlier threshold in robust standard deviations of the residual (1.4826 MAD).
OUTLIER_SIGMAS = 4.0
#: Longest plausible tip offset [m]; a longer one usually means the log's units are wrong.
MAX_TIP_M = 1.0
#: Fewest samples a pivot calibration accepts.
MIN_SAMPLES = 20


def swing_spread_deg(rotations: ArrayLike) -> tuple[float, float]:
    """RMS rotation of the tool about its two most-swung axes [deg], largest first.

    The rotations (M, 3, 3) are taken relative to their mean; the spreads are the square roots of
    the two largest eigenvalues of the covariance of the rotation vectors.
    """
    rot = Rotation.from_matrix(np.asarray(rotations, dtype=float))
    rel = (rot.mean().inv() * rot).as_rotvec()
    eig = np.sort(np.linalg.eigvalsh(np.cov(rel.T)))[::-1]
    return math.degrees(math.sqrt(max(eig[0], 0.0))), math.degrees(math.sqrt(max(eig[1], 0.0)))


def fixed_point_lstsq(positions: ArrayLike, rotations: ArrayLike) -> tuple[Array, Array, Array]:
    """Linear least-squares solution of ``p_k + R_k t = c``: ``t`` (3,), ``c`` (3,), residuals (M,) [m].

    The stacked system ``[R_k  -I] [t; c] = -p_k`` is solved by ``scipy.linalg.lstsq``.
    """
    p = np.asarray(positions, dtype=float)
    R = np.asarray(rotations, dtype=float)
    A = np.concatenate([R, np.broadcast_to(-np.eye(3), R.shape)], axis=2).reshape(-1, 6)
    x = lstsq(A, -p.ravel())[0]
    t, c = x[:3], x[3:]
    return t, c, np.linalg.norm(p + R @ t - c, axis=1)


def _residuals(x: Array, positions: Array, rotations: Array, fit_z: bool) -> Array:
    t, c = x[:3], x[3:6]
    coeffs = x[6:8] if fit_z else np.zeros(zfield.N_COEFFS)
    true_sensor = c - rotations @ t
    return (positions - zfield.distort(true_sensor, coeffs)).ravel()


def solve_pivot(
    positions: ArrayLike,
    rotations: ArrayLike,
    fit_z: bool = True,
    outlier_threshold_m: float | None = None,
    min_swing_deg: float = MIN_SWING_DEG,
) -> Calibration:
    """Solve the tip offset and the pivot point from a pivoting swing.

    Args:
        positions: sensor positions in {S} [m], shape (M, 3).
        rotations: sensor orientations R_S_E, shape (M, 3, 3).
        fit_z: also estimate the tracker's z error ``c2 d^2 + c3 d^3`` (reported as figures).
        outlier_threshold_m: residual above which a sample is rejected [m]; None sets it to
            :data:`OUTLIER_SIGMAS` robust standard deviations, at least :data:`OUTLIER_FLOOR_M`.
        min_swing_deg: least RMS swing about the second axis [deg].

    Returns:
        ``tip_in_sensor_m`` (3,) and ``pivot_in_source_m`` (3,), a residual per sample, the
        rejected samples, and the figures ``swing_deg``, ``swing_second_axis_deg``,
        ``z_coeffs_c2_per_m``, ``z_coeffs_c3_per_m2`` and ``z_error_min_m``/``z_error_max_m``.

    Raises:
        InputError: too few samples, too little swing, or a tip offset longer than
            :data:`MAX_TIP_M` (wrong units).
    """
    p = np.asarray(positions, dtype=float)
    R = np.asarray(rotations, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or R.shape != (len(p), 3, 3):
        raise InputError(
            f"pivot: expected positions (M, 3) and rotations (M, 3, 3), got {p.shape}, {R.shape}"
        )
    if len(p) < MIN_SAMPLES:
        raise InputError(f"pivot: {len(p)} samples; a pivot calibration needs at least {MIN_SAMPLES}")
    first, second = swing_spread_deg(R)
    if second < min_swing_deg:
        raise InputError(
            f"pivot: too little swing: the tool turned {first:.1f} deg and {second:.1f} deg RMS about "
            f"its two most-swung axes; at least {min_swing_deg:.1f} deg about both is needed. Keep "
            f"the tip in the divot and swing the tool in a cone, not in one plane"
        )

    # ---- linear least squares: [R_k  -I] [t; c] = -p_k
    x_lin = np.concatenate(fixed_point_lstsq(p, R)[:2])

    # ---- robust nonlinear fit with the z error, then without the outliers
    x0 = np.concatenate([x_lin, np.zeros(zfield.N_COEFFS if fit_z else 0)])
    robust = least_squares(
        _residuals, x0, args=(p, R, fit_z), loss="soft_l1", f_scale=OUTLIER_FLOOR_M, x_scale="jac"
    )
    res = np.linalg.norm(robust.fun.reshape(-1, 3), axis=1)
    if outlier_threshold_m is None:
        mad = float(np.median(np.abs(res - np.median(res))))
        outlier_threshold_m = max(OUTLIER_FLOOR_M, float(np.median(res)) + OUTLIER_SIGMAS * 1.4826 * mad)
    keep = res <= outlier_threshold_m
    final = least_squares(_residuals, robust.x, args=(p[keep], R[keep], fit_z), x_scale="jac")
    x = final.x
    res = np.linalg.norm(_residuals(x, p, R, fit_z).reshape(-1, 3), axis=1)
    tip, pivot = x[:3], x[3:6]
    if np.linalg.norm(tip) > MAX_TIP_M:
        raise InputError(
            f"pivot: the tip is {np.linalg.norm(tip):.2f} m from the sensor, more than a hand tool's "
            f"{MAX_TIP_M:.1f} m: are the log's units right (--units)?"
        )
    coeffs = x[6:8] if fit_z else np.zeros(zfield.N_COEFFS)
    dz_min, dz_max = zfield.z_error_range_m(pivot - R[keep] @ tip, coeffs)
    outliers = tuple(int(i) for i in np.flatnonzero(~keep))
    logger.info(
        "pivot: tip %.1f mm from the sensor, %d of %d samples rejected, swing %.1f/%.1f deg",
        1000 * np.linalg.norm(tip),
        len(outliers),
        len(p),
        first,
        second,
    )
    return Calibration(
        kind="pivot",
        values={"tip_in_sensor_m": tip, "pivot_in_source_m": pivot},
        residuals_m=res,
        outliers=outliers,
        figures={
            "swing_deg": first,
            "swing_second_axis_deg": second,
            "outlier_threshold_m": float(outlier_threshold_m),
            "z_coeffs_c2_per_m": float(coeffs[0]),
            "z_coeffs_c3_per_m2": float(coeffs[1]),
            "z_error_min_m": dz_min,
            "z_error_max_m": dz_max,
        },
    )
