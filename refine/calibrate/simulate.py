"""Simulated calibration measurements with a known truth, for tests and examples.

The tracker's errors come from the demonstration simulator's model
(:func:`refine.demo.simulate.corrupt_sensor_poses`: distance-dependent z error, horizontal and
rotation error fields, white noise, spikes). The hand's tremor is left out by default
(:func:`calibration_tracker_model`): during a calibration the tip sits in a divot or on a point,
so the hand moves the tool about the tip, which is part of the measured motion. Robot readings get
joint-reading noise and a random positioning error at the TCP (the robot's repeatability).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from refine.demo.simulate import TrackerModel, corrupt_sensor_poses
from refine.errors import InputError
from refine.frames import make_transform
from refine.paths import TrackerLog
from refine.robot.model import Robot
from refine.types import Array


def calibration_tracker_model(**changes: float | int) -> TrackerModel:
    """The tracker model of the calibration figures: 1 mm noise, 60 mm far-field z error.

    The demonstration model's defaults, with no tremor (the tip is held on the point) and no
    horizontal or rotation error fields unless ``changes`` set them; ``changes`` override any
    field of :class:`~refine.demo.simulate.TrackerModel`.
    """
    base = TrackerModel(
        position_noise_m=0.001,
        z_distortion_max_m=0.060,
        xy_error_max_m=0.0,
        orientation_distortion_max_deg=0.0,
        tremor_position_m=0.0,
        tremor_orientation_deg=0.0,
        pause_s=0.0,
    )
    return replace(base, **changes)  # type: ignore[arg-type]


def _log(
    t: Array, T_S_E: Array, model: TrackerModel, station: int, what: str
) -> tuple[TrackerLog, tuple[int, ...]]:
    p, R, outliers = corrupt_sensor_poses(t, T_S_E, model, first_outlier=5)
    log = TrackerLog(
        t=t, positions=p, rotations=R, station=station, source=f"simulated {what} (seed {model.seed})"
    )
    return log, outliers


def _pointing(direction: ArrayLike, tip_in_sensor: Array) -> Rotation:
    """A rotation R_S_E carrying the tip offset's direction onto ``direction`` (in {S})."""
    d = np.asarray(direction, dtype=float)
    rot, _ = Rotation.align_vectors([d / np.linalg.norm(d)], [tip_in_sensor / np.linalg.norm(tip_in_sensor)])
    return rot


# ---- pivot --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SimulatedPivot:
    """A simulated pivot log and its truth.

    Attributes:
        log: the tracker log.
        tip_in_sensor: true tip offset in {E} [m], shape (3,).
        pivot_in_source: true pivot point in {S} [m], shape (3,).
        outlier_indices: samples carrying a spike.
    """

    log: TrackerLog
    tip_in_sensor: Array
    pivot_in_source: Array
    outlier_indices: tuple[int, ...]


def simulate_pivot(
    tip_in_sensor: ArrayLike,
    pivot_in_source: ArrayLike,
    duration_s: float = 10.0,
    swing_deg: float = 25.0,
    model: TrackerModel | None = None,
    station: int = 1,
) -> SimulatedPivot:
    """Simulate a worker swinging the tool about its tip held in a divot.

    The tool starts pointing straight down the receiver's -z axis (the sensor above the tip) and
    swings in a cone: rotations of ``swing_deg`` amplitude about the receiver's x and y axes at
    0.31 Hz and 0.23 Hz, plus a slow spin of half that about the tool axis.

    Args:
        tip_in_sensor: true tip offset in {E} [m], shape (3,).
        pivot_in_source: true pivot in {S} [m], shape (3,).
        duration_s: length of the log [s].
        swing_deg: amplitude of the swing [deg]; 0 holds the tool still.
        model: tracker error model; :func:`calibration_tracker_model` when None.
        station: station number written into the log.
    """
    model = calibration_tracker_model() if model is None else model
    tip = np.asarray(tip_in_sensor, dtype=float)
    pivot = np.asarray(pivot_in_source, dtype=float)
    if tip.shape != (3,) or pivot.shape != (3,) or np.linalg.norm(tip) == 0.0:
        raise InputError("simulate_pivot: tip_in_sensor (non-zero) and pivot_in_source need 3 values [m]")
    t = np.arange(int(round(duration_s * model.rate_hz))) / model.rate_hz
    a = math.radians(swing_deg)
    swing = np.column_stack(
        [
            a * np.sin(2 * np.pi * 0.31 * t),
            a * np.sin(2 * np.pi * 0.23 * t + 1.0),
            0.5 * a * np.sin(2 * np.pi * 0.11 * t + 2.0),
        ]
    )
    down = _pointing([0.0, 0.0, -1.0], tip)
    R = (Rotation.from_rotvec(swing) * down).as_matrix()
    T_S_E = make_transform(R, pivot - R @ tip)
    log, outliers = _log(t, T_S_E, model, station, "pivot")
    return SimulatedPivot(log=log, tip_in_sensor=tip, pivot_in_source=pivot, outlier_indices=outliers)


