import numpy as np
import pytest

from refine.calibrate.receiver import find_dwells, register_receiver_from_log
from refine.calibrate.simulate import calibration_tracker_model, simulate_touches
from refine.errors import InputError
from refine.frames import rotation_angle_deg


def _errors(cal, cell):
    T = cal.values["source_in_world"]
    return (
        float(np.linalg.norm(T[:3, 3] - cell.source_in_world[:3, 3])),
        float(rotation_angle_deg(T[:3, :3], cell.source_in_world[:3, :3])),
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_six_points_one_wrongly_touched_register_within_1_mm_and_0_2_deg(seed, cell):
    sim = simulate_touches(
        cell.points,
        cell.source_in_world,
        cell.tip,
        wrong={2: [0.0, 0.02, 0.0]},
        model=calibration_tracker_model(seed=seed),
        seed=seed,
    )
    cal = register_receiver_from_log(sim.log, cell.tip, cell.points)
    position_error, angle_error = _errors(cal, cell)
    assert position_error < 1e-3 and angle_error < 0.2
    assert cal.outliers == (2,)
    assert cal.residuals_m[2] > 0.015


def test_without_the_z_model_the_far_field_error_spoils_the_registration(cell):
    sim = simulate_touches(
        cell.points, cell.source_in_world, cell.tip, model=calibration_tracker_model(seed=5), seed=5
    )
    position_error, _ = _errors(
        register_receiver_from_log(sim.log, cell.tip, cell.points, fit_z=False, threshold_m=0.1), cell
    )
    assert position_error > 5e-3


def test_dwells_are_found_where_the_tip_rested(cell):
    sim = simulate_touches(
        cell.points, cell.source_in_world, cell.tip, model=calibration_tracker_model(seed=0)
    )
    dwells = find_dwells(sim.log, cell.tip)
    assert len(dwells) == len(cell.points)
    for d, (start, stop) in zip(dwells, sim.dwell_ranges, strict=True):
        assert start - 30 <= d.start <= start + 60 and stop - 60 <= d.stop <= stop + 30


def test_a_missing_dwell_is_an_error_naming_the_counts(cell):
    sim = simulate_touches(
        cell.points[:5], cell.source_in_world, cell.tip, model=calibration_tracker_model(seed=0)
    )
    with pytest.raises(InputError, match="5 dwell.*6 points"):
        register_receiver_from_log(sim.log, cell.tip, cell.points)


def test_collinear_points_are_refused(cell):
    line = np.array([[1.0 + 0.1 * k, 0.0, 0.5] for k in range(5)])
    sim = simulate_touches(line, cell.source_in_world, cell.tip, model=calibration_tracker_model(seed=0))
    with pytest.raises(InputError, match="one line"):
        register_receiver_from_log(sim.log, cell.tip, line)


def test_too_few_points(cell):
    sim = simulate_touches(
        cell.points[:3], cell.source_in_world, cell.tip, model=calibration_tracker_model(seed=0)
    )
    with pytest.raises(InputError, match="at least 4"):
        register_receiver_from_log(sim.log, cell.tip, cell.points[:3])


@pytest.mark.parametrize("rate_hz", [60.0, 240.0])
def test_half_second_rests_count_and_shorter_ones_do_not(cell, rate_hz):
    model = calibration_tracker_model(seed=3, rate_hz=rate_hz)
    sim = simulate_touches(cell.points, cell.source_in_world, cell.tip, dwell_s=0.5, model=model)
    assert len(find_dwells(sim.log, cell.tip, min_dwell_s=0.5)) == 6
    short = simulate_touches(cell.points, cell.source_in_world, cell.tip, dwell_s=0.25, model=model)
    assert len(find_dwells(short.log, cell.tip, min_dwell_s=0.5)) == 0


def _six_point_case(seed: int, z_error_per_m2: float = 0.0):
    """An independent six-point session: 1 mm noise, a slow 2 mm drift, point 3 touched 20 mm off.

    ``z_error_per_m2`` adds a z error ``k d^2`` along the receiver's z axis (d: sensor distance).
    """
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    R_F_S = Rotation.from_euler("xyz", [2.0, -3.0, 75.0], degrees=True).as_matrix()
    t_F_S = np.array([0.9, -0.6, 0.45])
    points = np.array(
        [
            [1.2, -0.2, 0.30],
            [1.6, 0.3, 0.32],
            [1.0, 0.5, 0.55],
            [0.6, 0.1, 0.31],
            [1.4, -0.5, 0.70],
            [0.8, -0.3, 0.62],
        ]
    )
    tip = np.array([0.02, -0.01, 0.21])
    touched = points.copy()
    touched[3] += [0.0, 0.02, 0.0]
    positions, rotations = [], []
    for k, q in enumerate(touched):
        tilt = [180.0 + rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(0, 360)]
        R_S_E = R_F_S.T @ Rotation.from_euler("xyz", tilt, degrees=True).as_matrix()
        sensor = R_F_S.T @ (q - t_F_S) - R_S_E @ tip
        sensor[2] += z_error_per_m2 * float(sensor @ sensor)
        drift = 0.002 * k / 5.0 * np.array([1.0, 0.0, 0.0])
        positions.append(sensor + drift + rng.normal(0.0, 0.001 / np.sqrt(3), 3))
        rotations.append(R_S_E)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_F_S, t_F_S
    return np.array(positions), np.array(rotations), tip, points, T


def _error_mm(cal, T):
    return 1000.0 * float(np.linalg.norm(cal.values["source_in_world"][:3, 3] - T[:3, 3]))


def test_without_a_z_error_the_default_is_as_accurate_as_no_z_model():
    from refine.calibrate.receiver import register_receiver

    for seed in range(6):
        p, R, tip, points, T = _six_point_case(seed)
        default = register_receiver(p, R, tip, points)
        plain = register_receiver(p, R, tip, points, fit_z=False)
        assert _error_mm(default, T) <= _error_mm(plain, T) + 1e-6
        assert default.outliers == (3,)


def test_a_real_z_error_chooses_the_z_model_and_it_helps():
    from refine.calibrate.receiver import register_receiver

    p, R, tip, points, T = _six_point_case(1, z_error_per_m2=0.03)
    default = register_receiver(p, R, tip, points, threshold_m=0.005)
    plain = register_receiver(p, R, tip, points, fit_z=False, threshold_m=0.05)
    assert default.figures["z_model_used"] == 1.0
    assert _error_mm(default, T) < 0.5 * _error_mm(plain, T)
