"""The controller's straight TCP line between waypoints against figures computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from refine.optimise.controller_line import (
    check_controller_lines,
    sample_parameters,
    segment_margins,
    through_samples,
)
from refine.optimise.line_ik import segment_starts
from refine.optimise.verify import segment_singularity
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot
from refine.settings import Tolerances


@pytest.fixture(scope="module")
def ur10e_kin():
    return TcpKinematics(load_robot("ur10e"), np.eye(4), np.eye(4))


Q0 = np.radians([10.0, -100.0, 90.0, -80.0, -90.0, 0.0])


@pytest.mark.parametrize("turn_deg", [4.0, 10.0])
def test_a_turn_of_axis_1_leaves_the_line_by_the_sagitta_of_its_arc(ur10e_kin, turn_deg):
    """Axis 1 alone: the joint-linear TCP runs on an arc of radius r round the base z axis.

    Its midpoint is the sagitta r (1 - cos(turn / 2)) off the chord; the tool turns about the same
    axis at the same rate as the slerp between the two orientations, so they agree at equal t.
    """
    d = math.radians(turn_deg)
    q = np.array([Q0, Q0 + [d, 0, 0, 0, 0, 0]])
    p = ur10e_kin.pose(Q0)[:3, 3]
    radius = math.hypot(p[0], p[1])  # distance of the TCP from axis 1 (the base z axis)
    line = check_controller_lines(ur10e_kin, q, np.array([0.0, 1.0]), Tolerances())
    assert line.position_difference_m[0] == pytest.approx(radius * (1.0 - math.cos(d / 2.0)), rel=1e-6)
    assert line.orientation_difference_deg[0] < 1e-6
    assert line.ok and line.ik_error.max() < 1e-8
    # the line's joints put the TCP on the chord at the fraction t of its length
    ends = ur10e_kin.poses(q)[:, :3, 3]
    on_chord = ends[0] + line.t[:, None] * (ends[1] - ends[0])
    np.testing.assert_allclose(ur10e_kin.poses(line.q)[:, :3, 3], on_chord, atol=1e-9)


def test_a_long_turn_whose_chord_passes_the_base_axis_fails_on_the_line_only(ur10e_kin):
    """150 deg of axis 1: the joint-linear arc stays at radius r, the chord comes within
    r cos(75 deg) of the base axis, where the arm folds over its shoulder singularity."""
    q = np.array([Q0, Q0 + np.radians([150.0, 0, 0, 0, 0, 0])])
    between, _ = segment_singularity(ur10e_kin, q)
    tol = Tolerances(joint_step_deg=360.0)
    assert between[0] > tol.singularity_margin  # the joint-linear check passes it
    line = check_controller_lines(ur10e_kin, q, np.array([0.0, 1.0]), tol)
    reasons = {v.reason for v in line.violations}
    assert "singularity on the controller's line" in reasons or "no IK on the controller's line" in reasons
    assert not line.ok


def test_a_wrist_run_keeps_the_joint_linear_orientation(ur10e_kin):
    """Where the wrist is handed to the controller, the orientation is the joint-linear one: no
    orientation difference, whatever the joints do."""
    q = np.array([Q0, Q0 + np.radians([2.0, 3.0, -4.0, 20.0, 15.0, -30.0])])
    free = check_controller_lines(ur10e_kin, q, np.array([0.0, 1.0]), Tolerances())
    wrist = check_controller_lines(ur10e_kin, q, np.array([0.0, 1.0]), Tolerances(), wrist=np.array([True]))
    assert free.orientation_difference_deg[0] > 0.1  # a wrist motion turns the tool off the slerp
    assert wrist.orientation_difference_deg[0] < 1e-6


def test_a_clearance_break_on_the_line_is_reported_by_segment(ur10e_kin):
    """A clearance the dense check finds broken on the line's joints is a violation of its segment."""
    q = np.array([Q0, Q0 + [0.01, 0, 0, 0, 0, 0], Q0 + [0.02, 0, 0, 0, 0, 0]])
    seen = []

    def clearance(dense, place):
        seen.append(dense)
        assert len(place) == len(dense) and np.all(np.diff(place) > 0.0)  # along the path, in order
        np.testing.assert_array_equal(place[[0, -1]], [0.0, 2.0])
        per = np.full(len(dense) - 1, 0.05)
        per[-1] = -0.003  # the last step, inside the second segment
        return per, 1e-4

    line = check_controller_lines(
        ur10e_kin, q, np.array([0.0, 1.0, 2.0]), Tolerances(), clearance=clearance, reach=np.ones(6)
    )
    (dense,) = seen
    assert len(dense) == 3 + len(line.t)  # every waypoint and every sample, in order
    np.testing.assert_allclose(dense[0], q[0]) and np.testing.assert_allclose(dense[-1], q[-1])
    (v,) = line.violations
    assert (v.index_start, v.index_end, v.reason) == (1, 1, "clearance on the controller's line")
    assert v.worst == pytest.approx(-0.003) and line.clearance_proved is False
    # the joints differ by at most joint_difference_deg; with a reach of 1 m per joint the change
    # of any clearance is at most the sum of the joint differences, here below 6 x that
    assert np.all(line.clearance_change_m <= 6 * np.radians(line.joint_difference_deg) + 1e-12)