# ---- touched points -----------------------------------------------------------------------------


@dataclass(frozen=True)
class SimulatedTouches:
    """A simulated log of the tool tip resting on points, and its truth.

    Attributes:
        log: the tracker log.
        touched_world: where the tip really rested, in {F} [m], shape (N, 3) (differs from the
            given points at the wrongly touched ones).
        dwell_ranges: (start, stop) sample indices of each intended dwell.
        outlier_indices: samples carrying a spike.
    """

    log: TrackerLog
    touched_world: Array
    dwell_ranges: tuple[tuple[int, int], ...]
    outlier_indices: tuple[int, ...]


def _min_jerk(u: Array) -> Array:
    return u**3 * (10.0 - 15.0 * u + 6.0 * u * u)


def simulate_touches(
    points_world: ArrayLike,
    source_in_world: ArrayLike,
    tip_in_sensor: ArrayLike,
    wrong: dict[int, ArrayLike] | None = None,
    dwell_s: float = 1.0,
    move_s: float = 1.0,
    tilt_deg: float = 25.0,
    model: TrackerModel | None = None,
    station: int = 1,
    seed: int = 0,
) -> SimulatedTouches:
    """Simulate a worker resting the tool tip on each point in turn.

    The tool comes down onto each point (a minimum-jerk move with a 5 cm lift between points),
    rests for ``dwell_s`` with its axis tilted up to ``tilt_deg`` off the world's vertical, and
    moves on; the log starts and ends with a move from and to 10 cm above the first and last
    points.

    Args:
        points_world: the points in {F} [m], shape (N, 3).
        source_in_world: true T_F_S (4, 4).
        tip_in_sensor: true tip offset in {E} [m], shape (3,).
        wrong: offsets [m] of wrongly touched points by index: the tip rests there instead.
        dwell_s: rest on each point [s].
        move_s: time between points [s].
        tilt_deg: largest tilt of the tool axis from the vertical [deg].
        model: tracker error model; :func:`calibration_tracker_model` when None.
        station: station number written into the log.
        seed: seed of the tool tilts.
    """
    model = calibration_tracker_model() if model is None else model
    P = np.array(points_world, dtype=float)
    for k, offset in (wrong or {}).items():
        P[k] += np.asarray(offset, dtype=float)
    T_F_S = np.asarray(source_in_world, dtype=float)
    tip = np.asarray(tip_in_sensor, dtype=float)
    rng = np.random.default_rng(seed)
    down_world = Rotation.from_matrix(T_F_S[:3, :3]).inv().apply([0.0, 0.0, -1.0])
    base = _pointing(down_world, tip)
    tilts = Rotation.from_rotvec(
        rng.uniform(-1, 1, size=(len(P), 3)) * np.array([1, 1, 0.5]) * math.radians(tilt_deg) / math.sqrt(2)
    )
    orientations = [tilts[k] * base for k in range(len(P))]

    up = np.array([0.0, 0.0, 0.1])
    keys_p = [P[0] + up] + [q for p in P for q in (p, p)] + [P[-1] + up]
    keys_r = [orientations[0]] + [r for r in orientations for _ in (0, 1)] + [orientations[-1]]
    durations = [move_s] + [d for _ in P for d in (dwell_s, move_s)]
    rate = model.rate_hz
    positions, rotations, ranges = [], [], []
    k0 = 0
    for i, dur in enumerate(durations):
        n = max(int(round(dur * rate)), 1)
        u = _min_jerk(np.arange(n) / n)
        a_p, b_p = keys_p[i], keys_p[i + 1]
        lift = 0.05 * np.sin(np.pi * u) if (i % 2 == 0 and 0 < i < len(durations) - 1) else 0.0 * u
        seg = a_p + u[:, None] * (b_p - a_p)
        seg[:, 2] += lift
        positions.append(seg)
        rel = (keys_r[i].inv() * keys_r[i + 1]).as_rotvec()
        rotations.append((keys_r[i] * Rotation.from_rotvec(u[:, None] * rel)).as_matrix())
        if i % 2 == 1:
            ranges.append((k0, k0 + n))
        k0 += n
    tip_world = np.concatenate(positions)
    R_F_E = np.concatenate(rotations)
    t = np.arange(len(tip_world)) / rate
    T_S_F = np.linalg.inv(T_F_S)
    R_S_E = T_S_F[:3, :3] @ R_F_E
    tip_source = tip_world @ T_S_F[:3, :3].T + T_S_F[:3, 3]
    T_S_E = make_transform(R_S_E, tip_source - R_S_E @ tip)
    log, outliers = _log(t, T_S_E, model, station, "touches")
    return SimulatedTouches(log=log, touched_world=P, dwell_ranges=tuple(ranges), outlier_indices=outliers)


