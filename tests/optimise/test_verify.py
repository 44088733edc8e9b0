"""The verifier (``check_path``) on joint paths built to break each tolerance by a known amount.

Every expectation here comes from outside the code under test: the IRB 4600 forward kinematics and
geometric Jacobian are rebuilt from the data-sheet table in ``shared/ROBOTS.md`` with scipy rotations,
the targets are offset from those poses by hand-chosen distances and scipy rotation vectors, and each
check is put just beyond and just inside its threshold (by 0.1 %, or a few hundredths of a degree).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.frames import rotation_angle_deg
from refine.optimise.verify import (
    SVD_BELOW,
    Violation,
    check_path,
    rotation_angles_deg,
    runs,
    singularity_measures,
)
from refine.paths import FusedPath
from refine.problem import Tolerances

# ---- the IRB 4600-60/2.05 from its data sheet (shared/ROBOTS.md), not from the package's model
ORIGINS = np.array(
    [
        [0.0, 0.0, 0.495],
        [0.175, 0.0, 0.0],
        [0.0, 0.0, 0.900],
        [0.0, 0.0, 0.175],
        [0.960, 0.0, 0.0],
        [0.135, 0.0, 0.0],
    ]
)
AXES = np.eye(3)[[2, 1, 1, 0, 1, 0]]
LOWER_DEG = np.array([-180.0, -90.0, -180.0, -400.0, -125.0, -400.0])
UPPER_DEG = np.array([180.0, 150.0, 75.0, 400.0, 120.0, 400.0])
REACH_M = 2.05
TCP_Z_M = 0.35  # the ``straight_tool`` fixture: TCP 0.35 m along the flange z axis

LOOSE = dict(
    position_m=1.0, orientation_deg=89.0, joint_margin_deg=0.0, singularity_margin=0.0, joint_step_deg=1e3
)
"""Tolerances no test path breaks: each test tightens only the one it is about."""

Q0_DEG = np.array([10.0, 20.0, -30.0, 40.0, 50.0, 60.0])


def fk(q: np.ndarray) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """T_base_TCP and, per joint, (origin, axis) in the base frame."""
    T = np.eye(4)
    joints = []
    for origin, axis, qi in zip(ORIGINS, AXES, q, strict=True):
        T = T @ _transform(np.eye(3), origin)
        joints.append((T[:3, 3].copy(), T[:3, :3] @ axis))
        T = T @ _transform(Rotation.from_rotvec(axis * qi).as_matrix(), np.zeros(3))
    flange = _transform(Rotation.from_euler("y", 90.0, degrees=True).as_matrix(), np.zeros(3))
    return T @ flange @ _transform(np.eye(3), [0.0, 0.0, TCP_Z_M]), joints


def _transform(R, p) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def scaled_jacobian(q: np.ndarray) -> np.ndarray:
    """Geometric TCP Jacobian with the linear rows divided by the data-sheet reach."""
    T, joints = fk(q)
    J = np.array([np.concatenate([np.cross(z, T[:3, 3] - o), z]) for o, z in joints]).T
    return np.diag([1.0 / REACH_M] * 3 + [1.0] * 3) @ J


def manipulability(q: np.ndarray) -> float:
    """sqrt(det(Js Jsᵀ)) = |det Js| for six joints."""
    return abs(float(np.linalg.det(scaled_jacobian(q))))


def path(rows_deg) -> np.ndarray:
    return np.radians(np.asarray(rows_deg, dtype=float))


def fused_on(q: np.ndarray, offsets=None, turns=None) -> FusedPath:
    """Targets at the data-sheet FK of ``q``, moved by ``offsets`` [m] and turned by ``turns`` (R_TCP_target)."""
    poses = np.array([fk(qk)[0] for qk in q])
    positions = poses[:, :3, 3] + (0.0 if offsets is None else offsets)
    rotations = poses[:, :3, :3] if turns is None else poses[:, :3, :3] @ turns
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])
    n = len(q)
    return FusedPath(s, positions, rotations, np.full(n, 0.1), np.arange(n, dtype=float), np.zeros(n))


def reasons(check) -> list[tuple[str, int, int]]:
    return [(v.reason, v.index_start, v.index_end) for v in check.violations]


def near_q0(n: int) -> np.ndarray:
    """``n`` waypoints one degree apart on every joint, starting at Q0."""
    return path(Q0_DEG + np.arange(n)[:, None] * 1.0)


def test_the_independent_model_is_the_robot_the_verifier_checks(kin):
    """Guards the premise of this file: the data-sheet FK above equals the package's (to 1e-12 m)."""
    q = near_q0(4)
    np.testing.assert_allclose(kin.poses(q), np.array([fk(qk)[0] for qk in q]), atol=1e-12)


