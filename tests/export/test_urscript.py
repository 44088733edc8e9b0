from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.errors import InputError
from refine.export.rapid import segment_speeds
from refine.export.urscript import UrPass, continuous_rotvecs, parse_urscript, write_urscript
from refine.frames import invert_transform, make_transform, rotvec_from_matrix, transform_from_xyz_rpy
from refine.paths import Trajectory
from refine.problem import CadSettings, DemoSettings, Problem, ProcessSettings, RobotSettings, ToolSettings
from refine.robot.registry import load_robot

UR = "ur10e"


@pytest.fixture(scope="module")
def ur10e():
    return load_robot(UR)


@pytest.fixture(scope="module")
def ur_problem() -> Problem:
    return Problem(
        name="seal window-3",
        root=Path("."),
        robot=RobotSettings(
            model=UR, base_in_world=transform_from_xyz_rpy([-0.5, 0.4, 0.9], [0.0, 0.0, 135.0])
        ),
        tool=ToolSettings(
            name="nozzle",
            tcp_in_flange=transform_from_xyz_rpy([0.0, 0.01, 0.18], [0.0, 15.0, 0.0]),
            mass_kg=1.8,
            cog_in_flange_m=(0.0, 0.004, 0.07),
        ),
        cad=CadSettings(file=Path("pane.csv")),
        demonstration=DemoSettings(file=Path("demo.txt")),
        process=ProcessSettings(kind="seal", output="DO3"),
    )


Q0, Q1 = [20.0, -100.0, 110.0, -100.0, -90.0, -150.0], [50.0, -80.0, 90.0, -120.0, -70.0, 150.0]


def make_trajectory(robot, problem, n, q0_deg=Q0, q1_deg=Q1) -> Trajectory:
    """A joint path from q0 to q1 [deg] (wrist 3 turns 300 deg); poses by the UR10e FK in {F}."""
    u = np.linspace(0.0, 1.0, n)[:, None]
    q = np.radians(q0_deg) + np.radians(np.subtract(q1_deg, q0_deg)) * u + 0.02 * np.sin(2.0 * np.pi * u)
    poses = np.array([problem.robot.base_in_world @ robot.fk(qk) @ problem.tool.tcp_in_flange for qk in q])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))])
    v = 0.05 + 0.02 * np.sin(np.pi * u[:, 0])
    t = np.concatenate([[0.0], np.cumsum(np.diff(s) / (0.5 * (v[1:] + v[:-1])))])
    return Trajectory(t, s, q, poses[:, :3, 3].copy(), poses, poses[:, :3, :3].copy(), v)


@pytest.fixture(scope="module")
def path(ur10e, ur_problem) -> Trajectory:
    return make_trajectory(ur10e, ur_problem, 40)


@pytest.fixture(scope="module")
def script(tmp_path_factory, path, ur_problem, ur10e):
    return write_urscript(tmp_path_factory.mktemp("ur") / "seal.script", path, ur_problem, ur10e)


def _base_poses(problem, trajectory):
    return invert_transform(problem.robot.base_in_world) @ trajectory.poses


def _rotation_error(R_a, R_b) -> float:
    return float(np.linalg.norm(rotvec_from_matrix(np.swapaxes(R_a, -1, -2) @ R_b), axis=-1).max())


