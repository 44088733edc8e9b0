from __future__ import annotations

import dataclasses
import logging
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.errors import InputError
from refine.export.krl import KrlPass, kuka_status_turn, parse_krl, write_krl
from refine.export.rapid import abb_confdata, segment_speeds
from refine.frames import (
    invert_transform,
    kuka_abc_from_matrix,
    make_transform,
    matrix_from_kuka_abc,
    matrix_from_zyx,
    rotvec_from_matrix,
    transform_from_xyz_rpy,
)
from refine.paths import Trajectory
from refine.problem import CadSettings, DemoSettings, Problem, ProcessSettings, RobotSettings, ToolSettings
from refine.robot.model import Robot
from refine.robot.registry import load_robot

IIWA = "kuka_iiwa14_r820"


@pytest.fixture(scope="module")
def iiwa():
    return load_robot(IIWA)


@pytest.fixture(scope="module")
def iiwa_problem() -> Problem:
    return Problem(
        name="tig seam-2",
        root=Path("."),
        robot=RobotSettings(
            model=IIWA, base_in_world=transform_from_xyz_rpy([0.3, -0.2, 0.75], [0.0, 0.0, -40.0])
        ),
        tool=ToolSettings(
            name="tig torch",
            tcp_in_flange=transform_from_xyz_rpy([0.0, 0.015, 0.21], [0.0, 25.0, 0.0]),
            mass_kg=2.5,
            cog_in_flange_m=(0.0, 0.005, 0.09),
        ),
        cad=CadSettings(file=Path("seam.csv")),
        demonstration=DemoSettings(file=Path("demo.txt")),
        process=ProcessSettings(kind="weld", output="doArc"),
    )


def make_trajectory(robot, problem, n, q0_deg, q1_deg, speed=(0.008, 0.004)) -> Trajectory:
    """A smooth joint path from q0 to q1 [deg]; poses by the robot's FK in the world frame."""
    u = np.linspace(0.0, 1.0, n)[:, None]
    q = np.radians(q0_deg) + np.radians(np.subtract(q1_deg, q0_deg)) * u + 0.03 * np.sin(3.0 * np.pi * u)
    poses = np.array([problem.robot.base_in_world @ robot.fk(qk) @ problem.tool.tcp_in_flange for qk in q])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))])
    v = speed[0] + speed[1] * np.sin(2.0 * np.pi * u[:, 0])
    t = np.concatenate([[0.0], np.cumsum(np.diff(s) / (0.5 * (v[1:] + v[:-1])))])
    return Trajectory(t, s, q, poses[:, :3, 3].copy(), poses, poses[:, :3, :3].copy(), v)


Q0, Q1 = [-30.0, 35.0, -40.0, -75.0, 20.0, 60.0, -10.0], [25.0, 55.0, 30.0, -40.0, -35.0, -20.0, 80.0]


@pytest.fixture(scope="module")
def seam(iiwa, iiwa_problem) -> Trajectory:
    return make_trajectory(iiwa, iiwa_problem, 50, Q0, Q1)


@pytest.fixture(scope="module")
def program(tmp_path_factory, seam, iiwa_problem, iiwa):
    return write_krl(tmp_path_factory.mktemp("krl") / "tig seam-2.src", seam, iiwa_problem, iiwa)


def _rotation_error(R_a, R_b) -> float:
    return float(np.linalg.norm(rotvec_from_matrix(np.swapaxes(R_a, -1, -2) @ R_b), axis=-1).max())


def test_files_are_named_after_the_krl_program(program):
    src, dat = program
    assert (src.name, dat.name) == ("tig_seam_2.src", "tig_seam_2.dat")
    assert "DEF tig_seam_2( )" in src.read_text() and "DEFDAT tig_seam_2" in dat.read_text()


def test_round_trip_recovers_every_pose(program, seam):
    (run,) = parse_krl(*program)
    assert isinstance(run, KrlPass) and len(run.points) == len(seam)
    np.testing.assert_allclose(run.positions, seam.poses[:, :3, 3], rtol=0, atol=1e-6)
    assert _rotation_error(run.rotations, seam.poses[:, :3, :3]) < 1e-6


