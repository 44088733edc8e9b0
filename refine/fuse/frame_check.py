"""The tracker-frame check: a wrong ``source_in_world`` caught on the aligned demonstration.

**Tracker frame** (:func:`estimate_frame_error`, after alignment). The fusion fits a smooth
polynomial distortion that can absorb a rotated ``source_in_world`` (a rotation is linear in the
position), so the fusion residual cannot reveal one. Here the demonstrated TCP positions at the
matched times, uncorrected, are compared with the CAD points, in the receiver frame {S}, by
weighted least squares (Tukey weights) on a model with a rigid part (small rotation ``ω`` about the
receiver, offset ``t``) and a distance-dependent distortion (per receiver axis ``a d² + b d³ + c d⁴``,
``d`` the distance of the **sensor** from the receiver in metres: zero with zero slope at the
receiver, as a magnetic tracker's field error grows; the sensor, not the TCP a lever away, is
where the field is measured). Three choices keep the distortion from absorbing a rigid rotation
where the path runs away from the receiver (then every function of the path position is a
function of ``d``):

* only the residual **across** the path counts (projected off the CAD tangent): the time matching
  slides a waypoint along the path, so the along-path part is the matching's own guess;
* each distortion coefficient (its term's error at 1 m) has a Gaussian prior of the size the
  fusion expects of the tracker along that receiver axis (``refine.fuse.align.PRIOR_ERROR_M``: 10, 10
  and 50 mm), while rotation and offset are free: a rotation is explained by a distortion only as
  far as the tracker's documented error allows;
* the rotation turns the CAD path about its own centre, under a weak prior of
  :data:`ROTATION_PRIOR_RAD` on the whole rotation, and each Gauss-Newton step turns it only
  about the axes the data determine to within :data:`WEAK_CHECK_DEG`: rotation and offset are
  then separate parameters, and a rotation the path cannot show (a round profile about its
  normal) stays at zero instead of drifting, with an offset, along the direction the data leave
  free (turned by tens of degrees, the CAD path's tangents no longer match the turned path's and
  lent the drift the look of a determined rotation). The receiver's offset follows from the
  fitted one and the rotation about the axes the path shows (about the others the path shows
  neither a rotation nor the shift of its centre that would come with it);
* the rotation's uncertainty is the posterior covariance, with the residual variance counted once
  per *independent* residual: per occupied cell of :data:`CORRELATION_LENGTH_M` (a path that comes
  back over the same space, like a spiral, brings no new evidence about a smooth error) or per
  integrated autocorrelation time of the residuals along the path, summed over lags up to
  :data:`HAND_CORRELATION_S` (:func:`correlation_time`: a hand wandering slowly off the path by a
  millimetre for tenths of a second gives residuals that move together over dozens of waypoints
  on a fast path), whichever counts fewer, plus the rotation an unmodelled
  smooth error of :data:`SYSTEMATIC_ERROR_M` can mimic (large on small paths). The
  autocorrelation time is used rather than a block bootstrap: it is deterministic, costs one FFT
  per axis, and enters the same posterior covariance the rest of the check reads (the bootstrap
  would need a block length chosen from the same autocorrelation anyway, and tens of refits).

The path's shape decides which rotations it can show: along each principal axis of the rotation's
covariance the uncertainty is known, and an axis whose uncertainty is more than
:data:`UNOBSERVABLE_RATIO` times that of the best-determined axis (and above
:data:`FRAME_STOP_DEG`), or above :data:`WEAK_CHECK_DEG` whatever the others, is *not observable*
(a straight seam: a rotation about its own direction moves none of its points; a circle: a
rotation about its normal moves every point along the path; a nearly straight path running away
from the receiver: a rotation that moves it along the receiver z is what the distortion does). The check judges the **observable part** of the rotation (its projection on the other
axes): it is *significant* when its χ² against its covariance exceeds the quantile that
:data:`SIGNIFICANCE` standard uncertainties cut off one axis (two-sided 4.55 %), for as many degrees
of freedom as the path shows axes (:func:`frame_error_significant`). Significant and above
:data:`FRAME_WARN_DEG`, a warning is recorded; above :data:`FRAME_STOP_DEG` the run stops unless
``--accept-frame-error`` is given, naming the angle and its uncertainty. An axis that is not
observable is stated once in ``demo_quality`` (``frame.not_observable``, e.g. "about the path
direction"), as a fact of the path's shape, not a warning; ``frame.detectable_deg``
(:data:`SIGNIFICANCE` uncertainties of the observable part) is the least rotation the check can
tell from noise there. A path whose observable part is not significant but whose
``detectable_deg`` is above :data:`WEAK_CHECK_DEG` gets a warning that the frame cannot be checked
well (e.g. a spiral 60 mm across: a rotation of twice the stop limit could pass unseen). The
offset is judged the same way: a warning when it exceeds :data:`OFFSET_WARN_M` and its χ² against
its covariance (which includes what a weakly determined rotation moves the path's centre by) is
significant with 3 degrees of freedom.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from refine.demo.quality import (
    FRAME_STOP_DEG,
    FRAME_WARN_DEG,
    SIGNIFICANCE,
    UNOBSERVABLE_RATIO,
    WEAK_CHECK_DEG,
    DemoQuality,
    FrameEstimate,
)
from refine.errors import InputError, option
from refine.frames import check_transform, invert_transform, matrix_from_rotvec, rotvec_from_matrix
from refine.paths import Demonstration, FusedPath
from refine.types import Array

logger = logging.getLogger(__name__)

OFFSET_WARN_M = 0.025
"""Rigid tracker frame offset above which ``demo_quality`` carries a warning [m], when it is also
significant (its χ² against its covariance, as for the rotation, with 3 degrees of freedom)."""


_DISTANCE_SCALE_M = 1.0  # distances are divided by this in the distortion basis


CORRELATION_LENGTH_M = 0.05
"""Size of the cells of space within which the fit's residuals are taken as one observation [m]
(tracker distortion and tremor are smooth in space; a path that comes back over a cell brings no
new evidence about them), for the rotation's uncertainty."""


