"""The demonstration quality gate: dropouts bridged or refused, a wrong tracker frame caught.

Two checks stand between the tracker log and the optimiser; their figures go to ``result.json``
(``demo_quality``).

**Dropouts** (:func:`gate_dropouts`, on the raw log, before cleaning). A sample is bad when it is

* *zero*: the position is exactly (0, 0, 0) (a Liberty reports zeros for a sensor it lost; a real
  sensor can never sit inside the source);
* *frozen*: it repeats the previous sample exactly, in all six values, in a run of at least
  :data:`FROZEN_MIN_SAMPLES` (the device re-sent an old record; live readings always differ in
  the last digit);
* flagged by the device: its record carries an error indicator (Liberty ASCII header);
* a *jump*: it cannot be reached from the last good sample by a hand: farther than
  :data:`MAX_HAND_SPEED_M_S` times the time between them plus :data:`JUMP_TOLERANCE_M`, or turned
  faster than :data:`MAX_HAND_RATE_DEG_S` plus :data:`JUMP_TOLERANCE_DEG`;

and a *gap* is a time step longer than :data:`GAP_FACTOR` times the median step. A run of bad
samples is **bridged** when the time from the last good sample before it to the first good one
after it is at most :data:`MAX_BRIDGE_S`: positions by linear interpolation in time, orientations by
Slerp. Linear interpolation over ``h`` errs by at most ``h² / 8`` times the second derivative: for
a hand turning ±10 deg at 2 Hz, 0.5 deg at 50 ms, a sixth of the default 3 deg cone. Bad runs at
the very start or end of the log are **trimmed**. Any longer run inside the log **stops** the run
with an error naming its samples, times and kind.

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
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from refine.errors import InputError
from refine.frames import check_transform, invert_transform, matrix_from_rotvec, rotvec_from_matrix
from refine.paths import Demonstration, FusedPath, TrackerLog

logger = logging.getLogger(__name__)
Array = NDArray[np.float64]

MAX_BRIDGE_S = 0.05
"""Longest dropout bridged by interpolation [s] (module docstring for the error it allows)."""
FROZEN_MIN_SAMPLES = 3
"""Shortest run of identical samples that counts as frozen [samples]."""
MAX_HAND_SPEED_M_S = 3.0
"""Fastest a hand-held tool moves [m/s]; faster steps are jumps."""
MAX_HAND_RATE_DEG_S = 1500.0
"""Fastest a hand turns a tool [deg/s]."""
JUMP_TOLERANCE_M = 0.1
"""Position step always accepted on top of the speed bound [m]: single-sample spikes below it
are the outlier filter's business."""
JUMP_TOLERANCE_DEG = 45.0
"""Rotation step always accepted on top of the rate bound [deg]."""
GAP_FACTOR = 2.5
"""A time step longer than this many median steps is a gap."""
FRAME_WARN_DEG = 1.5
"""Tracker frame rotation above which ``demo_quality`` carries a warning [deg]."""
FRAME_STOP_DEG = 2.5
"""Tracker frame rotation above which the run stops without ``--accept-frame-error`` [deg]. On the
bundled simulated cells with their right frames the estimate is 0.1-2.4 deg where the path shows
the frame well; a 5 deg rotation about any world axis is estimated at 4.9-5.4 deg on the glass,
sealing, KR 8 and TIG cells (``benchmarks/frame_check.py``; some larger rotations are refused by
the fusion already: the demonstration does not follow the CAD path)."""
SIGNIFICANCE = 2.0
"""A rotation counts only when it exceeds this many standard uncertainties."""
UNOBSERVABLE_RATIO = 10.0
"""A rotation axis whose uncertainty is this many times that of the best-determined axis (and above
:data:`FRAME_STOP_DEG`) is not observable. On straight seams of 0.05-0.15 m, 0.6 m from the
receiver, the axis along the seam has 240-770 deg, the two across it 2-10 deg."""
WEAK_CHECK_DEG = 5.0
"""``frame.detectable_deg`` above which ``demo_quality`` warns that the frame cannot be checked
well [deg] (twice :data:`FRAME_STOP_DEG`: a rotation of twice the limit could pass unseen); an axis
whose own uncertainty exceeds it is not observable (a rotation of this size about it stays within
one standard uncertainty)."""
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


