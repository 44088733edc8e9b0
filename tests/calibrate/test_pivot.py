import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.calibrate.pivot import solve_pivot, swing_spread_deg
from refine.calibrate.simulate import calibration_tracker_model, simulate_pivot
from refine.errors import InputError


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tip_is_found_within_half_a_millimetre_from_a_10_s_swing(seed, cell):
    """1 mm noise, 60 mm far-field z error, spikes: the tip offset is within 0.5 mm of the truth."""
    sim = simulate_pivot(cell.tip, cell.pivot, duration_s=10.0, model=calibration_tracker_model(seed=seed))
    cal = solve_pivot(sim.log.positions, sim.log.rotations)
    assert np.linalg.norm(cal.values["tip_in_sensor_m"] - cell.tip) < 0.5e-3
    assert np.linalg.norm(cal.values["pivot_in_source_m"] - cell.pivot) < 3e-3
    assert set(sim.outlier_indices) <= set(cal.outliers)
    assert len(cal.outliers) < 0.01 * len(sim.log.t)


def test_the_z_error_is_in_the_data_and_the_model_removes_it(cell):
    """Without the z model the same log gives a tip several millimetres off."""
    sim = simulate_pivot(cell.tip, cell.pivot, model=calibration_tracker_model(seed=3))
    plain = solve_pivot(sim.log.positions, sim.log.rotations, fit_z=False)
    modelled = solve_pivot(sim.log.positions, sim.log.rotations)
    assert np.linalg.norm(plain.values["tip_in_sensor_m"] - cell.tip) > 3e-3
    assert np.linalg.norm(modelled.values["tip_in_sensor_m"] - cell.tip) < 0.5e-3
    # the simulator's z error: 60 mm * smoothstep(d / 1.2 m) = c2 d^2 + c3 d^3 with these values
    assert modelled.figures["z_coeffs_c2_per_m"] == pytest.approx(3 * 0.06 / 1.2**2, rel=0.15)
    assert modelled.figures["z_coeffs_c3_per_m2"] == pytest.approx(-2 * 0.06 / 1.2**3, rel=0.3)


def test_error_free_poses_give_the_exact_tip(cell):
    rng = np.random.default_rng(4)
    R = Rotation.from_rotvec(rng.normal(scale=0.4, size=(50, 3))).as_matrix()
    p = cell.pivot - R @ cell.tip
    cal = solve_pivot(p, R, fit_z=False)
    np.testing.assert_allclose(cal.values["tip_in_sensor_m"], cell.tip, atol=1e-9)
    np.testing.assert_allclose(cal.values["pivot_in_source_m"], cell.pivot, atol=1e-9)
    assert cal.outliers == ()


def test_too_little_swing_is_an_error_not_an_answer(cell):
    sim = simulate_pivot(cell.tip, cell.pivot, swing_deg=3.0, model=calibration_tracker_model(seed=0))
    with pytest.raises(InputError, match="too little swing"):
        solve_pivot(sim.log.positions, sim.log.rotations)


def test_a_swing_in_one_plane_is_too_little(cell):
    t = np.linspace(0, 10, 600)
    R = Rotation.from_rotvec(np.outer(np.radians(30) * np.sin(t), [1.0, 0.0, 0.0])).as_matrix()
    first, second = swing_spread_deg(R)
    assert first > 15 and second < 0.1
    with pytest.raises(InputError, match="too little swing"):
        solve_pivot(cell.pivot - R @ cell.tip, R)


def test_too_few_samples():
    with pytest.raises(InputError, match="at least"):
        solve_pivot(np.zeros((5, 3)), np.broadcast_to(np.eye(3), (5, 3, 3)))


def test_centimetres_read_as_inches_are_caught_by_the_tip_length(cell):
    """A log scaled 100x (metres read as centimetres) gives an implausible tip."""
    sim = simulate_pivot(cell.tip, cell.pivot, model=calibration_tracker_model(seed=0).without_errors())
    with pytest.raises(InputError, match="units"):
        solve_pivot(sim.log.positions * 100.0, sim.log.rotations, fit_z=False)