def test_a_path_on_its_targets_passes_with_the_default_tolerances(kin):
    q = near_q0(6)
    check = check_path(kin, q, fused_on(q), Tolerances(), axisymmetric=False)
    assert check.ok and check.violations == ()
    np.testing.assert_allclose(check.position_error_m, 0.0, atol=1e-12)
    np.testing.assert_allclose(check.orientation_deviation_deg, 0.0, atol=1e-5)


# ---- position


def test_a_position_error_just_beyond_the_tolerance_is_reported_with_its_size(kin):
    tol = 1e-6
    q = near_q0(6)
    sizes = tol * np.array([0.5, 0.999, 1.001, 1.002, 0.999, 1.0005])
    directions = np.random.default_rng(3).normal(size=(6, 3))
    offsets = sizes[:, None] * directions / np.linalg.norm(directions, axis=1)[:, None]
    fused = fused_on(q, offsets=offsets)
    check = check_path(kin, q, fused, Tolerances(**{**LOOSE, "position_m": tol}), axisymmetric=False)
    np.testing.assert_allclose(check.position_error_m, sizes, rtol=1e-6)
    assert reasons(check) == [("position", 2, 3), ("position", 5, 5)]
    first = check.violations[0]
    assert first.worst == pytest.approx(1.002e-6, rel=1e-6) and first.unit == "m" and first.limit == tol
    assert (first.s_start_m, first.s_end_m) == (fused.s[2], fused.s[3])
    assert check.violations[1].worst == pytest.approx(1.0005e-6, rel=1e-6)


# ---- orientation cone


def _turns(axes, angles_deg) -> np.ndarray:
    axes = np.asarray(axes, dtype=float)
    axes = axes / np.linalg.norm(axes, axis=1)[:, None]
    return Rotation.from_rotvec(axes * np.radians(angles_deg)[:, None]).as_matrix()


def test_an_orientation_just_outside_the_cone_is_reported_with_its_angle(kin):
    q = near_q0(5)
    angles = np.array([0.0, 2.99, 3.01, 1.0, 3.05])
    axes = np.random.default_rng(5).normal(size=(5, 3))
    check = check_path(
        kin,
        q,
        fused_on(q, turns=_turns(axes, angles)),
        Tolerances(**{**LOOSE, "orientation_deg": 3.0}),
        False,
    )
    np.testing.assert_allclose(check.orientation_deviation_deg, angles, atol=1e-6)
    assert reasons(check) == [("orientation", 2, 2), ("orientation", 4, 4)]
    assert [v.worst for v in check.violations] == pytest.approx([3.01, 3.05], abs=1e-6)
    assert check.violations[0].unit == "deg" and check.violations[0].limit == 3.0