def test_round_trip_recovers_every_pose_in_the_base_frame(script, path, ur_problem, ur10e):
    (run,) = parse_urscript(script)
    assert isinstance(run, UrPass) and len(run.poses) == len(path)
    expected = _base_poses(ur_problem, path)
    np.testing.assert_allclose(run.poses[:, :3, 3], expected[:, :3, 3], rtol=0, atol=1e-6)
    assert _rotation_error(run.poses[:, :3, :3], expected[:, :3, :3]) < 1e-6
    for k in (0, len(path) // 2, len(path) - 1):  # base-frame pose == fk(q) · set_tcp
        np.testing.assert_allclose(run.poses[k], ur10e.fk(path.q[k]) @ run.tcp_in_flange, atol=1e-6)
    np.testing.assert_allclose(run.tcp_in_flange, ur_problem.tool.tcp_in_flange, atol=1e-8)


def test_rotation_vectors_agree_with_scipy_and_stay_continuous(script, path, ur_problem):
    (run,) = parse_urscript(script)
    R = _base_poses(ur_problem, path)[:, :3, :3]
    assert _rotation_error(Rotation.from_rotvec(run.rotvecs).as_matrix(), R) < 1e-6
    raw = Rotation.from_matrix(R).as_rotvec()
    assert np.linalg.norm(np.diff(raw, axis=0), axis=1).max() > 5.0, "the raw vectors flip on this path"
    steps = np.linalg.norm(np.diff(run.rotvecs, axis=0), axis=1)
    assert steps.max() < 0.3, "written rotation vectors jump"
    within_pi = np.linalg.norm(run.rotvecs, axis=1) <= math.pi
    np.testing.assert_allclose(run.rotvecs[within_pi][:5], raw[within_pi][:5], atol=1e-8)


def test_speeds_blends_and_accelerations_are_as_planned(script, path):
    (run,) = parse_urscript(script)
    assert run.speeds[0] == pytest.approx(0.25)  # the move onto the first waypoint
    np.testing.assert_allclose(run.speeds[1:], segment_speeds(path), rtol=0, atol=0.5e-4 + 1e-12)
    assert 0.0 < run.blend_radii[0] <= 0.001 and 0.0 < run.blend_radii[-1] <= 0.001  # flies in and out
    gaps = np.linalg.norm(np.diff(run.poses[:, :3, 3], axis=0), axis=1)
    inner = run.blend_radii[1:-1]
    assert np.all(inner > 0.0) and np.all(inner <= 0.001 + 1e-12)
    assert np.all(inner <= 0.4 * np.minimum(gaps[:-1], gaps[1:]) + 1e-6)
    assert set(re.findall(r"movel\(p\[[^\]]*\], a=([^,]+),", script.read_text())) == {"1.2"}


def test_blends_shrink_so_they_never_overlap(tmp_path, ur10e, ur_problem):
    tr = make_trajectory(ur10e, ur_problem, 400)  # waypoints about 1 mm apart
    (run,) = parse_urscript(write_urscript(tmp_path / "dense.script", tr, ur_problem, ur10e, blend_m=0.005))
    gaps = np.linalg.norm(np.diff(run.poses[:, :3, 3], axis=0), axis=1)
    assert np.all(run.blend_radii[1:-1] + run.blend_radii[2:] <= gaps[1:] + 1e-6)
    assert run.blend_radii[1:-1].max() < 0.005


def test_approach_is_a_joint_move_on_the_branch_of_the_first_waypoint(script, path, ur_problem, ur10e):
    (run,) = parse_urscript(script)
    T_app = run.poses[0] @ make_transform(p=[0.0, 0.0, -0.1])
    np.testing.assert_allclose(ur10e.fk(run.q_approach) @ ur_problem.tool.tcp_in_flange, T_app, atol=1e-7)
    assert np.abs(run.q_approach - path.q[0]).max() < 0.5


def test_program_is_structurally_sane(script, path):
    lines = [ln.strip() for ln in script.read_text().splitlines() if ln.strip()]
    assert lines[0] == "def seal_window_3():" and lines[-2:] == ["end", "seal_window_3()"]
    assert sum(ln.startswith("def ") for ln in lines) == 1
    assert all(ln.count("(") == ln.count(")") and ln.count("[") == ln.count("]") for ln in lines)
    assert sum(ln.startswith("movel(") for ln in lines) == len(path) + 1
    movej = [ln for ln in lines if ln.startswith("movej(")]
    assert len(movej) == 3 and movej[0] == movej[-1] and movej[0].endswith("# home")
    code = [ln for ln in lines if not ln.startswith("#")]
    assert code.count("set_digital_out(3, True)") == 1  # in the thread that switches on the move
    on, off = code.index("run process_on()"), code.index("run process_off()")
    assert code[on + 1].startswith("movel(") and code[on - 3].startswith("movej(")
    assert (
        code[off + 1].startswith("movel(")
        and code[off + 2].startswith("movel(")
        and code[off + 3].startswith("movej(")
    )
    assert code.index("set_tcp(p[0,0.01,0.18,0,0.261799388,0])") < on


@pytest.mark.parametrize(("output", "number"), [("DO3", 3), ("do 5", 5), ("7", 7), ("doGlue", 0)])
def test_process_output_maps_to_a_digital_output(tmp_path, path, ur_problem, ur10e, output, number):
    problem = dataclasses.replace(ur_problem, process=ProcessSettings(kind="glue", output=output))
    target = write_urscript(tmp_path / "o.script", path, problem, ur10e)
    (run,) = parse_urscript(target)
    assert run.output == number
    assert f"process output '{output}'" in target.read_text()


def test_rejects_a_bad_output_and_a_non_ur_robot(tmp_path, path, ur_problem, ur10e):
    problem = dataclasses.replace(ur_problem, process=ProcessSettings(output="DO9"))
    with pytest.raises(InputError, match="0..7"):
        write_urscript(tmp_path / "x.script", path, problem, ur10e)
    with pytest.raises(InputError, match="UR robots"):
        write_urscript(tmp_path / "x.script", path, ur_problem, load_robot("kuka_iiwa14_r820"))


def test_three_passes_make_three_blocks_read_back_as_three_passes(tmp_path, ur10e, ur_problem):
    runs = [
        (f"bead {i}", make_trajectory(ur10e, ur_problem, 8 + i, Q0, np.add(Q1, [0, 3.0 * i, 0, 0, 0, 0])))
        for i in (1, 2, 3)
    ]
    target = write_urscript(tmp_path / "multi.script", runs[0][1], ur_problem, ur10e, passes=runs)
    text = target.read_text()
    assert [int(m) for m in re.findall(r"^  # pass (\d) of 3: bead", text, re.M)] == [1, 2, 3]
    assert text.count("movej(") == 5 and text.count("def ") == 1
    parsed = parse_urscript(target)
    assert [p.name for p in parsed] == ["bead 1", "bead 2", "bead 3"]
    for p, (_, tr) in zip(parsed, runs, strict=True):
        expected = _base_poses(ur_problem, tr)
        np.testing.assert_allclose(p.poses[:, :3, 3], expected[:, :3, 3], rtol=0, atol=1e-6)
        assert _rotation_error(p.poses[:, :3, :3], expected[:, :3, :3]) < 1e-6


def test_continuous_rotvecs_pick_the_closest_equivalent_vector():
    """Each vector is the same rotation as scipy's and the closest of all u·(θ + 2πk) to its predecessor."""
    rng = np.random.default_rng(2)
    axis = rng.normal(size=(6, 3))
    angles = np.linspace(2.6, 3.9, 60)  # passes through π, where scipy's vector flips
    rotvecs = np.concatenate([np.outer(angles, a / np.linalg.norm(a)) for a in axis])
    rotvecs = np.concatenate([rotvecs, Rotation.random(200, random_state=3).as_rotvec()])
    R = Rotation.from_rotvec(rotvecs).as_matrix()
    out = continuous_rotvecs(R)
    assert _rotation_error(Rotation.from_rotvec(out).as_matrix(), R) < 1e-9
    ref = Rotation.from_matrix(R).as_rotvec()
    np.testing.assert_allclose(out[0], ref[0], atol=1e-12)
    for k in range(1, len(out)):
        theta = np.linalg.norm(ref[k])
        unit = ref[k] / theta
        best = min(np.linalg.norm(unit * (theta + 2 * np.pi * m) - out[k - 1]) for m in range(-4, 5))
        assert np.linalg.norm(out[k] - out[k - 1]) <= best + 1e-9
    for i in range(6):  # along each smooth sweep through π the written vectors never jump
        sweep = out[60 * i : 60 * (i + 1)]
        assert np.linalg.norm(np.diff(sweep, axis=0), axis=1).max() < 0.05


def test_the_run_s_planned_air_moves_are_written_as_movej_through_each_via_point(tmp_path, path, ur_problem, ur10e):
    """Via points before the pass (the approach is the pass's first movej), the return's before home."""
    from refine.export.program import ProgramPass

    air_in = np.radians([[0.0, -90.0, 90.0, -90.0, -90.0, 0.0], [25.0, -95.0, 100.0, -105.0, -88.0, -140.0]])
    air_out = np.radians([[40.0, -70.0, 80.0, -100.0, -80.0, 100.0], [0.0, -90.0, 90.0, -90.0, -90.0, 0.0]])
    run = ProgramPass("pass 1", path, (), air_in, air_out)
    text = write_urscript(tmp_path / "air.script", path, ur_problem, ur10e, passes=[run]).read_text()
    movej = [
        np.array([float(v) for v in m[1].split(",")]) for m in re.finditer(r"movej\(\[([^\]]*)\]", text)
    ]
    # home, via, approach (the pass's first movej), via of the return, home
    assert len(movej) == 5
    np.testing.assert_allclose(movej[1], air_in[0], atol=1e-8)
    np.testing.assert_allclose(movej[2], air_in[1], atol=1e-8)
    np.testing.assert_allclose(movej[3], air_out[0], atol=1e-8)
    passes = parse_urscript(tmp_path / "air.script")
    np.testing.assert_allclose(passes[0].q_approach, air_in[-1], atol=1e-8)


def test_each_planned_movej_takes_its_planned_time(tmp_path, path, ur_problem, ur10e):
    """Via points, approach and home of a planned run carry ``t``: each move's planned time, rounded up to 1 ms."""
    from refine.export.program import ProgramPass

    air_in = np.radians([[0.0, -90.0, 90.0, -90.0, -90.0, 0.0], [25.0, -95.0, 100.0, -105.0, -88.0, -140.0]])
    air_out = np.radians([[40.0, -70.0, 80.0, -100.0, -80.0, 100.0], [0.0, -90.0, 90.0, -90.0, -90.0, 0.0]])
    run = ProgramPass("pass 1", path, (), air_in, air_out, air_in_s=(1.5, 2.25), air_out_s=(0.75, 1.0004))
    text = write_urscript(tmp_path / "timed.script", path, ur_problem, ur10e, passes=[run]).read_text()
    times = [m[1] for m in re.finditer(r"movej\(\[[^\]]*\], a=[0-9.]+, v=[0-9.]+(?:, t=([0-9.]+))?\)", text)]
    # the first home is the program's start (not planned); then via, approach, return via, home
    assert times == [None, "1.500", "2.250", "0.750", "1.001"]
