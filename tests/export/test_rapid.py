from __future__ import annotations

import math
import re

import numpy as np
import pytest

from refine.errors import InputError
from refine.export.rapid import abb_confdata, parse_rapid_targets, segment_speeds, write_rapid
from refine.frames import invert_transform, make_transform, matrix_from_quaternion, rotvec_from_matrix


@pytest.fixture()
def module(tmp_path, trajectory, problem, irb4600):
    return write_rapid(tmp_path / "bead.mod", trajectory, problem, irb4600)


def test_round_trip_recovers_positions_and_orientations(module, trajectory):
    positions, quats, _, _ = parse_rapid_targets(module)
    np.testing.assert_allclose(positions, trajectory.poses[:, :3, 3], rtol=0, atol=1e-6)
    R = matrix_from_quaternion(quats)
    R_rel = np.swapaxes(R, -1, -2) @ trajectory.poses[:, :3, :3]
    assert np.linalg.norm(rotvec_from_matrix(R_rel), axis=1).max() < 1e-6
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-8)
    assert np.all(np.sum(quats[1:] * quats[:-1], axis=1) > 0.0), "quaternion signs jump"


def test_each_target_is_reached_at_a_few_speed_levels_never_above_its_planned_speed(module, trajectory, problem):
    _, _, _, speeds = parse_rapid_targets(module)
    assert speeds[0] == pytest.approx(0.25)  # the approach onto the first target
    planned = segment_speeds(trajectory)
    share = problem.output.speed_share
    assert np.all(speeds[1:] <= planned + 1e-12)
    assert np.all(speeds[1:] >= 0.8 * planned), "a level far below the planned speed"
    assert np.all(speeds[1:] >= (1.0 - share) * planned - 1e-12), "a segment below the speed share"
    # levels a factor (1 - share) apart cover the planned speeds with this many; no more are written
    geometric = math.ceil(math.log(planned.max() / planned.min()) / -math.log(1.0 - share)) + 1
    written = len(re.findall(r"speeddata vPath", module.read_text()))
    assert len(set(speeds[1:].tolist())) == written <= max(problem.output.speed_levels, geometric)


def test_written_confdata_is_that_of_the_refined_joints(module, trajectory, irb4600):
    _, _, confs, _ = parse_rapid_targets(module)
    np.testing.assert_array_equal(confs, abb_confdata(irb4600, trajectory.q))


