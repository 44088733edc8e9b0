import numpy as np
import pytest

from refine.calibrate.robot_touch import calibrate_tcp, register_workpiece, tcp_positions_world
from refine.calibrate.simulate import simulate_tcp_readings, simulate_workpiece_readings
from refine.errors import InputError
from refine.frames import rotation_angle_deg, transform_from_xyz_rpy
from refine.robot.registry import load_robot

TCP = transform_from_xyz_rpy([0.01, -0.02, 0.35], [0.0, 10.0, 30.0])  # a bent gun [m, deg]
REFERENCE = np.array([1.2, 0.2, 0.6])  # the reference spike in the base frame [m]


@pytest.fixture(scope="module")
def robot():
    return load_robot("abb_irb4600_60_205")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_four_points_with_0_05_mm_repeatability_give_the_tcp_within_0_3_mm(robot, seed):
    sim = simulate_tcp_readings(robot, TCP, REFERENCE, n_points=4, repeatability_m=5e-5, seed=seed)
    cal = calibrate_tcp(robot.fk_many(sim.joints))
    assert np.linalg.norm(cal.values["tcp_in_flange"][:3, 3] - TCP[:3, 3]) < 0.3e-3
    assert np.linalg.norm(cal.values["reference_point_in_base_m"] - REFERENCE) < 0.3e-3
    assert cal.max_residual_m < 0.3e-3


def test_six_points_give_the_tool_orientation(robot):
    sim = simulate_tcp_readings(robot, TCP, REFERENCE, six_point=True, repeatability_m=5e-5, seed=3)
    cal = calibrate_tcp(robot.fk_many(sim.joints), six_point=True)
    T = cal.values["tcp_in_flange"]
    # 0.05 mm over a 100 mm move is 0.03 deg per axis
    assert rotation_angle_deg(T[:3, :3], TCP[:3, :3]) < 0.15
    assert np.linalg.norm(T[:3, 3] - TCP[:3, 3]) < 0.3e-3


def test_error_free_flange_poses_give_the_exact_tcp(robot):
    sim = simulate_tcp_readings(robot, TCP, REFERENCE, n_points=5, repeatability_m=0.0, seed=0)
    cal = calibrate_tcp(sim.flange_poses)
    np.testing.assert_allclose(cal.values["tcp_in_flange"][:3, 3], TCP[:3, 3], atol=1e-7)


def test_a_bad_reading_among_six_is_rejected(robot):
    sim = simulate_tcp_readings(robot, TCP, REFERENCE, n_points=6, repeatability_m=5e-5, seed=4)
    poses = sim.flange_poses.copy()
    poses[2, :3, 3] += [0.004, 0.0, 0.0]
    cal = calibrate_tcp(poses)
    assert cal.outliers == (2,)
    assert np.linalg.norm(cal.values["tcp_in_flange"][:3, 3] - TCP[:3, 3]) < 0.3e-3


def test_too_few_readings_and_too_little_tilt(robot):
    sim = simulate_tcp_readings(robot, TCP, REFERENCE, n_points=4, seed=0)
    with pytest.raises(InputError, match="at least 4"):
        calibrate_tcp(sim.flange_poses[:3])
    flat = simulate_tcp_readings(robot, TCP, REFERENCE, n_points=4, tilt_deg=1.0, seed=0)
    with pytest.raises(InputError, match="tilt the tool"):
        calibrate_tcp(flat.flange_poses)


def test_workpiece_registration_with_a_wrong_touch(robot):
    base = transform_from_xyz_rpy([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    cad = transform_from_xyz_rpy([1.30, 0.0, 0.60], [0.0, 0.0, 90.0])
    points = np.array(
        [[-0.55, -0.2, 0.0], [0.55, -0.2, 0.01], [0.55, 0.2, 0.02], [-0.55, 0.2, 0.0], [0.0, 0.0, 0.05]]
    )
    sim = simulate_workpiece_readings(robot, base, TCP, cad, points, wrong={1: [0.005, 0.0, 0.0]}, seed=1)
    cal = register_workpiece(tcp_positions_world(robot.fk_many(sim.joints), base, TCP), points)
    T = cal.values["cad_in_world"]
    assert np.linalg.norm(T[:3, 3] - cad[:3, 3]) < 0.2e-3
    assert rotation_angle_deg(T[:3, :3], cad[:3, :3]) < 0.02
    assert cal.outliers == (1,)
    assert cal.residuals_m[1] == pytest.approx(0.005, abs=3e-4)