@dataclass(frozen=True)
class BadRun:
    """A run of bad samples (or a gap) in a tracker log.

    Attributes:
        kind: ``"zero"``, ``"frozen"``, ``"jump"`` or ``"gap"`` (the first kind found in the run).
        first: first bad sample (for a gap: the sample after it).
        last: last bad sample (for a gap: the sample before it; ``last < first``).
        t_start_s: time of the last good sample before the run [s].
        t_end_s: time of the first good sample after it [s].
        action: ``"bridged"``, ``"trimmed"`` or ``"refused"``.
    """

    kind: str
    first: int
    last: int
    t_start_s: float
    t_end_s: float
    action: str

    @property
    def duration_s(self) -> float:
        """Time spanned by the bridge (good sample to good sample) [s]."""
        return self.t_end_s - self.t_start_s

    def describe(self) -> str:
        """One line for messages."""
        n = max(self.last - self.first + 1, 0)
        what = (
            f"{n} {self.kind} sample(s) {self.first}..{self.last}" if n else f"a gap after sample {self.last}"
        )
        return f"{what}, t = {self.t_start_s:.3f}..{self.t_end_s:.3f} s ({self.duration_s * 1e3:.0f} ms)"


@dataclass(frozen=True)
class FrameEstimate:
    """The tracker frame error estimated from the aligned demonstration.

    Attributes:
        rotation_deg: angle of the rigid rotation between demonstration and CAD path [deg].
        sigma_deg: its standard uncertainty [deg] (large where the path's shape cannot show a
            rotation, e.g. a short straight seam).
        axis_in_source: its unit axis in the receiver frame {S}.
        offset_m: length of the rigid offset [m].
        max_distortion_m: largest distance-dependent distortion fitted along the path [m].
        rms_after_m: RMS of what the model leaves unexplained [m].
        n_points: waypoints used.
        observable_rotation_deg: the part of the rotation about the axes the path shows (its
            projection off the axes in ``not_observable``) [deg]: what the check judges.
        observable_sigma_deg: its standard uncertainty [deg] (along it; without observable
            part, the largest uncertainty of an observable axis).
        detectable_deg: the least observable rotation the check tells from noise,
            :data:`SIGNIFICANCE` times ``observable_sigma_deg`` [deg].
        not_observable: axes the path cannot show a rotation about, each ``axis_in_source``
            (unit), ``sigma_deg`` and ``about`` (``"the path direction"`` when within 15 deg of
            the path's main direction, otherwise ``"receiver axis [x, y, z]"``).
        observable_chi2: the observable part's χ² against its covariance (squared Mahalanobis
            distance from no rotation), what :func:`frame_error_significant` tests.
        rotation_vector_deg: the whole estimate as a rotation vector in {S} [deg].
        covariance_deg2: its covariance, 3 x 3 in {S} [deg²].
        offset_sigma_m: the offset's standard uncertainty along it [m] (large where the rotation
            is weakly determined: the offset takes up what it moves the path's centre by).
        offset_chi2: the offset's χ² against its covariance (3 degrees of freedom).
    """

    rotation_deg: float
    sigma_deg: float
    axis_in_source: tuple[float, float, float]
    offset_m: float
    max_distortion_m: float
    rms_after_m: float
    n_points: int
    observable_rotation_deg: float = 0.0
    observable_sigma_deg: float = 0.0
    detectable_deg: float = 0.0
    not_observable: tuple[dict[str, Any], ...] = ()
    observable_chi2: float = 0.0
    rotation_vector_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    covariance_deg2: tuple[tuple[float, float, float], ...] = ()
    offset_sigma_m: float = 0.0
    offset_chi2: float = 0.0