# ---- robot readings -----------------------------------------------------------------------------


@dataclass(frozen=True)
class SimulatedReadings:
    """Simulated robot readings and their truth.

    Attributes:
        joints: the joint readings [rad], shape (N, n), with reading noise.
        flange_poses: the true flange poses T_base_flange reached, shape (N, 4, 4).
    """

    joints: Array
    flange_poses: Array


def _reach(robot: Robot, targets: Array, tcp_in_flange: Array, rng: np.random.Generator) -> Array:
    """Joints [rad] (N, n) reaching TCP poses T_base_TCP (N, 4, 4), by damped least-squares IK."""
    from refine.robot.kinematics import TcpKinematics, solve_ik

    kin = TcpKinematics(robot, np.eye(4), tcp_in_flange)
    lo, hi = robot.spec.lower, robot.spec.upper
    mid = 0.5 * (lo + hi)
    out = []
    for T in targets:
        for attempt in range(20):
            q0 = mid if attempt == 0 else rng.uniform(lo, hi)
            q, err = solve_ik(kin, T, q0, lo, hi, max_iterations=300, tol=1e-10)
            if err < 1e-8:
                break
        else:
            raise InputError(f"simulated robot readings: the robot cannot reach the pose at {T[:3, 3]} m")
        out.append(q)
    return np.array(out)


def _readings(
    robot: Robot,
    targets: Array,
    tcp_in_flange: Array,
    repeatability_m: float,
    joint_noise_deg: float,
    seed: int,
) -> SimulatedReadings:
    rng = np.random.default_rng(seed)
    reached = np.array(targets, dtype=float)
    reached[:, :3, 3] += rng.normal(scale=repeatability_m, size=(len(reached), 3))
    q = _reach(robot, reached, tcp_in_flange, rng)
    flange = robot.fk_many(q)
    noisy = q + rng.normal(scale=math.radians(joint_noise_deg), size=q.shape)
    return SimulatedReadings(joints=noisy, flange_poses=flange)