def test_an_axisymmetric_tool_is_judged_on_its_axis_tilt_alone(kin):
    """A 40 deg spin about the tool axis is free for a round nozzle; only the tilt of z counts."""
    q = near_q0(4)
    tilt = np.array([2.99, 3.01, 0.5, 2.0])
    # in the TCP frame: spin about z, then tilt about an axis in the xy plane
    spin = Rotation.from_euler("z", 40.0, degrees=True).as_matrix()
    turns = spin @ _turns([[1.0, 0.0, 0.0], [0.3, 1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]], tilt)
    tol = Tolerances(**{**LOOSE, "orientation_deg": 3.0})
    round_tool = check_path(kin, q, fused_on(q, turns=turns), tol, axisymmetric=True)
    np.testing.assert_allclose(round_tool.orientation_deviation_deg, tilt, atol=1e-6)
    assert reasons(round_tool) == [("orientation", 1, 1)]
    assert round_tool.violations[0].worst == pytest.approx(3.01, abs=1e-6)
    full = check_path(kin, q, fused_on(q, turns=turns), tol, axisymmetric=False)
    expected = np.degrees(Rotation.from_matrix(turns).magnitude())
    np.testing.assert_allclose(full.orientation_deviation_deg, expected, atol=1e-6)
    assert reasons(full) == [("orientation", 0, 3)]


def test_the_slack_of_a_repaired_path_widens_the_cone_where_it_is_given(kin):
    q = near_q0(4)
    angles = np.array([3.01, 3.01, 3.3, 3.3])
    turns = _turns(np.random.default_rng(7).normal(size=(4, 3)), angles)
    tol = Tolerances(**{**LOOSE, "orientation_deg": 3.0})
    slack = np.array([0.02, 0.0, 0.29, 0.31])
    check = check_path(kin, q, fused_on(q, turns=turns), tol, False, slack_deg=slack)
    assert reasons(check) == [("orientation", 1, 2)]
    assert check.violations[0].worst == pytest.approx(3.3, abs=1e-6)


# ---- joint-limit margin


@pytest.mark.parametrize("joint", range(6))
@pytest.mark.parametrize("side", ["lower", "upper"])
def test_a_joint_just_inside_its_margin_is_reported_and_one_just_outside_is_not(kin, joint, side):
    margin_deg = 2.0
    rows = np.tile(Q0_DEG, (4, 1))
    limit = LOWER_DEG[joint] if side == "lower" else UPPER_DEG[joint]
    inward = 1.0 if side == "lower" else -1.0
    rows[1, joint] = limit + inward * (margin_deg - 0.01)  # 1.99 deg from the limit: too close
    rows[2, joint] = limit + inward * (margin_deg + 0.01)  # 2.01 deg: fine
    rows[3, joint] = limit + inward * 0.5 * margin_deg
    q = path(rows)
    check = check_path(kin, q, fused_on(q), Tolerances(**{**LOOSE, "joint_margin_deg": margin_deg}), False)
    name = f"joint limit (joint {joint + 1})"
    assert reasons(check) == [(name, 1, 1), (name, 3, 3)]
    assert check.violations[0].worst == pytest.approx(math.radians(1.99), abs=1e-12)
    assert check.violations[1].worst == pytest.approx(math.radians(1.0), abs=1e-12)
    assert check.violations[0].unit == "rad" and check.violations[0].limit == pytest.approx(
        math.radians(2.0), abs=1e-6
    )
    assert check.joint_margin_rad[2] == pytest.approx(math.radians(2.01), abs=1e-12)


def test_the_joint_margin_figure_is_the_closest_joint_to_its_limit(kin):
    q = near_q0(3)
    expected = np.min(np.minimum(q - np.radians(LOWER_DEG), np.radians(UPPER_DEG) - q), axis=1)
    check = check_path(kin, q, fused_on(q), Tolerances(), False)
    np.testing.assert_allclose(check.joint_margin_rad, expected, atol=1e-12)
    assert np.allclose(
        expected, np.radians(120.0 - 50.0 - np.array([0.0, 1.0, 2.0]))
    )  # joint 5, upper limit 120 deg


# ---- joint step


def test_a_joint_step_just_over_the_limit_is_reported_in_degrees(kin):
    rows = np.tile(Q0_DEG, (4, 1))
    rows[:, 0] += [0.0, 19.99, 40.0, 40.0]  # steps 19.99, 20.01, 0
    rows[:, 3] += [0.0, 0.0, 0.0, -20.5]
    q = path(rows)
    check = check_path(kin, q, fused_on(q), Tolerances(**{**LOOSE, "joint_step_deg": 20.0}), False)
    assert reasons(check) == [("joint step (joint 1)", 1, 1), ("joint step (joint 4)", 2, 2)]
    assert [v.worst for v in check.violations] == pytest.approx([20.01, 20.5], abs=1e-9)
    assert check.violations[0].unit == "deg" and check.violations[0].limit == 20.0