@dataclass(frozen=True)
class DemoQuality:
    """The gate's figures, as written to ``result.json`` (``demo_quality``).

    Attributes:
        n_samples: samples in the raw log.
        sample_step_s: median time step [s].
        bad_runs: dropouts and gaps found, with what was done about each.
        frame: the tracker frame estimate (None before alignment).
        warnings: what the run should be told.
        device_errors: samples the device flagged (:func:`device_error_summary`).
    """

    n_samples: int
    sample_step_s: float
    bad_runs: tuple[BadRun, ...] = ()
    frame: FrameEstimate | None = None
    warnings: tuple[str, ...] = ()
    device_errors: dict[str, Any] | None = None

    def as_json(self) -> dict[str, Any]:
        """Plain values for ``result.json``."""
        return {
            "n_samples": self.n_samples,
            "sample_step_s": self.sample_step_s,
            "max_bridge_s": MAX_BRIDGE_S,
            "n_bridged": sum(r.action == "bridged" for r in self.bad_runs),
            "n_trimmed": sum(r.action == "trimmed" for r in self.bad_runs),
            "longest_bridged_s": max(
                (r.duration_s for r in self.bad_runs if r.action == "bridged"), default=0.0
            ),
            "bad_runs": [{**asdict(r), "duration_s": r.duration_s} for r in self.bad_runs],
            "frame": None if self.frame is None else asdict(self.frame),
            "frame_warn_deg": FRAME_WARN_DEG,
            "frame_unobservable_ratio": UNOBSERVABLE_RATIO,
            "frame_weak_check_deg": WEAK_CHECK_DEG,
            "frame_significance_sigmas": SIGNIFICANCE,
            "frame_stop_deg": FRAME_STOP_DEG,
            "warnings": list(self.warnings),
            "device_errors": self.device_errors,
        }


# ---- dropouts -----------------------------------------------------------------------------------


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(first, last) of each run of True."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _bad_samples(log: TrackerLog) -> tuple[NDArray[np.bool_], NDArray[np.int8]]:
    """Mask of bad samples and their kind code (1 zero, 2 frozen, 3 jump, 4 device error)."""
    p, R, t = log.positions, log.rotations, log.t
    m = len(t)
    kind = np.zeros(m, dtype=np.int8)
    kind[np.all(p == 0.0, axis=1)] = 1
    if log.device_error is not None:
        kind[(log.device_error != 0) & (kind == 0)] = 4
    same = np.concatenate([[False], np.all(p[1:] == p[:-1], axis=1) & np.all(R[1:] == R[:-1], axis=(1, 2))])
    for a, b in _runs(same):  # a..b repeat their predecessor; the run holds b - a + 2 samples
        if b - a + 2 >= FROZEN_MIN_SAMPLES:
            kind[a : b + 1] = np.where(kind[a : b + 1] == 0, 2, kind[a : b + 1])
    # jumps: walk from a trusted start, accepting what a hand can reach from the last good sample
    ok = np.flatnonzero(kind == 0)
    if ok.size:
        # start from the sample nearest the median of the first good ones; walk both ways
        head = ok[: min(len(ok), 61)]
        start = int(head[np.argmin(np.linalg.norm(p[head] - np.median(p[head], axis=0), axis=1))])
        _walk(p, R, t, kind, start)
        back = kind[: start + 1][::-1].copy()
        _walk(p[: start + 1][::-1], R[: start + 1][::-1], t[start] - t[: start + 1][::-1], back, 0)
        kind[: start + 1] = back[::-1]
    return kind > 0, kind


def _reachable(p: Array, R: Array, t: Array, g: int, idx: NDArray[np.intp]) -> NDArray[np.bool_]:
    """Whether a hand could move the sensor from sample ``g`` to each sample of ``idx``."""
    dt = t[idx] - t[g]
    near = np.linalg.norm(p[idx] - p[g], axis=1) <= MAX_HAND_SPEED_M_S * dt + JUMP_TOLERANCE_M
    cos = (np.einsum("ij,kij->k", R[g], R[idx]) - 1.0) / 2.0
    slow = np.arccos(np.clip(cos, -1.0, 1.0)) <= math.radians(MAX_HAND_RATE_DEG_S) * dt + math.radians(
        JUMP_TOLERANCE_DEG
    )
    return near & slow


