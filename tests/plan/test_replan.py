"""The program's motions planned again from an earlier run's: the same motions, each verified again.

A re-solve after the glass part moved 2 mm and turned 0.3 deg plans its approach and retract lines
from the previous lines' joints and must give the motions of a plan made afresh (the cold run's);
the lines are also checked against their own geometry (Pinocchio's TCP on the straight line). An
air move planned around the cell keeps its via points when its ends moved a little and the path
stays clear, and a cell object moved into those via points makes it plan again: the expectations
come from the geometry the tests build (a box around a point of the arm's axis), not from the
planner's checker.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pinocchio as pin
import pytest

import refine
import refine.plan.air
import refine.plan.line
import refine.plan.recheck
from refine.plan.air import plan_air

from .test_motions import (
    WALL_CENTRE,
    WALL_SIZE,
    box,
    checker_with,
    inside_box,
    joint_samples,
    joints_at,
    skeleton,
)
from .test_motions import glass as glass  # noqa: F401 - the module's fixture
from .test_motions import link as link  # noqa: F401 - the module's fixture

ROBOT = "abb_irb4600_60_205"


@pytest.fixture(scope="module")
def shifted(glass_shift):
    """The part-shift change solved cold and warm (``previous=`` the first answer), with the
    starts the warm lines' IK was given (each line_joints call's ``start``, None when cold)."""
    s = glass_shift
    starts: list[object] = []
    line_joints = refine.plan.line.line_joints

    def spy(*args, **kwargs):
        starts.append(args[5] if len(args) > 5 else kwargs.get("start"))
        return line_joints(*args, **kwargs)

    cold = refine.refine_path(ROBOT, s.positions, s.orientations, **s.part)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(refine.plan.line, "line_joints", spy)
        warm = refine.refine_path(ROBOT, s.positions, s.orientations, **s.part, previous=s.first)
    return s, cold, warm, starts


def test_a_re_solve_plans_the_cold_run_s_motions(shifted):
    """Each warm motion is the cold plan's: kind, planner, status, joints within 1e-6 rad, figures."""
    _, cold, warm, _ = shifted
    assert cold.status == warm.status == "ok"
    c, w = cold.run.motions, warm.run.motions
    assert [(m.kind, m.name, m.planner, m.status) for m in w] == [
        (m.kind, m.name, m.planner, m.status) for m in c
    ]
    for a, b in zip(c, w, strict=True):
        assert a.q.shape == b.q.shape, a.name
        np.testing.assert_allclose(b.q, a.q, atol=1e-6, rtol=0.0, err_msg=a.name)
        # the same joints to 1e-6 rad move no point of the arm by more than a few micrometres
        assert b.min_distance_m == pytest.approx(a.min_distance_m, abs=1e-5), a.name
        assert b.min_clearance_m == pytest.approx(a.min_clearance_m, abs=1e-5), a.name
        assert b.closest == a.closest, a.name
        assert b.min_joint_margin_rad == pytest.approx(a.min_joint_margin_rad, abs=1e-6), a.name
        if a.min_singularity is not None:
            assert b.min_singularity == pytest.approx(a.min_singularity, abs=1e-6), a.name
        if a.line_deviation_m is not None:
            assert b.line_deviation_m == pytest.approx(a.line_deviation_m, abs=1e-6), a.name


def _same(x, y, where, skip=("planner_time_s", "queries", "time_s")):
    """``x`` and ``y`` (dataclasses, mappings, sequences, arrays, values) equal to the bit, ``skip`` aside."""
    if dataclasses.is_dataclass(x):
        for f in dataclasses.fields(x):
            if f.name not in skip:
                _same(getattr(x, f.name), getattr(y, f.name), f"{where}.{f.name}")
    elif isinstance(x, dict):
        assert x.keys() == y.keys(), where
        for k in x:
            _same(x[k], y[k], f"{where}[{k!r}]")
    elif isinstance(x, (tuple, list)):
        assert type(x) is type(y) and len(x) == len(y), where
        for k, (u, v) in enumerate(zip(x, y, strict=True)):
            _same(u, v, f"{where}[{k}]")
    elif isinstance(x, np.ndarray):
        np.testing.assert_array_equal(x, y, err_msg=where)
    else:
        assert x == y or (x != x and y != y), where  # NaN equals NaN here