# ---- singularity at the waypoints


def test_the_singularity_figures_are_the_scaled_manipulability_and_smallest_singular_value(kin):
    q = path([Q0_DEG, [0.0, 100.0, -150.0, 0.0, 40.0, 0.0], [10.0, 20.0, -30.0, 40.0, 5.0, 60.0]])
    check = check_path(kin, q, fused_on(q), Tolerances(**LOOSE), False)
    np.testing.assert_allclose(check.singularity, [manipulability(qk) for qk in q], rtol=1e-9)
    smallest = [np.linalg.svd(scaled_jacobian(qk), compute_uv=False)[-1] for qk in q]
    np.testing.assert_allclose(check.sigma_min, smallest, rtol=1e-9)


def test_the_smallest_singular_values_are_computed_when_asked_for_also_after_a_replace(kin):
    """A check's smallest singular values come when read (no tolerance needs them), from its own Jacobians."""
    q = path([Q0_DEG, [0.0, 100.0, -150.0, 0.0, 40.0, 0.0], [10.0, 20.0, -30.0, 40.0, 5.0, 60.0]])
    check = check_path(kin, q, fused_on(q), Tolerances(**LOOSE), False)
    assert "sigma_min" not in vars(check)
    extra = Violation(0, 1, 0.0, 0.1, "clearance", 0.001, "m", 0.005)
    grown = dataclasses.replace(check, violations=(*check.violations, extra))
    smallest = [np.linalg.svd(scaled_jacobian(qk), compute_uv=False)[-1] for qk in q]
    np.testing.assert_allclose(grown.sigma_min, smallest, rtol=1e-9)
    np.testing.assert_allclose(check.sigma_min, smallest, rtol=1e-9)
    assert grown.violations[-1] is extra and "sigma_min" in vars(check)


def test_the_manipulability_alone_skips_the_singular_values(kin):
    q = path([Q0_DEG, [0.0, 100.0, -150.0, 0.0, 40.0, 0.0], [10.0, 20.0, -30.0, 40.0, 5.0, 60.0]])
    w, smin = singularity_measures(kin, q, smallest=False)
    np.testing.assert_allclose(w, [manipulability(qk) for qk in q], rtol=1e-9)
    assert np.isnan(smin).all() and smin.shape == (3,)


def test_a_wrist_just_below_the_singularity_margin_is_reported_with_its_measure(kin):
    """Wrist angles 30, 20, 5, 20, 30 deg: the margin set 0.1 % above / below the measure at 5 deg."""
    rows = np.tile(Q0_DEG, (5, 1))
    rows[:, 4] = [30.0, 20.0, 5.0, 20.0, 30.0]
    q = path(rows)
    w5 = manipulability(q[2])
    beyond = check_path(kin, q, fused_on(q), Tolerances(**{**LOOSE, "singularity_margin": 1.001 * w5}), False)
    assert reasons(beyond) == [("singularity", 2, 2)]
    assert beyond.violations[0].worst == pytest.approx(w5, rel=1e-9)
    assert beyond.violations[0].limit == pytest.approx(1.001 * w5)
    inside = check_path(kin, q, fused_on(q), Tolerances(**{**LOOSE, "singularity_margin": 0.999 * w5}), False)
    assert inside.ok


def test_a_stretched_wrist_is_a_singularity_of_measure_zero(kin):
    rows = np.tile(Q0_DEG, (3, 1))
    rows[:, 4] = [10.0, 0.0, 10.0]  # axes 4 and 6 in line
    q = path(rows)
    check = check_path(kin, q, fused_on(q), Tolerances(**{**LOOSE, "singularity_margin": 1e-6}), False)
    assert ("singularity", 1, 1) in reasons(check)
    assert check.singularity[1] < 1e-12 and check.sigma_min[1] < 1e-12


# ---- singularity between the waypoints


