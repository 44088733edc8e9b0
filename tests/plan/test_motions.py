"""The program's motions: a home inside the cell, a retract into a clamp, a link through the part.

The cell is the glass-adhesive problem's robot, placement and gun, with cell objects placed where
the tests need them. Expected outcomes come from the geometry the tests build (where a box sits
against the TCP line, which points of the arm lie inside a box), not from the planner's checker.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from refine.collision import CollisionModel
from refine.errors import InputError
from refine.frames import make_transform
from refine.plan.air import plan_air
from refine.plan.line import plan_line
from refine.plan.motion import Motion, joint_move_time
from refine.plan.verify import MotionChecker
from refine.problem import load_problem
from refine.robot.kinematics import TcpKinematics, solve_ik
from refine.robot.registry import robot_for
from refine.run.preflight import preflight
from refine.run.result import RunResult
from refine.settings import Shape

ROOT = Path(__file__).resolve().parents[2]
DOWN = np.diag([1.0, -1.0, -1.0])  # tool z pointing straight down, world frame


@pytest.fixture(scope="module")
def glass():
    problem = load_problem(ROOT / "problems" / "glass_adhesive")
    return problem, robot_for(problem.robot)


def kinematics(problem, robot) -> TcpKinematics:
    return TcpKinematics(robot, problem.robot.base_in_world, problem.tool.tcp_in_flange)


def joints_at(problem, robot, position, q0=None) -> np.ndarray:
    """Joints putting the TCP at ``position`` (world) with the tool pointing down (IK, checked)."""
    kin = kinematics(problem, robot)
    q0 = np.radians([0.0, 20.0, 20.0, 0.0, 50.0, 0.0]) if q0 is None else q0
    q, residual = solve_ik(
        kin,
        make_transform(DOWN, position),
        q0,
        robot.spec.lower,
        robot.spec.upper,
        max_iterations=300,
        tol=1e-10,
    )
    assert residual < 1e-6
    return q


def box(name, centre, size) -> Shape:
    return Shape(name, "box", make_transform(np.eye(3), centre), size_m=tuple(size))


def checker_with(problem, robot, cell) -> MotionChecker:
    model = CollisionModel(
        robot,
        problem.robot.base_in_world,
        problem.tool.tcp_in_flange,
        problem.tool.collision,
        tuple(cell),
        margin_m=problem.collision.margin_m,
        self_margin_m=problem.collision.self_margin_m,
    )
    return MotionChecker(
        kinematics(problem, robot), model, problem.tolerances, problem.collision.check_step_m
    )


def inside_box(points, centre, size) -> np.ndarray:
    """Distance [m] of each point (K, 3) outside an axis-aligned box (0 inside), own geometry."""
    excess = np.abs(points - np.asarray(centre)) - 0.5 * np.asarray(size)
    return np.linalg.norm(np.maximum(excess, 0.0), axis=1)


def skeleton(problem, robot, q) -> np.ndarray:
    """Points on the arm's axis line (joint origins, 8 points between each pair) and along the
    flange-to-TCP line, world frame: every one lies inside a link or the tool."""
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, q)
    pin.updateFramePlacements(robot.model, data)
    T = problem.robot.base_in_world
    origins = [data.oMi[j].translation for j in range(1, robot.model.njoints)]
    flange = data.oMf[robot.flange_id].homogeneous
    origins += [flange[:3, 3], (flange @ problem.tool.tcp_in_flange)[:3, 3]]
    u = np.linspace(0.0, 1.0, 9)[:, None]
    points = np.concatenate([a + u * (b - a) for a, b in zip(origins[:-1], origins[1:], strict=True)])
    return points @ T[:3, :3].T + T[:3, 3]


def joint_samples(rows, step_rad=0.0044) -> np.ndarray:
    """The joint-interpolated path through ``rows`` sampled every ``step_rad`` (0.25 deg) on the largest joint."""
    out = [rows[0]]
    for a, b in zip(rows[:-1], rows[1:], strict=True):
        m = max(1, math.ceil(np.abs(b - a).max() / step_rad))
        out += [a + (k / m) * (b - a) for k in range(1, m + 1)]
    return np.array(out)


# ---- home --------------------------------------------------------------------------------------


def test_a_home_inside_the_table_is_an_input_error_naming_the_table_and_the_distance(glass):
    problem, robot = glass
    table = next(o for o in problem.cell if o.name == "table")  # 1.0 x 1.6 x 0.05 m at z 0.425
    tcp = np.array([0.95, 0.0, 0.42])  # inside the table, beside the glass (x < 1.05)
    assert inside_box(tcp[None], table.pose[:3, 3], table.size_m)[0] == 0.0
    q = joints_at(problem, robot, tcp)
    bad = dataclasses.replace(
        problem, robot=dataclasses.replace(problem.robot, home_deg=tuple(np.degrees(q)))
    )
    with pytest.raises(InputError, match=r"home_deg.*inside table: distance -\d+\.\d mm \(margin 10 mm\)"):
        preflight(bad, robot=robot)
    clear = joints_at(problem, robot, np.array([1.2, 0.0, 0.9]))  # 0.25 m above the glass
    ok = dataclasses.replace(
        problem, robot=dataclasses.replace(problem.robot, home_deg=tuple(np.degrees(clear)))
    )
    preflight(ok, robot=robot)


def test_a_home_outside_the_joint_limits_is_an_input_error(glass):
    problem, robot = glass
    upper = math.degrees(robot.spec.upper[0])
    home = (upper + 1.0, 0.0, 0.0, 0.0, 30.0, 0.0)
    bad = dataclasses.replace(problem, robot=dataclasses.replace(problem.robot, home_deg=home))
    with pytest.raises(InputError, match="joint 1 at .* deg is outside its limits"):
        preflight(bad, robot=robot)


# ---- approach and retract -----------------------------------------------------------------------


def test_a_retract_into_a_clamp_is_caught_naming_the_clamp_and_where(glass):
    problem, robot = glass
    q = joints_at(problem, robot, np.array([1.2, 0.0, 0.66]))
    T = kinematics(problem, robot).pose(q)
    on_line = T[:3, 3] - 0.07 * T[:3, 2]  # 70 mm back along the tool axis: on the 100 mm retract
    checker = checker_with(problem, robot, [box("clamp", on_line, (0.03, 0.03, 0.03))])
    motion = plan_line(checker, "retract", "retract pass 1", q, T, retract_m=0.1)
    assert motion.status == "failed"
    hit = [i for i in motion.issues if i.cause == "collision"]
    assert hit and "clamp" in hit[0].objects and hit[0].distance_m < problem.collision.margin_m
    assert np.linalg.norm(hit[0].tcp_m - T[:3, 3]) <= 0.1 + 1e-9  # where: on the retract line
    aside = checker_with(problem, robot, [box("clamp", on_line + [0.0, 0.3, 0.0], (0.03, 0.03, 0.03))])
    clear = plan_line(aside, "retract", "retract pass 1", q, T, retract_m=0.1)
    assert clear.ok, clear.reason
    # the line: the TCP 100 mm straight back along the tool axis, orientation kept
    end = kinematics(problem, robot).pose(clear.q[-1])
    np.testing.assert_allclose(end[:3, 3], T[:3, 3] - 0.1 * T[:3, 2], atol=1e-7)
    np.testing.assert_allclose(end[:3, :3], T[:3, :3], atol=1e-7)
    assert clear.duration_s == pytest.approx(0.1 / 0.25)


def test_an_approach_runs_from_the_approach_point_onto_the_waypoint(glass):
    problem, robot = glass
    q = joints_at(problem, robot, np.array([1.2, 0.0, 0.66]))
    kin = kinematics(problem, robot)
    T = kin.pose(q)
    on_line = T[:3, 3] - 0.02 * T[:3, 2]  # 20 mm back along the tool axis: near the waypoint's end
    checker = checker_with(problem, robot, [box("clamp", on_line + [0.0, 0.3, 0.0], (0.03, 0.03, 0.03))])
    motion = plan_line(checker, "approach", "approach pass 1", q, T, retract_m=0.1)
    assert motion.ok, motion.reason
    np.testing.assert_allclose(kin.pose(motion.q[0])[:3, 3], T[:3, 3] - 0.1 * T[:3, 2], atol=1e-7)
    np.testing.assert_array_equal(motion.q[-1], q)
    blocked = checker_with(problem, robot, [box("clamp", on_line, (0.03, 0.03, 0.03))])
    hit = plan_line(blocked, "approach", "approach pass 1", q, T, retract_m=0.1).issues[0]
    assert "clamp" in hit.objects and hit.fraction > 0.5  # near the end of the approach, by the waypoint


def test_a_failed_motion_makes_the_run_infeasible(glass):
    problem, robot = glass
    failed = Motion(
        "retract", "retract pass 1", np.zeros((2, 6)), np.eye(4), np.eye(4), 0.4, "line", 0.0, "failed"
    )
    result = RunResult(problem, robot, (), None, motions=(failed,))
    assert result.status == "infeasible" and result.failed_motions == (failed,)
    from refine.cli import exit_status

    assert exit_status(result.status) == 1


# ---- a link through the part --------------------------------------------------------------------

WALL_CENTRE = (1.2, 0.0, 0.65)
WALL_SIZE = (0.3, 0.08, 0.4)  # z from 0.45 to 0.85 m, between the two passes' ends


@pytest.fixture(scope="module")
def link(glass):
    problem, robot = glass
    q_a = joints_at(problem, robot, np.array([1.2, -0.3, 0.7]))
    q_b = joints_at(problem, robot, np.array([1.2, 0.3, 0.7]), q_a)
    checker = checker_with(problem, robot, [box("part", WALL_CENTRE, WALL_SIZE)])
    spec = robot.spec
    motion = plan_air(
        checker, "link", "pass 1 -> pass 2", q_a, q_b, velocity=spec.velocity, acceleration=spec.acceleration
    )
    return problem, robot, checker, q_a, q_b, motion


def test_a_link_through_the_part_is_planned_around_it_by_via_points(link):
    problem, robot, _, q_a, q_b, motion = link
    direct = joint_samples(np.array([q_a, q_b]))
    assert min(inside_box(skeleton(problem, robot, q), WALL_CENTRE, WALL_SIZE).min() for q in direct) == 0.0
    assert motion.ok, motion.reason
    assert motion.planner == "RRT-Connect" and len(motion.via) >= 1
    assert motion.direct_issues and "part" in motion.direct_issues[0].objects
    np.testing.assert_array_equal(motion.q[0], q_a)
    np.testing.assert_array_equal(motion.q[-1], q_b)
    # own check of the written via-point path: every point of the arm's axis and the tool line
    # stays outside the part by the margin (they lie inside the links, so the links' distance is less)
    path = joint_samples(motion.q)
    least = min(inside_box(skeleton(problem, robot, q), WALL_CENTRE, WALL_SIZE).min() for q in path)
    assert least >= problem.collision.margin_m - 1e-4
    assert np.all(path >= robot.spec.lower) and np.all(path <= robot.spec.upper)
    assert motion.min_clearance_m >= -1e-4  # the planner's own verification agrees
    print(
        f"link through the part: {len(motion.via)} via points, planned and verified in "
        f"{motion.planner_time_s:.2f} s, least skeleton distance {least * 1e3:.1f} mm, "
        f"min distance {motion.min_distance_m * 1e3:.1f} mm ({' / '.join(motion.closest)}), {motion.duration_s:.2f} s"
    )


def test_the_planner_gives_the_same_via_points_every_run(link):
    problem, robot, checker, q_a, q_b, motion = link
    spec = robot.spec
    again = plan_air(
        checker, "link", "pass 1 -> pass 2", q_a, q_b, velocity=spec.velocity, acceleration=spec.acceleration
    )
    np.testing.assert_array_equal(again.q, motion.q)


def test_a_clear_joint_move_is_written_without_via_points(glass):
    problem, robot = glass
    q_a = joints_at(problem, robot, np.array([1.2, -0.3, 0.9]))
    q_b = joints_at(problem, robot, np.array([1.2, 0.3, 0.9]), q_a)
    checker = checker_with(problem, robot, [box("part", WALL_CENTRE, WALL_SIZE)])
    spec = robot.spec
    motion = plan_air(checker, "link", "l", q_a, q_b, velocity=spec.velocity, acceleration=spec.acceleration)
    assert motion.ok and motion.planner == "joint move" and len(motion.via) == 0


def test_a_joint_move_takes_the_slowest_joint_s_trapezoid():
    # joint 1: 1 rad at 1 rad/s, 2 rad/s^2: ramps of 0.25 rad, 0.5 rad cruising: 0.5 + 0.5 + 0.5 = 1.5 s
    # joint 2: 0.1 rad at 1 rad/s, 2 rad/s^2: a triangle, 2 sqrt(0.1 / 2) = 0.447 s
    q = np.array([[0.0, 0.0], [1.0, 0.1]])
    assert joint_move_time(q, np.array([1.0, 1.0]), np.array([2.0, 2.0])) == pytest.approx(1.5)
    assert joint_move_time(q[:, 1:], np.array([1.0]), np.array([2.0])) == pytest.approx(2.0 * math.sqrt(0.05))


def test_air_moves_run_at_the_output_s_share_of_each_joint_s_speed():
    """At 20 % of 2 rad/s (0.4 rad/s) and 2 rad/s^2, 1 rad takes 1 / 0.4 + 0.4 / 2 = 2.7 s by hand;
    the second move, 0.02 rad, is a triangle under the 0.08 rad of a full ramp: 2 sqrt(0.01) = 0.2 s."""
    from types import SimpleNamespace

    from refine.plan.motion import air_limits, joint_move_times
    from refine.settings import OutputSettings

    robot = SimpleNamespace(spec=SimpleNamespace(velocity=np.array([2.0]), acceleration=np.array([2.0])))
    problem = SimpleNamespace(output=OutputSettings(), robot=SimpleNamespace(joint_acceleration_deg_s2=None))
    v, a = air_limits(problem, robot)
    assert v == pytest.approx([0.4]) and a == pytest.approx([2.0])
    times = joint_move_times(np.array([[0.0], [1.0], [1.02]]), v, a)
    assert times == pytest.approx([2.7, 0.2])


@pytest.mark.parametrize("share", [0.0, 0.125, 1.5])
def test_an_air_speed_share_off_whole_percents_is_an_input_error(share):
    from refine.errors import InputError
    from refine.settings import OutputSettings

    with pytest.raises(InputError, match="air_speed_share"):
        OutputSettings(air_speed_share=share)