def test_a_re_solve_s_motions_are_those_of_one_that_measures_every_row_again(shifted):
    """The warm motions share rows (the home move ends on the approach's first row, the return
    starts on the retract's last): measured once per collision model, they give every motion the
    joints, figures and bounds, bit for bit, of a re-solve that keeps no row measured, with fewer
    FCL queries."""
    s, _, warm, _ = shifted
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(refine.plan.recheck, "MEASURED_ROWS", 0)
        bare = refine.refine_path(ROBOT, s.positions, s.orientations, **s.part, previous=s.first)
    assert [m.name for m in warm.run.motions] == [m.name for m in bare.run.motions]
    for a, b in zip(warm.run.motions, bare.run.motions, strict=True):
        _same(a, b, a.name)  # joints, figures, and the check's figures and bounds
    queries = [sum(m.check.queries for m in r.run.motions if m.kind != "path") for r in (warm, bare)]
    assert queries[0] < queries[1], queries


def test_a_re_solve_starts_the_lines_ik_from_the_previous_lines(shifted):
    """The warm lines' IK was given starts (the previous lines' joints), and those starts are near
    the new line joints: the previous line moved by the change of the anchor."""
    s, _, warm, starts = shifted
    assert starts and all(x is not None for x in starts)
    previous = {m.name: m for m in s.first.run.motions}
    for m in warm.run.motions:
        if m.kind in ("approach", "retract"):
            before = previous[m.name]
            assert np.abs(m.q - before.q).max() < 0.01  # a 2 mm shift moves the joints little


def test_a_re_planned_line_is_the_straight_tcp_line_off_the_moved_waypoint(shifted):
    """Pinocchio's TCP along each warm line: on the 100 mm line along the tool z axis from the pass's
    moved end waypoint, the orientation kept (own FK, not the planner's kinematics)."""
    s, _, warm, _ = shifted
    robot = warm.run.robot
    data = robot.model.createData()
    base, tcp = s.problem.robot.base_in_world, s.problem.tool.tcp_in_flange

    def pose(q):
        pin.framesForwardKinematics(robot.model, data, q)
        return base @ data.oMf[robot.flange_id].homogeneous @ tcp

    q_path = warm.joints
    for m in warm.run.motions:
        if m.kind not in ("approach", "retract"):
            continue
        anchor = q_path[-1] if m.kind == "retract" else q_path[0]
        np.testing.assert_array_equal(m.q[0 if m.kind == "retract" else -1], anchor)
        T = pose(anchor)
        for q in m.q:
            P = pose(q)
            along = (T[:3, 3] - P[:3, 3]) @ T[:3, 2]  # how far back along the tool axis [m]
            assert -1e-7 <= along <= 0.1 + 1e-7
            np.testing.assert_allclose(P[:3, 3], T[:3, 3] - along * T[:3, 2], atol=1e-7)
            np.testing.assert_allclose(P[:3, :3], T[:3, :3], atol=1e-7)


# ---- an air move around the part, planned again ---------------------------------------------------


def moved_ends(problem, robot, q_a, q_b, z=0.7, dx=0.002):
    """The link's two ends (TCP at y -0.3 and 0.3 m, height ``z``) moved ``dx`` [m] along world x."""
    a = joints_at(problem, robot, np.array([1.2 + dx, -0.3, z]), q_a)
    return a, joints_at(problem, robot, np.array([1.2 + dx, 0.3, z]), q_b)


def air_limits(robot) -> dict:
    """The robot's joint speed and acceleration limits as ``plan_air`` takes them."""
    return {"velocity": robot.spec.velocity, "acceleration": robot.spec.acceleration}


def least_skeleton_distance(problem, robot, rows, centre, size) -> float:
    """Least distance [m] of the arm's axis and tool line from a box along the joint path (own geometry)."""
    return min(inside_box(skeleton(problem, robot, q), centre, size).min() for q in joint_samples(rows))