def test_a_wrist_flip_between_two_clear_waypoints_is_reported_between_them(kin):
    """Wrist +1.25 -> -1.25 deg is sampled at +-0.4167 deg (2.5 deg in three steps of at most 1 deg).

    The margin is put 0.1 % above and below the measure there; both waypoints stay clear of it.
    """
    rows = np.tile(Q0_DEG, (4, 1))
    rows[:, 4] = [10.0, 1.25, -1.25, -10.0]
    q = path(rows)
    inner = np.array(Q0_DEG)
    inner[4] = 1.25 - 2.5 / 3.0
    w_inner = manipulability(np.radians(inner))
    assert manipulability(q[1]) > 2.0 * w_inner  # the waypoints themselves are clear
    beyond = check_path(
        kin, q, fused_on(q), Tolerances(**{**LOOSE, "singularity_margin": 1.001 * w_inner}), False
    )
    assert reasons(beyond) == [("singularity between waypoints", 1, 1)]
    assert beyond.violations[0].worst == pytest.approx(w_inner, rel=1e-9)
    assert beyond.singularity_between[1] == pytest.approx(w_inner, rel=1e-9)
    inside = check_path(
        kin, q, fused_on(q), Tolerances(**{**LOOSE, "singularity_margin": 0.999 * w_inner}), False
    )
    assert inside.ok


def test_a_flip_through_the_stretched_wrist_at_the_midpoint_measures_zero(kin):
    rows = np.tile(Q0_DEG, (2, 1))
    rows[:, 4] = [0.4, -0.4]  # under one degree: sampled at its midpoint, the stretched wrist
    q = path(rows)
    margin = 0.5 * manipulability(q[0])
    check = check_path(kin, q, fused_on(q), Tolerances(**{**LOOSE, "singularity_margin": margin}), False)
    assert reasons(check) == [("singularity between waypoints", 0, 0)]
    assert check.violations[0].worst < 1e-12


# ---- runs


def test_runs_are_the_inclusive_bounds_of_each_stretch_of_true():
    mask = np.array([True, True, False, True, False, False, True, True, True])
    assert runs(mask) == [(0, 1), (3, 3), (6, 8)]
    assert runs(np.zeros(4, dtype=bool)) == []
    assert runs(np.ones(3, dtype=bool)) == [(0, 2)]


def test_the_worst_of_a_run_is_its_own_worst_waypoint(kin):
    """Joint 5 at 1.5 then 1.0 deg from its upper limit (margin 2 deg): one run, worst 1.0 deg, the
    closest; the next waypoint, 3 deg away, is outside the run and does not count."""
    rows = np.tile(Q0_DEG, (4, 1))
    rows[1:, 4] = UPPER_DEG[4] - np.array([1.5, 1.0, 3.0])
    q = path(rows)
    check = check_path(kin, q, fused_on(q), Tolerances(**{**LOOSE, "joint_margin_deg": 2.0}), False)
    assert reasons(check) == [("joint limit (joint 5)", 1, 2)]
    assert check.violations[0].worst == pytest.approx(math.radians(1.0), abs=1e-12)


def test_a_repaired_waypoint_after_a_run_does_not_count_in_the_run_s_worst(kin):
    """Deviations 3.2, 3.1, 3.4 deg against a 3 deg cone, the third widened by 0.5 deg of slack:
    the run is waypoints 0-1, worst 3.2 deg, though the waypoint after it deviates more (allowed)."""
    q = near_q0(4)
    angles = np.array([3.2, 3.1, 3.4, 0.0])
    turns = _turns(np.random.default_rng(11).normal(size=(4, 3)), angles)
    tol = Tolerances(**{**LOOSE, "orientation_deg": 3.0})
    slack = np.array([0.0, 0.0, 0.5, 0.0])
    check = check_path(kin, q, fused_on(q, turns=turns), tol, False, slack_deg=slack)
    assert reasons(check) == [("orientation", 0, 1)]
    assert check.violations[0].worst == pytest.approx(3.2, abs=1e-6)


