"""The peers of refine bench (TrajOpt, Descartes): their environment, their answers, their registration."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from refine.bench import contenders as contenders_module
from refine.bench.contenders import verify
from refine.bench.suites import generated_problem
from refine.robot.kinematics import TcpKinematics

WAVE = {"robot": "abb_irb4600_60_205", "centre_m": [1.3, 0.0, 0.6], "length_m": 0.2, "tool_length_m": 0.35}
POST = {"name": "post", "centre_m": [1.5, 0.0, 0.55], "size_m": [0.1, 0.12, 0.3]}


def test_the_peers_join_the_contenders_when_the_runner_loads():
    import refine.bench.runner  # noqa: F401

    assert contenders_module.CONTENDERS["trajopt"].__name__ == "trajopt"
    assert contenders_module.CONTENDERS["descartes"].__name__ == "descartes"


def test_the_composed_urdf_places_world_tcp_cell_and_narrows_the_limits(tmp_path):
    from refine.bench.peers import TCP, WORLD, compose_urdf

    problem = generated_problem("t", "wave_box", {**WAVE, "boxes": [POST]}, 5)
    text, pairs = compose_urdf(problem, tmp_path)
    root = ET.fromstring(text)
    joints = {j.get("name"): j for j in root.findall("joint")}
    tcp = next(j for j in joints.values() if j.find("child").get("link") == TCP)
    assert tcp.find("parent").get("link") == problem.robot.spec.flange_frame
    assert [float(v) for v in tcp.find("origin").get("xyz").split()] == pytest.approx([0.0, 0.0, 0.35])
    (post,) = [lk for lk in root.findall("link") if lk.get("name") == "cell_post"]
    assert [float(v) for v in post.find("collision/geometry/box").get("size").split()] == pytest.approx(
        [0.1, 0.12, 0.3]
    )
    post_joint = next(j for j in joints.values() if j.find("child").get("link") == "cell_post")
    assert post_joint.find("parent").get("link") == WORLD
    assert [float(v) for v in post_joint.find("origin").get("xyz").split()] == pytest.approx([1.5, 0.0, 0.55])
    # the limits: the robot's own URDF file, read here, less the 2 deg default margin
    original = ET.parse(problem.robot.spec.urdf).getroot()
    for name in problem.robot.spec.joint_names:
        before = next(j for j in original.findall("joint") if j.get("name") == name).find("limit")
        after = joints[name].find("limit")
        assert float(after.get("lower")) == pytest.approx(float(before.get("lower")) + math.radians(2.0))
        assert float(after.get("upper")) == pytest.approx(float(before.get("upper")) - math.radians(2.0))
    assert ("cell_post", "link_6") in pairs or ("cell_post", "link_5") in pairs


def test_tesseract_places_the_tcp_where_pinocchio_does():
    pytest.importorskip("tesseract_robotics")
    from refine.bench.peers import TCP, tesseract_environment

    problem = generated_problem("t", "wave", WAVE, 5)
    problem.base_in_world = np.array(
        [[0.0, -1.0, 0.0, 0.2], [1.0, 0.0, 0.0, -0.1], [0.0, 0.0, 1.0, 0.3], [0, 0, 0, 1]]
    )
    _, env, _, _, names, _ = tesseract_environment(problem)
    kin = TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange)
    for q in (np.zeros(6), np.array([0.3, -0.4, 0.5, 1.0, 0.7, -2.0])):
        env.setState(names, q)
        T = np.asarray(env.getLinkTransform(TCP).matrix())
        assert T == pytest.approx(kin.pose(q), abs=1e-9)


@pytest.mark.slow
def test_trajopt_and_descartes_answer_a_short_wave_and_the_shared_check_grades_them():
    pytest.importorskip("tesseract_robotics")
    from refine.bench.peers import descartes, trajopt

    problem = generated_problem("t", "wave", WAVE, 8)
    answer = trajopt(problem)
    assert answer.status == "ok" and answer.q.shape == (8, 6)
    assert answer.times_s["seed"] > 0.0 and answer.times_s["solve"] > 0.0
    verdict = verify(problem, answer.q)
    assert verdict.max_position_error_m < 1e-5
    assert verdict.max_orientation_deviation_deg <= problem.tolerances.orientation_deg
    # its status and settings: TrajOpt's default SQP (50 iterations), the box inside the cone (the
    # nozzle of the generated wave is not axisymmetric: cone/sqrt(3) on each of the three axes)
    assert answer.solver_status == "successful" and answer.solver_options["sqp"]["max_iter"] == 50
    assert not problem.axisymmetric
    box = answer.solver_options["orientation_box_rad"]
    assert box == pytest.approx([math.radians(problem.tolerances.orientation_deg - 1e-3) / math.sqrt(3)] * 3)
    answer = descartes(problem)
    assert answer.status == "ok" and answer.q.shape == (8, 6)
    assert answer.solver_status == "successful" and answer.solver_options["use_redundant_joint_solutions"]
    verdict = verify(problem, answer.q)
    assert verdict.max_position_error_m < 1e-6  # the verifier's limit: KDL's IK is asked for 1e-10
    # its samples turn about the tool axis by at most half the cone
    assert verdict.max_orientation_deviation_deg <= 0.5 * problem.tolerances.orientation_deg + 1e-3


@pytest.mark.slow
def test_the_puzzle_piece_as_tesseract_poses_it(require):
    from refine.bench.suites import tesseract_puzzle
    from refine.frames import make_transform, matrix_from_fixed_xyz

    support = require.path(
        require.shared / "peers" / "tesseract_support", "the puzzle piece's files (../shared/peers)"
    )
    problem = tesseract_puzzle("t", support)
    assert problem.robot.spec.joint_names == tuple(f"joint_a{k}" for k in range(1, 8))
    assert problem.n_waypoints >= 437 and problem.axisymmetric
    # by hand from the URDF: world -> link_grinder (0.35, -0.35, 0.6) -> grinder_frame (0, 0, 0.1), turned pi about y
    assert problem.tool_in_world[:3, 3] == pytest.approx([0.35, -0.35, 0.7])
    assert problem.tool_in_world[:3, 2] == pytest.approx([0.0, 0.0, -1.0], abs=1e-5)

    # tool0 -> ee_mount -> tool1 -> part, the URDF's three origins
    def rpy(r):
        return matrix_from_fixed_xyz(r, degrees=False)

    expected = (
        make_transform(rpy([1.5708, 0.0, 0.0]), [0.0, 0.0, 0.0])
        @ make_transform(rpy([0.523599, -0.523599, 0.0]), [-0.0083, 0.0541, 0.0143])
        @ make_transform(rpy([0.0, -0.2618, 0.0]), [0.0110, 0.0030, -0.0379])
    )
    assert problem.tcp_in_flange == pytest.approx(expected, abs=1e-9)
    assert problem.fused.positions[0] == pytest.approx([0.0789071, 0.0, 0.0237139])
    assert verify(problem, None).reason == "no answer"


def test_the_peers_do_not_pose_a_problem_files_stationary_tool():
    from refine.bench.contenders import NotPosed
    from refine.bench.peers import descartes, trajopt

    problem = generated_problem("t", "wave", WAVE, 5)
    problem.tool_in_world = np.eye(4)  # the robot holds the part, the TCP stands in the world
    with pytest.raises(NotPosed, match="stationary"):
        trajopt(problem)
    with pytest.raises(NotPosed, match="stationary TCP"):
        descartes(problem)


@pytest.mark.slow
def test_trajopt_poses_the_puzzle_piece_as_tesseracts_example_and_holds_the_part_to_a_micrometre(require):
    pytest.importorskip("tesseract_robotics")
    from refine.bench.peers import EXAMPLE_START_RAD, trajopt
    from refine.bench.suites import tesseract_puzzle

    support = require.path(
        require.shared / "peers" / "tesseract_support", "the puzzle piece's files (../shared/peers)"
    )
    problem = tesseract_puzzle("t", support)
    answer = trajopt(problem)
    assert answer.status == "ok" and answer.solver_status == "successful"
    assert answer.solver_options["cartesian_coeff"] == [100.0, 100.0, 100.0, 10.0, 10.0, 0.0]
    assert answer.times_s["seed"] == 0.0  # seeded by the example's start state, no IK
    # graded by Pinocchio (refine's verifier), not by Tesseract: the grinder's point on the path
    # within the verifier's 1 µm and the grinder's axis on the path's axis
    verdict = verify(problem, answer.q)
    assert verdict.verified, verdict.reason
    assert verdict.max_position_error_m < 1e-6 and verdict.max_orientation_deviation_deg < 1e-2
    # the turn about the tool axis was left free: the answer's spin differs from the demonstrated
    # frames' (a held spin, TrajOpt's default coefficient 5, would keep it at 0)
    kin = TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange, problem.tool_in_world)
    turn = np.einsum("kji,kjl->kil", problem.fused.rotations, kin.poses(answer.q)[:, :3, :3])
    spin = np.degrees(np.arctan2(turn[:, 1, 0], turn[:, 0, 0]))
    assert np.abs(spin).max() > 1.0
    assert len(EXAMPLE_START_RAD) == problem.robot.nq


@pytest.mark.slow
def test_trajopt_poses_the_turned_puzzle_piece_as_the_example_and_its_answer_keeps_the_cell_margin():
    pytest.importorskip("tesseract_robotics")
    from pathlib import Path

    from refine.bench.peers import trajopt
    from refine.bench.suites import bundled_problem

    problem = bundled_problem("t", Path(__file__).resolve().parents[2] / "problems" / "puzzle_piece_turned")
    answer = trajopt(problem)
    assert answer.status == "ok" and answer.solver_status == "successful", answer.note
    assert answer.solver_options["cartesian_coeff"] == [100.0, 100.0, 100.0, 10.0, 10.0, 0.0]
    assert answer.solver_options["orientation_box_rad"] is None
    assert answer.times_s["seed"] == 0.0  # the example's start state at every waypoint, no IK
    # graded by refine's verifier (Pinocchio, FCL), not by Tesseract: the grinding point on the
    # path within 1 µm, the grinder's axis on the toolpath's axis, the arm 10 mm or more clear of
    # the part and the table densely between waypoints
    verdict = verify(problem, answer.q)
    assert verdict.verified, verdict.reason
    assert verdict.max_position_error_m < 1e-6 and verdict.max_orientation_deviation_deg < 1e-2
    assert verdict.min_clearance_m > 0.0
    # the spin about the grinder's axis was left free (coefficient 0): it leaves the toolpath's frames
    kin = TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange)
    turn = np.einsum("kji,kjl->kil", problem.fused.rotations, kin.poses(answer.q)[:, :3, :3])
    spin = np.degrees(np.arctan2(turn[:, 1, 0], turn[:, 0, 0]))
    assert np.abs(spin).max() > 1.0