def test_line_rows_ask_for_what_keeps_the_full_joint_margin_on_the_line(ur10e_kin):
    """Axis 1 turns 10 deg with axis 6 held 40 deg inside its lower limit: both waypoints keep a
    40 deg margin exactly, but the line's axis 6 dips below them (the joint-linear check passes).

    The rows of that dip ask axis 6 to rise by the dip; raising both waypoints' axis 6 by what the
    rows ask (a spin about the flange axis, which leaves the line's shape alone) keeps the full
    margin on the line, and by half of it does not.
    """
    from refine.optimise.controller_line import line_rows

    q_start = Q0.copy()
    q_start[5] = math.radians(-320.0)  # UR10e axis 6 is limited to +-360 deg: 40 deg of margin
    q = np.array([q_start, q_start + np.radians([10.0, 0, 0, 0, 0, 0])])
    tol = Tolerances(joint_margin_deg=40.0, joint_step_deg=360.0)
    line = check_controller_lines(ur10e_kin, q, np.array([0.0, 1.0]), tol)
    assert [v.reason for v in line.violations] == ["joint limit on the controller's line (joint 6)"]
    rows = line_rows(ur10e_kin, q, line, tol)
    assert rows and {r.label for r in rows} == {"controller line joint 6 lower"}
    assert all(r.gradient[5] == 1.0 and np.count_nonzero(r.gradient) == 1 for r in rows)
    # what the rows ask beyond the joint-linear motion at their samples [rad]
    need = max(r.lower - r.gradient @ ((1 - r.f) * q[r.k] + r.f * q[r.k + 1]) for r in rows)
    dip = math.radians(-320.0) - line.q[:, 5].min()  # the line's axis 6 below the waypoints'
    assert need == pytest.approx(dip, rel=1e-6) and 1e-4 < need < 0.01
    for share, ok in ((1.0, True), (0.5, False)):
        lifted = q.copy()
        lifted[:, 5] += share * need
        again = check_controller_lines(ur10e_kin, lifted, np.array([0.0, 1.0]), tol)
        assert again.ok is ok
    assert again.joint_margin_rad.min() < math.radians(40.0)


def test_the_line_source_makes_rows_only_for_an_answer_it_verified(ur10e_kin):
    """The seed's line is not fed back: rows come for the joints whose violations were asked for."""
    from types import SimpleNamespace

    from refine.optimise.controller_line import ControllerLineSource

    q_start = Q0.copy()
    q_start[5] = math.radians(-320.0)
    q = np.array([q_start, q_start + np.radians([10.0, 0, 0, 0, 0, 0])])
    tol = Tolerances(joint_margin_deg=40.0, joint_step_deg=360.0)
    source = ControllerLineSource(ur10e_kin, tol)
    problem = SimpleNamespace(fused=SimpleNamespace(s=np.array([0.002, 0.007])))
    assert source.rows(problem, q) == ()  # never verified: the seed
    (v,) = source.violations(problem, q)
    assert (v.reason, v.index_start, v.s_start_m) == (
        "joint limit on the controller's line (joint 6)",
        0,
        0.002,
    )
    assert source.rows(problem, q) and source.checks == 1
    assert source.rows(problem, q + 1e-3) == ()