SYSTEMATIC_ERROR_M = 0.001
"""RMS of the smooth tracker error the distortion model does not have [m] (the horizontal error
field and the orientation error times the sensor's lever to the TCP, both functions of the sensor
pose): shaped like a rotation, it moves the estimate by this over the path's RMS lever about the
axis. With it, the estimated angle differs from the planted one by more than 2 standard
uncertainties in 1.1 % of the 376 rows of ``benchmarks/frame_check.py`` (2.7 % before the
centre-pivoted fit and the residuals' autocorrelation) and by more than 3 in none (13.3 % and
5.7 % without it, measured with the earlier fit): the uncertainty is not too small."""


HAND_CORRELATION_S = 1.0
"""Longest time over which the residuals' autocorrelation is summed [s] (:func:`correlation_time`):
a hand wanders off the path and back within about a second; slower, smoother error is the
tracker's, a function of where the sensor is, which the cells of :data:`CORRELATION_LENGTH_M` and
:data:`SYSTEMATIC_ERROR_M` account for (summed over the whole path it would count them twice)."""


ROTATION_PRIOR_RAD = 1.0
"""Standard deviation of the Gaussian prior on the tracker frame rotation [rad]."""


DISTANCE_POWERS = (2, 3, 4)
"""Powers of the distance from the receiver in the distortion model (per receiver axis)."""


def _skew_rows(c: Array) -> Array:
    """Rows of d(ω × c)/dω = -[c]x, shape (N, 3, 3)."""
    z = np.zeros(len(c))
    return -np.stack(
        [
            np.stack([z, -c[:, 2], c[:, 1]], 1),
            np.stack([c[:, 2], z, -c[:, 0]], 1),
            np.stack([-c[:, 1], c[:, 0], z], 1),
        ],
        axis=1,
    )