def _walk(p: Array, R: Array, t: Array, kind: NDArray[np.int8], start: int) -> None:
    """Mark samples after ``start`` that no hand can reach from the last good one (kind 3).

    Vectorised: consecutive steps are tested at once; only after a failed step is the next
    reachable sample searched for, in blocks that double in size.
    """
    m = len(t)
    steps_ok = np.ones(m, dtype=bool)
    steps_ok[1:] = _consecutive_ok(p, R, t)
    # a break: where the step-by-step chain of good samples cannot be trusted
    breaks = np.flatnonzero(~steps_ok | (kind != 0) | np.concatenate([[False], kind[:-1] != 0]))
    g, k = start, start + 1
    while k < m:
        if g == k - 1:
            b = breaks[np.searchsorted(breaks, k)] if np.searchsorted(breaks, k) < len(breaks) else m
            if b > k:
                g, k = b - 1, b
                continue
            if kind[k] == 0 and _reachable(p, R, t, g, np.array([k]))[0]:
                g, k = k, k + 1
                continue
        size = 64
        while k < m:
            idx = np.arange(k, min(m, k + size))
            ok = (kind[idx] == 0) & _reachable(p, R, t, g, idx)
            if ok.any():
                j = int(idx[np.argmax(ok)])
                skipped = np.arange(k, j)
                kind[skipped[kind[skipped] == 0]] = 3
                g, k = j, j + 1
                break
            kind[idx[kind[idx] == 0]] = 3
            k, size = int(idx[-1]) + 1, size * 2


def _consecutive_ok(p: Array, R: Array, t: Array) -> NDArray[np.bool_]:
    """Whether each sample is reachable from the one before it, shape (M - 1,)."""
    dt = np.diff(t)
    near = np.linalg.norm(np.diff(p, axis=0), axis=1) <= MAX_HAND_SPEED_M_S * dt + JUMP_TOLERANCE_M
    cos = (np.einsum("kij,kij->k", R[:-1], R[1:]) - 1.0) / 2.0
    slow = np.arccos(np.clip(cos, -1.0, 1.0)) <= math.radians(MAX_HAND_RATE_DEG_S) * dt + math.radians(
        JUMP_TOLERANCE_DEG
    )
    return near & slow


def find_bad_runs(log: TrackerLog) -> list[BadRun]:
    """Every run of bad samples and every gap of ``log`` (module docstring), classified."""
    t = log.t
    mask, kind = _bad_samples(log)
    dt = float(np.median(np.diff(t)))
    names = {1: "zero", 2: "frozen", 3: "jump", 4: "device-error"}
    runs = []
    for a, b in _runs(mask):
        if a == 0 or b == len(t) - 1:
            action = "trimmed"
            t0, t1 = t[max(a - 1, 0)], t[min(b + 1, len(t) - 1)]
        else:
            t0, t1 = t[a - 1], t[b + 1]
            action = "bridged" if t1 - t0 <= MAX_BRIDGE_S + 1e-9 else "refused"
        runs.append(BadRun(names[int(kind[a : b + 1].max())], a, b, float(t0), float(t1), action))
    good = np.flatnonzero(~mask)
    if good.size > 1:
        steps = np.diff(t[good])
        for j in np.flatnonzero(steps > GAP_FACTOR * dt):
            k0, k1 = int(good[j]), int(good[j + 1])
            if k1 - k0 > 1:
                continue  # a bad run, reported above
            action = "bridged" if steps[j] <= MAX_BRIDGE_S + 1e-9 else "refused"
            runs.append(BadRun("gap", k1, k0, float(t[k0]), float(t[k1]), action))
    return sorted(runs, key=lambda r: r.t_start_s)


#: The Liberty's real-time error indicators (Polhemus PDI SDK, ``PDItracker.h``, ``ePiDevError``).
DEVICE_ERROR_MEANINGS = {
    **{
        c: f"source failure, axes {axes}"
        for c, axes in zip("abcdefg", ("X", "Y", "XY", "Z", "XZ", "YZ", "XYZ"), strict=True)
    },
    **{
        c: f"source failure, axes {axes}"
        for c, axes in zip("ABCDEFG", ("X", "Y", "XY", "Z", "XZ", "YZ", "XYZ"), strict=True)
    },
    "u": "out of map",
    "I": "built-in test error",
}
MAX_LISTED_RUNS = 50
"""Runs of flagged samples listed per indicator in ``demo_quality.device_errors.samples``."""


