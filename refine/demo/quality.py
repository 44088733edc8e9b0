"""The demonstration quality gate: dropouts bridged or refused, and the quality record.

Its figures go to ``result.json`` (``demo_quality``).

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

The tracker-frame check that runs on the aligned path, :mod:`refine.fuse.frame_check`, reports into
the same record (:class:`FrameEstimate`, ``DemoQuality.frame``) and its limits are written beside it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from refine.errors import InputError
from refine.paths import TrackerLog
from refine.types import Array

logger = logging.getLogger(__name__)
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


__all__ = [
    "BadRun",
    "DemoQuality",
    "FrameEstimate",
    "device_error_summary",
    "find_bad_runs",
    "gate_dropouts",
]
