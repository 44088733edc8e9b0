"""Behaviour of the simulated tracker demonstration (refine.demo.simulate)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.demo.simulate import (
    SimulatedDemo,
    TrackerModel,
    read_truth_csv,
    simulate_demonstration,
    write_truth_csv,
    z_distortion,
)
from refine.errors import InputError
from refine.frames import (
    invert_transform,
    make_transform,
    matrix_from_quaternion,
    rotation_angle_deg,
    transform_from_xyz_rpy,
)

T_F_S = transform_from_xyz_rpy([0.9, -0.3, 0.45], [0.0, 0.0, 90.0])
T_TCP_E = transform_from_xyz_rpy([-0.03, 0.0, -0.25], [180.0, 0.0, 30.0])
START = np.array([0.95, -0.25, 0.35])  # the sensor starts about 0.2 m from the receiver
DIRECTION = np.array([0.6, 0.8, 0.0])
LENGTH = 1.6  # far end about 1.8 m from the receiver, beyond range_m
R_DOWN = Rotation.from_euler("xyz", [180.0, 15.0, 40.0], degrees=True).as_matrix()


def straight_line(n: int = 401, speed: float = 0.1):
    s = np.linspace(0.0, LENGTH, n)
    positions = START + s[:, None] * DIRECTION
    rotations = np.repeat(R_DOWN[None], n, axis=0)
    return s, positions, rotations, np.full(n, speed)


def simulate(model: TrackerModel | None = None, **kw) -> SimulatedDemo:
    s, p, R, v = straight_line(**kw)
    return simulate_demonstration(s, p, R, v, T_F_S, T_TCP_E, model)


@pytest.fixture(scope="module")
def default_demo() -> SimulatedDemo:
    return simulate(TrackerModel(seed=7))


# ---- without errors the log is the kinematics --------------------------------------------------


def test_error_free_log_reproduces_the_true_sensor_poses_exactly():
    model = TrackerModel().without_errors()
    demo = simulate(model)
    k = np.arange(len(demo.log.t))
    tau = np.clip(k / 240.0 - 2.0, 0.0, None)
    p_tcp = START + (0.1 * tau)[:, None] * DIRECTION
    expected = invert_transform(T_F_S) @ make_transform(R_DOWN, p_tcp) @ T_TCP_E
    np.testing.assert_allclose(demo.log.positions, expected[:, :3, 3], atol=1e-12)
    np.testing.assert_allclose(demo.log.rotations, expected[:, :3, :3], atol=1e-12)
    np.testing.assert_allclose(demo.sensor_in_source, expected, atol=1e-12)
    assert demo.outlier_indices == ()


def test_orientation_is_interpolated_by_slerp_in_arc_length():
    s = np.linspace(0.0, 0.5, 6)
    positions = START + s[:, None] * DIRECTION
    angles = np.radians(20.0) * np.arange(6)  # 20 deg about the world z per 0.1 m
    rotations = Rotation.from_rotvec(angles[:, None] * [0.0, 0.0, 1.0]).as_matrix() @ R_DOWN
    model = TrackerModel(pause_s=0.0).without_errors()
    demo = simulate_demonstration(s, positions, rotations, np.full(6, 0.05), T_F_S, T_TCP_E, model)
    R_F_E = T_F_S[:3, :3] @ demo.log.rotations
    R_F_TCP = R_F_E @ T_TCP_E[:3, :3].T
    rotvec = np.radians(200.0) * demo.sample_s[:, None] * [0.0, 0.0, 1.0]
    expected = Rotation.from_rotvec(rotvec).as_matrix() @ R_DOWN
    assert np.max(rotation_angle_deg(R_F_TCP, expected)) < 1e-9


def test_time_law_integrates_the_inverse_speed():
    s = np.linspace(0.0, 1.0, 1001)
    speed = 0.06 + 0.06 * s  # t(s) = ln(1 + s) / 0.06
    positions = START + s[:, None] * DIRECTION
    rotations = np.repeat(R_DOWN[None], len(s), axis=0)
    model = TrackerModel(pause_s=0.5).without_errors()
    demo = simulate_demonstration(s, positions, rotations, speed, T_F_S, T_TCP_E, model)
    motion_t = demo.log.t[demo.motion_start :] - 0.5
    np.testing.assert_allclose(demo.sample_s[demo.motion_start :], np.expm1(0.06 * motion_t), atol=2e-6)
    assert motion_t[-1] == pytest.approx(np.log(2.0) / 0.06, abs=1.0 / 240.0)


# ---- with the default model the statistics match it --------------------------------------------


def test_sample_rate_and_pause_duration(default_demo: SimulatedDemo):
    t = default_demo.log.t
    np.testing.assert_allclose(np.diff(t), 1.0 / 240.0, rtol=1e-9)
    assert t[0] == 0.0
    assert default_demo.motion_start == 480  # 2.0 s at 240 Hz
    pause = default_demo.sensor_in_source[:480]
    np.testing.assert_allclose(pause, np.broadcast_to(pause[0], pause.shape), atol=1e-15)
    assert not np.allclose(default_demo.sensor_in_source[481], pause[0])
    assert default_demo.duration_s == pytest.approx(2.0 + LENGTH / 0.1, abs=1.0 / 240.0)


def test_position_noise_is_one_millimetre_per_axis(default_demo: SimulatedDemo):
    error = default_demo.log.positions - default_demo.sensor_in_source[:, :3, 3]
    d = np.diff(error, axis=0)
    robust_sigma = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / np.sqrt(2.0)
    np.testing.assert_allclose(robust_sigma, 0.001, rtol=0.08)


def test_z_error_grows_with_distance_to_sixty_millimetres(default_demo: SimulatedDemo):
    true_p = default_demo.sensor_in_source[:, :3, 3]
    dz = default_demo.log.positions[:, 2] - true_p[:, 2]
    dist = np.linalg.norm(true_p, axis=1)
    far = dist > 1.2
    near = dist < 0.4
    assert far.sum() > 500 and near.sum() > 500
    assert np.median(dz[far]) == pytest.approx(0.060, abs=0.002)
    assert abs(np.median(dz[near])) < 0.006
    mid = (dist > 0.55) & (dist < 0.65)
    expected_mid = z_distortion(true_p[mid], default_demo.model)
    assert np.median(dz[mid] - expected_mid) == pytest.approx(0.0, abs=0.001)


def test_horizontal_error_stays_within_its_bound(default_demo: SimulatedDemo):
    error = default_demo.log.positions - default_demo.sensor_in_source[:, :3, 3]
    window = 49  # a running mean over 0.2 s removes the noise and tremor
    kernel = np.ones(window) / window
    smooth = np.stack([np.convolve(error[:, j], kernel, mode="valid") for j in range(2)], axis=1)
    assert np.max(np.linalg.norm(smooth, axis=1)) < 0.003 + 0.0005
    assert np.max(np.linalg.norm(smooth, axis=1)) > 0.0005


def test_orientation_noise_is_0_15_degrees_rms(default_demo: SimulatedDemo):
    R_err = default_demo.log.rotations @ np.swapaxes(default_demo.sensor_in_source[:, :3, :3], 1, 2)
    step = Rotation.from_matrix(R_err[1:] @ np.swapaxes(R_err[:-1], 1, 2)).as_rotvec()
    robust_sigma = 1.4826 * np.median(np.abs(step - np.median(step, axis=0)), axis=0) / np.sqrt(2.0)
    rms_angle_deg = np.degrees(np.sqrt(np.sum(robust_sigma**2)))
    assert rms_angle_deg == pytest.approx(0.15, rel=0.1)


def test_orientation_distortion_is_slow_and_bounded(default_demo: SimulatedDemo):
    R_err = default_demo.log.rotations @ np.swapaxes(default_demo.sensor_in_source[:, :3, :3], 1, 2)
    rotvec = Rotation.from_matrix(R_err).as_rotvec()
    rotvec = np.delete(rotvec, [i + k for i in default_demo.outlier_indices for k in (-1, 0, 1)], 0)
    window = 49
    kernel = np.ones(window) / window
    smooth = np.stack([np.convolve(rotvec[:, j], kernel, mode="valid") for j in range(3)], axis=1)
    angle = np.degrees(np.linalg.norm(smooth, axis=1))
    assert angle.max() < 1.0 + 0.1
    assert angle.max() > 0.1


def test_outliers_are_single_sample_spikes_of_the_modelled_size(default_demo: SimulatedDemo):
    idx = np.array(default_demo.outlier_indices)
    assert len(idx) == 4
    assert np.all(idx >= default_demo.motion_start)
    assert np.all(np.diff(idx) >= 10)
    error = default_demo.log.positions - default_demo.sensor_in_source[:, :3, 3]
    spike = np.linalg.norm(error[idx] - 0.5 * (error[idx - 1] + error[idx + 1]), axis=1)
    assert np.all(spike > 0.015) and np.all(spike < 0.085)
    others = np.setdiff1d(np.arange(len(error)), idx)
    jumps = np.linalg.norm(np.diff(error[others], axis=0), axis=1)
    assert np.all(jumps < 0.010)
    angle = rotation_angle_deg(default_demo.log.rotations, default_demo.sensor_in_source[:, :3, :3])
    assert np.all(angle[idx] > 3.5) and np.all(angle[idx] < 22.0)
    assert np.all(angle[others] < 2.5)


def test_truth_is_the_given_tool_orientation_and_speed(default_demo: SimulatedDemo):
    s, _, R, v = straight_line()
    np.testing.assert_array_equal(default_demo.s, s)
    np.testing.assert_allclose(matrix_from_quaternion(default_demo.quaternions), R, atol=1e-12)
    np.testing.assert_array_equal(default_demo.speed, v)


# ---- determinism, validation, files -------------------------------------------------------------


def test_same_seed_gives_the_same_log_and_another_seed_another():
    a, b = simulate(TrackerModel(seed=3)), simulate(TrackerModel(seed=3))
    c = simulate(TrackerModel(seed=4))
    np.testing.assert_array_equal(a.log.positions, b.log.positions)
    np.testing.assert_array_equal(a.log.rotations, b.log.rotations)
    assert a.outlier_indices == b.outlier_indices
    assert not np.allclose(a.log.positions, c.log.positions)


@pytest.mark.parametrize(
    "change",
    [
        {"position_noise_m": -0.001},
        {"rate_hz": 0.0},
        {"tremor_band_hz": (12.0, 8.0)},
        {"tremor_band_hz": (8.0, 130.0)},
        {"outlier_position_m": (0.08, 0.02)},
        {"pause_s": float("nan")},
    ],
)
def test_model_rejects_bad_values_naming_the_field(change):
    name = next(iter(change))
    with pytest.raises(InputError, match=name):
        dataclasses.replace(TrackerModel(), **change)


def test_bad_paths_are_rejected():
    s, p, R, v = straight_line()
    with pytest.raises(InputError, match="speed"):
        simulate_demonstration(s, p, R, np.zeros_like(v), T_F_S, T_TCP_E)
    with pytest.raises(InputError, match="strictly increase"):
        simulate_demonstration(s[::-1], p, R, v, T_F_S, T_TCP_E)
    with pytest.raises(InputError, match="positions_world"):
        simulate_demonstration(s, p[:-1], R, v, T_F_S, T_TCP_E)


def test_truth_csv_round_trip(tmp_path, default_demo: SimulatedDemo):
    path = tmp_path / "truth.csv"
    write_truth_csv(path, default_demo.s, default_demo.quaternions, default_demo.speed)
    assert path.read_text().splitlines()[0] == "s,qw,qx,qy,qz,speed"
    truth = read_truth_csv(path)
    np.testing.assert_allclose(truth.s, default_demo.s, atol=1e-9)
    np.testing.assert_allclose(truth.quaternions, default_demo.quaternions, atol=1e-9)
    np.testing.assert_allclose(truth.speed, default_demo.speed, rtol=1e-9)


def test_truth_csv_with_a_wrong_header_is_rejected(tmp_path):
    path = tmp_path / "truth.csv"
    path.write_text("s,qx,qy,qz,qw,speed\n0,1,0,0,0,0.1\n")
    with pytest.raises(InputError, match="header"):
        read_truth_csv(path)