def _tilted_down(n: int, tilt_deg: float, spin_deg: float = 0.0) -> list[Rotation]:
    """``n`` tool orientations: tool z pointing down the base -z, tilted ``tilt_deg`` all round."""
    down = Rotation.from_rotvec([math.pi, 0.0, 0.0])
    out = []
    for k in range(n):
        azimuth = 2.0 * math.pi * k / n
        axis = np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
        spin = Rotation.from_rotvec([0.0, 0.0, math.radians(spin_deg) * (k - (n - 1) / 2)])
        out.append(Rotation.from_rotvec(math.radians(tilt_deg) * axis) * down * spin)
    return out


def simulate_tcp_readings(
    robot: Robot,
    tcp_in_flange: ArrayLike,
    reference_point_in_base: ArrayLike,
    n_points: int = 4,
    tilt_deg: float = 30.0,
    six_point: bool = False,
    axis_move_m: float = 0.1,
    repeatability_m: float = 5e-5,
    joint_noise_deg: float = 0.0,
    seed: int = 0,
) -> SimulatedReadings:
    """Simulate the readings of a four- (or six-) point TCP calibration.

    The TCP is brought to the reference point with the tool tilted ``tilt_deg`` from the vertical
    in ``n_points`` directions all round (and turned 20 deg about its axis between readings);
    with ``six_point`` two more readings keep the last orientation and move the TCP
    ``axis_move_m`` along the true tool +z and +x axes. Every reached pose misses its target by a
    normal error of ``repeatability_m`` per axis; the joint readings get ``joint_noise_deg``.
    """
    T_fl_tcp = np.asarray(tcp_in_flange, dtype=float)
    c = np.asarray(reference_point_in_base, dtype=float)
    targets = [make_transform(r.as_matrix(), c) for r in _tilted_down(n_points, tilt_deg, 20.0)]
    if six_point:
        R4 = targets[-1][:3, :3]
        targets += [
            make_transform(R4, c + axis_move_m * R4[:, 2]),
            make_transform(R4, c + axis_move_m * R4[:, 0]),
        ]
    return _readings(robot, np.array(targets), T_fl_tcp, repeatability_m, joint_noise_deg, seed)


def simulate_workpiece_readings(
    robot: Robot,
    base_in_world: ArrayLike,
    tcp_in_flange: ArrayLike,
    cad_in_world: ArrayLike,
    points_cad: ArrayLike,
    wrong: dict[int, ArrayLike] | None = None,
    tilt_deg: float = 15.0,
    repeatability_m: float = 5e-5,
    joint_noise_deg: float = 0.0,
    seed: int = 0,
) -> SimulatedReadings:
    """Simulate the robot's TCP touched onto reference points of the workpiece.

    Args:
        robot: the robot model.
        base_in_world: true T_F_R (4, 4).
        tcp_in_flange: true T_flange_TCP (4, 4).
        cad_in_world: true T_F_CAD (4, 4).
        points_cad: the points in the CAD frame [m], shape (N, 3).
        wrong: offsets [m] (CAD frame) of wrongly touched points, by index.
        tilt_deg: tilt of the tool from the vertical, all round [deg].
        repeatability_m: positioning error per axis, 1 sigma [m].
        joint_noise_deg: joint-reading noise, 1 sigma [deg].
        seed: seed of the errors.
    """
    P = np.array(points_cad, dtype=float)
    for k, offset in (wrong or {}).items():
        P[k] += np.asarray(offset, dtype=float)
    T_R_F = np.linalg.inv(np.asarray(base_in_world, dtype=float))
    T_R_cad = T_R_F @ np.asarray(cad_in_world, dtype=float)
    in_base = P @ T_R_cad[:3, :3].T + T_R_cad[:3, 3]
    rots = _tilted_down(len(P), tilt_deg)
    targets = np.array([make_transform(r.as_matrix(), p) for r, p in zip(rots, in_base, strict=True)])
    return _readings(
        robot, targets, np.asarray(tcp_in_flange, dtype=float), repeatability_m, joint_noise_deg, seed
    )
