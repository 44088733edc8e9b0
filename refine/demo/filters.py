"""Cleaning tracker samples: outliers, smoothing on R^3 and SO(3), speed, the start pause.

All functions are vectorised over samples and assume sample times that strictly increase and are
roughly uniform (as a tracker's are): smoothing widths are converted from seconds to samples with
the median time step.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import gaussian_filter1d

from refine.errors import InputError
from refine.frames import (
    continuous_quaternions,
    matrix_from_quaternion,
    quaternion_from_matrix,
    rotvec_from_matrix,
)

#: Scale from the median absolute deviation to the standard deviation of normal noise.
MAD_TO_SIGMA = 1.4826


def check_times(t: ArrayLike) -> NDArray:
    """Return sample times [s] (M,) as floats after checking that M >= 2 and they increase."""
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or len(t) < 2:
        raise InputError(f"sample times: expected shape (M,) with M >= 2, got {t.shape}")
    steps = np.diff(t)
    if np.any(steps <= 0.0):
        k = int(np.flatnonzero(steps <= 0.0)[0]) + 1
        raise InputError(f"sample times must strictly increase: t[{k}] = {t[k]} s after {t[k - 1]} s")
    return t


def _sigma_samples(t: NDArray, time_constant_s: float) -> float:
    if not (math.isfinite(time_constant_s) and time_constant_s >= 0.0):
        raise InputError(f"time_constant_s must be a finite number >= 0 s, got {time_constant_s!r}")
    return time_constant_s / float(np.median(np.diff(t)))


def _robust_odd_extension(x: NDArray, h: int) -> NDArray:
    """Pad ``x`` (M, k) with ``h`` samples at each end: point reflection about a robust line.

    At the start, ``b`` is the median slope ``(x[j+h] - x[j]) / h`` and ``a`` the median of
    ``x[j] - b j`` over the first ``2h + 1`` samples; the padding is ``x[-j] = 2a - x[j]``. A linear
    trend continues unchanged (so a running median does not lag at the ends), noise keeps its
    level, and an outlier at the end sample is neither copied nor trusted as the pivot.
    """
    n = min(len(x), 2 * h + 1)
    j = np.arange(n)[:, None]

    def pivot(y: NDArray) -> NDArray:
        lag = min(h, n - 1)
        slope = np.median((y[lag:n] - y[: n - lag]) / lag, axis=0)
        return np.median(y[:n] - slope * j, axis=0)

    reach = np.minimum(np.arange(1, h + 1), len(x) - 1)  # short logs reuse their last sample
    head = 2.0 * pivot(x) - x[reach][::-1]
    tail = 2.0 * pivot(x[::-1]) - x[::-1][reach]
    return np.concatenate([head, x, tail])


_CHUNK_ELEMENTS = 1 << 21
"""Window elements processed at once by the running statistics (2 M floats, 16 MB per array):
memory stays linear in the number of samples whatever the window."""


def _window_stats(x: NDArray, h: int, mad: bool = True) -> tuple[NDArray, NDArray | None]:
    """Medians of the detrended windows ``k ± h`` of ``x`` (M, k), and their MADs.

    The window of sample ``k`` is ``D[k, c, i] = x[k+i-h, c] - slope[k, c] (i - h)``: its local slope
    (the median of ``(x[j+h] - x[j]) / h`` over the ``h + 1`` pairs inside the window: a few
    outliers do not tilt it, and the long baseline keeps noise from tilting it) removed. Returns
    ``median(D, axis=-1)`` and ``median(|D - median|, axis=-1)``, each of shape (M, k), computed in
    blocks of samples so that memory stays linear in M.
    """
    padded = _robust_odd_extension(x, h)
    m, k = x.shape
    med = np.empty((m, k))
    spread = np.empty((m, k)) if mad else None
    ramp = np.arange(-h, h + 1)
    step = max(64, _CHUNK_ELEMENTS // (k * (2 * h + 1)))
    for a in range(0, m, step):
        b = min(m, a + step)
        windows = sliding_window_view(padded[a : b + 2 * h], 2 * h + 1, axis=0)
        slope = np.median(windows[..., h:] - windows[..., : h + 1], axis=-1) / h
        detrended = windows - slope[..., None] * ramp
        med[a:b] = np.median(detrended, axis=-1)
        if spread is not None:
            spread[a:b] = np.median(np.abs(detrended - med[a:b, :, None]), axis=-1)
    return med, spread


def running_median(x: ArrayLike, half_window: int) -> NDArray:
    """Trend-corrected running median of each column of ``x`` (M,) or (M, k).

    Value at ``k``: the median over the window ``k ± half_window`` of ``x_j - b_k (j - k)``, with
    ``b_k`` the window's robust slope (median of ``(x_{j+h} - x_j) / h``). On a flat signal this
    is the plain running median; on a steep one it stays on the signal, where a plain median is
    shifted by one sample step for every outlier in the window. Ends are padded by a robust point
    reflection.
    """
    x = np.asarray(x, dtype=float)
    med, _ = _window_stats(x.reshape(len(x), -1), int(half_window), mad=False)
    return med.reshape(x.shape)


def hampel(
    x: ArrayLike, half_window: int, n_sigmas: float, min_deviation: float = 0.0
) -> tuple[NDArray, NDArray]:
    """Hampel filter: replace samples far from their running median by that median.

    For each sample ``k`` (and each column independently) with the window ``k ± half_window``:
    ``m_k`` is the window median, ``sigma_k = 1.4826 · median_j |x_j - m_k|`` (the MAD scaled to
    a standard deviation for normal noise, times ``n / (n - 0.8)`` for a window of ``n`` samples,
    the usual small-sample correction), and ``x_k`` is an outlier when
    ``|x_k - m_k| > max(n_sigmas · sigma_k, min_deviation)``. Runs of up to ``half_window``
    outliers are found.

    ``sigma_k`` is floored at its median over the whole signal (per column): the MAD of a
    15-sample window often underestimates the noise, and without the floor a 3-sigma test flags
    several per cent of clean noisy samples instead of a fraction of a per cent.

    The window is detrended first (see :func:`running_median`): on a steep signal a plain window
    median and MAD grow with the slope, hide outliers and drag in their neighbours. The ends are
    padded by point reflection about a robust line through the first (last) ``2 half_window + 1``
    samples, so a spike on the very first or last sample is found too.

    Args:
        x: samples, shape (M,) or (M, k), M >= 2, uniformly sampled.
        half_window: half-width of the window [samples], >= 1.
        n_sigmas: threshold [robust standard deviations], > 0.
        min_deviation: floor on the threshold, in the unit of ``x``; keeps flat or quantised
            stretches (where the MAD is zero) from flagging their smallest wiggles.

    Returns:
        ``(filtered, outlier_mask)``: ``x`` with outliers replaced by the running median, and the
        mask, both of the shape of ``x``.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim not in (1, 2) or len(x) < 2:
        raise InputError(f"hampel: expected shape (M,) or (M, k) with M >= 2, got {x.shape}")
    if int(half_window) < 1 or not n_sigmas > 0.0:
        raise InputError(f"hampel: need half_window >= 1 and n_sigmas > 0, got {half_window}, {n_sigmas}")
    x2 = x.reshape(len(x), -1)
    med, spread = _window_stats(x2, int(half_window))
    n = 2 * int(half_window) + 1  # small-sample correction of the MAD (Croux & Rousseeuw, 1992)
    sigma = MAD_TO_SIGMA * n / (n - 0.8) * spread
    sigma = np.maximum(sigma, np.median(sigma, axis=0))
    mask = np.abs(x2 - med) > np.maximum(n_sigmas * sigma, min_deviation)
    filtered = np.where(mask, med, x2)
    return filtered.reshape(x.shape), mask.reshape(x.shape)