def test_a_link_planned_again_keeps_its_via_points_when_its_ends_moved_a_little(link):
    problem, robot, checker, q_a, q_b, motion = link
    assert motion.planner == "RRT-Connect" and len(motion.via) >= 1
    a, b = moved_ends(problem, robot, q_a, q_b)
    again = plan_air(checker, "link", motion.name, a, b, previous=motion, **air_limits(robot))
    assert again.ok, again.reason
    assert again.planner == "RRT-Connect"
    np.testing.assert_array_equal(again.via, motion.via)
    np.testing.assert_array_equal(again.q[0], a)
    np.testing.assert_array_equal(again.q[-1], b)
    assert again.direct_issues and "part" in again.direct_issues[0].objects  # the direct move checked again
    least = least_skeleton_distance(problem, robot, again.q, WALL_CENTRE, WALL_SIZE)
    assert least >= problem.collision.margin_m - 1e-4


def test_a_box_moved_into_a_kept_link_makes_it_plan_again(link):
    """The link's via points, checked clear in a cell with a post beside them, then the post moved
    120 mm onto a point of the tool's line at the first via point: the old via points collide (own
    geometry), so they are not kept, and what is planned instead keeps the post's margin (or the
    move fails). The ends are far from the post, so only the whole path's check can refuse them."""
    problem, robot, _, q_a, q_b, motion = link
    size = (0.06, 0.06, 0.06)
    onto = skeleton(problem, robot, motion.via[0])[-5]  # on the tool's line at the first via point
    aside = onto + np.array([0.12, 0.0, 0.0])  # beyond the tool, away from the arm
    assert least_skeleton_distance(problem, robot, motion.q, aside, size) > 0.05
    before = checker_with(problem, robot, [box("part", WALL_CENTRE, WALL_SIZE), box("post", aside, size)])
    previous = dataclasses.replace(motion, check=before.clearance(motion.q))  # checked with the post aside
    assert previous.check.ok
    # the old via point's tool line runs through the moved post: the old path collides with it
    assert inside_box(skeleton(problem, robot, motion.via[0]), onto, size).min() == 0.0
    after = checker_with(problem, robot, [box("part", WALL_CENTRE, WALL_SIZE), box("post", onto, size)])
    a, b = moved_ends(problem, robot, q_a, q_b)
    calls = []
    rrt = refine.plan.air._rrt_connect

    def counted(*args, **kwargs):
        calls.append(args[3])  # the extra clearance asked
        return rrt(*args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(refine.plan.air, "_rrt_connect", counted)
        again = plan_air(
            after, "link", motion.name, a, b, previous=previous, time_limit_s=1.0, **air_limits(robot)
        )
    assert calls  # planned again
    assert not (again.via.shape == motion.via.shape and np.array_equal(again.via, motion.via))
    if again.ok:
        assert (
            least_skeleton_distance(problem, robot, again.q, onto, size) >= problem.collision.margin_m - 1e-4
        )
        assert least_skeleton_distance(problem, robot, again.q, WALL_CENTRE, WALL_SIZE) >= 0.01 - 1e-4
    else:
        assert any(i.cause == "no path found" for i in again.issues)


def test_a_direct_move_planned_again_is_the_direct_move_checked_afresh(glass):
    """A clear joint move planned again from an earlier one is the same direct move, checked again."""
    problem, robot = glass
    q_a = joints_at(problem, robot, np.array([1.2, -0.3, 0.9]))
    q_b = joints_at(problem, robot, np.array([1.2, 0.3, 0.9]), q_a)
    checker = checker_with(problem, robot, [box("part", WALL_CENTRE, WALL_SIZE)])
    limits = air_limits(robot)
    first = plan_air(checker, "link", "l", q_a, q_b, **limits)
    a, b = moved_ends(problem, robot, q_a, q_b, z=0.9)
    again = plan_air(checker, "link", "l", a, b, previous=first, **limits)
    fresh = plan_air(checker, "link", "l", a, b, **limits)
    assert again.ok and again.planner == "joint move" and len(again.via) == 0
    np.testing.assert_array_equal(again.q, fresh.q)
    assert again.min_distance_m == fresh.min_distance_m and again.min_clearance_m == fresh.min_clearance_m
    assert math.isfinite(again.min_distance_m)
