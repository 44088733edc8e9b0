import numpy as np
import pytest

from refine.calibrate.receiver import find_dwells, register_receiver_from_log
from refine.calibrate.simulate import calibration_tracker_model, simulate_touches
from refine.errors import InputError
from refine.frames import rotation_angle_deg, transform_from_xyz_rpy

SOURCE_IN_WORLD = transform_from_xyz_rpy([1.30, -0.82, 0.72], [0.0, 0.0, 90.0])  # the glass cell's
TIP = np.array([0.03, -0.01, 0.25])
# six points on the fixture, 0.5 to 1.5 m from the receiver and 0.45 to 0.95 m high [m]
POINTS = np.array(
    [
        [1.00, -0.55, 0.45],
        [1.70, -0.35, 0.60],
        [1.05, -0.05, 0.80],
        [1.75, 0.15, 0.45],
        [0.90, 0.40, 0.60],
        [1.55, 0.60, 0.95],
    ]
)


def _errors(cal):
    T = cal.values["source_in_world"]
    return (
        float(np.linalg.norm(T[:3, 3] - SOURCE_IN_WORLD[:3, 3])),
        float(rotation_angle_deg(T[:3, :3], SOURCE_IN_WORLD[:3, :3])),
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_six_points_one_wrongly_touched_register_within_1_mm_and_0_2_deg(seed):
    sim = simulate_touches(
        POINTS,
        SOURCE_IN_WORLD,
        TIP,
        wrong={2: [0.0, 0.02, 0.0]},
        model=calibration_tracker_model(seed=seed),
        seed=seed,
    )
    cal = register_receiver_from_log(sim.log, TIP, POINTS)
    position_error, angle_error = _errors(cal)
    assert position_error < 1e-3 and angle_error < 0.2
    assert cal.outliers == (2,)
    assert cal.residuals_m[2] > 0.015


def test_without_the_z_model_the_far_field_error_spoils_the_registration():
    sim = simulate_touches(POINTS, SOURCE_IN_WORLD, TIP, model=calibration_tracker_model(seed=5), seed=5)
    position_error, _ = _errors(
        register_receiver_from_log(sim.log, TIP, POINTS, fit_z=False, threshold_m=0.1)
    )
    assert position_error > 5e-3


def test_dwells_are_found_where_the_tip_rested():
    sim = simulate_touches(POINTS, SOURCE_IN_WORLD, TIP, model=calibration_tracker_model(seed=0))
    dwells = find_dwells(sim.log, TIP)
    assert len(dwells) == len(POINTS)
    for d, (start, stop) in zip(dwells, sim.dwell_ranges, strict=True):
        assert start - 30 <= d.start <= start + 60 and stop - 60 <= d.stop <= stop + 30


def test_a_missing_dwell_is_an_error_naming_the_counts():
    sim = simulate_touches(POINTS[:5], SOURCE_IN_WORLD, TIP, model=calibration_tracker_model(seed=0))
    with pytest.raises(InputError, match="5 dwell.*6 points"):
        register_receiver_from_log(sim.log, TIP, POINTS)


def test_collinear_points_are_refused():
    line = np.array([[1.0 + 0.1 * k, 0.0, 0.5] for k in range(5)])
    sim = simulate_touches(line, SOURCE_IN_WORLD, TIP, model=calibration_tracker_model(seed=0))
    with pytest.raises(InputError, match="one line"):
        register_receiver_from_log(sim.log, TIP, line)


def test_too_few_points():
    sim = simulate_touches(POINTS[:3], SOURCE_IN_WORLD, TIP, model=calibration_tracker_model(seed=0))
    with pytest.raises(InputError, match="at least 4"):
        register_receiver_from_log(sim.log, TIP, POINTS[:3])