def test_speeds_are_the_segment_speeds_to_the_written_resolution(program, seam):
    (run,) = parse_krl(*program)
    assert run.speeds[0] == pytest.approx(0.25)  # the approach onto the first point
    np.testing.assert_allclose(run.speeds[1:], segment_speeds(seam), rtol=0, atol=0.5e-4 + 1e-12)
    vel = [float(v) for v in re.findall(r"^\s*\$VEL\.CP = (\S+)$", program[0].read_text(), re.M)]
    assert all(a != b for a, b in zip(vel, vel[1:], strict=False)), "$VEL.CP rewritten without a change"


def test_a_constant_speed_sets_vel_cp_once_on_the_seam(tmp_path, iiwa, iiwa_problem):
    tr = make_trajectory(iiwa, iiwa_problem, 12, Q0, Q1, speed=(0.006, 0.0))
    src, _ = write_krl(tmp_path / "c.src", tr, iiwa_problem, iiwa)
    assert re.findall(r"\$VEL\.CP = (\S+)", src.read_text()) == ["0.25", "0.006", "0.25"]


def test_status_turn_and_e1_written_are_those_of_the_refined_joints(program, seam, iiwa):
    (run,) = parse_krl(*program)
    status, turn = kuka_status_turn(iiwa, seam.q)
    np.testing.assert_array_equal(run.status, status)
    np.testing.assert_array_equal(run.turn, turn)
    np.testing.assert_array_equal(run.status, [_lbr_status(iiwa, q) for q in seam.q])
    np.testing.assert_allclose(run.e1_deg, np.degrees(seam.q[:, 2]), atol=1e-6)
    assert len(set(run.turn)) > 1, "the seam should cross axis sign changes"


def test_a_status_change_along_a_pass_is_reported_as_a_singularity(
    tmp_path, seam, iiwa_problem, iiwa, caplog
):
    """A LIN motion keeps its start Status; the seam's A6 crosses 0 (a wrist singularity) mid-pass."""
    with caplog.at_level(logging.WARNING, logger="refine.export.krl"):
        write_krl(tmp_path / "w.src", seam, iiwa_problem, iiwa)
    assert "Status changes along a LIN pass ([2, 6])" in caplog.text
    caplog.clear()
    calm = make_trajectory(iiwa, iiwa_problem, 10, Q0, np.add(Q0, 10.0))
    with caplog.at_level(logging.WARNING, logger="refine.export.krl"):
        write_krl(tmp_path / "c.src", calm, iiwa_problem, iiwa)
    assert "Status changes" not in caplog.text