def device_error_summary(codes: NDArray[np.int16] | None) -> dict[str, Any]:
    """What the device flagged, for ``demo_quality.device_errors``.

    Args:
        codes: the error indicator per sample (character code, 0 for none), or None.

    Returns:
        ``n_flagged`` (samples), ``by_indicator`` (indicator -> samples), ``samples`` (indicator
        -> ``[first, last]`` runs of flagged samples, the first :data:`MAX_LISTED_RUNS`),
        ``n_runs`` (indicator -> runs) and ``meaning`` (indicator -> what the Liberty means by it,
        "unknown" for an indicator the SDK does not list).
    """
    out: dict[str, Any] = {"n_flagged": 0, "by_indicator": {}, "samples": {}, "n_runs": {}, "meaning": {}}
    if codes is None:
        return out
    flagged = codes[codes != 0]
    out["n_flagged"] = int(flagged.size)
    for c in np.unique(flagged):
        key = chr(int(c))
        runs = _runs(codes == c)
        out["by_indicator"][key] = int(np.count_nonzero(codes == c))
        out["samples"][key] = [[a, b] for a, b in runs[:MAX_LISTED_RUNS]]
        out["n_runs"][key] = len(runs)
        out["meaning"][key] = DEVICE_ERROR_MEANINGS.get(key, "unknown")
    return out


def gate_dropouts(log: TrackerLog) -> tuple[TrackerLog, DemoQuality]:
    """Bridge short dropouts, trim bad ends, refuse long dropouts (module docstring).

    Returns:
        The log with bridged samples replaced and bad ends cut, and the gate's figures.

    Raises:
        InputError: a dropout or gap longer than :data:`MAX_BRIDGE_S` inside the log, naming its
            samples, its times and its kind; or fewer than 2 good samples.
    """
    from refine.demo import fill_positions, fill_rotations

    runs = find_bad_runs(log)
    refused = [r for r in runs if r.action == "refused"]
    where = log.source or "tracker log"
    if refused:
        worst = max(refused, key=lambda r: r.duration_s)
        raise InputError(
            f"{where}: the tracker lost the sensor for {worst.describe()}, longer than the "
            f"{MAX_BRIDGE_S * 1e3:.0f} ms that can be bridged"
            + (f" ({len(refused)} such dropouts)" if len(refused) > 1 else "")
            + "; record the demonstration again or cut the log"
        )
    device = device_error_summary(log.device_error)
    mask = np.zeros(len(log.t), dtype=bool)
    for r in runs:
        if r.kind != "gap":
            mask[r.first : r.last + 1] = True
    keep = np.ones(len(log.t), dtype=bool)
    for r in runs:
        if r.action == "trimmed":
            keep[r.first : r.last + 1] = False
    if keep.sum() < 2:
        raise InputError(f"{where}: fewer than 2 good samples (zeros, frozen or impossible jumps)")
    positions = fill_positions(log.t, log.positions, mask)
    rotations = fill_rotations(log.t, log.rotations, mask)
    t = log.t[keep]
    cleaned = replace(
        log, t=t - t[0], positions=positions[keep], rotations=rotations[keep], device_error=None
    )
    if runs:
        logger.info("%s: %s", where, "; ".join(f"{r.action} {r.describe()}" for r in runs))
    quality = DemoQuality(len(log.t), float(np.median(np.diff(log.t))), tuple(runs), device_errors=device)
    return cleaned, quality


# ---- tracker frame ------------------------------------------------------------------------------


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
    prior = np.concatenate([np.full(3, ROTATION_PRIOR_RAD**-2), np.full(3, 1e-3), np.tile(1.0 / np.asarray(PRIOR_ERROR_M) ** 2, n_terms)])
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
        raise InputError(
            f"{demo.source or 'demonstration'}: {text}: frames.source_in_world looks wrong (limit "
            f"{FRAME_STOP_DEG:g} deg); check it, or pass --accept-frame-error to go on with a warning"
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


__all__ = [
    "BadRun",
    "DemoQuality",
    "device_error_summary",
    "FrameEstimate",
    "correlation_time",
    "estimate_frame_error",
    "find_bad_runs",
    "gate_dropouts",
    "frame_error_significant",
    "gate_frame",
]