def rotation_outliers(
    rotations: ArrayLike, half_window: int, n_sigmas: float, min_angle_deg: float = 0.0
) -> NDArray:
    """Hampel test for orientations, done on SO(3) rather than on Euler angles.

    The running median rotation is the component-wise :func:`running_median` of sign-continuous
    quaternions, normalised. Each sample's residual is the rotation vector of
    ``R_median^T · R`` [rad]; :func:`hampel` is applied to its three components (floor
    ``min_angle_deg``), and a sample is an outlier if any component is.

    Args:
        rotations: orientations, shape (M, 3, 3).
        half_window: half-width of the window [samples].
        n_sigmas: threshold [robust standard deviations].
        min_angle_deg: floor on the threshold [deg].

    Returns:
        Outlier mask, shape (M,).
    """
    R = np.asarray(rotations, dtype=float)
    q = continuous_quaternions(quaternion_from_matrix(R))
    R_med = matrix_from_quaternion(running_median(q, half_window))
    residual = rotvec_from_matrix(np.einsum("kji,kjl->kil", R_med, R))
    _, mask = hampel(residual, half_window, n_sigmas, min_deviation=math.radians(min_angle_deg))
    return mask.any(axis=1)


def smooth_positions(t: ArrayLike, positions: ArrayLike, time_constant_s: float) -> NDArray:
    """Gaussian smoothing of positions with standard deviation ``time_constant_s`` in time.

    Args:
        t: sample times [s], shape (M,), strictly increasing, about uniform.
        positions: positions [m], shape (M, 3).
        time_constant_s: standard deviation of the Gaussian kernel [s]; 0 returns a copy.

    Returns:
        Smoothed positions [m], shape (M, 3); the ends are extended with their edge value.
    """
    sigma = _sigma_samples(check_times(t), time_constant_s)
    p = np.array(positions, dtype=float)
    return gaussian_filter1d(p, sigma, axis=0, mode="nearest") if sigma > 0.0 else p