def test_tool_base_and_points_chain_to_the_flange_pose(program, seam, iiwa_problem, iiwa):
    """$BASE · E6POS == base-frame TCP == fk(q) · $TOOL, both frames as the .dat says to calibrate them."""
    src, dat = program
    frames = {
        m[0]: _frame(m[1])
        for m in re.findall(r"; ((?:TOOL|BASE)_DATA\[\d+\]) .*must be \{([^}]*)\}", dat.read_text())
    }
    text = src.read_text()
    tool = frames[re.search(r"\$TOOL = (\w+\[\d+\])", text)[1]]
    base = frames[re.search(r"\$BASE = (\w+\[\d+\])", text)[1]]
    np.testing.assert_allclose(tool, iiwa_problem.tool.tcp_in_flange, atol=1e-6)
    np.testing.assert_allclose(base, invert_transform(iiwa_problem.robot.base_in_world), atol=1e-6)
    (run,) = parse_krl(src, dat)
    for k in (0, len(seam) // 2, len(seam) - 1):
        T = base @ make_transform(run.rotations[k], run.positions[k])
        np.testing.assert_allclose(T, iiwa.fk(seam.q[k]) @ tool, atol=2e-6)


def test_program_is_structurally_sane(program, seam):
    src, dat = program
    code = [ln.strip() for ln in src.read_text().splitlines() if ln.strip()]
    assert code[:2] == ["&ACCESS RVP", "&REL 1"] and code[-1] == "END"
    assert sum(ln.startswith("DEF ") for ln in code) == 1 and sum(ln == "END" for ln in code) == 1
    depth = 0
    for ln in code:
        depth += ln.upper().startswith(";FOLD") - ln.upper().startswith(";ENDFOLD")
        assert depth >= 0
    assert depth == 0
    dat_lines = [ln.strip() for ln in dat.read_text().splitlines() if ln.strip()]
    assert dat_lines[2].startswith("DEFDAT ") and dat_lines[-1] == "ENDDAT"
    declared = re.findall(r"^DECL E6POS (\w+)=", dat.read_text(), re.M)
    used = re.findall(r"^\s*(?:PTP|LIN) (\w+)", src.read_text(), re.M)
    assert used[0] == used[-1] == "XHOMEPOS" and "DECL E6AXIS XHOMEPOS={A1 " in dat.read_text()
    used = used[1:-1]
    assert len(declared) == len(set(declared)) == len(seam) + 2
    assert set(used) == set(declared) and len(used) == len(declared)
    lin = re.findall(r"^\s*LIN (XP\d+)( C_DIS)?$", src.read_text(), re.M)
    assert [bool(c) for _, c in lin] == [False] + [True] * (len(seam) - 2) + [False]
    body = src.read_text()
    assert body.index("LIN XP1\n") < body.index("$OUT[1]=TRUE") < body.index("LIN XP2 ")
    assert (
        body.index(f"LIN XP{len(seam)}\n") < body.index("$OUT[1]=FALSE ; arc off") < body.index("LIN XRET1")
    )
    assert "doArc" in body and "mapped to $OUT[1]" in body


@pytest.mark.parametrize(("output", "number"), [("$OUT[12]", 12), ("$out[ 7 ]", 7), ("33", 33), ("doArc", 1)])
def test_process_output_maps_to_an_out_number(tmp_path, seam, iiwa_problem, iiwa, output, number):
    problem = dataclasses.replace(iiwa_problem, process=ProcessSettings(kind="weld", output=output))
    (run,) = parse_krl(*write_krl(tmp_path / "o.src", seam, problem, iiwa))
    assert run.output == number


def test_rejects_a_bad_output_and_a_non_kuka_robot(tmp_path, seam, iiwa_problem, iiwa):
    problem = dataclasses.replace(iiwa_problem, process=ProcessSettings(output="$OUT[0]"))
    with pytest.raises(InputError, match=r"\$OUT"):
        write_krl(tmp_path / "x.src", seam, problem, iiwa)
    with pytest.raises(InputError, match="KUKA"):
        write_krl(tmp_path / "x.src", seam, iiwa_problem, load_robot("ur10e"))


def test_three_passes_make_three_folds_read_back_as_three_passes(tmp_path, iiwa, iiwa_problem):
    runs = [
        (f"layer {i}", make_trajectory(iiwa, iiwa_problem, 10 + 3 * i, Q0, np.add(Q1, 4.0 * i)))
        for i in range(1, 4)
    ]
    src, dat = write_krl(tmp_path / "multi.src", runs[0][1], iiwa_problem, iiwa, passes=runs)
    text = src.read_text()
    assert [int(m) for m in re.findall(r"^;FOLD pass (\d) of 3", text, re.M)] == [1, 2, 3]
    assert len(re.findall(r"^;ENDFOLD$", text, re.M)) == 3
    parsed = parse_krl(src, dat)
    assert [p.name for p in parsed] == ["layer 1", "layer 2", "layer 3"]
    for p, (_, tr) in zip(parsed, runs, strict=True):
        assert len(p.points) == len(tr)
        np.testing.assert_allclose(p.positions, tr.poses[:, :3, 3], rtol=0, atol=1e-6)
        assert _rotation_error(p.rotations, tr.poses[:, :3, :3]) < 1e-6


# ---- Status and Turn --------------------------------------------------------------------------


def _lbr_status(robot, q) -> int:
    """Independent LBR rule: wrist root (link_6 origin) behind x of link_1; A4 < 0; A6 <= 0."""
    links = robot.link_poses(q)
    wrist_in_a1 = invert_transform(links["link_1"]) @ links["link_6"][:, 3]
    return (wrist_in_a1[0] < 0.0) + 2 * (q[3] < 0.0) + 4 * (q[5] <= 0.0)


def _turn(q) -> int:
    return sum(2**i for i, angle in enumerate(q) if angle < 0.0)


LBR_ANCHORS = [  # joints [deg] -> Status from the arm's shape
    ([0, 60, 0, 30, 0, 45, 0], 0),  # leaning forward, forearm up and forward: basic area
    ([0, 30, 0, -60, 0, 45, 0], 2),  # forearm bent the other way (A4 < 0), still in front
    ([0, 30, 0, 100, 0, 10, 0], 1),  # A2 > 0 but the forearm folds back over the base: overhead
    ([90, -30, 0, 20, 0, 10, 0], 1),  # leaning back: overhead, whatever A1
    ([0, 30, 0, -60, 0, -45, 0], 6),  # A4 < 0 and A6 < 0
]


@pytest.mark.parametrize(("q_deg", "status"), LBR_ANCHORS)
def test_lbr_status_of_known_arm_shapes(iiwa, q_deg, status):
    s, t = kuka_status_turn(iiwa, np.radians(q_deg))
    assert s == status and t == _turn(np.radians(q_deg))


@pytest.mark.parametrize("tiny", [-1e-22, 1e-22, -1e-12, 0.0])
def test_a_joint_held_at_zero_has_turn_bit_0_whatever_the_sign_of_its_rounding(iiwa, tiny):
    """KUKA: T bit i = 0 when A(i+1) >= 0. A seventh axis at +-1e-22 rad is at zero: bit 6 clear;
    at -1e-6 rad (5.7e-5 deg, still printed as 0.0001 deg) it is negative: bit 6 set."""
    q = np.radians([10.0, 30.0, -5.0, -60.0, 20.0, 45.0, 0.0])  # A3, A4 < 0: bits 2 and 3
    q[6] = tiny
    assert kuka_status_turn(iiwa, q)[1] == 4 + 8
    q[6] = -1e-6
    assert kuka_status_turn(iiwa, q)[1] == 4 + 8 + 64


def test_lbr_status_and_turn_on_random_configurations(iiwa):
    rng = np.random.default_rng(3)
    q = rng.uniform(iiwa.spec.lower, iiwa.spec.upper, size=(600, 7))
    status, turn = kuka_status_turn(iiwa, q)
    assert status.shape == turn.shape == (600,)
    for k in range(len(q)):
        assert status[k] == _lbr_status(iiwa, q[k]) and turn[k] == _turn(q[k])
    assert set(status) == set(range(8)), "every overhead/elbow/wrist combination is covered"
    assert set(turn & 1) == {0, 1} and set(turn >> 6) == {0, 1}


def test_six_axis_status_follows_the_kuka_rule(irb4600):
    """On a 6-axis arm: bit 0 overhead, bit 1 wrist in front of the A2-A3 line, bit 2 A5 < 0.

    Cross-checked two ways: a plane computation in the frame of link 1, and ABB's cfx of the same
    geometry (front of axis 1 / front of the lower arm / A5 sign) with bit 1 inverted.
    """
    rng = np.random.default_rng(11)
    q = rng.uniform(irb4600.spec.lower, irb4600.spec.upper, size=(400, 6))
    q[0] = np.radians([0, 0, 0, 0, 30, 0])  # upper arm up, forearm forward: KUKA's usual S 2
    q[1] = np.radians([0, 0, 0, 0, -30, 0])  # the same with A5 < 0: S 6
    status, turn = kuka_status_turn(irb4600, q)
    assert (status[0], status[1]) == (2, 6)
    cfx = abb_confdata(irb4600, q)[:, 3]
    for k in range(len(q)):
        links = irb4600.link_poses(q[k])
        to_a1 = invert_transform(links["link_1"])
        p2, p3, w = ((to_a1 @ links[name][:, 3])[:3] for name in ("link_2", "link_3", "link_5"))
        u, d = p3 - p2, w - p2
        front = u[2] * d[0] - u[0] * d[2] > 0.0  # y-component of u x d, y of the A1 frame
        assert status[k] == (w[0] < 0.0) + 2 * front + 4 * (q[k, 4] < 0.0)
        assert status[k] == cfx[k] // 4 + 2 * (1 - (cfx[k] // 2) % 2) + 4 * (cfx[k] % 2)
        assert turn[k] == _turn(q[k])
    assert set(status) == set(range(8))


def test_a_six_axis_kuka_program_writes_no_redundancy(tmp_path, irb4600, problem, trajectory):
    kuka6 = Robot(dataclasses.replace(irb4600.spec, controller="kuka"), irb4600.model)
    (run,) = parse_krl(*write_krl(tmp_path / "six.src", trajectory, problem, kuka6))
    np.testing.assert_array_equal(run.e1_deg, 0.0)
    np.testing.assert_array_equal(run.status, kuka_status_turn(irb4600, trajectory.q)[0])


# ---- A, B, C ------------------------------------------------------------------------------------


def _frame(body: str):
    v = dict(item.split() for item in body.split(","))
    abc = [float(v[k]) for k in "ABC"]
    return make_transform(matrix_from_kuka_abc(abc), np.array([float(v[k]) for k in "XYZ"]) / 1000.0)


def test_abc_match_frames_and_scipy_on_10000_rotations_with_gimbal_lock(tmp_path, iiwa, iiwa_problem):
    rng = np.random.default_rng(5)
    R = Rotation.random(10_000, random_state=6).as_matrix()
    locked = rng.choice([-90.0, 90.0, 90.0 - 1e-4, -90.0 + 1e-7], size=500)
    R[:500] = matrix_from_zyx(*np.radians([rng.uniform(-180, 180, 500), locked, rng.uniform(-180, 180, 500)]))
    n = len(R)
    poses = make_transform(R, rng.uniform(-1.0, 1.0, (n, 3)))
    q = rng.uniform(iiwa.spec.lower, iiwa.spec.upper, size=(n, 7))
    tr = Trajectory(
        np.arange(n, dtype=float), np.arange(n, dtype=float), q, poses[:, :3, 3], poses, R, np.full(n, 0.01)
    )
    src, dat = write_krl(tmp_path / "abc.src", tr, iiwa_problem, iiwa)
    written = np.array(
        [
            [float(x) for x in m]
            for m in re.findall(r"DECL E6POS XP\d+=\{[^}]*?A (\S+),B (\S+),C (\S+),", dat.read_text())
        ]
    )
    diff = (written - kuka_abc_from_matrix(R) + 180.0) % 360.0 - 180.0
    assert np.abs(diff).max() < 1e-6
    assert np.all(np.abs(written[:, 1]) <= 90.0)
    exact = np.abs(locked) == 90.0
    assert exact.sum() > 100 and np.all(np.abs(written[:500][exact, 1]) == 90.0)
    assert np.all(written[:500][exact, 2] == 0.0), "at gimbal lock C is 0 and A carries the rotation"
    assert _rotation_error(Rotation.from_euler("ZYX", written, degrees=True).as_matrix(), R) < 1e-6
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # scipy warns at gimbal lock and zeroes C too
        ref = Rotation.from_matrix(R).as_euler("ZYX", degrees=True)
    regular = np.abs(ref[:, 1]) < 89.99
    assert regular.sum() > 9_000
    assert np.abs((written - ref + 180.0) % 360.0 - 180.0)[regular].max() < 1e-5
    (run,) = parse_krl(src, dat)
    np.testing.assert_allclose(run.positions, poses[:, :3, 3], rtol=0, atol=1e-6)
    assert _rotation_error(run.rotations, R) < 1e-6
