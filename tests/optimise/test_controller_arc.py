"""Circular moves on the CAD's arcs: where they go, the controller's circle, and its check.

Expectations come from the geometry built here (a circle of known centre, radius and plane), not
from the module's own formulas.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.optimise.controller_arc import (
    PATH_FRAME,
    SLERP,
    arc_pieces,
    arc_poses,
    arc_runs,
    check_circular_moves,
    circle_through,
)
from refine.robot.kinematics import TcpKinematics, solve_ik_batch
from refine.robot.registry import load_robot
from refine.settings import Tolerances

CENTRE = np.array([0.6, -0.1, 0.3])
RADIUS = 0.02
TILT = Rotation.from_euler("xy", [20.0, -10.0], degrees=True)  # the arc's plane: tilted
NORMAL = TILT.apply([0.0, 0.0, 1.0])


def on_circle(angles_deg) -> np.ndarray:
    """Points of the circle at the angles (counter-clockwise about NORMAL from TILT's x axis)."""
    a = np.radians(np.asarray(angles_deg, dtype=float))
    local = np.column_stack([RADIUS * np.cos(a), RADIUS * np.sin(a), np.zeros_like(a)])
    return CENTRE + TILT.apply(local)


def path_line_arc_line() -> np.ndarray:
    """5 waypoints on a straight lead-in, a quarter arc in 16 steps, 5 on a straight lead-out."""
    arc = on_circle(np.linspace(0.0, 90.0, 17))
    t_in = TILT.apply([0.0, 1.0, 0.0])  # the arc's tangent at 0 deg
    t_out = TILT.apply([-1.0, 0.0, 0.0])  # and at 90 deg
    lead_in = arc[0] - np.outer(np.arange(5, 0, -1) * 0.002, t_in)
    lead_out = arc[-1] + np.outer(np.arange(1, 6) * 0.002, t_out)
    return np.vstack([lead_in, arc, lead_out])


def test_the_circle_through_three_points_is_the_one_they_were_placed_on():
    c, r, n, sweep = circle_through(*on_circle([10.0, 50.0, 100.0]))
    np.testing.assert_allclose(c, CENTRE, atol=1e-12)
    assert r == pytest.approx(RADIUS, abs=1e-12)
    np.testing.assert_allclose(n, NORMAL, atol=1e-12)
    assert math.degrees(sweep) == pytest.approx(90.0, abs=1e-9)
    # the same points the other way round turn about the opposite normal, through the via again
    c2, _, n2, sweep2 = circle_through(*on_circle([100.0, 50.0, 10.0]))
    np.testing.assert_allclose(n2, -NORMAL, atol=1e-12)
    assert math.degrees(sweep2) == pytest.approx(90.0, abs=1e-9)
    # a via on the far side: the long way round
    _, _, _, sweep3 = circle_through(*on_circle([0.0, 200.0, 90.0]))
    assert math.degrees(sweep3) == pytest.approx(270.0, abs=1e-9)
    assert circle_through(np.zeros(3), np.array([1.0, 0, 0]), np.array([2.0, 0, 0])) is None


def test_the_arc_is_found_between_its_ends_and_no_straight_waypoint_joins_it():
    runs = arc_runs(path_line_arc_line())
    assert runs == [(5, 21)]  # the arc's 17 waypoints, from its start to its end


def _runs_window_by_window(p: np.ndarray) -> list[tuple[int, int]]:
    """The runs with every window of four tested on its own (no all-at-once screen)."""
    from refine.optimise.controller_arc import _on_circle

    runs, a = [], 0
    while a + 3 < len(p):
        if _on_circle(p[a : a + 4]) is None:
            a += 1
            continue
        b = a + 3
        while b + 1 < len(p) and _on_circle(p[a : b + 2]) is not None:
            b += 1
        runs.append((a, b))
        a = b
    return runs


def test_a_waypoint_off_the_arc_splits_it_and_the_screen_drops_no_window():
    p = path_line_arc_line()
    radial = (p[13] - CENTRE) / RADIUS
    off = p.copy()
    off[13] += 1e-3 * radial  # 1 mm outwards: every window holding waypoint 13 is off the circle
    assert arc_runs(off) == [(5, 12), (14, 21)]
    near = p.copy()
    near[13] += 4e-7 * radial  # well inside the 5 um a waypoint may sit off its circle
    assert arc_runs(near) == [(5, 21)]
    rng = np.random.default_rng(3)
    for scale in (1e-6, 3e-6, 6e-6):  # noise about the threshold: the screen keeps what the test keeps
        noisy = np.vstack([p, p[::-1] + [0.0, 0.0, 0.01]]) + rng.normal(0.0, scale, (2 * len(p), 3))
        assert arc_runs(noisy) == _runs_window_by_window(noisy)
    assert arc_runs(p[:3]) == []


def test_pieces_keep_under_the_sweep_limit_and_the_speed_share():
    p = path_line_arc_line()
    same = np.full(len(p) - 1, 0.01)
    pieces = arc_pieces(p, same, 0.02)
    assert [(a.start, a.via, a.end) for a in pieces] == [(5, 13, 21)]  # one quarter: 90 deg is allowed
    assert math.degrees(pieces[0].sweep_rad) == pytest.approx(90.0, abs=1e-9)
    assert pieces[0].length_m == pytest.approx(RADIUS * math.pi / 2, rel=1e-12)
    # 3 % slower from the arc's 9th segment on: two moves, each at its slowest segment's speed
    v = same.copy()
    v[13:] = 0.0097
    pieces = arc_pieces(p, v, 0.02)
    assert [(a.start, a.end) for a in pieces] == [(5, 13), (13, 21)]
    assert [a.speed_m_s for a in pieces] == [0.01, 0.0097]
    assert arc_pieces(p, v, 0.05)[0].speed_m_s == 0.0097


def test_the_slerp_circle_runs_on_the_circle_and_turns_from_start_to_end():
    pieces = arc_pieces(path_line_arc_line(), np.full(26, 0.01), 0.02)
    Rs = Rotation.from_euler("xyz", [170.0, 10.0, 0.0], degrees=True)
    Re = Rotation.from_rotvec([0.0, 0.0, 0.6]) * Rs
    f = np.linspace(0.0, 1.0, 9)
    T = arc_poses(pieces[0], Rs.as_matrix(), Re.as_matrix(), f, SLERP)
    np.testing.assert_allclose(T[:, :3, 3], on_circle(90.0 * f), atol=1e-12)
    # about a fixed axis at a constant rate: z 0.6 f rad
    expect = Rotation.from_rotvec(np.outer(0.6 * f, [0.0, 0.0, 1.0])) * Rs
    np.testing.assert_allclose(T[:, :3, :3], expect.as_matrix(), atol=1e-12)


def test_the_path_frame_circle_keeps_a_tool_that_turns_with_the_tangent_fixed_in_the_frame():
    pieces = arc_pieces(path_line_arc_line(), np.full(26, 0.01), 0.02)
    Rs = Rotation.from_euler("xyz", [160.0, 15.0, 30.0], degrees=True)
    turn = Rotation.from_rotvec(NORMAL * math.pi / 2)  # the arc's frame turns 90 deg about its normal
    f = np.linspace(0.0, 1.0, 7)
    T = arc_poses(pieces[0], Rs.as_matrix(), (turn * Rs).as_matrix(), f, PATH_FRAME)
    expect = Rotation.from_rotvec(np.outer(f * math.pi / 2, NORMAL)) * Rs
    np.testing.assert_allclose(T[:, :3, :3], expect.as_matrix(), atol=1e-12)
    # the slerp of the same ends turns about the normal too here: the two models agree
    T2 = arc_poses(pieces[0], Rs.as_matrix(), (turn * Rs).as_matrix(), f, SLERP)
    np.testing.assert_allclose(T2[:, :3, :3], expect.as_matrix(), atol=1e-12)


@pytest.fixture(scope="module")
def ur10e_arc():
    """A UR10e on the arc, its tool turning with the tangent, joints by IK."""
    robot = load_robot("ur10e")
    kin = TcpKinematics(robot, np.eye(4), np.eye(4))
    p = path_line_arc_line() - CENTRE + np.array([0.5, 0.2, 0.3])
    ang = np.concatenate([np.zeros(5), np.linspace(0.0, math.pi / 2, 17), np.full(5, math.pi / 2)])
    R = Rotation.from_rotvec(np.outer(ang, NORMAL)) * Rotation.from_euler("x", 180.0, degrees=True)
    T = np.tile(np.eye(4), (len(p), 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R.as_matrix(), p
    seed = np.radians([20.0, -100.0, 110.0, -100.0, -90.0, 0.0])
    q = []
    for Tk in T:
        qk, err = solve_ik_batch(kin, Tk[None], seed[None], robot.spec.lower, robot.spec.upper, tol=1e-12)
        assert err[0] < 1e-9
        q.append(qk[0])
        seed = qk[0]
    return kin, np.array(q), kin.poses(np.array(q)), R.as_matrix()


def test_a_verified_arc_has_no_cad_deviation_and_the_refined_orientation(ur10e_arc):
    kin, q, poses, R = ur10e_arc
    pieces = arc_pieces(poses[:, :3, 3], np.full(len(q) - 1, 0.01), 0.02)
    exact = (
        np.array(
            [
                CENTRE + TILT.apply([RADIUS * math.cos(a), RADIUS * math.sin(a), 0.0])
                for a in np.linspace(0.0, math.pi / 2, 2001)
            ]
        )
        - CENTRE
        + np.array([0.5, 0.2, 0.3])
    )
    for model in (SLERP, PATH_FRAME):
        (c,) = check_circular_moves(kin, q, poses, pieces, model, Tolerances(), rotations_demo=R, exact=exact)
        assert c.ok, c.reasons
        assert c.cad_deviation_m < 1e-7  # the dense polyline's own sagitta is 2.5e-8 m
        assert c.axis_vs_refined_deg < 1e-5 and c.rotation_vs_refined_deg < 1e-5
        assert c.ik_error < 1e-9


def test_a_circle_off_the_cad_and_one_past_the_cone_are_refused(ur10e_arc):
    kin, q, poses, R = ur10e_arc
    pieces = arc_pieces(poses[:, :3, 3], np.full(len(q) - 1, 0.01), 0.02)
    # the CAD's arc 1 mm away along the arc's normal (densely: chords 2.5e-8 m off it)
    a = np.linspace(0.0, math.pi / 2, 2001)
    local = np.column_stack([RADIUS * np.cos(a), RADIUS * np.sin(a), np.full_like(a, 0.001)])
    shifted = TILT.apply(local) + np.array([0.5, 0.2, 0.3])
    (c,) = check_circular_moves(kin, q, poses, pieces, SLERP, Tolerances(), exact=shifted)
    assert not c.ok and c.cad_deviation_m == pytest.approx(0.001, abs=1e-7)
    tilted = Rotation.from_rotvec([0.0, math.radians(4.0), 0.0]).apply(np.eye(3))  # 4 deg off the demo
    demo = np.einsum("ij,kjl->kil", tilted, R)
    (c,) = check_circular_moves(
        kin, q, poses, pieces, SLERP, Tolerances(orientation_deg=3.0), rotations_demo=demo
    )
    assert not c.ok and c.vs_demo_deg == pytest.approx(4.0, abs=1e-6)


def test_only_runs_on_one_of_the_cad_s_arcs_become_pieces():
    p = path_line_arc_line()
    v = np.full(len(p) - 1, 0.01)
    assert len(arc_pieces(p, v, 0.02, [(CENTRE, RADIUS, -NORMAL)])) == 1  # either sense of the normal
    assert arc_pieces(p, v, 0.02, []) == []  # a spline or a mesh boundary: no arc of the CAD
    assert arc_pieces(p, v, 0.02, [(CENTRE + [0.0, 0.0, 1e-4], RADIUS, NORMAL)]) == []
    assert arc_pieces(p, v, 0.02, [(CENTRE, RADIUS + 1e-4, NORMAL)]) == []


def test_the_cad_circles_are_the_drawing_s_arcs_and_the_program_s_arc_moves(tmp_path):
    import ezdxf

    from refine.cad.dxf import dxf_circles
    from refine.cad.gcode import gcode_circles

    doc = ezdxf.new()
    msp = doc.modelspace()
    msp.add_line((0, 0), (100, 0))
    msp.add_arc((100, 20), 20.0, -90.0, 0.0)
    # a quarter-circle bulge from (120, 20) to (100, 40): centre (100, 20), radius 20 mm
    msp.add_lwpolyline([(120, 20, math.tan(math.pi / 8)), (100, 40, 0.0)], format="xyb")
    doc.saveas(tmp_path / "p.dxf")
    found = dxf_circles(tmp_path / "p.dxf", "mm", layer="0")
    assert len(found) == 2
    for c, r, n in found:
        np.testing.assert_allclose(c, [0.1, 0.02, 0.0], atol=1e-12)
        assert r == pytest.approx(0.02, abs=1e-12)
        np.testing.assert_allclose(n, [0.0, 0.0, 1.0], atol=1e-12)
    (tmp_path / "p.nc").write_text(
        "G21 G90 G17\nG1 X0 Y0 Z5\nG1 X10 Y0\nG3 X20 Y10 I0 J10\nG2 X30 Y20 Z8 I10 J0\n"
    )
    ((c, r, n),) = gcode_circles(tmp_path / "p.nc", "mm")  # the second arc is a helix: no circle
    np.testing.assert_allclose(c, [0.01, 0.01, 0.005], atol=1e-12)
    assert r == pytest.approx(0.01, abs=1e-12)
    np.testing.assert_allclose(np.abs(n), [0.0, 0.0, 1.0], atol=1e-12)


def test_a_piece_s_speed_rounded_down_to_the_programs_step_stays_within_the_share():
    p = path_line_arc_line()
    v = np.full(len(p) - 1, 0.00675)
    v[13:] = 0.00665  # 1.5 % slower: within 2 % ... until 6.65 mm/s is written as 6.6 mm/s (2.2 %)
    assert [(a.start, a.end) for a in arc_pieces(p, v, 0.02, speed_resolution_m_s=1e-6)] == [(5, 21)]
    pieces = arc_pieces(p, v, 0.02)  # the programs' 0.1 mm/s
    assert [(a.start, a.end) for a in pieces] == [(5, 13), (13, 21)]
    assert [round(a.speed_m_s * 1e4) for a in pieces] == [67, 66]  # 6.7 and 6.6 mm/s, never above
