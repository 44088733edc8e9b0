"""The refinement NLP evaluated at known joints: every row, bound and cost term against its definition.

Targets are put at known offsets and turns from the poses Pinocchio gives (an implementation
separate from the CasADi kinematics inside the NLP); bounds come from the data-sheet limits; the
orientation cost from its documented formula ``mean 2(1 - cos θ)·(180/π)²``.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.errors import InputError
from refine.optimise.problem import ActiveSet, Weights, build_refinement
from refine.paths import FusedPath
from refine.problem import Tolerances

LOWER_DEG = np.array([-180.0, -90.0, -180.0, -400.0, -125.0, -400.0])  # IRB 4600 data sheet
UPPER_DEG = np.array([180.0, 150.0, 75.0, 400.0, 120.0, 400.0])
REACH_M = 2.05
N = 5


@pytest.fixture(scope="module")
def q():
    base = np.radians([10.0, 20.0, -30.0, 40.0, 50.0, 60.0])
    return base + np.radians(np.arange(N)[:, None] * np.array([1.0, -0.5, 0.8, 2.0, -1.5, 3.0]))


def _fused(kin, q, offsets, turns, s_scale=1.0):
    poses = kin.poses(q)
    positions = poses[:, :3, 3] + offsets
    s = s_scale * np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])
    return FusedPath(
        s, positions, poses[:, :3, :3] @ turns, np.full(N, 0.1), np.arange(N, dtype=float), np.zeros(N)
    )


def _turns(angles_deg, seed=0, axes=None):
    axes = np.random.default_rng(seed).normal(size=(N, 3)) if axes is None else np.asarray(axes, dtype=float)
    axes = axes / np.linalg.norm(axes, axis=1)[:, None]
    return Rotation.from_rotvec(axes * np.radians(angles_deg)[:, None]).as_matrix()


def _evaluate(nlp, x):
    fg = ca.Function("fg", [nlp.nlp["x"], nlp.nlp["p"]], [nlp.nlp["f"], nlp.nlp["g"]])
    f, g = fg(x, nlp.params)
    return float(f), np.asarray(g).ravel()


def _standard(robot, tool, kin, q, tolerances, **options):
    """The NLP on targets at OFFSETS and turned by ANGLES from the poses of ``q``."""
    return build_refinement(
        robot, _fused(kin, q, OFFSETS, _turns(ANGLES)), np.eye(4), tool, tolerances, **options
    )


ANGLES = np.array([0.0, 1.0, 2.5, 4.0, 0.3])
OFFSETS = np.array(
    [[0.0, 0.0, 0.0], [1e-3, 0.0, 0.0], [0.0, -2e-3, 0.0], [0.0, 0.0, 3e-3], [1e-3, 1e-3, -1e-3]]
)


def test_rows_are_the_position_error_the_cone_cosine_and_the_joint_steps(irb4600, straight_tool, kin, q):
    fused = _fused(kin, q, OFFSETS, _turns(ANGLES))
    nlp = build_refinement(irb4600, fused, np.eye(4), straight_tool, Tolerances())
    _, g = _evaluate(nlp, q.ravel())
    per_waypoint = g[: 4 * N].reshape(N, 4)
    np.testing.assert_allclose(per_waypoint[:, :3], -OFFSETS, atol=1e-12)  # reached minus target
    np.testing.assert_allclose(per_waypoint[:, 3], np.cos(np.radians(ANGLES)), atol=1e-12)
    steps = g[4 * N : 4 * N + 6 * (N - 1)].reshape(N - 1, 6)
    np.testing.assert_allclose(steps, np.diff(q, axis=0), atol=1e-15)
    assert len(g) == 4 * N + 6 * (N - 1)


def test_row_bounds_are_equality_on_position_the_cone_and_the_step_limit(irb4600, straight_tool, kin, q):
    tol = Tolerances(orientation_deg=4.5, joint_step_deg=12.0)
    nlp = build_refinement(irb4600, _fused(kin, q, OFFSETS, _turns(ANGLES)), np.eye(4), straight_tool, tol)
    lbg, ubg = nlp.lbg[: 4 * N].reshape(N, 4), nlp.ubg[: 4 * N].reshape(N, 4)
    np.testing.assert_array_equal(lbg[:, :3], 0.0)
    np.testing.assert_array_equal(ubg[:, :3], 0.0)
    np.testing.assert_allclose(lbg[:, 3], math.cos(math.radians(4.5)), rtol=1e-15)
    assert np.all(ubg[:, 3] >= 1.0) and np.all(ubg[:, 3] < 1.0 + 1e-6)
    np.testing.assert_allclose(nlp.lbg[4 * N :], -math.radians(12.0), rtol=1e-15)
    np.testing.assert_allclose(nlp.ubg[4 * N :], math.radians(12.0), rtol=1e-15)


def test_variable_bounds_are_the_data_sheet_limits_less_the_margin(irb4600, straight_tool, kin, q):
    nlp = _standard(irb4600, straight_tool, kin, q, Tolerances(joint_margin_deg=3.5))
    np.testing.assert_allclose(nlp.lbx, np.tile(np.radians(LOWER_DEG + 3.5), N), atol=1e-12)
    np.testing.assert_allclose(nlp.ubx, np.tile(np.radians(UPPER_DEG - 3.5), N), atol=1e-12)


def test_an_axisymmetric_cone_row_is_the_cosine_of_the_tool_axis_tilt(irb4600, straight_tool, kin, q):
    tilt = np.array([0.5, 1.5, 2.0, 3.0, 0.0])
    spin = Rotation.from_euler("z", 50.0, degrees=True).as_matrix()
    turns = spin @ _turns(tilt, axes=[[1, 0, 0], [0, 1, 0], [1, 1, 0], [1, -2, 0], [0, 1, 0]])
    nlp = build_refinement(
        irb4600,
        _fused(kin, q, 0.0 * OFFSETS, turns),
        np.eye(4),
        straight_tool,
        Tolerances(),
        axisymmetric=True,
    )
    _, g = _evaluate(nlp, q.ravel())
    np.testing.assert_allclose(g[: 4 * N].reshape(N, 4)[:, 3], np.cos(np.radians(tilt)), atol=1e-12)


def test_the_orientation_cost_is_the_mean_of_two_one_minus_cos_in_squared_degrees(
    irb4600, straight_tool, kin, q
):
    weights = Weights(orientation=1.7, velocity=0.0, acceleration=0.0)
    nlp = build_refinement(
        irb4600,
        _fused(kin, q, OFFSETS, _turns(ANGLES)),
        np.eye(4),
        straight_tool,
        Tolerances(),
        weights=weights,
    )
    f, _ = _evaluate(nlp, q.ravel())
    expected = 1.7 * np.mean(2.0 * (1.0 - np.cos(np.radians(ANGLES)))) * (180.0 / math.pi) ** 2
    assert f == pytest.approx(expected, rel=1e-12)
    assert f == pytest.approx(1.7 * np.mean(ANGLES**2), rel=1e-3)  # about the squared angle in degrees


def _smoothness(irb4600, straight_tool, kin, q, x_rows, s_scale=1.0, **w):
    fused = _fused(kin, q, OFFSETS, _turns(0.0 * ANGLES), s_scale)
    nlp = build_refinement(
        irb4600, fused, np.eye(4), straight_tool, Tolerances(), weights=Weights(orientation=0.0, **w)
    )
    return _evaluate(nlp, np.asarray(x_rows).ravel())[0]


def test_the_velocity_term_is_a_weighted_square_of_the_joint_step_per_metre(irb4600, straight_tool, kin, q):
    """Zero for joints that do not move; 4x for steps twice as large, weight times, 1/4 on twice the path."""
    q0, step = q[0], np.radians([0.5, -0.2, 0.3, 1.0, -0.7, 0.4])
    ramp = q0 + np.arange(N)[:, None] * step
    ramp2 = q0 + np.arange(N)[:, None] * 2.0 * step
    f = _smoothness(irb4600, straight_tool, kin, q, ramp, velocity=1e-3, acceleration=0.0)
    assert f > 0.0
    assert _smoothness(
        irb4600, straight_tool, kin, q, np.tile(q0, (N, 1)), velocity=1e-3, acceleration=0.0
    ) == (pytest.approx(0.0, abs=1e-15))
    assert _smoothness(
        irb4600, straight_tool, kin, q, ramp2, velocity=1e-3, acceleration=0.0
    ) == pytest.approx(4.0 * f, rel=1e-12)
    assert _smoothness(
        irb4600, straight_tool, kin, q, ramp, velocity=3e-3, acceleration=0.0
    ) == pytest.approx(3.0 * f, rel=1e-12)
    assert _smoothness(
        irb4600, straight_tool, kin, q, ramp, 2.0, velocity=1e-3, acceleration=0.0
    ) == pytest.approx(0.25 * f, rel=1e-12)


def test_the_acceleration_term_vanishes_on_a_constant_step_and_not_on_a_bend(irb4600, straight_tool, kin, q):
    q0, step = q[0], np.radians([0.5, -0.2, 0.3, 1.0, -0.7, 0.4])
    ramp = q0 + np.arange(N)[:, None] * step
    bend = q0 + (np.arange(N)[:, None] ** 2) * step
    kw = dict(velocity=0.0, acceleration=1e-6)
    assert _smoothness(irb4600, straight_tool, kin, q, ramp, **kw) == pytest.approx(0.0, abs=1e-12)
    f = _smoothness(irb4600, straight_tool, kin, q, bend, **kw)
    assert f > 0.0
    # second differences per metre squared: twice the path length is 1/16 of the cost
    assert _smoothness(irb4600, straight_tool, kin, q, bend, 2.0, **kw) == pytest.approx(f / 16.0, rel=1e-12)


def test_singularity_rows_are_the_scaled_manipulability_at_waypoints_and_inside_segments(
    irb4600, straight_tool, kin, q
):
    active = ActiveSet(singular_waypoints=(1, 3), singular_segments=((2, 0.25),))
    tol = Tolerances(singularity_margin=0.013)
    nlp = build_refinement(
        irb4600, _fused(kin, q, OFFSETS, _turns(ANGLES)), np.eye(4), straight_tool, tol, active=active
    )
    _, g = _evaluate(nlp, q.ravel())
    scale = np.diag([1.0 / REACH_M] * 3 + [1.0] * 3)
    points = [q[1], q[3], 0.75 * q[2] + 0.25 * q[3]]
    expected = [abs(np.linalg.det(scale @ kin.jacobian(p))) for p in points]
    np.testing.assert_allclose(g[4 * N + 6 * (N - 1) :], expected, rtol=1e-9)
    np.testing.assert_allclose(nlp.lbg[4 * N + 6 * (N - 1) :], 0.013)
    assert np.all(np.isinf(nlp.ubg[4 * N + 6 * (N - 1) :]))


def test_the_elastic_problem_bounds_each_slack_by_the_extra_cone_it_may_open(irb4600, straight_tool, kin, q):
    nlp = _standard(irb4600, straight_tool, kin, q, Tolerances(orientation_deg=3.0), elastic_deg=2.0)
    slack_lo, slack_hi = nlp.lbx[6 * N :], nlp.ubx[6 * N :]
    np.testing.assert_array_equal(slack_lo, 0.0)
    np.testing.assert_allclose(
        slack_hi, math.cos(math.radians(3.0)) - math.cos(math.radians(5.0)), rtol=1e-12
    )
    sigma = np.linspace(0.0, 1e-3, N)
    _, g = _evaluate(nlp, np.concatenate([q.ravel(), sigma]))
    np.testing.assert_allclose(g[: 4 * N].reshape(N, 4)[:, 3], np.cos(np.radians(ANGLES)) + sigma, atol=1e-12)


def test_slack_in_degrees_is_the_cone_widening_the_cosine_slack_buys(irb4600, straight_tool, kin, q):
    fused = _fused(kin, q, OFFSETS, _turns(ANGLES))
    strict = build_refinement(irb4600, fused, np.eye(4), straight_tool, Tolerances(orientation_deg=3.0))
    np.testing.assert_array_equal(strict.slack_deg(q.ravel()), np.zeros(N))
    elastic = strict.rebuilt(elastic_deg=2.0)
    widened = np.array([0.0, 0.5, 1.0, 2.0, 0.1])  # extra cone [deg]
    sigma = np.cos(np.radians(3.0)) - np.cos(np.radians(3.0 + widened))
    np.testing.assert_allclose(elastic.slack_deg(np.concatenate([q.ravel(), sigma])), widened, atol=1e-9)


def test_the_inspection_singularity_function_is_the_scaled_manipulability(irb4600, straight_tool, kin, q):
    from refine.optimise.waypoint import singularity_function

    f = singularity_function(irb4600, np.eye(4), straight_tool)
    scale = np.diag([1.0 / REACH_M] * 3 + [1.0] * 3)
    for qk in q:
        expected = abs(np.linalg.det(scale @ kin.jacobian(qk)))
        assert float(f(qk)) == pytest.approx(expected, rel=1e-9, abs=1e-6)


def test_smoothness_and_mid_range_terms_have_their_documented_values(irb4600, straight_tool, kin, q):
    """velocity · |Δq/Δs|², acceleration · |Δ²q/Δs²|² (weights carry the deg² conversion) and
    mid_range · ((q - mid) / half range)², each summed over the path and averaged per waypoint."""
    fused = _fused(kin, q, OFFSETS, _turns(0.0 * ANGLES))
    h = np.mean(np.diff(fused.s))
    bend = q[0] + (np.arange(N)[:, None] ** 2) * np.radians([0.5, -0.2, 0.3, 1.0, -0.7, 0.4])
    mid, half = np.radians(LOWER_DEG + UPPER_DEG) / 2.0, np.radians(UPPER_DEG - LOWER_DEG) / 2.0
    expected = {
        "velocity": 2e-3 * np.sum((np.diff(bend, axis=0) / h) ** 2) / N,
        "acceleration": 3e-7 * np.sum((np.diff(bend, 2, axis=0) / h**2) ** 2) / N,
        "mid_range": 0.4 * np.sum(((bend - mid) / half) ** 2) / N,
    }
    weights = {"velocity": 2e-3, "acceleration": 3e-7, "mid_range": 0.4}
    for term, value in expected.items():
        w = {k: (weights[k] if k == term else 0.0) for k in weights}
        nlp = build_refinement(
            irb4600, fused, np.eye(4), straight_tool, Tolerances(), weights=Weights(orientation=0.0, **w)
        )
        assert _evaluate(nlp, bend.ravel())[0] == pytest.approx(value, rel=1e-9), term


def test_linearised_rows_are_their_gradient_times_the_interpolated_joints(irb4600, straight_tool, kin, q):
    from refine.optimise.problem import LinearRow

    gradient = np.array([0.3, -0.1, 0.2, 0.0, 0.05, -0.4])
    rows = (
        LinearRow(1, 0.0, gradient, 0.02, "link_3 / table"),
        LinearRow(2, 0.4, -gradient, -0.1, "tool / part"),
    )
    nlp = _standard(irb4600, straight_tool, kin, q, Tolerances(), active=ActiveSet(linear_rows=rows))
    _, g = _evaluate(nlp, q.ravel())
    tail = g[4 * N + 6 * (N - 1) :]
    np.testing.assert_allclose(tail, [gradient @ q[1], -gradient @ (0.6 * q[2] + 0.4 * q[3])], atol=1e-12)
    np.testing.assert_allclose(nlp.lbg[4 * N + 6 * (N - 1) :], [0.02, -0.1])
    assert np.all(np.isinf(nlp.ubg[4 * N + 6 * (N - 1) :]))


@pytest.mark.parametrize(
    ("active", "message"),
    [
        (ActiveSet(singular_waypoints=(N,)), rf"singular waypoint {N} outside \[0, {N}\)"),
        (ActiveSet(singular_waypoints=(-1,)), "singular waypoint -1"),
        (ActiveSet(singular_segments=((N - 1, 0.5),)), "singular segment point"),
        (ActiveSet(singular_segments=((0, 0.0),)), "singular segment point"),
        (ActiveSet(singular_segments=((0, 1.0),)), "singular segment point"),
    ],
)
def test_an_active_set_outside_the_path_is_refused(irb4600, straight_tool, kin, q, active, message):
    from refine.errors import InputError

    with pytest.raises(InputError, match=message):
        _standard(irb4600, straight_tool, kin, q, Tolerances(), active=active)


@pytest.mark.parametrize(
    ("k", "f", "size"), [(N, 0.0, 6), (-1, 0.0, 6), (0, 1.0, 6), (0, -0.1, 6), (0, 0.0, 5)]
)
def test_a_linear_row_outside_the_path_or_of_the_wrong_size_is_refused(
    irb4600, straight_tool, kin, q, k, f, size
):
    from refine.errors import InputError
    from refine.optimise.problem import LinearRow

    row = LinearRow(k, f, np.ones(size), 0.0, "probe")
    with pytest.raises(InputError, match="linear row 'probe'"):
        _standard(irb4600, straight_tool, kin, q, Tolerances(), active=ActiveSet(linear_rows=(row,)))


def test_the_first_and_last_waypoints_may_carry_active_rows(irb4600, straight_tool, kin, q):
    from refine.optimise.problem import LinearRow

    active = ActiveSet((0, N - 1), ((0, 0.5), (N - 2, 0.99)), (LinearRow(0, 0.0, np.ones(6), -10.0),))
    nlp = _standard(irb4600, straight_tool, kin, q, Tolerances(), active=active)
    assert len(nlp.lbg) == 4 * N + 6 * (N - 1) + 4 + 1


def test_three_waypoints_are_enough_for_a_problem_and_two_are_not(irb4600, straight_tool, kin, q):
    """The documented minimum: 3 waypoints (one second difference of the smoothness term)."""
    poses = kin.poses(q[:3])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))])
    fused = FusedPath(s, poses[:, :3, 3], poses[:, :3, :3], np.full(3, 0.1), np.arange(3.0), np.zeros(3))
    nlp = build_refinement(irb4600, fused, np.eye(4), straight_tool, Tolerances())
    assert nlp.nlp["x"].numel() == 3 * 6
    _, g = _evaluate(nlp, q[:3].ravel())
    np.testing.assert_allclose(g[: 4 * 3].reshape(3, 4)[:, :3], 0.0, atol=1e-12)  # on the targets
    two = FusedPath(s[:2], poses[:2, :3, 3], poses[:2, :3, :3], np.full(2, 0.1), np.arange(2.0), np.zeros(2))
    with pytest.raises(InputError, match="at least 3 waypoints, got 2"):
        build_refinement(irb4600, two, np.eye(4), straight_tool, Tolerances())


def test_the_elastic_cost_charges_every_waypoint_s_slack_alike_and_linearly(irb4600, straight_tool, kin, q):
    """The repair's L1 penalty: slack costs the same per unit at every waypoint, twice the slack twice
    the cost, so the answer uses the least total slack (the joints, hence the other terms, held fixed)."""
    nlp = _standard(irb4600, straight_tool, kin, q, Tolerances(orientation_deg=3.0), elastic_deg=2.0)
    f0, _ = _evaluate(nlp, np.concatenate([q.ravel(), np.zeros(N)]))
    delta = 1e-4
    unit = []
    for k in range(N):
        one, _ = _evaluate(nlp, np.concatenate([q.ravel(), delta * np.eye(N)[k]]))
        two, _ = _evaluate(nlp, np.concatenate([q.ravel(), 2.0 * delta * np.eye(N)[k]]))
        assert two - f0 == pytest.approx(2.0 * (one - f0), rel=1e-9)
        unit.append((one - f0) / delta)
    assert min(unit) > 0.0
    np.testing.assert_allclose(unit, unit[0], rtol=1e-9)
    # as documented: one degree of slack at one waypoint of a 3° cone costs about 11 (deg² units),
    # more than the whole orientation cost of a good path
    one_degree = unit[0] * (math.cos(math.radians(3.0)) - math.cos(math.radians(4.0)))
    assert one_degree == pytest.approx(11.0, rel=0.1)