def test_a_re_solve_of_a_moved_path_drops_the_line_s_rows_and_keeps_the_others(ur10e_kin):
    """The line's rows hold for the path they were made on; a clearance row is its source's to refresh."""
    from refine.optimise.controller_line import ControllerLineSource
    from refine.optimise.problem import LinearRow

    rows = (
        LinearRow(0, 0.5, np.eye(6)[5], -6.0, "controller line joint 6 lower"),
        LinearRow(1, 0.0, np.ones(6), 0.1, "link_3 / table"),
        LinearRow(0, 0.25, np.ones(6), 0.02, "controller line singularity"),
    )
    kept = ControllerLineSource(ur10e_kin, Tolerances()).refresh_rows(rows, np.zeros((3, 6)))
    assert [r.label for r in kept] == ["link_3 / table"]


def test_the_final_check_takes_the_line_source_s_ik_only_for_the_same_joints_kinematics_and_wrist(ur10e_kin):
    """The refinement's own line check of its answer stands in for the final check's IK, and gives
    the final check what it finds by itself; other joints, another TCP or another wrist get none."""
    from types import SimpleNamespace

    from refine.optimise.controller_line import ControllerLineSource

    q = np.array([Q0, Q0 + np.radians([150.0, 0, 0, 0, 0, 0]), Q0 + np.radians([150.0, 5.0, 0, 0, 0, 0])])
    tol = Tolerances(joint_step_deg=360.0)
    source = ControllerLineSource(ur10e_kin, tol)
    source.violations(SimpleNamespace(fused=SimpleNamespace(s=np.arange(3.0))), q)
    no_wrist = np.zeros(2, dtype=bool)
    known = source.checked(q, ur10e_kin, no_wrist)
    assert known is not None
    s = np.array([0.0, 0.4, 0.5])
    alone = check_controller_lines(ur10e_kin, q, s, tol)
    taken = check_controller_lines(ur10e_kin, q, s, tol, known=known)
    assert not alone.ok and taken.violations == alone.violations
    np.testing.assert_array_equal(taken.q, alone.q)
    for field in (
        "singularity",
        "ik_error",
        "position_difference_m",
        "orientation_difference_deg",
        "joint_margin_rad",
    ):
        np.testing.assert_array_equal(getattr(taken, field), getattr(alone, field))
    tcp = np.eye(4)
    tcp[2, 3] = 0.001
    other_tcp = TcpKinematics(ur10e_kin.robot, np.eye(4), tcp)
    assert source.checked(q, other_tcp, no_wrist) is None
    assert source.checked(q, ur10e_kin, np.array([True, False])) is None
    assert source.checked(q + 1e-9, ur10e_kin, no_wrist) is None


@pytest.mark.parametrize("layout", ["in order", "shuffled", "crowded"])
def test_the_newton_start_is_one_damped_step_with_the_damped_inverse_interpolated_per_sample(layout):
    """Random waypoint Jacobians, samples and pose errors: each row's start is the joint-linear
    joints plus P e with P = P_a + t (P_b - P_a) of its segment and each waypoint's damped inverse
    P = J^T (J J^T + damping^2 I)^-1 worked out by its singular values (V diag(s / (s^2 + d^2)) U^T),
    row by row; a row whose step exceeds NEWTON_STEP_MAX keeps the joint-linear joints. The samples
    segment after segment (some segments empty), in no order, or most in one segment."""
    from scipy.spatial.transform import Rotation

    from refine.optimise import line_start as cl

    rng = np.random.default_rng(7)
    n_wp, m = 9, 40
    J_wp = rng.normal(size=(n_wp, 6, 6))
    segment = np.sort(rng.integers(0, n_wp - 1, m))
    if layout == "shuffled":
        segment = rng.permutation(segment)
    elif layout == "crowded":
        segment = np.sort(np.where(np.arange(m) % 8 == 0, segment, 3))
    t = rng.uniform(0.05, 0.95, m)
    q_lin = rng.normal(size=(m, 6))
    lin = np.tile(np.eye(4), (m, 1, 1))
    lin[:, :3, :3] = Rotation.random(m, random_state=1).as_matrix()
    lin[:, :3, 3] = rng.normal(size=(m, 3))
    err = (
        rng.normal(size=(m, 6)) * np.where(np.arange(m) % 5 == 0, 1e-1, 1e-5)[:, None]
    )  # some steps too long
    targets = lin.copy()
    targets[:, :3, 3] += err[:, :3]
    targets[:, :3, :3] = Rotation.from_rotvec(err[:, 3:]).as_matrix() @ lin[:, :3, :3]
    got = cl.newton_start(J_wp, segment, t, q_lin, lin, targets)

    def damped_inverse(J):
        U, sv, Vt = np.linalg.svd(J)
        return Vt.T @ np.diag(sv / (sv**2 + cl.NEWTON_DAMPING**2)) @ U.T

    taken = 0
    for k in range(m):
        a, b = damped_inverse(J_wp[segment[k]]), damped_inverse(J_wp[segment[k] + 1])
        dq = (a + t[k] * (b - a)) @ err[k]
        want = q_lin[k] + dq if np.abs(dq).max() <= cl.NEWTON_STEP_MAX else q_lin[k]
        taken += np.abs(dq).max() <= cl.NEWTON_STEP_MAX
        np.testing.assert_allclose(got[k], want, rtol=1e-9, atol=1e-15)
    assert 0 < taken < m


