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
