"""A stationary tool: the robot holds the part, the TCP stands in the world; poses and Jacobians in the part's frame."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from refine.frames import make_transform, matrix_from_fixed_xyz
from refine.robot.kinematics import TcpKinematics, solve_ik
from refine.robot.registry import load_robot

PART_IN_FLANGE = make_transform(matrix_from_fixed_xyz([30.0, -20.0, 10.0], degrees=True), [0.05, -0.02, 0.15])
TOOL_IN_WORLD = make_transform(matrix_from_fixed_xyz([180.0, 0.0, 45.0], degrees=True), [1.2, 0.3, 0.9])
BASE = make_transform(matrix_from_fixed_xyz([0.0, 0.0, 20.0], degrees=True), [0.1, -0.2, 0.0])


@pytest.fixture(scope="module")
def kin():
    return TcpKinematics(load_robot("abb_irb4600_60_205"), BASE, PART_IN_FLANGE, TOOL_IN_WORLD)


Q = np.array([0.2, 0.3, -0.1, 0.7, 0.9, -0.4])


def test_the_pose_is_the_tool_seen_from_the_part(kin):
    held = TcpKinematics(kin.robot, BASE, PART_IN_FLANGE)  # the part's frame in the world, as a TCP
    expected = np.linalg.inv(held.pose(Q)) @ TOOL_IN_WORLD
    assert kin.pose(Q) == pytest.approx(expected, abs=1e-12)
    qs = np.array([Q, -Q, 0.5 * Q])
    assert kin.poses(qs) == pytest.approx(np.array([np.linalg.inv(held.pose(q)) @ TOOL_IN_WORLD for q in qs]))


def test_the_jacobian_is_the_derivative_of_that_pose_in_the_part_frame(kin):
    h = 1e-6
    numeric = np.empty((6, 6))
    for k in range(6):
        dq = np.zeros(6)
        dq[k] = h
        Tp, Tm = kin.pose(Q + dq), kin.pose(Q - dq)
        numeric[:3, k] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
        numeric[3:, k] = pin.log3(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * h)
    assert kin.jacobian(Q) == pytest.approx(numeric, abs=1e-6)
    T, J = kin.pose_jacobian(Q)
    assert T == pytest.approx(kin.pose(Q)) and J == pytest.approx(numeric, abs=1e-6)
    p, R, Js = kin.batch(np.array([Q, Q]))
    assert p[1] == pytest.approx(T[:3, 3]) and R[0] == pytest.approx(T[:3, :3])
    assert Js[0] == pytest.approx(numeric, abs=1e-6)


def test_ik_brings_the_part_point_to_the_tool(kin):
    target = kin.pose(Q) @ make_transform(matrix_from_fixed_xyz([2.0, -3.0, 4.0], degrees=True), [0.01, -0.02, 0.015])
    spec = kin.robot.spec
    q, error = solve_ik(kin, target, Q, spec.lower, spec.upper)
    assert error < 1e-6
    # the point of the part at the target, carried by the robot, is where the tool stands
    held = TcpKinematics(kin.robot, BASE, PART_IN_FLANGE)
    assert (held.pose(q) @ target) == pytest.approx(TOOL_IN_WORLD, abs=1e-6)


def test_axis_only_ik_leaves_the_spin_free(kin):
    # a target turned 90 deg about its own z: the same tool axis and point, another spin
    spun = kin.pose(Q) @ make_transform(matrix_from_fixed_xyz([0.0, 0.0, 90.0], degrees=True), [0.0, 0.0, 0.0])
    spec = kin.robot.spec
    q, error = solve_ik(kin, spun, Q, spec.lower, spec.upper, axis_only=True)
    assert error < 1e-9  # nothing to do: the start already has that point and axis
    assert q == pytest.approx(Q, abs=1e-12)
    tilted = spun @ make_transform(matrix_from_fixed_xyz([4.0, -3.0, 0.0], degrees=True), [0.01, 0.0, -0.02])
    q, error = solve_ik(kin, tilted, Q, spec.lower, spec.upper, axis_only=True)
    reached = kin.pose(q)
    assert error < 1e-6
    assert reached[:3, 3] == pytest.approx(tilted[:3, 3], abs=1e-6)
    assert reached[:3, 2] == pytest.approx(tilted[:3, 2], abs=1e-6)
    # the spin kept is the start's (about 90 deg off the target's), not the target's
    assert abs(float(reached[:3, 0] @ tilted[:3, 0])) < 0.2


def test_the_symbolic_pose_is_the_part_seen_by_the_tool(kin):
    from refine.optimise.kinematics import fk_function

    p, R = fk_function(kin.robot, BASE, PART_IN_FLANGE, TOOL_IN_WORLD)(Q)
    T_world_part = BASE @ kin.robot.fk(Q) @ PART_IN_FLANGE  # by hand: base, flange, part
    expected = np.linalg.inv(T_world_part) @ TOOL_IN_WORLD
    assert np.array(R) == pytest.approx(expected[:3, :3], abs=1e-12)
    assert np.array(p).ravel() == pytest.approx(expected[:3, 3], abs=1e-12)


def test_the_refinement_puts_the_held_part_on_the_fixed_tool(kin):
    """Known part poses seen from the tool => known flange poses: T_F_flange = T_F_tool · T_part_tool⁻¹ · T_flange_part⁻¹.

    Exactly for the position of each path point (carried by the flange onto the tool's point), within
    the cone for the orientation (the answer trades the demonstrated orientation against smoothness).
    """
    from refine.optimise.problem import build_refinement
    from refine.optimise.solve import solve_refinement
    from refine.paths import FusedPath
    from refine.settings import Tolerances

    robot = kin.robot
    t = np.linspace(0.0, 1.0, 60)[:, None]
    qs = Q + 0.1 * np.sin(2 * np.pi * t * np.array([1.0, 0.5, 0.7, 0.3, 0.9, 0.4]))
    targets = kin.poses(qs)  # a path of the part the robot can follow
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(targets[:, :3, 3], axis=0), axis=1))]
    fused = FusedPath(s, targets[:, :3, 3], targets[:, :3, :3], np.full(60, 0.05), s / 0.05, np.zeros(60))
    nlp = build_refinement(
        robot, fused, BASE, PART_IN_FLANGE, Tolerances(), tool_in_world=TOOL_IN_WORLD, joint_steps=()
    )
    result = solve_refinement(nlp)
    assert result.status == "ok"
    cone = np.radians(Tolerances().orientation_deg)
    for q, T in zip(result.q, targets, strict=True):
        flange = BASE @ robot.fk(q)
        expected = TOOL_IN_WORLD @ np.linalg.inv(T) @ np.linalg.inv(PART_IN_FLANGE)
        point = PART_IN_FLANGE @ np.append(T[:3, 3], 1.0)  # the path point, in the flange frame
        assert (flange @ point)[:3] == pytest.approx((expected @ point)[:3], abs=1e-6)
        assert (flange @ point)[:3] == pytest.approx(TOOL_IN_WORLD[:3, 3], abs=1e-6)
        turn = np.arccos(np.clip((np.trace(flange[:3, :3].T @ expected[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
        assert turn <= cone + 1e-6


# ---- the problem file: [tool] tcp_in_world with part_in_flange


@pytest.fixture
def puzzle(tmp_path):
    import shutil
    from pathlib import Path

    folder = tmp_path / "puzzle_piece"
    shutil.copytree(Path(__file__).parent.parent / "problems" / "puzzle_piece", folder)
    return folder / "problem.toml"


def _edit(toml, old, new):
    text = toml.read_text()
    assert old in text
    toml.write_text(text.replace(old, new, 1))


def test_a_stationary_tool_is_read_with_the_held_part_as_the_flange_frame(puzzle):
    from refine.frames import transform_from_xyz_rpy
    from refine.problem import load_problem

    tool = load_problem(puzzle).tool
    assert tool.stationary
    # the example's grinder_frame: 0.1 m above (0.35, -0.35, 0.6), turned over about y
    assert tool.tcp_in_world[:3, 3] == pytest.approx([0.35, -0.35, 0.7])
    assert tool.tcp_in_world[:3, 2] == pytest.approx([0.0, 0.0, -1.0])
    part = transform_from_xyz_rpy([0.016887, 0.007326, 0.075648], [119.147590, 7.435636, -43.064335])
    assert tool.tcp_in_flange == pytest.approx(part)


@pytest.mark.parametrize(
    ("old", "new", "said"),
    [
        ("part_in_flange = {", "tcp_in_flange = {", "needs part_in_flange"),
        ('[frames]\n', None, None),
    ],
)
def test_a_stationary_tool_refuses_what_it_cannot_mean(puzzle, old, new, said):
    from refine.errors import InputError
    from refine.problem import load_problem

    if new is None:  # a CAD frame in the world: the path is in the held part's frame
        puzzle.write_text(
            puzzle.read_text() + '\n[frames]\ncad_in_world = { xyz = [0.1, 0.0, 0.0], rpy_deg = [0.0, 0.0, 0.0] }\n'
        )
        said = "cad_in_world"
    else:
        _edit(puzzle, old, new)
    with pytest.raises(InputError, match=said):
        load_problem(puzzle)


def test_a_tool_on_the_flange_takes_no_part_in_flange(puzzle):
    from refine.errors import InputError
    from refine.problem import load_problem

    _edit(puzzle, "tcp_in_world = {", "tcp_in_flange = {")
    with pytest.raises(InputError, match="part_in_flange is for a stationary tool"):
        load_problem(puzzle)


@pytest.mark.parametrize(
    ("kind", "said"),
    [
        ("sunrise", "workpiece"),
        ("urscript", "has no external-TCP"),
        ("tp", "remote TCP"),
        ("inform", "stationary-tool"),
    ],
)
def test_programs_are_refused_by_name_with_a_stationary_tool(kind, said):
    from refine.errors import InputError
    from refine.settings.stationary import check_stationary_programs

    with pytest.raises(InputError, match=f"program format '{kind}' with a stationary tool.*{said}.*are rapid, krl;"):
        check_stationary_programs(("rapid", kind))
    check_stationary_programs(("rapid", "krl"))


def test_the_run_refuses_the_robots_own_program_before_solving(puzzle):
    from refine.errors import InputError
    from refine.problem import load_problem
    from refine.run.preflight import preflight

    _edit(puzzle, "programs = []", 'programs = ["sunrise"]')
    with pytest.raises(InputError, match="'sunrise' with a stationary tool"):
        preflight(load_problem(puzzle))


def _held_part(tmp_path, model, part, tool_in_world, q0, output, n):
    """A problem with a stationary tool and a timed path of ``n`` points swept about ``q0``.

    The poses by hand: the part's frame in the world, then the standing tool seen from it.
    """
    from refine.paths import Trajectory
    from refine.problem import Problem
    from refine.settings import CadSettings, ProcessSettings, RobotSettings, ToolSettings

    robot = load_robot(model)
    problem = Problem(
        name="grind",
        root=tmp_path,
        robot=RobotSettings(model=model, base_in_world=BASE),
        tool=ToolSettings(name="grinder", tcp_in_flange=part, tcp_in_world=tool_in_world),
        cad=CadSettings(file=tmp_path / "path.csv", format="toolpath", speed_m_s=0.05),
        demonstration=None,
        process=ProcessSettings(kind="other", output=output),
    )
    t = np.linspace(0.0, 1.0, n)[:, None]
    qs = q0 + 0.1 * np.sin(2 * np.pi * t * np.array([1.0, 0.5, 0.7, 0.3, 0.9, 0.4]))
    poses = np.array([np.linalg.inv(BASE @ robot.fk(q) @ part) @ tool_in_world for q in qs])
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))]
    trajectory = Trajectory(
        t=s / 0.05, s=s, q=qs, positions_ref=poses[:, :3, 3], poses=poses, rotations_demo=poses[:, :3, :3],
        speed=np.full(n, 0.05),
    )
    return robot, problem, trajectory, qs


def test_rapid_writes_a_stationary_tcp_and_the_held_part_as_a_robot_held_work_object(tmp_path):
    """Re-read: fk(q) · wobj uframe · target == tooldata tframe (all in the base), at every target."""
    import re

    from refine.export.rapid import parse_rapid_targets, write_rapid
    from refine.frames import matrix_from_quaternion

    robot, problem, trajectory, qs = _held_part(
        tmp_path, "abb_irb4600_60_205", PART_IN_FLANGE, TOOL_IN_WORLD, Q, "doGrind", 30
    )
    module = write_rapid(tmp_path / "grind.mod", trajectory, problem, robot)
    text = module.read_text()
    nums = r"\[([^\]]*)\]"

    def pose(trans, quat):
        return make_transform(
            matrix_from_quaternion([float(v) for v in quat.split(",")]),
            np.array([float(v) for v in trans.split(",")]) / 1000.0,
        )

    tool = re.search(rf"PERS tooldata grinder:=\[FALSE,\[{nums},{nums}\]", text)
    wobj = re.search(rf"PERS wobjdata wobjPart:=\[TRUE,TRUE,\"\",\[{nums},{nums}\]", text)
    assert tool and wobj
    tframe, uframe = pose(tool[1], tool[2]), pose(wobj[1], wobj[2])
    positions, quats, _, _ = parse_rapid_targets(module)
    for k in range(len(qs)):
        target = make_transform(matrix_from_quaternion(quats[k]), positions[k])
        assert robot.fk(qs[k]) @ uframe @ target == pytest.approx(tframe, abs=1e-6)
    moves = [ln.strip() for ln in text.splitlines() if ln.strip().startswith(("MoveL", "MoveAbsJ", "TriggL"))]
    assert moves and all("\\WObj:=wobjPart" in m for m in moves)


@pytest.mark.slow
def test_a_held_part_on_a_standing_grinder_runs_end_to_end(tmp_path):
    """A toolpath in the part's frame, followed by an IRB 4600 holding the part: ok, timed relative to
    the part, and a RAPID module whose targets re-read against forward kinematics meet the toolpath."""
    import re

    import refine
    from refine.export.rapid import parse_rapid_targets
    from refine.frames import matrix_from_quaternion

    robot = load_robot("abb_irb4600_60_205")
    held = TcpKinematics(robot, np.eye(4), PART_IN_FLANGE, TOOL_IN_WORLD)
    t = np.linspace(0.0, 1.0, 40)[:, None]
    poses = held.poses(Q + 0.08 * np.sin(np.pi * t * np.array([1.0, 0.5, 0.7, 0.3, 0.9, 0.4])))
    rows = [f"{k + 1},{p[0] * 1e3:.6f},{p[1] * 1e3:.6f},{p[2] * 1e3:.6f},{a[0]:.9f},{a[1]:.9f},{a[2]:.9f}"
            for k, (p, a) in enumerate(zip(poses[:, :3, 3], poses[:, :3, 2], strict=True))]
    (tmp_path / "path.csv").write_text("\n".join(rows) + "\n")

    def pose(T):
        from refine.frames import fixed_xyz_from_matrix

        return f"{{ xyz = {list(map(float, T[:3, 3]))}, rpy_deg = {list(map(float, fixed_xyz_from_matrix(T[:3, :3])))} }}"

    (tmp_path / "problem.toml").write_text(
        f'''name = "held"
[robot]
model = "abb_irb4600_60_205"
[tool]
name = "grinder"
tcp_in_world = {pose(TOOL_IN_WORLD)}
part_in_flange = {pose(PART_IN_FLANGE)}
axisymmetric = true
[cad]
file = "path.csv"
format = "toolpath"
units = "mm"
spacing_m = 0.005
speed_m_s = 0.05
[process]
kind = "other"
output = "doGrind"
[output]
programs = ["rapid"]
'''
    )
    result = refine.solve(tmp_path)
    assert result.status == "ok"
    written = result.write(tmp_path / "out")
    module = next(p for p in written.values() if str(p).endswith(".mod"))
    text = module.read_text()
    nums = r"\[([^\]]*)\]"
    uf = re.search(rf"wobjdata wobjPart:=\[TRUE,TRUE,\"\",\[{nums},{nums}\]", text)
    uframe = make_transform(matrix_from_quaternion([float(v) for v in uf[2].split(",")]),
                            np.array([float(v) for v in uf[1].split(",")]) / 1e3)
    positions, quats, _, _ = parse_rapid_targets(module)
    trajectory = result.run.passes[0].trajectory
    q = trajectory.q
    # the speed is the part's past the tool: the toolpath's arc length over time, at most speed_m_s
    part_moves = np.linalg.norm(np.diff(held.poses(q)[:, :3, 3], axis=0), axis=1) / np.diff(trajectory.t)
    assert part_moves.max() <= 0.05 * 1.01 and np.median(part_moves) > 0.04
    for k in (0, len(q) // 2, len(q) - 1):
        target = make_transform(matrix_from_quaternion(quats[k]), positions[k])
        # the TCP's place in the world, by hand: base (identity), flange, part, target
        assert (robot.fk(q[k]) @ uframe @ target)[:3, 3] == pytest.approx(TOOL_IN_WORLD[:3, 3], abs=1e-5)
    # each target's position in the part lies on the toolpath's chords (resampled along them)
    a, b = poses[:-1, :3, 3], poses[1:, :3, 3]
    u = np.clip(np.einsum("mkj,kj->mk", positions[:, None] - a, b - a) / np.einsum("kj,kj->k", b - a, b - a), 0, 1)
    gaps = np.linalg.norm(positions[:, None] - (a + u[..., None] * (b - a)), axis=2).min(axis=1)
    assert gaps.max() < 1e-6


def test_krl_writes_an_external_tcp_the_standing_tool_as_base_and_the_part_as_tool(tmp_path):
    """Re-read: BASE_DATA · point == fk(q) · TOOL_DATA (all in the base), at every point."""
    import re

    from refine.export.krl import parse_krl, write_krl
    from refine.frames import matrix_from_kuka_abc

    part = make_transform(matrix_from_fixed_xyz([10.0, 20.0, -30.0], degrees=True), [0.02, 0.01, 0.12])
    tool_in_world = make_transform(matrix_from_fixed_xyz([170.0, 5.0, 0.0], degrees=True), [0.9, 0.2, 0.6])
    q0 = np.radians([10.0, -80.0, 90.0, 5.0, 40.0, 10.0])
    robot, problem, trajectory, qs = _held_part(tmp_path, "kuka_kr8_r1440_2_arc_hw", part, tool_in_world, q0, "3", 20)
    src, dat = write_krl(tmp_path / "grind.src", trajectory, problem, robot)
    assert "$IPO_MODE = #TCP" in src.read_text()
    text = dat.read_text()

    def frame(which):
        m = re.search(rf"; {which}\[1\] \([^)]*\) must be \{{X ([-\d.]+),Y ([-\d.]+),Z ([-\d.]+),A ([-\d.]+),B ([-\d.]+),C ([-\d.]+)\}}", text)
        v = [float(x) for x in m.groups()]
        return make_transform(matrix_from_kuka_abc(v[3:]), np.array(v[:3]) / 1e3)

    base_data, tool_data = frame("BASE_DATA"), frame("TOOL_DATA")
    (read,) = parse_krl(src, dat)
    for k in range(len(qs)):
        point = make_transform(read.rotations[k], read.positions[k])
        assert base_data @ point == pytest.approx(robot.fk(qs[k]) @ tool_data, abs=1e-5)


def test_the_puzzle_seed_turns_the_part_about_the_grinder_to_keep_the_elbow_in_range():
    """The toolpath's own spin would drive the iiwa's elbow into its limit; the chosen spins reach every point."""
    from pathlib import Path

    from refine.optimise.outcome import problem_bounds, problem_kinematics, problem_targets
    from refine.optimise.seed import initial_guess
    from refine.optimise.spin import path_spins, spun
    from refine.problem import load_problem
    from refine.robot.registry import robot_for
    from refine.run.stages import fused_path, refinement_for

    problem = load_problem(Path(__file__).parent.parent / "problems" / "puzzle_piece")
    robot = robot_for(problem.robot)
    nlp = refinement_for(problem, robot, fused_path(problem))
    q = initial_guess(nlp)
    reached, targets = problem_kinematics(nlp).poses(q), problem_targets(nlp)
    lower, upper = problem_bounds(nlp)
    assert np.abs(reached[:, :3, 3] - targets[:, :3, 3]).max() < 1e-5
    assert np.einsum("ki,ki->k", reached[:, :3, 2], targets[:, :3, 2]).min() > np.cos(np.radians(0.01))
    assert np.all((q >= lower - 1e-9) & (q <= upper + 1e-9))
    # the spins are a turn about each target's own axis: the axis and the point stay
    from refine.optimise.reach import reach_model

    spins = path_spins(reach_model(robot, np.radians(2.0)), targets, nlp.base_in_world, nlp.tcp_in_flange, nlp.tool_in_world)
    turned = spun(targets, spins)
    assert turned[:, :3, 2:] == pytest.approx(targets[:, :3, 2:], abs=1e-12)
    assert np.abs(spins).max() > 0.1  # the toolpath's own spin is not kept