def test_a_previous_line_s_bows_start_the_ik_where_its_samples_match_and_the_figures_are_the_cold_check_s(
    ur10e_kin,
):
    """A path, its line checked; then the waypoints moved 1e-9 rad, one waypoint 0.02 rad (far), and
    one segment's largest step taken from just under 4 deg to just over (8 sub-steps to 10, so the
    samples after it shift): the bows start exactly the samples of the other segments, each start
    within 1e-9 of the new line's pose (targets by hand: chord and scipy slerp), and the check equals
    the cold one within the IK's tolerance (joints 1e-8 rad, residual 1e-9 m+rad stacked)."""
    from scipy.spatial.transform import Rotation, Slerp

    from refine.optimise.controller_line import IK_TOLERANCE, sample_parameters
    from refine.optimise.line_start import PREVIOUS_MOVE_MAX_RAD, previous_bows

    rng = np.random.default_rng(11)
    steps = np.radians(rng.uniform(-3.0, 3.0, size=(12, 6)))
    steps[5] = np.radians([4.0 - 1e-6, 1.0, -1.0, 0.5, 0.5, -0.5])  # segment 5: 8 sub-steps
    q_old = Q0 + np.vstack([np.zeros(6), np.cumsum(steps, axis=0)])
    tol = Tolerances(joint_step_deg=360.0)
    s = np.arange(len(q_old), dtype=float)
    old = check_controller_lines(ur10e_kin, q_old, s, tol)
    q = q_old + rng.uniform(-1e-9, 1e-9, size=q_old.shape)
    q[6:, 0] += np.radians(2e-6)  # segment 5's step over 4 deg: 10 sub-steps
    q[9] += 0.02  # far: segments 8 and 9 start without a bow
    m, segment, t = sample_parameters(q)
    kept = np.delete(np.arange(len(m)), [5, 8, 9])
    assert old.samples[5] == 8 and m[5] == 10 and (m[kept] == old.samples[kept]).all()
    assert 0.02 > PREVIOUS_MOVE_MAX_RAD > 2e-6

    bows = previous_bows(q, m, segment, t, (q_old, old), IK_TOLERANCE)
    expected = ~np.isin(segment, [5, 8, 9])
    np.testing.assert_array_equal(np.isfinite(bows).all(axis=1), expected)
    q_lin = q[segment] + t[:, None] * (q[segment + 1] - q[segment])
    start = (q_lin + bows)[expected]
    poses = ur10e_kin.poses(q)
    reached = ur10e_kin.poses(start)
    for k, T in zip(np.flatnonzero(expected), reached, strict=True):
        a, b, tk = poses[segment[k]], poses[segment[k] + 1], t[k]
        p = a[:3, 3] + tk * (b[:3, 3] - a[:3, 3])
        R = Slerp([0.0, 1.0], Rotation.from_matrix([a[:3, :3], b[:3, :3]]))([tk]).as_matrix()[0]
        err = np.concatenate([p - T[:3, 3], Rotation.from_matrix(R @ T[:3, :3].T).as_rotvec()])
        assert np.linalg.norm(err) <= 1e-9

    cold = check_controller_lines(ur10e_kin, q, s, tol)
    warm = check_controller_lines(ur10e_kin, q, s, tol, previous=(q_old, old))
    np.testing.assert_allclose(warm.q, cold.q, rtol=0.0, atol=1e-8)
    assert warm.ik_error.max() <= IK_TOLERANCE and cold.ik_error.max() <= IK_TOLERANCE
    np.testing.assert_allclose(warm.singularity, cold.singularity, rtol=0.0, atol=1e-8)
    np.testing.assert_allclose(warm.joint_margin_rad, cold.joint_margin_rad, rtol=0.0, atol=1e-8)
    for field in ("samples", "t", "segment", "position_difference_m", "orientation_difference_deg"):
        np.testing.assert_array_equal(getattr(warm, field), getattr(cold, field))
    assert [(v.index_start, v.index_end, v.reason) for v in warm.violations] == [
        (v.index_start, v.index_end, v.reason) for v in cold.violations
    ]