def test_a_tool_axis_on_its_demonstrated_axis_to_round_off_deviates_by_zero(kin):
    """Demonstrated rotations orthonormal only to 1e-12 (as any measured rotation is): the cosine
    of the axis tilt comes out as 1 + 1e-12 and must read as 0 deg, not as an undefined angle."""
    q = near_q0(3)
    fused = fused_on(q)
    rough = FusedPath(
        fused.s, fused.positions, fused.rotations * (1.0 + 1e-12), fused.speed, fused.t_demo, fused.residual
    )
    check = check_path(kin, q, rough, Tolerances(**{**LOOSE, "orientation_deg": 3.0}), axisymmetric=True)
    np.testing.assert_allclose(check.orientation_deviation_deg, 0.0, atol=1e-4)
    assert check.ok


def test_segment_samples_are_at_whole_fractions_of_each_segment(kin):
    """A segment whose largest joint move is 2.5 deg is sampled at 1/3 and 2/3 (steps <= 1 deg would
    need 3 steps), one of 0.4 deg at its middle; the minimum of each is found among those samples."""
    from refine.optimise.verify import segment_singularity

    q = np.zeros((3, 6))
    q[:, 4] = np.radians([30.0, 27.5, 27.9])  # the wrist bends: the measure falls as q5 falls
    w, frac = segment_singularity(kin, q)
    np.testing.assert_allclose(frac, [2 / 3, 0.5])
    expected = singularity_measures(kin, np.array([q[0] + 2 / 3 * (q[1] - q[0]), 0.5 * (q[1] + q[2])]))[0]
    np.testing.assert_allclose(w, expected, rtol=1e-12)


def test_midpoint_jacobians_given_serve_only_where_the_midpoint_is_each_segment_s_only_sample(kin):
    """Jacobians given for the midpoints are those of the midpoints when every segment moves at most
    2 deg (its only sample); with a segment of 2.5 deg (sampled at thirds) they are not used."""
    from refine.optimise.verify import segment_singularity

    q = np.zeros((3, 6))
    q[:, 4] = np.radians([30.0, 28.5, 27.9])  # steps of 1.5 and 0.6 deg: one sample per segment
    mid = q[:-1] + 0.5 * np.diff(q, axis=0)
    w, frac = segment_singularity(kin, q, midpoint_jacobians=kin.jacobians(mid))
    np.testing.assert_allclose(frac, [0.5, 0.5])
    np.testing.assert_allclose(w, singularity_measures(kin, mid)[0], rtol=1e-12)
    wrong = np.zeros((2, 6, 6))  # not the midpoints' Jacobians: where used, every measure would be 0
    q[1, 4] = np.radians(27.5)  # the first segment moves 2.5 deg: sampled at 1/3 and 2/3
    w, frac = segment_singularity(kin, q, midpoint_jacobians=wrong)
    np.testing.assert_allclose(frac, [2 / 3, 0.5])
    assert np.all(w > 0.0)


def test_the_rounds_take_the_singular_points_from_the_check_of_the_same_joints(kin):
    """The wrist flip of the test above: the check keeps where in segment 1 the least measure is
    (a third or two thirds of the way, +-0.4167 deg), and the rounds' new singular points taken
    from it are those computed afresh."""
    from refine.optimise.problem import ActiveSet
    from refine.optimise.rounds import new_singular_points

    rows = np.tile(Q0_DEG, (4, 1))
    rows[:, 4] = [10.0, 1.25, -1.25, -10.0]
    q = path(rows)
    inner = np.array(Q0_DEG)
    inner[4] = 1.25 - 2.5 / 3.0
    margin = 1.001 * manipulability(np.radians(inner))
    check = check_path(kin, q, fused_on(q), Tolerances(**{**LOOSE, "singularity_margin": margin}), False)
    assert min(abs(check.singularity_between_at[1] - f) for f in (1 / 3, 2 / 3)) < 1e-12
    fresh = new_singular_points(kin, q, margin, ActiveSet())
    taken = new_singular_points(kin, q, margin, ActiveSet(), check)
    assert taken == fresh and any(k == 1 for k, _ in taken.singular_segments)