def _across(c: Array) -> Array:
    """Projectors (N, 3, 3) off the tangent of the path through points ``c`` (N, 3).

    The time matching may slide a waypoint along the path: only the residual across it counts.
    """
    tangent = np.gradient(c, axis=0) if len(c) > 1 else np.zeros((1, 3))
    norm = np.linalg.norm(tangent, axis=1, keepdims=True)
    tangent = np.divide(tangent, norm, out=np.zeros_like(tangent), where=norm > 0)
    return np.eye(3) - tangent[:, :, None] * tangent[:, None, :]


def estimate_frame_error(
    demo: Demonstration, fused: FusedPath, source_in_world: ArrayLike, sensor_in_tcp: ArrayLike
) -> FrameEstimate:
    """The rigid rotation and offset between the aligned demonstration and the CAD path.

    Args:
        demo: the cleaned demonstration.
        fused: the fused path (its ``t_demo`` gives the demonstration time of each waypoint).
        source_in_world: T_F_S as given in the problem.
        sensor_in_tcp: T_TCP_E.

    Returns:
        The estimate (module docstring for the model).
    """
    from refine.fuse.align import PRIOR_ERROR_M, demo_tcp_poses

    T_F_S = check_transform(source_in_world, "source_in_world")
    T_S_F = invert_transform(T_F_S)
    tcp = demo_tcp_poses(demo, T_F_S, sensor_in_tcp)[:, :3, 3]
    x_F = np.column_stack([np.interp(fused.t_demo, demo.t, tcp[:, j]) for j in range(3)])
    x = x_F @ T_S_F[:3, :3].T + T_S_F[:3, 3]
    c = fused.positions @ T_S_F[:3, :3].T + T_S_F[:3, 3]
    n = len(c)
    # the distortion is a function of where the sensor is (not the TCP, a lever away)
    sensor = np.column_stack([np.interp(fused.t_demo, demo.t, demo.positions[:, j]) for j in range(3)])
    d = np.linalg.norm(sensor, axis=1) / _DISTANCE_SCALE_M
    radial = np.stack([d**k for k in DISTANCE_POWERS], axis=1)  # (N, K)
    n_terms = radial.shape[1]
    nk = 6 + 3 * n_terms
    basis = np.zeros((n, 3, nk - 6))
    for j in range(3):
        basis[:, j, j::3] = radial
    # prior: each distortion coefficient (its term's error at 1 m) ~ the tracker's expected error
    # along that receiver axis; offset free (a 30 m ridge keeps N regular), the rotation under a
    # prior of 1 rad (57 deg): far weaker than any axis the path shows (a 1 mm error over a 40 mm
    # path is a few degrees), it keeps an axis the path cannot show at zero instead of letting
    # Gauss-Newton throw it anywhere
    prior = np.concatenate(
        [
            np.full(3, ROTATION_PRIOR_RAD**-2),
            np.full(3, 1e-3),
            np.tile(1.0 / np.asarray(PRIOR_ERROR_M) ** 2, n_terms),
        ]
    )
    # one independent residual per occupied cell of CORRELATION_LENGTH_M (a smooth error seen twice
    # where the path comes back is one observation)
    cells = len(np.unique(np.floor(c / CORRELATION_LENGTH_M).astype(np.int64), axis=0))
    inflation = max(1.0, n / cells)
    # the rotation turns the CAD path about its centre (then rotation and offset are independent
    # parameters, and a rotation the path cannot show stays at zero instead of drifting along the
    # ridge with an offset); the offset is converted to the receiver's at the end
    pivot = c.mean(axis=0)
    w = np.ones(n)
    coef = np.zeros(nk)
    var = (1e-3) ** 2
    resid = np.zeros(n)
    left = np.zeros((n, 3))
    # the time matching slides a waypoint along the demonstrated path, the CAD path's tangent
    across = _across(c)
    # Gauss-Newton on the rotation about the path's centre; a step turns only about the axes the
    # data determine better than WEAK_CHECK_DEG (about the others it stays at the prior's zero:
    # turned far, the CAD path's tangents no longer match the turned path's and lend such an axis
    # a precision it does not have)
    R = np.eye(3)
    A = np.zeros((n, 3, nk))
    M = np.zeros((3 * n, nk))
    for _ in range(6):
        cR = (c - pivot) @ R.T + pivot
        A = np.concatenate([_skew_rows(cR - pivot), np.broadcast_to(np.eye(3), (n, 3, 3)), basis], axis=2)
        A = np.einsum("nij,njk->nik", across, A)
        r = np.einsum("nij,nj->ni", across, x - cR)
        M = (A * np.sqrt(w)[:, None, None]).reshape(3 * n, nk)
        N = M.T @ M / (var * inflation) + np.diag(prior)
        b = M.T @ (r * np.sqrt(w)[:, None]).reshape(-1) / (var * inflation)
        b[:3] -= prior[:3] * rotvec_from_matrix(R)  # the prior holds the whole rotation, not the step
        ev_r, V_r = np.linalg.eigh(np.linalg.inv(N)[:3, :3])
        free = V_r[:, np.sqrt(np.clip(ev_r, 0.0, None)) <= math.radians(WEAK_CHECK_DEG)]
        basis_step = np.zeros((nk, free.shape[1] + nk - 3))
        basis_step[:3, : free.shape[1]] = free
        basis_step[3:, free.shape[1] :] = np.eye(nk - 3)
        step = basis_step @ np.linalg.solve(basis_step.T @ N @ basis_step, basis_step.T @ b)
        coef = step
        R = matrix_from_rotvec(step[:3]) @ R
        left = r - np.einsum("nik,k->ni", A, step)
        resid = np.linalg.norm(left, axis=1)
        cutoff = 4.685 * (1.4826 * np.median(resid) + 1e-4)  # Tukey: far waypoints get no say
        w = np.clip(1.0 - (resid / cutoff) ** 2, 0.0, None) ** 2
        # residual variance per coordinate across the path (two per waypoint)
        var = max(float(np.sum(w * resid**2) / max(np.sum(w) * 2 - nk, 1)), 1e-12)
    distortion = np.einsum("nik,k->ni", basis, coef[6:])
    # residuals correlated along the path (slow hand wander, smooth errors) count as fewer: in the
    # uncertainty only (the fit keeps its balance against the distortion's prior)
    span_s = float(np.ptp(fused.t_demo)) if n > 1 else 0.0
    max_lag = int(math.ceil(HAND_CORRELATION_S * (n - 1) / span_s)) if span_s > 0 else 0
    correlated = max(inflation, correlation_time(left, w, max_lag))
    posterior = np.linalg.inv(M.T @ M / (var * correlated) + np.diag(prior))
    # the rotation an unmodelled smooth error can mimic, about the receiver as it is calibrated
    cov_sys = _systematic_covariance(np.einsum("nij,njk->nik", across, _skew_rows(c @ R.T)), w)
    cov = posterior[:3, :3] + cov_sys
    sigma = float(np.degrees(np.sqrt(np.trace(cov) / 3.0)))
    rv = rotvec_from_matrix(R)
    angle = float(np.degrees(np.linalg.norm(rv)))
    axis = tuple(float(v) for v in (rv / np.linalg.norm(rv) if angle > 0 else np.array([0.0, 0.0, 1.0])))
    if angle > 0:
        u = rv / np.linalg.norm(rv)
        sigma = float(np.degrees(np.sqrt(u @ cov @ u)))
    obs_angle, obs_sigma, obs_chi2, hidden = _observable_part(rv, cov, c)
    # the receiver's offset: x = R (c - p) + p + t = R c + (t + p - R p), with R the rotation about
    # the axes the path shows (about the others the path shows no rotation, so none of its shift of
    # the pivot either; a rotation the data leave free would make the offset any size); it takes up
    # what a wrongly estimated rotation moves the pivot by (R p x δω), and the path's centre for the
    # systematic part
    shown = np.eye(3)
    for h in hidden:
        a = np.asarray(h["axis_in_source"], dtype=float)
        shown = shown - np.outer(a, a)
    Rp = matrix_from_rotvec(shown @ rotvec_from_matrix(R)) @ pivot
    offset = coef[3:6] + pivot - Rp
    J = np.concatenate([-_skew_rows(Rp[None])[0] @ shown, np.eye(3)], axis=1)  # d(offset) / d(ω, t)
    centre = _skew_rows((np.sum(w[:, None] * (c @ R.T), axis=0) / max(float(np.sum(w)), 1e-12))[None])[0]
    cov_offset = J @ posterior[:6, :6] @ J.T + centre @ cov_sys @ centre.T + SYSTEMATIC_ERROR_M**2 * np.eye(3)
    ev_o, V_o = np.linalg.eigh(0.5 * (cov_offset + cov_offset.T))
    offset_chi2 = float(np.sum((V_o.T @ offset) ** 2 / np.clip(ev_o, 1e-30, None)))
    offset_len = float(np.linalg.norm(offset))
    u_o = offset / offset_len if offset_len > 0 else V_o[:, 0]
    offset_sigma = float(np.sqrt(max(u_o @ cov_offset @ u_o, 0.0)))
    return FrameEstimate(
        rotation_deg=angle,
        sigma_deg=sigma,
        axis_in_source=axis,  # type: ignore[arg-type]
        offset_m=offset_len,
        max_distortion_m=float(np.linalg.norm(distortion, axis=1).max()),
        rms_after_m=float(np.sqrt(np.mean(resid**2))),
        n_points=n,
        observable_rotation_deg=obs_angle,
        observable_sigma_deg=obs_sigma,
        detectable_deg=SIGNIFICANCE * obs_sigma,
        not_observable=hidden,
        observable_chi2=obs_chi2,
        rotation_vector_deg=tuple(float(v) for v in np.degrees(rv)),  # type: ignore[arg-type]
        covariance_deg2=tuple(tuple(float(v) for v in row) for row in np.degrees(np.degrees(cov))),  # type: ignore[arg-type]
        offset_sigma_m=offset_sigma,
        offset_chi2=offset_chi2,
    )


