import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from refine.calibrate.cost import calibration_cost, path_errors
from refine.cli import main
from refine.errors import InputError
from refine.frames import make_transform, transform_from_xyz_rpy
from refine.problem import load_problem
from refine.settings import CalibrationSettings, FrameUncertainty

GLASS = Path(__file__).resolve().parents[2] / "problems" / "glass_adhesive"


def _nominal():
    return {
        "base_in_world": transform_from_xyz_rpy([0.1, -0.2, 0.0], [0, 0, 15]),
        "tcp_in_flange": transform_from_xyz_rpy([0.0, 0.0, 0.35], [0, 20, 0]),
        "cad_in_world": transform_from_xyz_rpy([1.3, 0.0, 0.6], [0, 0, 90]),
        "source_in_world": transform_from_xyz_rpy([1.3, -0.82, 0.72], [0, 0, 90]),
        "sensor_in_tcp": transform_from_xyz_rpy([-0.03, 0, -0.25], [180, 0, 30]),
    }


def _path(n=50):
    rng = np.random.default_rng(0)
    positions = np.column_stack([np.linspace(1.0, 1.6, n), np.linspace(-0.5, 0.5, n), np.full(n, 0.6)])
    rotations = np.array(
        [transform_from_xyz_rpy([0, 0, 0], [180 + a, b, 0])[:3, :3] for a, b in rng.normal(0, 10, (n, 2))]
    )
    return make_transform(rotations, positions)


def test_a_tcp_translation_error_moves_every_point_by_itself():
    """|error| = |delta t|: its mean is sigma * sqrt(8 / pi) (Maxwell), and no orientation error."""
    sigma = 0.001
    settings = CalibrationSettings({"tcp_in_flange": FrameUncertainty(xyz_m=(sigma,) * 3)}, samples=20000)
    cost = calibration_cost(_path(), _nominal(), settings)[0]
    assert cost.mean_position_error_m == pytest.approx(sigma * math.sqrt(8 / math.pi), rel=0.03)
    assert cost.mean_orientation_error_deg < 1e-9


def test_a_base_yaw_error_grows_with_the_distance_from_the_base_axis():
    """Rotation about the base z by delta moves a point at radius r by |delta| r: mean sqrt(2/pi) sigma r."""
    sigma_deg = 0.05
    nominal = _nominal()
    nominal["base_in_world"] = np.eye(4)
    path = _path()
    settings = CalibrationSettings(
        {"base_in_world": FrameUncertainty(rpy_deg=(0, 0, sigma_deg))}, samples=20000
    )
    cost = calibration_cost(path, nominal, settings)[0]
    r = np.linalg.norm(path[:, :2, 3], axis=1).mean()
    assert cost.mean_position_error_m == pytest.approx(
        math.sqrt(2 / math.pi) * math.radians(sigma_deg) * r, rel=0.03
    )
    assert cost.mean_orientation_error_deg == pytest.approx(math.sqrt(2 / math.pi) * sigma_deg, rel=0.03)


def test_the_robot_and_the_part_moved_together_cost_nothing():
    nominal = _nominal()
    nominal["base_in_world"] = nominal["cad_in_world"] = np.eye(4)
    move = transform_from_xyz_rpy([0.003, -0.002, 0.001], [0.1, 0.2, 0.3])
    pos, _ = path_errors(_path(), nominal, {"base_in_world": move, "cad_in_world": move})
    assert pos.max() < 1e-12


@pytest.mark.parametrize("frame", ["source_in_world", "sensor_in_tcp"])
def test_a_tracker_frame_rotation_turns_the_tool_by_its_angle_and_moves_nothing(frame):
    delta = transform_from_xyz_rpy([0.002, 0, 0], [0.3, -0.2, 0.1])
    angle = np.degrees(
        np.linalg.norm(np.radians([0.3, -0.2, 0.1]))
    )  # small: close to the rotation-vector norm
    pos, ang = path_errors(_path(), _nominal(), {frame: delta})
    assert pos.max() < 1e-12
    np.testing.assert_allclose(ang, angle, rtol=2e-3)


def test_calibration_table_is_read_and_checked(tmp_path):
    problem = tmp_path / "glass"
    shutil.copytree(GLASS, problem)
    toml = problem / "problem.toml"
    toml.write_text(
        toml.read_text()
        + "\n[calibration]\ncad_in_world = { xyz_m = 0.0005, rpy_deg = [0.01, 0.01, 0.05] }\nsamples = 200\n"
    )
    cal = load_problem(problem).calibration
    assert cal.frames["cad_in_world"].rpy_deg == (0.01, 0.01, 0.05) and cal.samples == 200
    toml.write_text(toml.read_text().replace("cad_in_world = { xyz_m", "cad_in_wrld = { xyz_m"))
    with pytest.raises(InputError, match="cad_in_wrld"):
        load_problem(problem)


def test_cost_cli_prints_a_row_per_frame(tmp_path, capsys):
    problem = tmp_path / "glass"
    shutil.copytree(GLASS, problem)
    toml = problem / "problem.toml"
    assert main(["calibrate", "cost", str(problem)]) == 2
    assert "no [calibration] table" in capsys.readouterr().err
    toml.write_text(
        toml.read_text()
        + "\n[calibration]\nsamples = 200\ntcp_in_flange = { xyz_m = 0.0003 }\nsensor_in_tcp = { rpy_deg = 0.5 }\n"
    )
    assert main(["calibrate", "cost", str(problem)]) == 0
    out = capsys.readouterr().out
    assert "tcp_in_flange" in out and "sensor_in_tcp" in out and "all" in out


def test_a_run_of_a_problem_with_calibration_prints_the_table_for_its_refined_poses():
    from types import SimpleNamespace

    from refine.calibrate.cost import run_cost_lines

    problem = load_problem(Path(__file__).resolve().parents[2] / "problems" / "glass_calibrated")
    poses = _path(30)
    result = SimpleNamespace(
        problem=problem, passes=[SimpleNamespace(trajectory=SimpleNamespace(poses=poses))]
    )
    lines = run_cost_lines(result)
    assert "on 30 waypoints" in lines[1]
    assert [line.split()[0] for line in lines[3:8]] == [
        "tcp_in_flange",
        "cad_in_world",
        "source_in_world",
        "sensor_in_tcp",
        "all",
    ]


def test_a_tcp_rotation_turns_the_tool_about_its_tip_and_leaves_the_tip_in_place():
    delta = transform_from_xyz_rpy([0.0, 0.0, 0.0], [0.0, 0.4, 0.0])
    pos, ang = path_errors(_path(), _nominal(), {"tcp_in_flange": delta})
    assert pos.max() < 1e-12
    np.testing.assert_allclose(ang, 0.4, rtol=1e-9)
