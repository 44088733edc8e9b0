"""A simulated magnetic-tracker demonstration, for tests, benchmarks and generated problems.

A worker moves the hand tool along a known path at a known speed; the tracker sensor {E} on the
tool is sampled in the receiver frame {S} and corrupted the way a Polhemus Liberty near steel is:

* **tremor**: real motion of the hand, band-limited to 8-12 Hz (the truth is the intended motion,
  so for refine it is an error like the others);
* **wander** (off by default): the hand drifting slowly off the intended path, per axis a
  first-order low-pass filtered white noise (an Ornstein-Uhlenbeck process: a random walk pulled
  back to the path) with RMS ``wander_position_m`` and correlation time ``wander_time_s`` (its
  autocorrelation falls as ``exp(-|Δt| / wander_time_s)``); real motion like the tremor;
* **distortion**: slow, deterministic functions of the sensor position in {S}: a z error growing
  smoothly with the distance from the receiver, a horizontal error field and a rotation error field;
* **noise**: white position and orientation noise on every sample;
* **outliers**: a few single-sample spikes.

The log starts with a pause: the tool is held still at the path start for ``pause_s``.

Everything is drawn from one ``numpy`` generator seeded by :attr:`TrackerModel.seed`, so a given
model and path always give the same log.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation, Slerp

from refine.errors import InputError
from refine.frames import (
    check_rotation,
    check_transform,
    continuous_quaternions,
    invert_transform,
    make_transform,
    matrix_from_rotvec,
    quaternion_from_matrix,
)
from refine.paths import TrackerLog
from refine.types import Array

logger = logging.getLogger(__name__)

#: Wavelength of the slowly varying distortion fields [m] (each wave is scaled by 0.75-1.25).
FIELD_WAVELENGTH_M = 1.5
_TREMOR_COMPONENTS = 3  # sinusoids per tremor axis
_OUTLIER_SEPARATION = 10  # minimum distance between two outlier samples [samples]
_TRUTH_HEADER = "s,qw,qx,qy,qz,speed"


@dataclass(frozen=True)
class TrackerModel:
    """Error model of the tracker and the worker's hand.

    Attributes:
        rate_hz: sample rate [Hz].
        position_noise_m: white position noise, 1 sigma per axis [m].
        z_distortion_max_m: z error (along the receiver z axis) reached at ``range_m`` from the
            receiver [m], signed. It grows as a smoothstep ``3u^2 - 2u^3`` of ``u = d / range_m``:
            zero with zero slope at the receiver, this value with zero slope at ``range_m``, and
            constant beyond.
        range_m: distance from the receiver at which the z error reaches its maximum [m].
        xy_error_max_m: largest magnitude of the horizontal (receiver x, y) error field [m], a
            smooth function of the sensor position with a wavelength of about 1.5 m.
        orientation_noise_deg: white orientation noise, RMS of the rotation angle [deg].
        orientation_distortion_max_deg: largest angle of the position-dependent rotation error
            field [deg], same wavelength as the horizontal field.
        tremor_position_m: hand tremor, RMS per axis [m].
        tremor_orientation_deg: hand tremor, RMS of the rotation angle [deg].
        tremor_band_hz: frequency band of the tremor (low, high) [Hz].
        n_outliers: number of single-sample spikes, all during the motion.
        outlier_position_m: range of the spike position magnitude (low, high) [m].
        outlier_orientation_deg: range of the spike rotation angle (low, high) [deg].
        pause_s: time the tool is held still at the path start before moving [s].
        seed: seed of the random generator.
        wander_position_m: slow hand wander off the path, RMS per axis [m] (0: none).
        wander_time_s: correlation time of the wander [s] (> 0).
    """

    rate_hz: float = 240.0
    position_noise_m: float = 0.001
    z_distortion_max_m: float = 0.060
    range_m: float = 1.2
    xy_error_max_m: float = 0.003
    orientation_noise_deg: float = 0.15
    orientation_distortion_max_deg: float = 1.0
    tremor_position_m: float = 0.0003
    tremor_orientation_deg: float = 0.2
    tremor_band_hz: tuple[float, float] = (8.0, 12.0)
    n_outliers: int = 4
    outlier_position_m: tuple[float, float] = (0.020, 0.080)
    outlier_orientation_deg: tuple[float, float] = (5.0, 20.0)
    pause_s: float = 2.0
    seed: int = 0
    wander_position_m: float = 0.0
    wander_time_s: float = 0.3

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            values = value if isinstance(value, tuple) else (value,)
            if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
                raise InputError(f"TrackerModel.{f.name} must be finite numbers, got {value!r}")
            if f.name != "z_distortion_max_m" and min(values) < 0:
                raise InputError(f"TrackerModel.{f.name} must be >= 0, got {value!r}")
        if self.rate_hz <= 0 or self.range_m <= 0 or self.wander_time_s <= 0:
            raise InputError(
                f"TrackerModel.rate_hz, range_m and wander_time_s must be > 0, got {self.rate_hz}, "
                f"{self.range_m}, {self.wander_time_s}"
            )
        for name in ("tremor_band_hz", "outlier_position_m", "outlier_orientation_deg"):
            lo_hi = getattr(self, name)
            if len(lo_hi) != 2 or lo_hi[0] > lo_hi[1]:
                raise InputError(f"TrackerModel.{name} must be (low, high), got {lo_hi!r}")
        if self.tremor_band_hz[1] >= self.rate_hz / 2:
            raise InputError(
                f"TrackerModel.tremor_band_hz {self.tremor_band_hz} must lie below the Nyquist "
                f"frequency {self.rate_hz / 2} Hz"
            )
        if not isinstance(self.n_outliers, int) or not isinstance(self.seed, int):
            raise InputError(
                f"TrackerModel.n_outliers and seed must be integers, got {self.n_outliers!r}, {self.seed!r}"
            )

    def without_errors(self) -> TrackerModel:
        """The same model (rate, pause, seed) with every error source switched off."""
        return replace(
            self,
            position_noise_m=0.0,
            z_distortion_max_m=0.0,
            xy_error_max_m=0.0,
            orientation_noise_deg=0.0,
            orientation_distortion_max_deg=0.0,
            tremor_position_m=0.0,
            tremor_orientation_deg=0.0,
            n_outliers=0,
            wander_position_m=0.0,
        )


@dataclass(frozen=True)
class SimulatedDemo:
    """A simulated tracker log with the truth it was made from.

    Attributes:
        log: the corrupted log, sensor {E} in the receiver frame {S}, M samples.
        s: arc length of the given path points [m], shape (N,).
        quaternions: true tool (TCP) orientation in {F} at ``s``, (qw, qx, qy, qz), shape (N, 4),
            signs made continuous.
        speed: true TCP speed at ``s`` [m/s], shape (N,).
        sample_s: arc length of the intended TCP position at each sample [m], shape (M,).
        sensor_in_source: intended (error-free) sensor poses T_S_E per sample, shape (M, 4, 4).
        motion_start: index of the first sample of the motion (the pause ends before it).
        outlier_indices: samples carrying a spike, increasing.
        model: the error model used.
    """

    log: TrackerLog
    s: Array
    quaternions: Array
    speed: Array
    sample_s: Array
    sensor_in_source: Array
    motion_start: int
    outlier_indices: tuple[int, ...]
    model: TrackerModel

    @property
    def duration_s(self) -> float:
        """Time of the last sample [s]."""
        return float(self.log.t[-1])

    def summary(self, positions: Array, drag_deg: Array, speed: Array) -> list[str]:
        """Lines describing the demonstrated path and the log, as the problem generators print them.

        ``positions`` (N, 3) [m] in the world, ``drag_deg`` (N,) the drag angle [deg] and ``speed``
        (N,) the TCP speed [m/s] the demonstration was made from.
        """
        lo, hi = positions.min(axis=0), positions.max(axis=0)
        sensor = self.sensor_in_source[:, :3, 3]
        dist = np.linalg.norm(sensor, axis=1)
        dz = self.log.positions[:, 2] - sensor[:, 2]
        return [
            f"bead in world: x {lo[0]:.3f}..{hi[0]:.3f}, y {lo[1]:.3f}..{hi[1]:.3f}, z {lo[2]:.3f}..{hi[2]:.3f} m",
            f"drag angle {drag_deg.min():.1f}..{drag_deg.max():.1f} deg, speed "
            f"{speed.min() * 1000:.1f}..{speed.max() * 1000:.1f} mm/s",
            f"demo: {len(self.log.t)} samples at {self.model.rate_hz:g} Hz, {self.duration_s:.2f} s "
            f"({self.model.pause_s:g} s pause), outliers at samples {list(self.outlier_indices)}",
            f"sensor to receiver {dist.min():.2f}..{dist.max():.2f} m; z error (median) near "
            f"{np.median(dz[dist < dist.min() + 0.1]) * 1000:.1f} mm, far "
            f"{np.median(dz[dist > dist.max() - 0.1]) * 1000:.1f} mm",
        ]


# ---- error fields -------------------------------------------------------------------------------


def z_distortion(positions: ArrayLike, model: TrackerModel) -> Array:
    """Z error [m] of the tracker at sensor positions in {S} [m], shape (..., 3) -> (...)."""
    d = np.linalg.norm(np.asarray(positions, dtype=float), axis=-1)
    u = np.clip(d / model.range_m, 0.0, 1.0)
    return model.z_distortion_max_m * u * u * (3.0 - 2.0 * u)


class _WaveField:
    """A smooth field R^3 -> [-1, 1]^k: per component 0.6 sin(k1.p + a) + 0.4 sin(k2.p + b)."""

    def __init__(self, rng: np.random.Generator, n_components: int) -> None:
        directions = rng.normal(size=(n_components, 2, 3))
        directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
        wavelengths = FIELD_WAVELENGTH_M * rng.uniform(0.75, 1.25, size=(n_components, 2, 1))
        self.wave_vectors = 2.0 * np.pi * directions / wavelengths
        self.phases = rng.uniform(0.0, 2.0 * np.pi, size=(n_components, 2))
        self.weights = np.array([0.6, 0.4])

    def __call__(self, positions: Array) -> Array:
        arg = np.einsum("cwj,...j->...cw", self.wave_vectors, positions) + self.phases
        return np.sin(arg) @ self.weights


def _tremor(rng: np.random.Generator, t: Array, band: tuple[float, float], rms: float) -> Array:
    """Three axes of band-limited tremor with the given RMS per axis, shape (M, 3)."""
    freqs = rng.uniform(band[0], band[1], size=(3, _TREMOR_COMPONENTS))
    phases = rng.uniform(0.0, 2.0 * np.pi, size=(3, _TREMOR_COMPONENTS))
    amplitude = rms * math.sqrt(2.0 / _TREMOR_COMPONENTS)
    return amplitude * np.sin(2.0 * np.pi * t[:, None, None] * freqs + phases).sum(axis=-1)


def _wander(rng: np.random.Generator, t: Array, rms: float, time_s: float) -> Array:
    """Three axes of slow wander, shape (M, 3): a stationary AR(1) process per axis.

    ``x[k] = a x[k-1] + sqrt(1 - a²) rms e[k]`` with ``a = exp(-Δt / time_s)`` and ``e`` standard
    normal (the exact sampling of an Ornstein-Uhlenbeck process at the step ``Δt``), started
    from its stationary distribution: RMS ``rms``, autocorrelation ``exp(-|lag| / time_s)``.
    """
    from scipy.signal import lfilter

    e = rng.normal(size=(len(t), 3))
    if rms == 0.0 or len(t) == 0:
        return np.zeros((len(t), 3))
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    a = math.exp(-dt / time_s)
    drive = math.sqrt(1.0 - a * a) * rms * e
    drive[0] = rms * e[0]
    return lfilter([1.0], [1.0, -a], drive, axis=0)


def _random_directions(rng: np.random.Generator, n: int) -> Array:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _pick_outliers(rng: np.random.Generator, first: int, stop: int, n: int) -> tuple[int, ...]:
    chosen: list[int] = []
    for k in rng.permutation(np.arange(first, max(first, stop))):
        if all(abs(int(k) - c) >= _OUTLIER_SEPARATION for c in chosen):
            chosen.append(int(k))
            if len(chosen) == n:
                return tuple(sorted(chosen))
    raise InputError(f"the motion has too few samples to place {n} separated outliers")


# ---- the simulation -----------------------------------------------------------------------------


def corrupt_sensor_poses(
    t: ArrayLike, sensor_in_source: ArrayLike, model: TrackerModel, first_outlier: int = 0
) -> tuple[Array, Array, tuple[int, ...]]:
    """Apply the tracker error model to intended sensor poses, as the tracker would report them.

    Tremor, distortion, noise, outliers and wander are drawn from one generator seeded by
    ``model.seed`` (in that order, wander last so a log without it is the same as before) and
    applied in {S} (the wander, real motion of the hand, is added to the sensor position like the
    tremor).

    Args:
        t: sample times [s], shape (M,).
        sensor_in_source: intended sensor poses T_S_E, shape (M, 4, 4).
        model: the error model.
        first_outlier: index of the first sample that may carry a spike.

    Returns:
        Measured positions [m] (M, 3), measured rotations R_S_E (M, 3, 3) and the indices of the
        samples carrying a spike, increasing.

    Raises:
        InputError: too few samples after ``first_outlier`` to place the spikes.
    """
    t = np.asarray(t, dtype=float)
    T_S_E = np.asarray(sensor_in_source, dtype=float)
    p_true, R_true = T_S_E[:, :3, 3], T_S_E[:, :3, :3]

    # ---- errors, drawn in a fixed order from one generator
    rng = np.random.default_rng(model.seed)
    m = len(t)
    rms_axis = np.radians(model.tremor_orientation_deg) / math.sqrt(3.0)
    tremor_p = _tremor(rng, t, model.tremor_band_hz, model.tremor_position_m)
    tremor_r = _tremor(rng, t, model.tremor_band_hz, rms_axis)
    xy_field, rot_field = _WaveField(rng, 2), _WaveField(rng, 3)
    noise_p = rng.normal(scale=model.position_noise_m, size=(m, 3))
    noise_r = rng.normal(scale=np.radians(model.orientation_noise_deg) / math.sqrt(3.0), size=(m, 3))
    outliers: tuple[int, ...] = ()
    if model.n_outliers > 0:
        outliers = _pick_outliers(rng, first_outlier, m - 5, model.n_outliers)
    idx = np.array(outliers, dtype=int)
    spike_p = _random_directions(rng, len(idx)) * rng.uniform(*model.outlier_position_m, size=(len(idx), 1))
    spike_r = _random_directions(rng, len(idx)) * np.radians(
        rng.uniform(*model.outlier_orientation_deg, size=(len(idx), 1))
    )
    wander_p = (
        _wander(rng, t, model.wander_position_m, model.wander_time_s)
        if model.wander_position_m > 0.0
        else np.zeros((m, 3))
    )

    # ---- apply them in {S}
    p = p_true + tremor_p + wander_p
    p[:, 2] += z_distortion(p_true, model)
    p[:, :2] += (model.xy_error_max_m / math.sqrt(2.0)) * xy_field(p_true)
    p += noise_p
    p[idx] += spike_p
    rot_dist = (np.radians(model.orientation_distortion_max_deg) / math.sqrt(3.0)) * rot_field(p_true)
    R = matrix_from_rotvec(noise_r) @ matrix_from_rotvec(rot_dist) @ matrix_from_rotvec(tremor_r)
    R = R @ R_true
    R[idx] = matrix_from_rotvec(spike_r) @ R[idx]
    return p, R, outliers


def _check_path(s: Array, positions: Array, rotations: Array, speed: Array) -> None:
    n = len(s)
    if s.shape != (n,) or n < 2:
        raise InputError(f"s: expected shape (N,) with N >= 2, got {s.shape}")
    for name, arr, tail in (("positions_world", positions, (3,)), ("speed", speed, ())):
        if arr.shape != (n, *tail):
            raise InputError(f"{name}: expected shape {(n, *tail)}, got {arr.shape}")
    if rotations.shape != (n, 3, 3):
        raise InputError(f"tool_rotations_world: expected shape {(n, 3, 3)}, got {rotations.shape}")
    if not all(np.all(np.isfinite(a)) for a in (s, positions, speed)):
        raise InputError("s, positions_world and speed must be finite")
    if np.any(np.diff(s) <= 0.0):
        raise InputError("s: arc length must strictly increase")
    if np.any(speed <= 0.0):
        raise InputError(f"speed: every value must be > 0 m/s, smallest is {speed.min()}")


def simulate_demonstration(
    s: ArrayLike,
    positions_world: ArrayLike,
    tool_rotations_world: ArrayLike,
    speed: ArrayLike,
    source_in_world: ArrayLike,
    sensor_in_tcp: ArrayLike,
    model: TrackerModel | None = None,
    station: int = 1,
) -> SimulatedDemo:
    """Simulate the tracker log of a worker moving the tool along a path.

    The TCP follows the path at the given speed: the time law ``t(s) = integral of ds / speed``
    is sampled at ``model.rate_hz``; positions are interpolated linearly in arc length and
    orientations by Slerp. The log starts with ``model.pause_s`` of the tool held at the path
    start. The intended sensor pose ``T_S_E = inv(T_F_S) @ T_F_TCP @ T_TCP_E`` is then corrupted by
    tremor, distortion, noise and outliers (in that order, all in {S}).

    Args:
        s: arc length of the path points [m], shape (N,), strictly increasing.
        positions_world: TCP positions in {F} [m], shape (N, 3).
        tool_rotations_world: tool orientations R_F_TCP, shape (N, 3, 3).
        speed: TCP speed at each point [m/s], shape (N,), > 0.
        source_in_world: T_F_S, the tracker receiver in {F}, (4, 4).
        sensor_in_tcp: T_TCP_E, the sensor on the hand tool, (4, 4).
        model: the error model; ``TrackerModel()`` when None.
        station: station number written into the log.

    Returns:
        The log and the truth (orientations and speed at ``s``).

    Raises:
        InputError: shapes, non-increasing ``s``, non-positive speed, invalid transforms.
    """
    model = TrackerModel() if model is None else model
    s = np.asarray(s, dtype=float)
    positions = np.asarray(positions_world, dtype=float)
    rotations = np.asarray(tool_rotations_world, dtype=float)
    speed = np.asarray(speed, dtype=float)
    _check_path(s, positions, rotations, speed)
    check_rotation(rotations, "tool_rotations_world")
    T_F_S = check_transform(source_in_world, "source_in_world")
    T_TCP_E = check_transform(sensor_in_tcp, "sensor_in_tcp")

    # ---- time law and samples
    inv_speed = 1.0 / speed
    t_of_s = np.concatenate([[0.0], np.cumsum(0.5 * (inv_speed[1:] + inv_speed[:-1]) * np.diff(s))])
    n_pause = int(round(model.pause_s * model.rate_hz))
    n_motion = int(math.floor(t_of_s[-1] * model.rate_hz + 1e-9)) + 1
    t = np.arange(n_pause + n_motion) / model.rate_hz
    tau = np.clip(t - n_pause / model.rate_hz, 0.0, None)
    sample_s = np.interp(tau, t_of_s, s)

    # ---- intended poses
    p_F_TCP = np.stack([np.interp(sample_s, s, positions[:, j]) for j in range(3)], axis=1)
    R_F_TCP = Slerp(s, Rotation.from_matrix(rotations))(sample_s).as_matrix()
    T_S_E = invert_transform(T_F_S) @ make_transform(R_F_TCP, p_F_TCP) @ T_TCP_E

    p, R, outliers = corrupt_sensor_poses(t, T_S_E, model, first_outlier=n_pause + 5)
    m = len(t)

    log = TrackerLog(t=t, positions=p, rotations=R, station=station, source=f"simulated (seed {model.seed})")
    logger.info(
        "simulated %d samples (%.1f s pause, %.1f s motion) with %d outliers",
        m,
        n_pause / model.rate_hz,
        t_of_s[-1],
        len(outliers),
    )
    return SimulatedDemo(
        log=log,
        s=s.copy(),
        quaternions=continuous_quaternions(quaternion_from_matrix(rotations)),
        speed=speed.copy(),
        sample_s=sample_s,
        sensor_in_source=T_S_E,
        motion_start=n_pause,
        outlier_indices=outliers,
        model=model,
    )


# ---- dropouts ------------------------------------------------------------------------------------

DROPOUT_KINDS = ("zero", "frozen", "flip", "gap")


def inject_dropout(log: TrackerLog, first: int, count: int, kind: str = "zero") -> TrackerLog:
    """A copy of ``log`` with a dropout of ``count`` samples from sample ``first``.

    Kinds: ``"zero"``: the samples read (0, 0, 0) and no rotation, as a Liberty reports a lost
    sensor; ``"frozen"``: they repeat sample ``first - 1``; ``"flip"``: their positions are
    mirrored through the receiver (the hemisphere ambiguity of a magnetic tracker); ``"gap"``:
    they are missing (times jump).

    Raises:
        InputError: an unknown kind, or a dropout not strictly inside the log.
    """
    if kind not in DROPOUT_KINDS:
        raise InputError(f"dropout kind {kind!r} is not one of {', '.join(DROPOUT_KINDS)}")
    if not (1 <= first and count >= 1 and first + count < len(log.t)):
        raise InputError(f"dropout {first}..{first + count - 1} must lie inside the {len(log.t)} samples")
    t, p, R = log.t.copy(), log.positions.copy(), log.rotations.copy()
    k = slice(first, first + count)
    if kind == "gap":
        keep = np.ones(len(t), dtype=bool)
        keep[k] = False
        return replace(log, t=t[keep], positions=p[keep], rotations=R[keep])
    if kind == "zero":
        p[k], R[k] = 0.0, np.eye(3)
    elif kind == "frozen":
        p[k], R[k] = p[first - 1], R[first - 1]
    else:
        p[k] = -p[k]
    return replace(log, positions=p, rotations=R)


# ---- truth.csv ----------------------------------------------------------------------------------


class Truth(NamedTuple):
    """The contents of a ``truth.csv``.

    Attributes:
        s: arc length along the CAD path [m], shape (N,).
        quaternions: true tool orientation in {F}, (qw, qx, qy, qz), shape (N, 4).
        speed: true TCP speed [m/s], shape (N,).
    """

    s: Array
    quaternions: Array
    speed: Array


def write_truth_csv(path: str | Path, s: ArrayLike, quaternions: ArrayLike, speed: ArrayLike) -> None:
    """Write ``truth.csv`` with the header ``s,qw,qx,qy,qz,speed`` (SI units).

    Args:
        path: file to write.
        s: arc length along the CAD path [m], shape (N,).
        quaternions: true tool orientation in {F}, (qw, qx, qy, qz), shape (N, 4).
        speed: true TCP speed [m/s], shape (N,).
    """
    s = np.asarray(s, dtype=float)
    q = np.asarray(quaternions, dtype=float)
    v = np.asarray(speed, dtype=float)
    if s.ndim != 1 or q.shape != (len(s), 4) or v.shape != s.shape:
        raise InputError(
            f"truth: expected s (N,), quaternions (N, 4), speed (N,), got {s.shape}, {q.shape}, {v.shape}"
        )
    rows = np.column_stack([s, q, v])
    np.savetxt(path, rows, delimiter=",", header=_TRUTH_HEADER, comments="", fmt="%.10g")


def read_truth_csv(path: str | Path) -> Truth:
    """Read a ``truth.csv`` written by :func:`write_truth_csv`.

    Raises:
        InputError: the header is not ``s,qw,qx,qy,qz,speed`` or a row is malformed.
    """
    path = Path(path)
    with path.open(encoding="utf-8") as f:
        header = f.readline().strip().replace(" ", "")
    if header != _TRUTH_HEADER:
        raise InputError(f"{path}: header must be {_TRUTH_HEADER!r}, got {header!r}")
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as e:
        raise InputError(f"{path}: malformed row: {e}") from e
    if data.shape[1] != 6 or len(data) == 0:
        raise InputError(f"{path}: expected rows of 6 values, got shape {data.shape}")
    return Truth(s=data[:, 0], quaternions=data[:, 1:5], speed=data[:, 5])


def perturb_log(log: TrackerLog, model: TrackerModel, seed: int) -> TrackerLog:
    """``log`` with white noise of ``model``'s size added to every sample (a re-recording's noise).

    Positions get ``position_noise_m`` per axis; rotations a random turn whose angle has the RMS
    ``orientation_noise_deg`` (each of the three rotation-vector components ``sigma / sqrt(3)``).
    """
    rng = np.random.default_rng(seed)
    n = len(log.t)
    dp = rng.normal(0.0, model.position_noise_m, (n, 3))
    vec = rng.normal(0.0, math.radians(model.orientation_noise_deg) / math.sqrt(3.0), (n, 3))
    R = matrix_from_rotvec(vec) @ np.asarray(log.rotations)
    return replace(log, positions=np.asarray(log.positions) + dp, rotations=R)