def correlation_time(
    residuals: ArrayLike, weights: ArrayLike | None = None, max_lag: int | None = None
) -> float:
    """Integrated autocorrelation time of residuals along the path [waypoints] (module docstring).

    Per component, ``1 + 2 Σ ρ(k)`` over the lags ``k = 1, 2, ...`` up to the first whose
    autocorrelation ``ρ(k)`` is not positive (the initial positive sequence), and at most
    ``max_lag``; the components are
    averaged weighted by their variance. Independent residuals give 1; a residual that wanders
    with a correlation of ``exp(-k / τ)`` gives about ``2 τ``: the fit then has that many times fewer
    independent observations than waypoints.

    Args:
        residuals: the fit's residuals in waypoint (time) order, shape (N, 3) [m].
        weights: the waypoints' robust weights, shape (N,); None: all 1.
        max_lag: the longest lag summed [waypoints]; None: no limit.

    Returns:
        The factor (>= 1) [waypoints per independent observation].
    """
    e = np.asarray(residuals, dtype=float).reshape(len(residuals), -1)
    if weights is not None:
        e = e * np.sqrt(np.asarray(weights, dtype=float))[:, None]
    e = e - e.mean(axis=0)
    n = len(e)
    total, energy = 0.0, 0.0
    for col in e.T:
        power = float(col @ col)
        if n < 3 or power <= 0.0:
            continue
        spectrum = np.fft.rfft(col, 2 * n)  # zero-padded: the circular correlation is the linear one
        rho = np.fft.irfft(spectrum * np.conj(spectrum), 2 * n)[1:n] / power  # lags 1..n-1
        stop = np.flatnonzero(rho <= 0.0)
        k = int(stop[0]) if stop.size else len(rho)
        if max_lag is not None:
            k = min(k, max(int(max_lag), 0))
        total += power * (1.0 + 2.0 * float(rho[:k].sum()))
        energy += power
    return max(1.0, total / energy) if energy > 0.0 else 1.0