def test_only_segments_whose_two_waypoints_both_stayed_take_a_previous_bow(ur10e_kin):
    """A path's line checked; then every waypoint moved 1e-3 rad on joint 1 but waypoints 3 and 4
    (far beyond the move that keeps a bow, under the one that changes a sample count): only
    segment 3's samples take a bow, each the previous line's ``q_line - q_lin`` at its sample (by
    hand from the previous check's arrays); with waypoint 4 moved too, no sample takes one."""
    from refine.optimise.controller_line import IK_TOLERANCE, sample_parameters
    from refine.optimise.line_start import PREVIOUS_MOVE_MAX_RAD, previous_bows

    rng = np.random.default_rng(4)
    steps = np.radians(rng.uniform(-2.0, 2.0, size=(8, 6)))
    q_old = Q0 + np.vstack([np.zeros(6), np.cumsum(steps, axis=0)])
    old = check_controller_lines(ur10e_kin, q_old, np.arange(len(q_old), dtype=float), Tolerances())
    q = q_old.copy()
    q[:, 0] += 1e-3
    q[[3, 4], 0] = q_old[[3, 4], 0]
    assert 1e-3 > 2 * PREVIOUS_MOVE_MAX_RAD
    m, segment, t = sample_parameters(q)
    assert (m == old.samples).all()
    bows = previous_bows(q, m, segment, t, (q_old, old), IK_TOLERANCE)
    ours = segment == 3
    np.testing.assert_array_equal(np.isfinite(bows).all(axis=1), ours)
    assert np.isnan(bows[~ours]).all()
    s_old, t_old = old.segment[ours], old.t[ours]
    by_hand = old.q[ours] - (q_old[s_old] + t_old[:, None] * (q_old[s_old + 1] - q_old[s_old]))
    np.testing.assert_array_equal(bows[ours], by_hand)
    q[4, 0] += 1e-3
    assert np.isnan(previous_bows(q, m, segment, t, (q_old, old), IK_TOLERANCE)).all()


def test_the_per_segment_joint_margins_are_the_least_margin_of_any_sample_of_the_segment():
    """Against a loop over every segment's samples and joints, to the bit (the margins are rounded
    differences, so the sample nearest a limit has the least one)."""
    rng = np.random.default_rng(11)
    counts = np.array([1, 7, 3, 11, 5])  # samples per segment, segment after segment
    segment = np.repeat(np.arange(len(counts)), counts)
    q_line = rng.uniform(-3.0, 3.0, (len(segment), 6))
    lower, upper = -np.linspace(2.9, 3.1, 6), np.linspace(2.8, 3.2, 6)
    first = segment_starts(segment)
    got = segment_margins(q_line, first, lower, upper)
    for k in range(len(counts)):
        rows = q_line[segment == k]
        for j in range(6):
            want = min(min(float(r[j]) - float(lower[j]), float(upper[j]) - float(r[j])) for r in rows)
            assert got[k, j] == want


def test_the_dense_path_runs_through_each_waypoint_then_the_samples_of_its_segment():
    """Waypoint k, the samples of segment k in order of t, waypoint k+1, ...: each row's place is
    ``k + t``, as a loop over the segments lays them out."""
    rng = np.random.default_rng(5)
    q = rng.normal(size=(4, 6))
    m, segment, t = sample_parameters(np.array([[0.0] * 6, [0.01] * 6, [0.1] * 6, [0.11] * 6]))
    q_line = rng.normal(size=(len(t), 6))
    dense, place = through_samples(q, q_line, m, segment, t)
    rows, places = [], []
    for k in range(len(q)):
        rows.append(q[k])
        places.append(float(k))
        for i in np.flatnonzero(segment == k):
            rows.append(q_line[i])
            places.append(k + float(t[i]))
    np.testing.assert_array_equal(dense, np.array(rows))
    np.testing.assert_array_equal(place, np.array(places))
    assert np.all(np.diff(place) > 0.0)