def smooth_rotations(t: ArrayLike, rotations: ArrayLike, time_constant_s: float) -> NDArray:
    """Gaussian smoothing of orientations on SO(3).

    Quaternions are first made sign-continuous (so a path through ``q`` and ``-q``, or a full
    turn, is not averaged with its antipode), then Gaussian-weighted component-wise and
    renormalised. For sign-aligned quaternions this normalised weighted sum is the chordal
    (quaternion L2) mean of the window; it matches the geodesic mean to third order in the spread
    of the window and, unlike filtering Euler angles, has no wrap-around or gimbal-lock artefacts.

    Args:
        t: sample times [s], shape (M,), strictly increasing, about uniform.
        rotations: orientations, shape (M, 3, 3).
        time_constant_s: standard deviation of the Gaussian kernel [s]; 0 returns a copy.

    Returns:
        Smoothed orientations, shape (M, 3, 3).
    """
    sigma = _sigma_samples(check_times(t), time_constant_s)
    R = np.array(rotations, dtype=float)
    if sigma == 0.0:
        return R
    q = continuous_quaternions(quaternion_from_matrix(R))
    return matrix_from_quaternion(gaussian_filter1d(q, sigma, axis=0, mode="nearest"))


def speed_along_track(t: ArrayLike, positions: ArrayLike) -> NDArray:
    """Speed of the sensor along its own track [m/s], shape (M,), by central differences."""
    t = check_times(t)
    velocity = np.gradient(np.asarray(positions, dtype=float), t, axis=0)
    return np.linalg.norm(velocity, axis=1)


def find_motion_start(
    t: ArrayLike,
    positions_smoothed: ArrayLike,
    pause_speed_m_s: float,
    leave_radius_m: float = 0.005,
    sustain_s: float = 0.2,
) -> int:
    """Index of the first sample at which the tool leaves the start pause for good.

    The rule: split the samples into runs where the speed is above ``pause_speed_m_s``. The
    motion starts at the first sample of the first run that either lasts ``sustain_s`` or longer,
    or carries the tool farther than ``leave_radius_m`` from the median position of all samples
    before the run (the pause). Short blips of noise and slow drift inside the pause therefore
    do not count. A log that starts moving returns 0.

    Args:
        t: sample times [s], shape (M,).
        positions_smoothed: smoothed sensor positions [m], shape (M, 3).
        pause_speed_m_s: speed under which the tool counts as still [m/s].
        leave_radius_m: distance from the pause position that counts as having left it [m].
        sustain_s: how long the speed must stay above the threshold to count [s].

    Raises:
        InputError: the tool never leaves the pause (naming the largest speed and distance).
    """
    t = check_times(t)
    p = np.asarray(positions_smoothed, dtype=float)
    moving = speed_along_track(t, p) > pause_speed_m_s
    edges = np.flatnonzero(np.diff(np.concatenate([[0], moving.astype(np.int8), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if t[b - 1] - t[a] >= sustain_s:
            return int(a)
        pause = np.median(p[:a], axis=0) if a > 0 else p[0]
        if np.max(np.linalg.norm(p[a:b] - pause, axis=1)) > leave_radius_m:
            return int(a)
    reach = float(np.max(np.linalg.norm(p - p[0], axis=1)))
    raise InputError(
        f"no motion found: speed never stays above pause_speed_m_s = {pause_speed_m_s} m/s for "
        f"{sustain_s} s and the tool stays within {reach:.4f} m of its start"
    )
