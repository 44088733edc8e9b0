import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from refine.calibrate.simulate import calibration_tracker_model, simulate_pivot, simulate_touches
from refine.cli import main
from refine.demo import write_liberty_ascii
from refine.frames import invert_transform, rotation_angle_deg, transform_from_xyz_rpy
from refine.problem import load_problem

ROOT = Path(__file__).resolve().parents[2]
GLASS = ROOT / "problems" / "glass_adhesive"


@pytest.fixture(scope="module")
def pivot_log(tmp_path_factory, cell):
    path = tmp_path_factory.mktemp("pivot") / "pivot.liberty"
    sim = simulate_pivot(cell.tip, [0.55, 0.25, -0.25], model=calibration_tracker_model(seed=0))
    write_liberty_ascii(path, sim.log, units="cm", with_frame_count=True, rate_hz=240.0)
    return path


def test_pivot_json_has_the_documented_keys_in_metres(pivot_log, capsys, cell):
    assert main(["calibrate", "pivot", str(pivot_log), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("tip_in_sensor_m", "pivot_in_source_m", "rms_residual_m", "max_residual_m", "outliers"):
        assert key in out
    assert np.linalg.norm(np.array(out["tip_in_sensor_m"]) - cell.tip) < 0.5e-3
    assert out["rms_residual_m"] < 3e-3


def test_pivot_summary_prints_a_problem_snippet(pivot_log, capsys):
    assert main(["calibrate", "pivot", str(pivot_log)]) == 0
    out = capsys.readouterr().out
    assert "[tool]" in out and "sensor_in_tcp = { xyz = [" in out and "rms residual" in out


def test_pivot_write_keeps_the_tool_orientation(pivot_log, tmp_path, capsys, cell):
    problem = tmp_path / "glass"
    shutil.copytree(GLASS, problem)
    before = load_problem(problem).tool.sensor_in_tcp
    assert main(["calibrate", "pivot", str(pivot_log), "--write", str(problem)]) == 0
    after = load_problem(problem).tool.sensor_in_tcp
    assert rotation_angle_deg(before[:3, :3], after[:3, :3]) < 1e-3
    assert np.linalg.norm(invert_transform(after)[:3, 3] - cell.tip) < 0.5e-3
    text = (problem / "problem.toml").read_text()
    assert "# the Liberty sensor on the hand gun's barrel" in text  # comments kept


def test_a_log_from_the_wrong_station_exits_2(pivot_log, capsys):
    assert main(["calibrate", "pivot", str(pivot_log), "--station", "2"]) == 2
    err = capsys.readouterr().err
    assert "no samples of station 2" in err and "stations found: 1" in err


def test_units_mixed_up_exit_2(pivot_log, capsys):
    assert main(["calibrate", "pivot", str(pivot_log), "--units", "in"]) == 2
    err = capsys.readouterr().err
    assert "units: cm" in err and "'in'" in err


def test_too_little_swing_exits_2(tmp_path, capsys, cell):
    path = tmp_path / "still.liberty"
    sim = simulate_pivot(
        cell.tip, [0.55, 0.25, -0.25], swing_deg=2.0, model=calibration_tracker_model(seed=0)
    )
    write_liberty_ascii(path, sim.log, units="in")
    assert main(["calibrate", "pivot", str(path)]) == 2
    assert "too little swing" in capsys.readouterr().err


@pytest.fixture(scope="module")
def touch_files(tmp_path_factory, cell):
    folder = tmp_path_factory.mktemp("touch")
    sim = simulate_touches(
        cell.points,
        cell.source_in_world,
        cell.tip,
        wrong={4: [0.0, 0.0, 0.02]},
        model=calibration_tracker_model(seed=1),
    )
    write_liberty_ascii(folder / "touch.liberty", sim.log, units="in")
    lines = ["name,x,y,z"] + [f"corner{k},{p[0]},{p[1]},{p[2]}" for k, p in enumerate(cell.points)]
    (folder / "points.csv").write_text("\n".join(lines) + "\n")
    return folder / "touch.liberty", folder / "points.csv"


def test_receiver_json_and_the_wrong_point(touch_files, capsys, cell):
    log, points = touch_files
    args = ["calibrate", "receiver", str(log), str(points), "--tip-in-sensor", *map(str, cell.tip), "--json"]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    T = np.array(out["source_in_world"])
    assert np.linalg.norm(T[:3, 3] - cell.source_in_world[:3, 3]) < 1e-3
    assert rotation_angle_deg(T[:3, :3], cell.source_in_world[:3, :3]) < 0.2
    assert out["outliers"] == [4] and len(out["residuals_m"]) == 6


def test_receiver_write_updates_the_frames_table(touch_files, tmp_path, capsys, cell):
    log, points = touch_files
    problem = tmp_path / "glass"
    shutil.copytree(GLASS, problem)
    args = [
        "calibrate",
        "receiver",
        str(log),
        str(points),
        "--tip-in-sensor",
        *map(str, cell.tip),
        "--write",
        str(problem),
    ]
    assert main(args) == 0
    assert "REJECTED" in capsys.readouterr().out
    T = load_problem(problem).frames.source_in_world
    assert np.linalg.norm(T[:3, 3] - cell.source_in_world[:3, 3]) < 1e-3


def test_receiver_points_in_millimetres_exit_2(touch_files, tmp_path, capsys, cell):
    log, _ = touch_files
    points = tmp_path / "mm.csv"
    points.write_text(
        "x,y,z\n" + "\n".join(f"{p[0] * 1000},{p[1] * 1000},{p[2] * 1000}" for p in cell.points) + "\n"
    )
    assert main(["calibrate", "receiver", str(log), str(points), "--tip-in-sensor", *map(str, cell.tip)]) == 2
    assert "millimetres" in capsys.readouterr().err


def test_receiver_without_a_tip_exits_2(touch_files, capsys):
    log, points = touch_files
    assert main(["calibrate", "receiver", str(log), str(points)]) == 2
    assert "--tip-in-sensor" in capsys.readouterr().err


def _joints_csv(path, joints):
    n = joints.shape[1]
    rows = [",".join(f"j{k + 1}" for k in range(n))]
    rows += [",".join(f"{v:.6f}" for v in np.degrees(q)) for q in joints]
    path.write_text("\n".join(rows) + "\n")


@pytest.fixture(scope="module")
def tcp_readings(tmp_path_factory):
    from refine.calibrate.simulate import simulate_tcp_readings
    from refine.robot.registry import load_robot

    robot = load_robot("abb_irb4600_60_205")
    tcp = transform_from_xyz_rpy([0.01, -0.02, 0.35], [0.0, 10.0, 30.0])
    sim = simulate_tcp_readings(robot, tcp, [1.2, 0.2, 0.6], six_point=True, repeatability_m=5e-5, seed=0)
    path = tmp_path_factory.mktemp("tcp") / "tcp.csv"
    _joints_csv(path, sim.joints)
    return path, tcp


def test_tcp_six_point_json(tcp_readings, capsys):
    path, tcp = tcp_readings
    assert (
        main(["calibrate", "tcp", str(path), "--robot", "abb_irb4600_60_205", "--six-point", "--json"]) == 0
    )
    out = json.loads(capsys.readouterr().out)
    T = np.array(out["tcp_in_flange"])
    assert np.linalg.norm(T[:3, 3] - tcp[:3, 3]) < 0.3e-3
    assert rotation_angle_deg(T[:3, :3], tcp[:3, :3]) < 0.15
    assert out["outliers"] == [] and out["max_residual_m"] < 0.3e-3


def test_tcp_four_point_write_keeps_the_problem_orientation(tcp_readings, tmp_path, capsys):
    path, tcp = tcp_readings
    problem = tmp_path / "glass"
    shutil.copytree(GLASS, problem)
    lines = path.read_text().splitlines()
    four = tmp_path / "four.csv"
    four.write_text("\n".join(lines[:5]) + "\n")
    assert main(["calibrate", "tcp", str(four), "--write", str(problem), "--problem", str(problem)]) == 0
    T = load_problem(problem).tool.tcp_in_flange
    assert np.linalg.norm(T[:3, 3] - tcp[:3, 3]) < 0.3e-3
    assert rotation_angle_deg(T[:3, :3], np.eye(3)) < 1e-6  # the glass gun is straight


def test_joint_readings_without_a_robot_exit_2(tcp_readings, capsys):
    path, _ = tcp_readings
    assert main(["calibrate", "tcp", str(path)]) == 2
    assert "--robot" in capsys.readouterr().err


def test_tcp_with_too_few_readings_exits_2(tcp_readings, tmp_path, capsys):
    path, _ = tcp_readings
    three = tmp_path / "three.csv"
    three.write_text("\n".join(path.read_text().splitlines()[:4]) + "\n")
    assert main(["calibrate", "tcp", str(three), "--robot", "abb_irb4600_60_205"]) == 2
    assert "at least 4" in capsys.readouterr().err


def test_workpiece_from_controller_positions_in_mm(tmp_path, capsys):
    cad = transform_from_xyz_rpy([1.30, 0.0, 0.60], [0.0, 0.0, 90.0])
    points = np.array([[-0.55, -0.2, 0.0], [0.55, -0.2, 0.01], [0.55, 0.2, 0.02], [-0.55, 0.2, 0.0]])
    world = points @ cad[:3, :3].T + cad[:3, 3]
    rows = ["x,y,z,qw,qx,qy,qz"] + [f"{p[0] * 1000},{p[1] * 1000},{p[2] * 1000},0,1,0,0" for p in world]
    (tmp_path / "touch.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "points.csv").write_text("x,y,z\n" + "\n".join(",".join(map(str, p)) for p in points) + "\n")
    args = [
        "calibrate",
        "workpiece",
        str(tmp_path / "touch.csv"),
        str(tmp_path / "points.csv"),
        "--units",
        "mm",
    ]
    assert main([*args, "--json"]) == 0
    T = np.array(json.loads(capsys.readouterr().out)["cad_in_world"])
    np.testing.assert_allclose(T, cad, atol=1e-9)
    # the same positions read as metres are 1000 times too far
    assert main(args[:-2]) == 2
    assert "units" in capsys.readouterr().err


def test_workpiece_collinear_points_exit_2(tmp_path, capsys):
    rows = ["x,y,z,qw,qx,qy,qz"] + [f"{1.0 + 0.1 * k},0,0.5,1,0,0,0" for k in range(4)]
    (tmp_path / "touch.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "points.csv").write_text("x,y,z\n" + "\n".join(f"{0.1 * k},0,0" for k in range(4)) + "\n")
    assert main(["calibrate", "workpiece", str(tmp_path / "touch.csv"), str(tmp_path / "points.csv")]) == 2
    assert "one line" in capsys.readouterr().err


def test_receiver_path_moves_a_wrong_source_back_onto_the_path(tmp_path, capsys):
    """The glass demo (full tracker error model) re-registers a receiver set 4 cm and 2.5 deg off."""
    from refine.calibrate.files import update_problem

    problem = tmp_path / "glass"
    shutil.copytree(GLASS, problem)
    truth = load_problem(problem).frames.source_in_world
    update_problem(
        problem, "frames", "source_in_world", truth @ transform_from_xyz_rpy([0.02, -0.03, 0.01], [1, -1, 2])
    )
    log = problem / "demo.liberty"
    assert (
        main(["calibrate", "receiver-path", str(log), "--problem", str(problem), "--write", str(problem)])
        == 0
    )
    T = load_problem(problem).frames.source_in_world
    assert np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 5e-3
    assert rotation_angle_deg(T[:3, :3], truth[:3, :3]) < 0.2


def test_pivot_from_binary_and_csv_logs(tmp_path, capsys, cell):
    """The same swing read from Liberty binary (cm) and from CSV (mm) gives the tip."""
    from refine.demo import write_liberty_binary
    from refine.frames import tracker_angles_from_matrix

    sim = simulate_pivot(cell.tip, cell.pivot, model=calibration_tracker_model(seed=2))
    binary = tmp_path / "pivot.lyb"
    write_liberty_binary(binary, sim.log, units="cm")
    assert (
        main(["calibrate", "pivot", str(binary), "--format", "liberty_binary", "--units", "cm", "--json"])
        == 0
    )
    assert (
        np.linalg.norm(np.array(json.loads(capsys.readouterr().out)["tip_in_sensor_m"]) - cell.tip) < 0.5e-3
    )

    angles = tracker_angles_from_matrix(sim.log.rotations, degrees=True)
    rows = ["t,x,y,z,azimuth,elevation,roll"] + [
        f"{t:.5f},{p[0] * 1000:.4f},{p[1] * 1000:.4f},{p[2] * 1000:.4f},{a[0]:.5f},{a[1]:.5f},{a[2]:.5f}"
        for t, p, a in zip(sim.log.t, sim.log.positions, angles, strict=True)
    ]
    csv = tmp_path / "pivot.csv"
    csv.write_text("\n".join(rows) + "\n")
    assert main(["calibrate", "pivot", str(csv), "--format", "csv", "--units", "mm", "--json"]) == 0
    assert (
        np.linalg.norm(np.array(json.loads(capsys.readouterr().out)["tip_in_sensor_m"]) - cell.tip) < 0.5e-3
    )
    # millimetres read as metres: the positions are beyond any tracker's range
    assert main(["calibrate", "pivot", str(csv), "--format", "csv"]) == 2
    assert "read as 'm': are the units right?" in capsys.readouterr().err
    # a CSV log has one station
    assert main(["calibrate", "pivot", str(csv), "--format", "csv", "--units", "mm", "--station", "2"]) == 2
    assert "one station" in capsys.readouterr().err


def test_receiver_path_refuses_a_far_source_unless_allowed(tmp_path, capsys):
    """A receiver 0.64 m and 60 deg from the problem's is named, and written once allowed."""
    from refine.calibrate.files import update_problem

    problem = tmp_path / "glass"
    shutil.copytree(GLASS, problem)
    truth = load_problem(problem).frames.source_in_world
    update_problem(
        problem, "frames", "source_in_world", truth @ transform_from_xyz_rpy([0.5, 0.4, 0.0], [0, 0, 60])
    )
    args = ["calibrate", "receiver-path", str(problem / "demo.liberty"), "--problem", str(problem)]
    assert main(args) == 2
    assert "deg from the first guess" in capsys.readouterr().err
    allow = ["--max-guess-offset-m", "1.0", "--max-guess-turn-deg", "90", "--write", str(problem)]
    assert main(args + allow) == 0
    T = load_problem(problem).frames.source_in_world
    assert np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 5e-3
    assert rotation_angle_deg(T[:3, :3], truth[:3, :3]) < 0.2