def _jacobians_with(singular: np.ndarray, columns: int, seed: int) -> np.ndarray:
    """Scaled Jacobians (M, 6, columns) with the singular values ``singular`` (M, 6), random bases."""
    rng = np.random.default_rng(seed)
    M = len(singular)
    U = np.linalg.qr(rng.normal(size=(M, 6, 6)))[0]
    V = np.linalg.qr(rng.normal(size=(M, columns, columns)))[0][:, :, :6]
    return U @ (singular[:, :, None] * np.swapaxes(V, 1, 2))


@pytest.mark.parametrize("columns", [6, 7])
def test_the_smallest_singular_value_is_the_svd_s_from_clear_of_the_singularity_to_on_it(kin, columns):
    """The measures of Jacobians of known singular values: σ_min and sqrt(det(Js Jsᵀ)) = Π σ.

    Largest 1.7, smallest from 1.7 down through the switch to the SVD (:data:`SVD_BELOW`) to 1e-9
    and exactly 0; the expectation is the singular values put in, and numpy's SVD of the same matrix.
    """
    smallest = np.array([0.45, 0.4, 3e-2, 1.01 * SVD_BELOW * 1.7, 0.99 * SVD_BELOW * 1.7, 1e-4, 1e-9, 0.0])
    singular = np.column_stack([np.full(8, 1.7), [1.2] * 8, [0.9] * 8, [0.6] * 8, [0.5] * 8, smallest])
    Js = _jacobians_with(singular, columns, seed=columns)
    scale = np.array([1.0 / kin.robot.spec.reach_m] * 3 + [1.0] * 3)[:, None]
    w, smin = singularity_measures(kin, np.zeros((8, columns)), jacobians=Js / scale)
    np.testing.assert_allclose(smin, smallest, rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(smin, np.linalg.svd(Js, compute_uv=False)[:, -1], rtol=1e-9, atol=1e-14)
    # six joints: |det Js|; seven: sqrt(det(Js Jsᵀ)), whose determinant's round-off (about 1e-16) puts
    # the root within 1e-8 of the product
    atol = 1e-14 if columns == 6 else 1e-7
    np.testing.assert_allclose(w, singular.prod(axis=1), rtol=1e-9, atol=atol)
    w_only, _ = singularity_measures(kin, np.zeros((8, columns)), smallest=False, jacobians=Js / scale)
    np.testing.assert_allclose(w_only, singular.prod(axis=1), rtol=1e-9, atol=atol)


def test_the_orientation_angle_is_the_geodesic_angle_from_round_off_to_a_half_turn():
    """Angles put in as rotation vectors (1e-9 rad to π) come out as scipy's angle of R_aᵀ R_b."""
    rng = np.random.default_rng(5)
    angles = np.concatenate(
        [[1e-9, 1e-6, 1e-3, 0.05, 1.0, np.pi / 2 - 1e-9, np.pi / 2, 2.5, np.pi - 1e-6, np.pi]] * 20
    )
    axes = rng.normal(size=(len(angles), 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    R_a = Rotation.random(len(angles), random_state=6).as_matrix()
    R_b = R_a @ Rotation.from_rotvec(axes * angles[:, None]).as_matrix()
    got = rotation_angles_deg(R_a, R_b)
    np.testing.assert_allclose(got, np.degrees(angles), rtol=0.0, atol=1e-10)
    np.testing.assert_allclose(got, rotation_angle_deg(R_a, R_b), rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(rotation_angles_deg(R_a, R_a), 0.0, atol=1e-12)


def test_the_orientation_angle_of_rounded_matrices_is_the_one_of_their_nearest_rotations_as_before():
    """Matrices off orthonormal by 1e-6 (rotations written with six decimals) get scipy's angle itself."""
    R_a = Rotation.random(50, random_state=7).as_matrix()
    R_b = R_a @ Rotation.from_rotvec(np.full((50, 3), 0.02)).as_matrix()
    rounded = np.round(R_b, 6)
    np.testing.assert_array_equal(rotation_angles_deg(R_a, rounded), rotation_angle_deg(R_a, rounded))
    np.testing.assert_array_equal(
        rotation_angles_deg(np.round(R_a, 6), R_b), rotation_angle_deg(np.round(R_a, 6), R_b)
    )


def test_the_orthonormality_error_is_the_largest_entry_of_rt_r_less_the_identity():
    """Against each matrix's own ``|RᵀR - I|`` (a loop of 3 × 3 products): rotations, rotations off
    by rounding and by 1e-11, a scaled one and a shear."""
    from refine.optimise.verify import orthonormal_error

    rng = np.random.default_rng(4)
    R = Rotation.random(60, random_state=4).as_matrix()
    R[::5] += 1e-11 * rng.normal(size=R[::5].shape)
    R[1] *= 1.001
    R[2, 0, 1] += 0.3
    expected = np.array([np.abs(r.T @ r - np.eye(3)).max() for r in R])
    assert np.abs(orthonormal_error(R) - expected).max() <= 1e-15


def plain_segment_minima(q: np.ndarray, measure, max_step_deg: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Segment by segment: the samples at j/m, m = max(2, ceil(largest joint move / step)), their least
    ``measure`` and the first fraction where it is."""
    least, where = [], []
    for a, b in zip(q[:-1], q[1:], strict=True):
        m = max(2, math.ceil(math.degrees(np.abs(b - a).max()) / max_step_deg))
        fractions = [j / m for j in range(1, m)]
        values = [measure(a + f * (b - a)) for f in fractions]
        i = int(np.argmin(values))  # the first of equal least values
        least.append(values[i])
        where.append(fractions[i])
    return np.array(least), np.array(where)


def test_each_segment_s_least_measure_and_where_it_is_are_those_of_a_plain_loop_over_its_samples(kin):
    """Segments of 0.4 to 9.3 deg (one to ten samples), the wrist through its stretched pose inside
    some of them: the data-sheet model's measure at every sample, segment by segment."""
    from refine.optimise.verify import segment_singularity

    rows = np.tile(Q0_DEG, (7, 1))
    rows[:, 4] = [6.0, 5.6, 3.1, -2.2, -4.0, 5.3, 4.9]  # 0.4, 2.5, 5.3, 1.8, 9.3, 0.4 deg
    rows[:, 0] += [0.0, 0.3, 0.1, 0.9, 0.2, 0.0, 0.7]
    q = path(rows)
    w, frac = segment_singularity(kin, q)
    expected_w, expected_frac = plain_segment_minima(q, manipulability)
    np.testing.assert_allclose(w, expected_w, rtol=1e-9, atol=1e-12)
    assert np.array_equal(frac, expected_frac)
    assert len(set(np.round(1.0 / frac, 6))) > 2  # not all at the midpoint


def test_equal_least_measures_in_a_segment_give_its_first_sample():
    """A stand-in model whose measure is constant over stretches of joint 1: ties inside segments,
    where the first sample with the least value is the one reported (as a plain loop's argmin)."""
    from types import SimpleNamespace

    from refine.optimise.verify import segment_singularity

    def jacobians(q):  # |det| = (1 + floor(10 q1))⁶: equal on each 0.1 rad of joint 1
        return (1.0 + np.floor(10.0 * np.abs(q[:, 0])))[:, None, None] * np.eye(6)

    stand_in = SimpleNamespace(robot=SimpleNamespace(spec=SimpleNamespace(reach_m=1.0), chain=None), jacobians=jacobians)
    q = np.zeros((5, 6))
    q[:, 0] = [0.35, 0.02, 0.05, 0.31, 0.0]  # 19, 1.7, 15, 18 deg: the least values come in runs
    w, frac = segment_singularity(stand_in, q)
    expected_w, expected_frac = plain_segment_minima(q, lambda qk: float(np.abs(np.linalg.det(jacobians(qk[None])[0]))))
    assert np.array_equal(w, expected_w)
    assert np.array_equal(frac, expected_frac)
    assert np.any(frac < 0.5) and np.any(frac > 0.5)