def test_targets_are_tcp_poses_in_the_world_through_wobj_and_tool(module, trajectory, problem, irb4600):
    """uframe · target == base-frame TCP pose == fk(q) · tooldata, for every waypoint."""
    text = module.read_text()
    nums = r"\[([^\]]*)\]"
    uf = re.search(rf"wobjdata \w+:=\[FALSE,TRUE,\"\",\[{nums},{nums}\]", text)
    T_base_world = make_transform(
        matrix_from_quaternion([float(v) for v in uf[2].split(",")]),
        np.array([float(v) for v in uf[1].split(",")]) / 1000.0,
    )
    np.testing.assert_allclose(T_base_world, invert_transform(problem.robot.base_in_world), atol=1e-7)
    positions, quats, _, _ = parse_rapid_targets(module)
    for k in (0, len(trajectory) // 2, len(trajectory) - 1):
        T_target = make_transform(matrix_from_quaternion(quats[k]), positions[k])
        expected = irb4600.fk(trajectory.q[k]) @ problem.tool.tcp_in_flange
        np.testing.assert_allclose(T_base_world @ T_target, expected, atol=1e-6)


def test_module_is_syntactically_sane(module, trajectory, problem):
    text = module.read_text()
    lines = [ln.strip() for ln in text.splitlines()]
    assert lines[0].startswith("MODULE ") and lines[-1] == "ENDMODULE"
    assert sum(ln.startswith("MODULE ") for ln in lines) == 1
    procs = [ln for ln in lines if ln.startswith("PROC ")]
    assert len(procs) == sum(ln == "ENDPROC" for ln in lines) >= 2
    code = [ln for ln in lines if ln and not ln.startswith("!")]
    assert all(
        ln.split("!")[0].strip().endswith(";")
        for ln in code
        if not ln.startswith(("MODULE", "ENDMODULE", "PROC", "ENDPROC"))
    )
    assert all(ln.count("[") == ln.count("]") and ln.count("(") == ln.count(")") for ln in code)
    targets = re.findall(r"CONST robtarget (\w+):=", text)
    assert len(targets) == len(trajectory) == len(set(targets))
    body = text.split("PROC main()")[1]
    for name in targets:
        assert re.search(rf"\b{name}\b", body), f"robtarget {name} never used"
    moves = re.findall(r"^\s*(?:MoveL|TriggL) (p\d+), \w+, (?:trO\w+, )?(\w+),", body, re.M)
    assert [m[0] for m in moves] == targets
    # a glue path flies through, also at its ends: z1, or z0 where z1 would cut a corner by more
    # than the path tolerance (the turn from the approach onto the path)
    assert {m[1] for m in moves} <= {"z1", "z0"} and moves[len(moves) // 2][1] == "z1"
    main = body.split("ENDPROC")[0]
    assert main.count("MoveAbsJ jHome") == 2 and "CONST jointtarget jHome:=" in text
    on = f"TriggIO trOn, 0 \\Time \\DOp:={problem.process.output}, 1;"
    assert main.index(on) < main.index(f"TriggL {targets[0]}, vAir, trOn,")
    assert "SetDO" not in body
    assert "PERS tooldata glue_gun:=[TRUE,[[10,0,220]," in text
    assert "[4.5,[0,10,80],[1,0,0,0],0,0,0]]" in text


# ---- configuration data ------------------------------------------------------------------------


def _quadrant(deg: float) -> int:
    """ABB quadrant by the manual's wording: 0 for [0, 90), -1 for [-90, 0), 1 for [90, 180)..."""
    k = 0
    while deg >= 90.0 * (k + 1):
        k += 1
    while deg < 90.0 * k:
        k -= 1
    return k


def _expected_cfx(robot, q) -> int:
    """Independent geometry: the arm plane seen in the frame of link 1 (x forward, z up)."""
    links = robot.link_poses(q)
    to_link1 = invert_transform(links["link_1"])
    p2, p3, wrist = ((to_link1 @ links[name][:, 3])[:3] for name in ("link_2", "link_3", "link_5"))
    arm, w = p3 - p2, wrist - p2
    behind_axis1 = wrist[0] < 0.0
    behind_lower_arm = arm[2] * w[0] - arm[0] * w[2] < 0.0
    return 4 * behind_axis1 + 2 * behind_lower_arm + (q[4] < 0.0)


ANCHORS = [  # joints [deg] -> cfx known from the arm's shape
    ([0, 0, 0, 0, 0, 0], 0),  # arm out front, wrist straight: front/front/positive
    ([0, 0, 0, 0, -30, 0], 1),  # same arm, wrist bent the other way
    ([0, 0, -120, 0, 30, 0], 6),  # forearm folded back over the top: behind axis 1 and lower arm
    ([0, 60, -100, 0, -30, 0], 3),  # lower arm leaning forward, forearm up and back
    ([0, -80, 20, 0, 30, 0], 4),  # lower arm leaning back, forearm level: behind axis 1 only
]


@pytest.mark.parametrize(("q_deg", "cfx"), ANCHORS)
def test_cfx_of_known_arm_shapes(irb4600, q_deg, cfx):
    assert abb_confdata(irb4600, np.radians(q_deg))[3] == cfx


def test_confdata_spans_quadrants_and_both_wrist_signs(irb4600):
    rng = np.random.default_rng(7)
    lo, hi = irb4600.spec.lower, irb4600.spec.upper
    q = rng.uniform(lo, hi, size=(400, 6))
    q[:8, [0, 3, 5]] = np.radians(
        [
            [-179, -391, 355],
            [-91, -269, -181],
            [-90, -90, -90],
            [-45, -1, -0.5],
            [0, 0, 0],
            [45, 89.9, 90],
            [120, 181, 270],
            [179.9, 399, 399],
        ]
    )
    conf = abb_confdata(irb4600, q)
    deg = np.degrees(q)
    for k in range(len(q)):
        assert list(conf[k, :3]) == [_quadrant(deg[k, j]) for j in (0, 3, 5)]
        assert conf[k, 3] == _expected_cfx(irb4600, q[k])
    assert set(conf[:, 3] % 2) == {0, 1}  # both signs of axis 5
    assert {-2, -1, 0, 1} <= set(conf[:, 0])
    assert conf[:, 1].min() <= -4 and conf[:, 1].max() >= 3
    assert len(set(conf[:, 3])) >= 4


def test_single_and_many_configurations_agree(irb4600, trajectory):
    many = abb_confdata(irb4600, trajectory.q[:5])
    assert all(
        list(abb_confdata(irb4600, qk)) == list(row) for qk, row in zip(trajectory.q[:5], many, strict=True)
    )


def test_rejects_a_bad_zone(tmp_path, trajectory, problem, irb4600):
    with pytest.raises(InputError, match="zone"):
        write_rapid(tmp_path / "x.mod", trajectory, problem, irb4600, zone="zz")


def test_the_run_s_planned_air_moves_are_written_as_joint_targets_with_exact_stops(
    tmp_path, trajectory, problem, irb4600
):
    """Via points and approach joints of the home move, via points of the return, in order, exact."""
    air_in = np.radians([[10.0, 5.0, 0.0, 0.0, 30.0, 0.0], [20.0, 10.0, 5.0, 0.0, 40.0, 0.0], [-19.5, 9.0, -14.0, 39.0, 49.0, -59.0]])
    air_out = np.radians([[30.0, -5.0, 10.0, 0.0, 45.0, 10.0], [0.0, 0.0, 0.0, 0.0, 30.0, 0.0]])
    text = write_rapid(
        tmp_path / "air.mod", trajectory, problem, irb4600, air_in=air_in, air_out=air_out
    ).read_text()
    decl = {
        m[1]: np.array([float(v) for v in m[2].split(",")])
        for m in re.finditer(r"CONST jointtarget (\w+):=\[\[([^\]]*)\]", text)
    }
    main = text.split("PROC main()")[1].split("ENDPROC")[0]
    order = re.findall(r"MoveAbsJ (\w+)\\NoEOffs, vAir, (\w+),", main)
    assert [name for name, _ in order] == ["jHome", "jIn1", "jIn2", "jIn3", "jOut1", "jHome"]
    assert all(zone == "fine" for _, zone in order)
    for k, q in enumerate(air_in, start=1):
        np.testing.assert_allclose(decl[f"jIn{k}"], np.degrees(q), atol=1e-4)
    np.testing.assert_allclose(decl["jOut1"], np.degrees(air_out[0]), atol=1e-4)
    assert "MoveJ RelTool" not in main  # the approach point is the planned joint target
    lines = [ln.strip() for ln in main.splitlines() if ln.strip()]
    at = lines.index(next(ln for ln in lines if ln.startswith("MoveAbsJ jIn3")))
    assert lines[at + 3].startswith("TriggL p0000, vAir, trOn")  # then the straight line onto the first target
    assert re.search(r"MoveL RelTool\(p\d+, 0, 0, -100\), vAir, fine,", main)  # the retract, exact


def test_a_later_pass_s_module_starts_with_the_planned_link_not_at_home(tmp_path, trajectory, problem, irb4600):
    link = np.radians([[5.0, 5.0, 0.0, 0.0, 30.0, 0.0], [-19.5, 9.0, -14.0, 39.0, 49.0, -59.0]])
    text = write_rapid(
        tmp_path / "p2.mod", trajectory, problem, irb4600, air_in=link, start_home=False, end_home=False
    ).read_text()
    main = text.split("PROC main()")[1].split("ENDPROC")[0]
    assert re.findall(r"MoveAbsJ (\w+)\\NoEOffs", main) == ["jIn1", "jIn2"]


def test_each_planned_air_move_runs_in_its_planned_time(tmp_path, trajectory, problem, irb4600):
    """``MoveAbsJ`` through a planned move carries each move's time (``\\T``, rounded up to 1 ms)."""
    air_in = np.radians([[10.0, 5.0, 0.0, 0.0, 30.0, 0.0], [-19.5, 9.0, -14.0, 39.0, 49.0, -59.0]])
    air_out = np.radians([[30.0, -5.0, 10.0, 0.0, 45.0, 10.0], [0.0, 0.0, 0.0, 0.0, 30.0, 0.0]])
    text = write_rapid(
        tmp_path / "timed.mod",
        trajectory,
        problem,
        irb4600,
        air_in=air_in,
        air_out=air_out,
        air_in_s=(1.25, 2.0001),
        air_out_s=(0.5, 3.0),
    ).read_text()
    main = text.split("PROC main()")[1].split("ENDPROC")[0]
    timed = re.findall(r"MoveAbsJ (\w+)\\NoEOffs, vAir(?:\\T:=([0-9.]+))?, fine,", main)
    # the first move home is where the program starts from: not a planned move, at vAir
    assert timed == [("jHome", ""), ("jIn1", "1.250"), ("jIn2", "2.001"), ("jOut1", "0.500"), ("jHome", "3.000")]