def _systematic_covariance(rot_rows: Array, w: Array) -> Array:
    """Covariance [rad²] of the rotation a smooth, unmodelled error of RMS :data:`SYSTEMATIC_ERROR_M` can mimic.

    Args:
        rot_rows: the rotation's columns of the (across-path) design, shape (N, 3, 3).
        w: the waypoints' weights, shape (N,).

    Returns:
        ``SYSTEMATIC_ERROR_M² (Σ wᵢ Aᵢᵀ Aᵢ / Σ wᵢ)⁻¹`` with the rotation's columns centred (an offset
        takes the mean): an error of that RMS shaped exactly like a rotation about an axis moves
        the estimate by it divided by the path's RMS lever about that axis.
    """
    sw = max(float(np.sum(w)), 1e-12)
    mean = np.einsum("n,nij->ij", w, rot_rows) / sw
    centred = rot_rows - mean
    G = np.einsum("n,nij,nik->jk", w, centred, centred) / sw
    return SYSTEMATIC_ERROR_M**2 * np.linalg.pinv(G + 1e-12 * np.eye(3))


def _observable_part(
    rv: Array, cov: Array, c: Array
) -> tuple[float, float, float, tuple[dict[str, Any], ...]]:
    """Split a rotation vector [rad] by the principal axes of its covariance [rad²] (module docstring).

    Args:
        rv: the estimated rotation vector, in {S}.
        cov: its covariance.
        c: the CAD points in {S} (for the path's main direction).

    Returns:
        The observable part's angle [deg], its uncertainty along it [deg], its χ² against its
        covariance (the squared Mahalanobis distance from no rotation, with as many degrees of
        freedom as there are observable axes) and the axes not observable.
    """
    ev, V = np.linalg.eigh(0.5 * (cov + cov.T))
    sig = np.degrees(np.sqrt(np.clip(ev, 0.0, None)))
    seen = ~(((sig > UNOBSERVABLE_RATIO * sig.min()) & (sig > FRAME_STOP_DEG)) | (sig > WEAK_CHECK_DEG))
    coords = V[:, seen].T @ rv
    part = V[:, seen] @ coords
    chi2 = float(np.sum(coords**2 / np.clip(ev[seen], 1e-30, None)))
    obs = float(np.degrees(np.linalg.norm(part)))
    if obs > 0.0:
        u = part / np.linalg.norm(part)
        obs_sigma = float(np.degrees(np.sqrt(max(u @ cov @ u, 0.0))))
    else:
        obs_sigma = float(sig[seen].max()) if seen.any() else float(sig.min())
    centred = c - c.mean(axis=0)
    main_dir = np.linalg.svd(centred, full_matrices=False)[2][0] if len(c) > 1 else np.zeros(3)
    hidden = []
    for k in np.flatnonzero(~seen):
        a = V[:, k] * (1.0 if V[np.argmax(np.abs(V[:, k])), k] > 0 else -1.0)
        along = abs(float(a @ main_dir)) >= math.cos(math.radians(15.0))
        about = "the path direction" if along else f"receiver axis [{a[0]:.2f}, {a[1]:.2f}, {a[2]:.2f}]"
        hidden.append({"axis_in_source": [float(v) for v in a], "sigma_deg": float(sig[k]), "about": about})
    return obs, obs_sigma, chi2, tuple(hidden)


