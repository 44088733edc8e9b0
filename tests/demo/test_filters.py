"""Behaviour of the demonstration filters (refine.demo.filters) and clean_demonstration."""

import logging

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.demo import clean_demonstration, fill_rotations
from refine.demo.filters import (
    find_motion_start,
    hampel,
    rotation_outliers,
    smooth_positions,
    smooth_rotations,
    speed_along_track,
)
from refine.errors import InputError
from refine.frames import matrix_from_rotvec, matrix_from_zyx, rotation_angle_deg
from refine.paths import TrackerLog
from refine.problem import DemoSettings

RATE = 240.0


def _noisy_rotations(R_true, noise_deg, seed):
    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, np.radians(noise_deg), size=(len(R_true), 3))
    return matrix_from_rotvec(noise) @ R_true


def _pause_then_move(seed, pause_s=2.0, speed=0.05, ramp_s=0.3, noise_m=1e-3, duration_s=6.0):
    """Positions held still for pause_s, then moving along a line; velocity ramps up smoothly."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s * RATE)) / RATE
    u = np.clip((t - pause_s) / ramp_s, 0.0, 1.0) if ramp_s > 0 else (t >= pause_s) * 1.0
    v = speed * (3 * u**2 - 2 * u**3)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    direction = np.array([0.8, 0.6, 0.0])
    truth = np.array([0.3, -0.2, 0.1]) + s[:, None] * direction
    return t, truth, truth + rng.normal(0.0, noise_m, size=truth.shape)


# ---- Hampel -------------------------------------------------------------------------------------


def test_hampel_replaces_injected_spikes_including_at_the_ends():
    rng = np.random.default_rng(0)
    t = np.arange(2000) / RATE
    clean = np.column_stack([0.2 * np.sin(t), 0.1 * np.cos(0.5 * t)])
    x = clean + rng.normal(0.0, 1e-3, size=clean.shape)
    spikes = np.array([0, 100, 101, 555, 1200, 1999])
    x[spikes, 0] += 0.05 * rng.choice([-1.0, 1.0], size=len(spikes))
    filtered, mask = hampel(x, half_window=7, n_sigmas=3.0, min_deviation=5e-3)
    assert set(np.flatnonzero(mask[:, 0])) == set(spikes)
    assert not mask[:, 1].any()
    assert np.abs(filtered - clean).max() < 5e-3


def test_hampel_on_a_steep_signal_flags_the_spikes_and_not_their_neighbours():
    x = np.arange(1000) * (1.0 / RATE)  # 1 m/s at 240 Hz: 4 mm per sample
    spikes = [200, 500, 501, 502]
    x[spikes] += 0.05
    _, mask = hampel(x, half_window=7, n_sigmas=3.0, min_deviation=1e-3)
    assert list(np.flatnonzero(mask)) == spikes


def test_hampel_leaves_clean_data_untouched():
    t = np.arange(3000) / RATE
    x = 0.3 * np.sin(2 * np.pi * 0.4 * t) + 0.05 * t
    filtered, mask = hampel(x, half_window=7, n_sigmas=3.0, min_deviation=1e-9)
    assert not mask.any()
    assert np.array_equal(filtered, x)


def test_rotation_outliers_finds_orientation_spikes_not_fast_turns():
    t = np.arange(1500) / RATE
    R = matrix_from_zyx(2 * np.pi * 0.5 * t, 0.3 * np.sin(t), 0.2)  # 180 deg/s of yaw
    R = _noisy_rotations(R, 0.05, seed=1)
    assert not rotation_outliers(R, 7, 3.0, min_angle_deg=0.5).any()
    spikes = [3, 400, 401, 1000]
    R[spikes] = matrix_from_rotvec([[0.0, 0.2, 0.0]]) @ R[spikes]
    assert list(np.flatnonzero(rotation_outliers(R, 7, 3.0, min_angle_deg=0.5))) == spikes


def test_fill_rotations_slerps_between_good_neighbours():
    t = np.arange(5) / 10.0
    R = Rotation.from_euler("z", [[0], [10], [99], [30], [40]], degrees=True).as_matrix()
    filled = fill_rotations(t, R, np.array([False, False, True, False, False]))
    assert Rotation.from_matrix(filled[2]).as_euler("zyx", degrees=True)[0] == pytest.approx(20.0)


# ---- smoothing -----------------------------------------------------------------------------------


def test_smooth_positions_reduces_noise_and_keeps_a_straight_line():
    t, truth, noisy = _pause_then_move(seed=2, ramp_s=1.0)
    smoothed = smooth_positions(t, noisy, 0.05)
    err_before = np.linalg.norm(noisy - truth, axis=1).mean()
    err_after = np.linalg.norm(smoothed - truth, axis=1).mean()
    assert err_after < err_before / 4
    line = np.outer(t, [0.1, 0.0, 0.0])
    np.testing.assert_allclose(smooth_positions(t, line, 0.05)[100:-100], line[100:-100], atol=1e-12)


@pytest.mark.parametrize(
    "case",
    ["general", "through_180_deg", "full_yaw_turn"],
)
def test_smooth_rotations_reduces_noise_on_so3(case):
    t = np.arange(int(3 * RATE)) / RATE
    if case == "general":
        R_true = matrix_from_zyx(0.5 * np.sin(t), 0.4 * np.cos(0.7 * t), 0.3 * t)
    elif case == "through_180_deg":  # the rotation angle crosses 180 deg: qw changes sign
        R_true = matrix_from_rotvec(np.outer(np.radians(150 + 20 * t), [1.0, 1.0, 0.0]) / np.sqrt(2))
    else:  # 360 deg of yaw in 3 s with some pitch
        R_true = matrix_from_zyx(2 * np.pi * t / 3.0, 0.2 * np.sin(t), 0.0)
    noisy = _noisy_rotations(R_true, 1.0, seed=3)
    smoothed = smooth_rotations(t, noisy, 0.05)
    inner = slice(60, -60)  # the ends are extended with the edge value
    before = rotation_angle_deg(noisy, R_true)[inner]
    after = rotation_angle_deg(smoothed, R_true)[inner]
    assert after.mean() < before.mean() / 3
    assert after.max() < 0.6
    np.testing.assert_allclose(np.linalg.det(smoothed), 1.0, atol=1e-12)


def test_smoothing_with_zero_time_constant_changes_nothing():
    t = np.arange(10) / RATE
    R = Rotation.random(10, random_state=4).as_matrix()
    np.testing.assert_allclose(smooth_rotations(t, R, 0.0), R)


# ---- speed and motion start ----------------------------------------------------------------------


def test_speed_along_a_straight_line_is_its_speed():
    t = np.arange(100) / RATE
    p = np.outer(t, [0.03, 0.04, 0.0])
    np.testing.assert_allclose(speed_along_track(t, p), 0.05)
    with pytest.raises(InputError, match="strictly increase"):
        speed_along_track(np.zeros(100), p)


@pytest.mark.parametrize(("speed", "ramp_s"), [(0.05, 0.3), (0.1, 0.0), (0.2, 0.1)])
def test_motion_start_found_within_0_1_s_after_a_2_s_pause_with_1_mm_noise(speed, ramp_s):
    t, _, noisy = _pause_then_move(seed=5, speed=speed, ramp_s=ramp_s)
    smoothed = smooth_positions(t, noisy, 0.05)
    assert speed_along_track(t, smoothed)[: int(1.8 * RATE)].max() > 0.01  # noise looks like motion
    k = find_motion_start(t, smoothed, pause_speed_m_s=0.01)
    assert abs(t[k] - 2.0) < 0.1


def test_motion_start_is_zero_for_a_log_that_starts_moving_and_an_error_if_never():
    t = np.arange(200) / RATE
    assert find_motion_start(t, np.outer(t, [0.1, 0, 0]), 0.01) == 0
    with pytest.raises(InputError, match="no motion found"):
        find_motion_start(t, np.zeros((200, 3)), 0.01)


# ---- the whole cleaning --------------------------------------------------------------------------


def test_clean_demonstration_replaces_spikes_smooths_and_finds_the_start(tmp_path, caplog):
    t, truth, noisy = _pause_then_move(seed=6, noise_m=2e-4)
    R_true = matrix_from_zyx(0.2 * np.sin(t), 0.3, 0.1 * t)
    R = _noisy_rotations(R_true, 0.05, seed=7)
    pos_spikes, rot_spikes = [10, 700, 701], [300, 701, 1300]
    noisy[pos_spikes] += [0.03, -0.02, 0.04]
    R[rot_spikes] = matrix_from_rotvec([[0.0, 0.0, 0.3]]) @ R[rot_spikes]
    log = TrackerLog(t=t, positions=noisy, rotations=R, source="synthetic")
    with caplog.at_level(logging.INFO, logger="refine.demo"):
        demo = clean_demonstration(log, DemoSettings(file=tmp_path / "unused.txt", smoothing_s=0.15))
    assert demo.n_outliers == 5
    assert "replaced 5 outlier sample(s)" in caplog.text
    # 0.15 s of smoothing rounds off the 0.25 m/s^2 start by about a*sigma^2/2 ~ 3 mm
    assert np.linalg.norm(demo.positions - truth, axis=1)[100:-100].max() < 4e-3
    assert np.linalg.norm(demo.positions - truth, axis=1)[int(3 * RATE) : -100].max() < 2e-4
    assert rotation_angle_deg(demo.rotations, R_true)[100:-100].max() < 0.2
    assert abs(t[demo.motion_start] - 2.0) < 0.1
    assert demo.speed[int(4 * RATE)] == pytest.approx(0.05, rel=0.05)


def test_clean_demonstration_leaves_a_clean_log_without_outliers(tmp_path):
    t, _, noisy = _pause_then_move(seed=8, noise_m=2e-4)
    R = _noisy_rotations(matrix_from_zyx(t, 0.1, 0.0), 0.05, seed=9)
    log = TrackerLog(t=t, positions=noisy, rotations=R)
    assert clean_demonstration(log, DemoSettings(file=tmp_path / "x.txt")).n_outliers == 0
