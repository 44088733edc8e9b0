"""Align a demonstration to the CAD path: demonstrated tool orientation and speed per waypoint.

Method (all in the receiver frame {S}, where the tracker's error lives; distances are frame-free):

1. Demonstrated TCP poses ``T_F_TCP = T_F_S @ T_S_E @ inv(T_TCP_E)``.
2. Coarse alignment by monotone dynamic time warping (DTW) between the demo TCP positions, from
   ``PRE_MOTION_S`` before ``motion_start``, box-averaged and resampled in time so that a demo row
   advances about half a CAD step at the mean speed, and the CAD points, thinned to at most
   ``DTW_MAX_POINTS``. Each demo row may advance the CAD index by 0, 1 or 2; the first row is matched
   to the CAD start, the last to the CAD end. The recursion is vectorised per row with numpy
   (no DTW package is installed, and this one needs just these steps and end conditions).
3. Tracker distortion (``fit_distortion``): the sensor positions get a correction that is a
   quadratic polynomial (10 terms per axis) of the sensor position in {S}, averaged over
   ``BASIS_SMOOTHING_M`` of path (noise in the argument would let the polynomial fit the noise).
   It is fitted by Tukey-weighted least squares on the *cross-track* part of the residual only
   (point-to-line, as in ICP): a residual's along-track part is the alignment's own guess, while
   a smooth field seen cross-track on one stretch is along-track on another and recovered there.
   A ridge from ``PRIOR_ERROR_M`` (z errors of tens of mm, x/y of a few) settles what the path
   cannot: among fields that explain the data alike, the one mostly along z. Three fit/re-project
   rounds follow each of two DTW passes; a third DTW pass runs on the corrected positions.
4. Every corrected demo sample is projected onto the CAD polyline near its match, giving its arc
   length ``s_i``; a monotone copy (``isotonic_regression``) only picks the samples of each window.
   Samples resting at either end (within 3 noise sigmas + 1 mm of the first or last arc length:
   the pause) are left out. Speed ``v(s)``: least-squares slope of ``s_i`` over ``t_i`` for the
   samples within ``s ± speed_smoothing_m`` (a box window twice ``speed_smoothing_m`` wide).
   Matched time ``t(s)``: where the least-squares line over ``s ± TIME_HALF_WIDTH_M`` passes ``s``,
   clipped to that window, then made strictly increasing. Speeds below ``SPEED_FLOOR_FRACTION`` of
   the median speed (none at all where a window holds no motion) are raised to that floor, so
   every speed is > 0 for the timing stage.
5. Tool orientation at ``t(s)`` by ``scipy`` ``Slerp`` over the demo TCP rotations.

Limits: only the position error is corrected (the tracker's orientation error is not); a field
along the path that no stretch of it sees cross-track (e.g. an x error on a straight line along x)
cannot be told from timing; where the worker stops mid-path, ``t(s)`` may be off by up to
``TIME_HALF_WIDTH_M`` of arc length.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import uniform_filter1d
from scipy.optimize import isotonic_regression
from scipy.spatial.distance import cdist

from refine.errors import InputError
from refine.frames import check_transform, invert_transform, transform_points
from refine.paths import CadPath, Demonstration
from refine.types import Array

logger = logging.getLogger(__name__)

logger = logging.getLogger(__name__)
PRE_MOTION_S = 1.0  # demo kept before motion_start [s]
START_WINDOW_S = 0.2  # the demo's start position is its mean over this much time [s]
DTW_MAX_POINTS = 600  # CAD points used by the DTW at most
SPEED_FLOOR_FRACTION = 0.1  # speed floor as a fraction of the median demonstrated speed
MAX_RESIDUAL_M = 0.1  # demo-to-CAD distance beyond which a waypoint is not covered [m]
MAX_CORRECTION_M = 0.15  # largest tracker position correction accepted [m]
MAX_MEAN_HAND_SPEED_M_S = 2.0  # mean speed above which a demonstration is implausible [m/s]
TIME_HALF_WIDTH_M = 0.005  # half-width of the arc-length window that fits t(s) [m]
BASIS_SMOOTHING_M = 0.02  # path length the distortion's argument is averaged over [m]
PRIOR_ERROR_M = (0.01, 0.01, 0.05)  # expected tracker error along the receiver's x, y, z [m]
_RIDGE_NOISE_M = 3e-3  # noise the ridge assumes, pessimistic: rows are correlated [m]
_FIT_ROUNDS = (3, 3, 0)  # distortion fit/re-project rounds after each DTW pass


@dataclass(frozen=True)
class Alignment:
    """The demonstration matched to the CAD waypoints.

    Attributes:
        t: demo time matched to each waypoint [s], shape (N,), strictly increasing.
        speed: demonstrated speed along the CAD path [m/s], shape (N,), >= speed_floor.
        speed_floor: the floor applied to ``speed`` [m/s].
        residual: distance between the corrected demo TCP at ``t`` and the CAD point [m], shape (N,).
        raw_median_residual: median demo-to-path distance before any distortion correction [m].
        max_correction: largest fitted tracker position correction on the demo [m].
        start_shift_m: on a closed path, the arc length from the first waypoint to the nearest
            path point of the corrected demo's mean position in the start pause, signed along the
            path [m]; 0 on an open path. The demo's start position is its mean over the first
            ``START_WINDOW_S`` (the start pause), but not past ``motion_start``.
        corrected: the demo TCP at ``t`` after the tracker position correction, in the receiver
            frame {S} [m], shape (N, 3) (``residual`` is its distance to the CAD point), or None.
    """

    t: Array
    speed: Array
    speed_floor: float
    residual: Array
    raw_median_residual: float
    max_correction: float
    start_shift_m: float = 0.0
    corrected: Array | None = None


def demo_tcp_poses(demo: Demonstration, source_in_world: ArrayLike, sensor_in_tcp: ArrayLike) -> Array:
    """Demonstrated TCP poses ``T_F_TCP = T_F_S @ T_S_E @ inv(T_TCP_E)``, shape (M, 4, 4)."""
    T_F_S = check_transform(source_in_world, "source_in_world")
    T_TCP_E = check_transform(sensor_in_tcp, "sensor_in_tcp")
    T_S_E = np.zeros((len(demo.t), 4, 4))
    T_S_E[:, :3, :3], T_S_E[:, :3, 3], T_S_E[:, 3, 3] = demo.rotations, demo.positions, 1.0
    return np.einsum("ij,mjk,kl->mil", T_F_S, T_S_E, invert_transform(T_TCP_E), optimize=False)


def monotone_dtw(cost: Array) -> NDArray[np.intp]:
    """Monotone DTW: the column matched to each row, first row to column 0, last to the last.

    Args:
        cost: matching cost, shape (M, N); each row may advance the column by 0, 1 or 2.

    Returns:
        Column index per row, shape (M,), non-decreasing.

    Raises:
        InputError: when M rows cannot reach the last column (M < (N - 1) / 2 + 1).
    """
    m, n = cost.shape
    D = np.full((m, n), np.inf)
    D[0, 0] = cost[0, 0]
    for i in range(1, m):
        prev, row = D[i - 1], D[i]
        row[:] = prev
        np.minimum(row[1:], prev[:-1], out=row[1:])
        np.minimum(row[2:], prev[:-2], out=row[2:])
        row += cost[i]
    if not np.isfinite(D[-1, -1]):
        raise InputError(f"DTW: {m} demo rows cannot cover {n} path points (need >= {(n + 1) // 2})")
    cols = np.empty(m, dtype=np.intp)
    j = cols[-1] = n - 1
    for i in range(m - 1, 0, -1):
        lo = max(j - 2, 0)
        j = lo + int(np.argmin(D[i - 1, lo : j + 1]))
        cols[i - 1] = j
    return cols


def _project(
    points: Array, centre_s: Array, cad_s: Array, cad: Array, radius: float
) -> tuple[Array, Array, Array, Array]:
    """Closest point on the CAD polyline within ``radius`` [m] of arc length around ``centre_s``.

    Returns:
        Arc length [m] (M,), foot point [m] (M, 3), unit tangent (M, 3), distance [m] (M,).
    """
    n_seg = len(cad_s) - 1
    k = min(int(np.ceil(radius / np.median(np.diff(cad_s)))) + 1, n_seg)
    seg0 = np.clip(np.searchsorted(cad_s, centre_s) - 1, 0, n_seg - 1)
    seg = np.clip(seg0[:, None] + np.arange(-k, k + 1), 0, n_seg - 1)
    A, AB = cad[seg], cad[seg + 1] - cad[seg]
    u = np.clip(np.einsum("mkd,mkd->mk", points[:, None] - A, AB) / np.sum(AB**2, axis=-1), 0, 1)
    foot = A + u[..., None] * AB
    best = np.argmin(np.sum((points[:, None] - foot) ** 2, axis=-1), axis=1)
    rows = np.arange(len(points))
    seg, u, foot, AB = seg[rows, best], u[rows, best], foot[rows, best], AB[rows, best]
    s = cad_s[seg] + u * (cad_s[seg + 1] - cad_s[seg])
    tangent = AB / np.linalg.norm(AB, axis=1, keepdims=True)
    return s, foot, tangent, np.linalg.norm(points - foot, axis=1)


def resample_in_time(t: Array, x: Array, t_new: Array) -> Array:
    """Linear interpolation of the rows of x (M, 3) from times t to t_new [s]."""
    return np.column_stack([np.interp(t_new, t, c) for c in x.T])


def _basis(q: Array, centre: Array, scale: float) -> Array:
    """Quadratic monomials of normalised positions, shape (M, 10)."""
    x, y, z = ((q - centre) / scale).T
    return np.stack([np.ones_like(x), x, y, z, x * x, y * y, z * z, x * y, x * z, y * z], axis=1)


def _apply(phi: Array, W: Array) -> Array:
    """Correction phi @ W [m], shape (M, 3); einsum keeps these tiny products off threaded BLAS."""
    return np.einsum("ik,ka->ia", phi, W)


def _fit_distortion(phi: Array, p: Array, foot: Array, tangent: Array, dist: Array) -> Array:
    """Coefficients W (10, 3) minimising the robust cross-track part of p + phi W - foot."""
    cutoff = 4.685 * (1.4826 * np.median(dist) + 1e-4)  # Tukey's biweight: far rows get no say
    w = np.clip(1.0 - (dist / cutoff) ** 2, 0.0, None) ** 2
    P = np.eye(3) - tangent[:, :, None] * tangent[:, None, :]  # projector onto the normal plane
    nk, wphi = phi.shape[1], w[:, None] * phi
    outer = (wphi[:, :, None] * phi[:, None, :]).reshape(len(phi), -1)
    N = np.einsum("iq,ir->qr", outer, P.reshape(len(P), 9)).reshape(nk, nk, 3, 3).transpose(0, 2, 1, 3)
    N = N.reshape(3 * nk, 3 * nk)
    rhs = np.einsum("ik,iab,ib->ka", wphi, P, foot - p).reshape(-1)
    N[np.diag_indices_from(N)] += np.tile((_RIDGE_NOISE_M / np.asarray(PRIOR_ERROR_M)) ** 2, nk)
    return np.linalg.solve(N, rhs).reshape(nk, 3)


def _window_fit(
    t: Array, s_raw: Array, s_mono: Array, centre: Array, s_lo: Array, s_hi: Array
) -> tuple[Array, Array]:
    """Least-squares line s ≈ s̄ + v (t - t̄) over the samples with s_mono in [s_lo, s_hi].

    Returns:
        Speed v [m/s] (NaN where not positive) and the time the line passes ``centre`` [s],
        clipped to the window; both shape (N,).
    """
    m = len(t)
    mid = np.searchsorted(s_mono, centre)
    lo = np.clip(np.minimum(np.searchsorted(s_mono, s_lo, "left"), mid - 2), 0, m - 5)
    hi = np.minimum(np.maximum(np.searchsorted(s_mono, s_hi, "right"), lo + 5), m)
    tc = t - t.mean()
    sums = [np.concatenate([[0.0], np.cumsum(x)]) for x in (tc, s_raw, tc * tc, tc * s_raw)]
    St, Ss, Stt, Sts = (c[hi] - c[lo] for c in sums)
    n = (hi - lo).astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = (n * Sts - St * Ss) / (n * Stt - St**2)
        t_fit = t.mean() + St / n + (centre - Ss / n) / v
    ok = np.isfinite(v) & (v > 0)
    t_fit = np.clip(np.where(ok, t_fit, 0.5 * (t[lo] + t[hi - 1])), t[lo], t[hi - 1])
    return np.where(ok, v, np.nan), t_fit


def _time_law(t: Array, s_raw: Array, cad_s: Array, half_width: float) -> tuple[Array, Array]:
    """Speed [m/s] (NaN where undefined) and strictly increasing matched time [s] per waypoint."""
    s_mono = isotonic_regression(s_raw).x
    # both fits stay clear of the samples resting at either end (pause, ramp)
    noise = 1.4826 * float(np.median(np.abs(s_raw - s_mono)))
    s_a, s_b = s_mono[0] + 3.0 * noise + 1e-3, s_mono[-1] - 3.0 * noise - 1e-3
    v = _window_fit(
        t, s_raw, s_mono, cad_s, np.maximum(cad_s - half_width, s_a), np.minimum(cad_s + half_width, s_b)
    )[0]
    half = np.clip(np.minimum(cad_s - s_a, s_b - cad_s), 0.0, TIME_HALF_WIDTH_M)
    t_fit = _window_fit(t, s_raw, s_mono, cad_s, cad_s - half, cad_s + half)[1]
    t_fit = np.maximum.accumulate(t_fit)
    return v, t_fit + 1e-9 * np.arange(len(t_fit))  # strictly increasing; 1 ns steps are harmless


def _coarse_match(
    pg: Array, phi_g: Array, cad_s: Array, cad: Array, cols: Array, radius: float, fit: bool
) -> tuple[Array, Array, float]:
    """DTW passes on the grid rows, with the distortion fit between them.

    Returns:
        Arc length [m] per grid row (M,), distortion coefficients (10, 3) and the median
        row-to-path distance of the first pass, before any correction [m].
    """
    W, raw_median = np.zeros((phi_g.shape[1], 3)), np.nan
    for rounds in _FIT_ROUNDS if fit else (0,):
        pc = pg + _apply(phi_g, W)
        sg = cad_s[cols][monotone_dtw(cdist(pc, cad[cols]))]
        sg, foot, tangent, dist = _project(pc, sg, cad_s, cad, radius)
        if np.isnan(raw_median):
            raw_median = float(np.median(dist))
            if raw_median > MAX_RESIDUAL_M:
                break
        for _ in range(rounds):
            W = _fit_distortion(phi_g, pg, foot, tangent, dist)
            sg, foot, tangent, dist = _project(pg + _apply(phi_g, W), sg, cad_s, cad, radius)
    return sg, W, raw_median


def refine_start(p_start: Array, cad_s: Array, cad: Array, s0: float, radius: float) -> float:
    """Arc length [m] of the point of a closed path nearest to ``p_start`` within ``radius`` of ``s0``."""
    L = float(cad_s[-1])
    ring_s, ring = cad_s[:-1], cad[:-1]
    n = len(ring)
    k = int(np.ceil(radius / np.median(np.diff(cad_s)))) + 1
    j = int(np.searchsorted(cad_s, s0 % L)) + np.arange(-k, k + 1)
    a, b = ring[j % n], ring[(j + 1) % n]
    ab = b - a
    u = np.clip(np.einsum("ij,ij->i", p_start - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
    best = int(np.argmin(np.linalg.norm(a + u[:, None] * ab - p_start, axis=1)))
    seg = np.diff(cad_s)[j[best] % n]
    return float((ring_s[j[best] % n] + u[best] * seg) % L)


def start_position(t: Array, p: Array, t_motion: float) -> Array:
    """Mean position [m] over the first ``START_WINDOW_S`` of ``t``, but not past ``t_motion``."""
    first = t <= min(t[0] + START_WINDOW_S, t_motion)
    return p[first].mean(axis=0) if np.count_nonzero(first) > 1 else p[0]


def align(
    cad: CadPath,
    demo: Demonstration,
    source_in_world: ArrayLike,
    sensor_in_tcp: ArrayLike,
    *,
    speed_smoothing_m: float = 0.03,
    fit_distortion: bool = True,
) -> Alignment:
    """Match every CAD waypoint to a demonstration time (see the module docstring for the method).

    Args:
        cad: the CAD path in {F}.
        demo: the cleaned demonstration (sensor {E} in the receiver {S}).
        source_in_world: receiver pose in the world, T_F_S, shape (4, 4).
        sensor_in_tcp: sensor pose in the tool frame, T_TCP_E, shape (4, 4).
        speed_smoothing_m: half-width of the arc-length window of the speed fit [m], > 0.
        fit_distortion: fit and remove a smooth tracker position error before the final match.

    Raises:
        InputError: bad arguments; a demonstration that does not follow the path (median
            distance > ``MAX_RESIDUAL_M`` before correction), stops short of it (> 5 % of the
            waypoints farther than ``MAX_RESIDUAL_M``), needs a correction > ``MAX_CORRECTION_M``
            or covers it faster than ``MAX_MEAN_HAND_SPEED_M_S``.
    """
    if not speed_smoothing_m > 0.0:
        raise InputError(f"speed_smoothing_m must be > 0 m, got {speed_smoothing_m}")
    T_S_F = invert_transform(check_transform(source_in_world, "source_in_world"))
    T_E_TCP = invert_transform(check_transform(sensor_in_tcp, "sensor_in_tcp"))
    if np.any(np.diff(demo.t) <= 0.0):
        k = int(np.argmax(np.diff(demo.t) <= 0.0))
        raise InputError(
            f"demo {demo.source!r}: times must be strictly increasing, but sample {k + 1} "
            f"is at {demo.t[k + 1]:.4f} s after {demo.t[k]:.4f} s"
        )
    i0 = int(np.searchsorted(demo.t, demo.t[demo.motion_start] - PRE_MOTION_S))
    t, q = demo.t[i0:], demo.positions[i0:]
    if len(t) < 10:
        raise InputError(f"demo {demo.source!r}: needs >= 10 samples from motion start, got {len(t)}")
    p = q + np.einsum("mij,j->mi", demo.rotations[i0:], T_E_TCP[:3, 3])  # TCP in {S}
    cad_s, cad_S, L = cad.s, transform_points(T_S_F, cad.positions), cad.length

    # ---- coarse grids: CAD thinned for the DTW, demo resampled to ~half a coarse step per row
    cols = np.unique(np.r_[np.arange(0, len(cad_s), -(-len(cad_s) // DTW_MAX_POINTS)), len(cad_s) - 1])
    h = L / (len(cols) - 1)
    dt_demo, t_move = float(np.median(np.diff(t))), t[-1] - demo.t[demo.motion_start]
    dt_grid = max(0.5 * h * t_move / L, (t[-1] - t[0]) / (8 * len(cols)))
    tg = np.linspace(t[0], t[-1], int(np.ceil((t[-1] - t[0]) / dt_grid)) + 1)
    pg = resample_in_time(t, uniform_filter1d(p, max(1, round(dt_grid / dt_demo)), axis=0), tg)
    # the distortion is a function of heavily smoothed positions: noise in its argument would
    # let the polynomial "explain" the noise (errors in variables)
    n_arg = max(1, round(BASIS_SMOOTHING_M * t_move / L / dt_demo))
    q_arg = uniform_filter1d(q, n_arg, axis=0)
    centre = q_arg.mean(axis=0)
    scale = max(float(np.sqrt(np.mean(np.sum((q_arg - centre) ** 2, axis=1)))), 1e-3)
    phi_g = _basis(resample_in_time(t, q_arg, tg), centre, scale)

    # ---- DTW passes, with the distortion fit between them
    sg, W, raw_median = _coarse_match(pg, phi_g, cad_s, cad_S, cols, 2.0 * h + 0.02, fit_distortion)
    if raw_median > MAX_RESIDUAL_M:
        raise InputError(
            f"demo {demo.source!r} does not follow the CAD path {cad.source!r}: "
            f"median distance {raw_median * 1e3:.0f} mm after alignment "
            f"(limit {MAX_RESIDUAL_M * 1e3:.0f} mm); check frames and units"
        )

    # ---- every sample projected near its match; speed and time per waypoint
    correction = _apply(_basis(q_arg, centre, scale), W)
    pc = p + correction
    s_raw = _project(pc, np.interp(t, tg, sg), cad_s, cad_S, 0.5 * h + 0.005)[0]
    v, t_match = _time_law(t, s_raw, cad_s, speed_smoothing_m)
    floor = SPEED_FLOOR_FRACTION * float(np.nanmedian(v)) if np.any(np.isfinite(v)) else np.nan
    corrected = resample_in_time(t, pc, t_match)
    residual = np.linalg.norm(corrected - cad_S, axis=1)

    # ---- does the demonstration cover the path?
    span, max_corr = float(t_match[-1] - t_match[0]), float(np.linalg.norm(correction, axis=1).max())
    far = residual > MAX_RESIDUAL_M
    if far.mean() > 0.05:
        raise InputError(
            f"demo {demo.source!r} does not cover the CAD path {cad.source!r}: "
            f"{far.mean():.0%} of waypoints, between s = {cad_s[far].min():.2f} and "
            f"{cad_s[far].max():.2f} m of {L:.2f} m, are farther than "
            f"{MAX_RESIDUAL_M * 1e3:.0f} mm from it (largest {residual.max() * 1e3:.0f} mm)"
        )
    if max_corr > MAX_CORRECTION_M:
        raise InputError(
            f"demo {demo.source!r} follows the CAD path {cad.source!r} only after a "
            f"tracker correction of {max_corr * 1e3:.0f} mm (limit "
            f"{MAX_CORRECTION_M * 1e3:.0f} mm); check source_in_world and the path"
        )
    if not np.isfinite(floor) or span <= 0.0 or L / span > MAX_MEAN_HAND_SPEED_M_S:
        raise InputError(
            f"demo {demo.source!r}: the {L:.2f} m path is matched to {span:.3f} s of "
            f"demonstration (> {MAX_MEAN_HAND_SPEED_M_S} m/s); wrong time units?"
        )
    speed = np.maximum(np.nan_to_num(v, nan=floor), floor)
    shift = 0.0
    if cad.closed:
        p_start = start_position(t, pc, float(demo.t[demo.motion_start]))
        shift = refine_start(p_start, cad_s, cad_S, 0.0, 2.0 * h + 0.02)
        shift = shift - L if shift > 0.5 * L else shift
    logger.info(
        "aligned %d waypoints to %d demo samples: raw median distance %.1f mm, max "
        "correction %.1f mm, residual median %.1f mm max %.1f mm, %.0f%% at speed floor",
        len(cad_s),
        len(t),
        raw_median * 1e3,
        max_corr * 1e3,
        np.median(residual) * 1e3,
        residual.max() * 1e3,
        100 * np.mean(speed == floor),
    )
    return Alignment(t_match, speed, floor, residual, raw_median, max_corr, shift, corrected)