def frame_error_significant(est: FrameEstimate) -> bool:
    """Whether the observable part of the rotation is told from noise (module docstring).

    Its χ² against its covariance must exceed the quantile that :data:`SIGNIFICANCE` standard
    uncertainties cut off one axis (two-sided, 4.55 %), for as many degrees of freedom as the path
    shows axes: 4.0 for one, 6.2 for two, 8.0 for three.
    """
    k = 3 - len(est.not_observable)
    return k > 0 and est.observable_chi2 > _chi2_threshold(k)


def _chi2_threshold(dof: int) -> float:
    """The χ² with ``dof`` degrees of freedom exceeded as rarely as :data:`SIGNIFICANCE` sigmas on one axis."""
    from scipy.special import chdtri, ndtr  # what scipy.stats' norm.sf and chi2.isf call, without its import

    return float(chdtri(dof, 2.0 * float(ndtr(-SIGNIFICANCE))))


def gate_frame(
    quality: DemoQuality,
    demo: Demonstration,
    fused: FusedPath,
    source_in_world: ArrayLike,
    sensor_in_tcp: ArrayLike,
    *,
    accept: bool = False,
) -> DemoQuality:
    """Estimate the frame error and stop (or, with ``accept``, warn) when it is too large.

    Raises:
        InputError: an observable rotation above :data:`FRAME_STOP_DEG` without ``accept``, naming the angle,
            its axis and the option that lets the run go on.
    """
    est = estimate_frame_error(demo, fused, source_in_world, sensor_in_tcp)
    warnings = list(quality.warnings)
    hidden = ", ".join(f"about {h['about']} (± {h['sigma_deg']:.0f} deg)" for h in est.not_observable)
    text = (
        f"the demonstration is rotated by {est.observable_rotation_deg:.1f} ± {est.observable_sigma_deg:.1f} deg"
        + (" about the axes the path shows" if est.not_observable else "")
        + f" (total estimate {est.rotation_deg:.1f} deg about the receiver axis [{est.axis_in_source[0]:.2f}, "
        f"{est.axis_in_source[1]:.2f}, {est.axis_in_source[2]:.2f}]) against the CAD path, offset "
        f"{est.offset_m * 1e3:.0f} mm" + (f"; not observable {hidden}" if hidden else "")
    )
    significant = frame_error_significant(est)
    if est.observable_rotation_deg > FRAME_STOP_DEG and significant and not accept:
        go_on = option("pass --accept-frame-error", "pass accept_frame_error=True to refine.solve")
        raise InputError(
            f"{demo.source or 'demonstration'}: {text}: frames.source_in_world looks wrong (limit "
            f"{FRAME_STOP_DEG:g} deg); check it, or {go_on} to go on with a warning",
            key="frames.source_in_world",
            value=round(float(est.observable_rotation_deg), 3),
            expected=f"a tracker frame within {FRAME_STOP_DEG:g} deg of the demonstration's fit to the CAD path",
            file=str(demo.source) if demo.source else None,
        )
    if est.observable_rotation_deg > FRAME_WARN_DEG and significant:
        warnings.append(f"{text}; frames.source_in_world may be off (warning above {FRAME_WARN_DEG:g} deg)")
    elif est.detectable_deg > WEAK_CHECK_DEG:
        shown = (
            f"no axis of a tracker frame rotation better than ± {est.observable_sigma_deg:.1f} deg"
            if len(est.not_observable) == 3
            else f"a tracker frame rotation only to ± {est.observable_sigma_deg:.1f} deg"
        )
        warnings.append(
            f"the path's shape shows {shown} (estimate {est.observable_rotation_deg:.1f} deg"
            + (f"; not observable {hidden}" if hidden else "")
            + "): frames.source_in_world cannot be checked well"
        )
    elif est.not_observable:  # a fact of the path's shape, stated once in demo_quality, not a warning
        logger.info(
            "tracker frame rotation not observable %s; the other axes to ± %.1f deg",
            hidden,
            est.observable_sigma_deg,
        )
    if est.offset_m > OFFSET_WARN_M and est.offset_chi2 > _chi2_threshold(3):
        warnings.append(
            f"tracker frame offset {est.offset_m * 1e3:.0f} mm, significant (warning above {OFFSET_WARN_M * 1e3:.0f} mm): "
            "frames.source_in_world's position may be off"
        )
    for w in warnings[len(quality.warnings) :]:
        logger.warning("%s", w)
    return replace(quality, frame=est, warnings=tuple(warnings))


__all__ = ["correlation_time", "estimate_frame_error", "frame_error_significant", "gate_frame"]
