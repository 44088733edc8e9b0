import numpy as np
import pytest
import toppra
from scipy.integrate import trapezoid

import refine.timing as timing
from refine.errors import InputError, SolverError
from refine.timing import RAMP, time_parameterise

N_JOINTS = 6


def smooth_path(n_pts=501, length=1.0, seed=0):
    """Waypoints of a smooth 6-joint path: random sums of slow sines, |q'| of order 1 rad/m."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, length, n_pts)
    amp = rng.uniform(0.05, 0.2, (3, N_JOINTS))
    freq = rng.uniform(0.5, 2.0, (3, N_JOINTS)) * 2 * np.pi / length
    phase = rng.uniform(0, 2 * np.pi, (3, N_JOINTS))
    q = np.sum(amp * np.sin(freq * s[:, None, None] + phase), axis=1)
    return s, q


def dense_joint_motion(s, q, tm, per_segment=20):
    """Joint velocity and acceleration inside every segment, as the robot would execute them.

    sdot^2 is linear in s on each segment (constant sddot), the path is the same not-a-knot spline
    TOPPRA uses.
    """
    path = toppra.SplineInterpolator(s, q)
    x = tm.speed**2
    u = np.diff(x) / (2 * np.diff(s))
    frac = np.linspace(0.0, 1.0, per_segment)
    s_d = (s[:-1, None] + np.diff(s)[:, None] * frac).ravel()
    x_d = (x[:-1, None] + np.diff(x)[:, None] * frac).ravel()
    u_d = np.repeat(u, per_segment)
    dq, ddq = path(s_d, 1), path(s_d, 2)
    return dq * np.sqrt(x_d)[:, None], ddq * x_d[:, None] + dq * u_d[:, None]


def test_loose_limits_reproduce_the_demonstrated_speed():
    s, q = smooth_path()
    cap = 0.05 + 0.02 * np.sin(2 * np.pi * s)
    tm = time_parameterise(s, q, cap, np.full(N_JOINTS, 3.0), np.full(N_JOINTS, 20.0))

    assert all(seg.reason == RAMP for seg in tm.slow_segments)
    ramps = np.zeros(len(s), dtype=bool)
    for seg in tm.slow_segments:
        ramps[seg.index_start : seg.index_end + 1] = True
    assert ramps.sum() < 10
    np.testing.assert_allclose(tm.speed[~ramps], cap[~ramps], rtol=0.01)
    s_fine = np.linspace(0, 1, 20001)
    expected = trapezoid(1 / np.interp(s_fine, s, cap), s_fine)
    assert tm.cycle_time_s == pytest.approx(expected, rel=0.01)
    assert tm.t[0] == 0.0 and np.all(np.diff(tm.t) > 0)
    assert tm.speed[0] == 0.0 and tm.speed[-1] == 0.0
    assert tm.speed_tracking_error_rel < 1e-3
    assert tm.speed_tracking_error_mean_rel <= tm.speed_tracking_error_rel


def test_joint_velocity_limit_slows_the_middle_and_is_never_exceeded():
    s, q = smooth_path(seed=1)
    q[:, 3] = 0.3 * np.tanh((s - 0.5) / 0.05)  # |q4'| peaks at 6 rad/m at s = 0.5 m
    vlim = np.array([3.0, 3.0, 3.0, 0.3, 3.0, 3.0])
    tm = time_parameterise(s, q, np.full(len(s), 0.1), vlim, np.full(N_JOINTS, 20.0))

    middle = [seg for seg in tm.slow_segments if seg.s_start_m < 0.5 < seg.s_end_m]
    assert len(middle) == 1
    assert middle[0].reason == "joint velocity (joint 4)"
    assert middle[0].min_ratio == pytest.approx(0.3 / 6 / 0.1, rel=0.01)
    assert all(seg.reason == RAMP for seg in tm.slow_segments if seg is not middle[0])
    assert np.all(np.abs(tm.qd) <= vlim * (1 + 1e-6))
    qd_dense, _ = dense_joint_motion(s, q, tm)
    # Inside a segment sdot^2 is linear in s while the bound (v4 / q4')^2 is convex at the dip,
    # so the chord overshoots by a second-order term ~ (ds / w)^2 = (2 mm / 5 cm)^2 = 1.6e-3
    # (measured 1.0e-3).
    assert np.all(np.abs(qd_dense) <= vlim * (1 + 5e-3))
    # the edges of the slowdown, within 5 % of the demo, still count in the tracking error
    assert 0.0 < tm.speed_tracking_error_rel < 0.05


def test_acceleration_limits_hold_between_waypoints():
    s, q = smooth_path(seed=2)
    alim = np.array([0.5, 0.8, 0.6, 1.0, 0.7, 0.9])
    tm = time_parameterise(s, q, np.full(len(s), 0.5), np.full(N_JOINTS, 3.0), alim)

    assert any(seg.reason.startswith("joint acceleration") for seg in tm.slow_segments)
    assert np.all(np.abs(tm.qdd) <= alim * (1 + 1e-3))
    _, qdd_dense = dense_joint_motion(s, q, tm)
    # TOPPRA enforces the limits at both ends of each 2 mm segment with that segment's sddot;
    # in between qdd(s) is smooth, so it can overshoot by about ds^2 / 8 * |d2 qdd / ds2|,
    # ~ (2 pi ds / 0.5 m)^2 / 8 = 8e-5 for these sines (shortest period 0.5 m; measured 1.3e-4).
    # Add the 1e-3 slack time_parameterise itself accepts at waypoints: 2e-3 in all.
    assert np.max(np.abs(qdd_dense) / alim) <= 1 + 2e-3


def test_robot_brakes_before_the_demonstrated_speed_steps_down():
    s = np.linspace(0.0, 1.0, 501)
    slope = np.array([1.0, -0.5, 2.0, 0.2, -1.0, 0.5])
    q = s[:, None] * slope  # straight in joint space: q'' = 0
    alim = np.full(N_JOINTS, 0.5)
    cap = np.where(s < 0.6, 0.2, 0.05)
    tm = time_parameterise(s, q, cap, np.full(N_JOINTS, 3.0), alim)

    i_step = int(np.argmax(s >= 0.6))
    decel = np.min(alim / np.abs(slope))  # largest sddot the limits allow [m/s^2]
    braking = (0.2**2 - 0.05**2) / (2 * decel)  # braking distance [m]
    before = (s > 0.6 - braking + 0.01) & (s < 0.6)
    profile = np.sqrt(0.05**2 + 2 * decel * (s[i_step] - s[before]))
    np.testing.assert_allclose(tm.speed[before], profile, rtol=0.01)
    assert np.all(np.diff(tm.speed[before]) < 0)
    assert np.all(tm.speed[i_step:] <= 0.05 * (1 + 1e-6))
    braking_segments = [seg for seg in tm.slow_segments if seg.s_start_m < 0.59 < seg.s_end_m]
    assert [seg.reason for seg in braking_segments] == ["joint acceleration (joint 3)"]


def test_without_start_stop_the_path_starts_and_ends_at_the_demonstrated_speed():
    s, q = smooth_path(seed=3)
    cap = np.full(len(s), 0.05)
    tm = time_parameterise(s, q, cap, np.full(N_JOINTS, 3.0), np.full(N_JOINTS, 20.0), start_stop=False)
    np.testing.assert_allclose(tm.speed, cap, rtol=0.01)
    assert tm.slow_segments == ()
    assert tm.cycle_time_s == pytest.approx(1.0 / 0.05, rel=0.01)


def test_without_start_stop_a_curved_start_is_entered_as_fast_as_the_limits_allow():
    s = np.linspace(0.0, 1.0, 201)
    q = np.column_stack([np.sin(8 * s), s])  # |q1''| up to 64 rad/m^2 near both ends
    alim = np.array([0.5, 0.5])
    tm = time_parameterise(s, q, np.full(len(s), 0.5), np.array([3.0, 3.0]), alim, start_stop=False)
    assert 0.0 < tm.speed[0] < 0.5 and 0.0 < tm.speed[-1] < 0.5
    assert all(seg.reason.startswith("joint acceleration") for seg in tm.slow_segments)
    assert np.all(np.abs(tm.qdd) <= alim * (1 + 1e-3))


def test_a_result_breaking_a_joint_limit_raises_solver_error(monkeypatch):
    s, q = smooth_path(seed=4)
    real = timing._solve_path_speed
    monkeypatch.setattr(timing, "_solve_path_speed", lambda *a: 1e3 * real(*a))
    with pytest.raises(SolverError, match=r"joint \d velocity .* rad/s exceeds .* at s = "):
        time_parameterise(s, q, np.full(len(s), 0.05), np.full(N_JOINTS, 3.0), np.full(N_JOINTS, 20.0))


GOOD = {
    "s": np.linspace(0.0, 1.0, 11),
    "q": np.zeros((11, 2)) + np.linspace(0.0, 1.0, 11)[:, None],
    "speed_cap": np.full(11, 0.1),
    "velocity_limits": np.ones(2),
    "acceleration_limits": np.ones(2),
}


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("s", np.linspace(0.0, 1.0, 10), r"q: expected shape \(10, n\)"),
        ("s", np.r_[0.0, 0.1, 0.1, np.linspace(0.3, 1.0, 8)], "s: must strictly increase"),
        ("q", np.zeros((11, 2, 1)), r"q: expected shape \(11, n\)"),
        ("speed_cap", np.r_[np.full(10, 0.1), 0.0], "speed_cap: must be > 0, got 0 at index 10"),
        ("speed_cap", np.full(10, 0.1), r"speed_cap: expected shape \(11,\), got \(10,\)"),
        ("velocity_limits", np.ones(3), r"velocity_limits: expected shape \(2,\)"),
        ("acceleration_limits", np.array([1.0, -1.0]), "acceleration_limits: must be > 0"),
        ("q", np.full((11, 2), np.nan), "q: contains NaN"),
    ],
)
def test_bad_inputs_raise_input_error_naming_the_argument(name, value, message):
    args = {**GOOD, name: value}
    with pytest.raises(InputError, match=message):
        time_parameterise(**args)


def test_bad_tolerance_and_too_few_waypoints_raise_input_error():
    with pytest.raises(InputError, match="tolerance_rel"):
        time_parameterise(**GOOD, tolerance_rel=1.5)
    with pytest.raises(InputError, match=r"N >= 3"):
        time_parameterise(
            **{**GOOD, "s": GOOD["s"][:2], "q": GOOD["q"][:2], "speed_cap": GOOD["speed_cap"][:2]}
        )


def _straight(slope, n_pts=401):
    s = np.linspace(0.0, 1.0, n_pts)
    return s, s[:, None] * np.asarray(slope)


def test_a_path_held_back_by_a_joint_speed_is_ramp_limit_ramp_in_contiguous_pieces():
    """Straight in joint space with joint 2 at 2 rad/m and 0.2 rad/s: 0.1 m/s, half the 0.2 m/s cap.

    Every waypoint is slow: the run splits into the ramp up (until joint 2 binds), the stretch
    held by joint 2's speed limit, and the ramp down; the pieces touch without gap or overlap.
    """
    s, q = _straight([0.5, 2.0, -1.0])
    vlim, alim = np.array([3.0, 0.2, 3.0]), np.full(3, 0.5)
    tm = time_parameterise(s, q, np.full(len(s), 0.2), vlim, alim)
    reasons = [seg.reason for seg in tm.slow_segments]
    assert reasons == [RAMP, "joint velocity (joint 2)", RAMP]
    first, middle, last = tm.slow_segments
    assert first.index_start == 0 and last.index_end == len(s) - 1
    assert middle.index_start == first.index_end + 1 and last.index_start == middle.index_end + 1
    # the ramp reaches 0.1 m/s at the path acceleration joint 2 allows, 0.5 / 2 = 0.25 m/s^2
    ramp_m = 0.1**2 / (2 * 0.25)
    assert s[first.index_end] == pytest.approx(ramp_m, abs=0.01)
    assert s[last.index_start] == pytest.approx(1.0 - ramp_m, abs=0.01)
    assert middle.min_ratio == pytest.approx(0.5, rel=1e-3)
    assert np.all(np.abs(tm.qd) <= vlim * (1 + 1e-6))


def test_an_unexplained_slowdown_names_the_closest_limit(monkeypatch):
    """A slowdown no limit accounts for (planted here) is reported as such, naming the joint nearest
    its speed limit: joint 3, whose |q3'| = 3 s rises to 1.8 rad/m in the slowed stretch (joint 2 is
    at 1.3 rad/m throughout, so it would be the answer if the least use counted)."""
    s, q = _straight([0.5, -1.3, 0.0])
    q[:, 2] = 1.5 * s**2
    real = timing._solve_path_speed

    def dip(*args):
        speed = real(*args)
        return speed * np.where((s > 0.4) & (s < 0.6), 0.5, 1.0)

    monkeypatch.setattr(timing, "_solve_path_speed", dip)
    tm = time_parameterise(s, q, np.full(len(s), 0.1), np.ones(3), np.full(3, 1e3))
    (unexplained,) = [seg for seg in tm.slow_segments if not seg.explained]
    assert unexplained.reason.startswith("not explained by limits (closest: joint velocity (joint 3)")
    assert 0.4 < unexplained.s_start_m < unexplained.s_end_m < 0.6
    assert tm.speed_tracking_error_rel == pytest.approx(0.5, abs=1e-6)


def test_a_toppra_failure_is_a_solver_error(monkeypatch):
    s, q = _straight([1.0, 0.5])

    def broken(*_args, **_kwargs):
        raise RuntimeError("planted")

    instance_type = timing._toppra()[3]  # the TOPPRA the timing runs (the free end's too)
    monkeypatch.setattr(instance_type, "compute_parameterization", broken)
    with pytest.raises(SolverError, match="TOPPRA failed: planted"):
        time_parameterise(s, q, np.full(len(s), 0.1), np.ones(2), np.ones(2))


def test_without_start_stop_the_ends_run_at_their_own_caps():
    """The first waypoint's cap is 30 mm/s, the last's 45 mm/s, the rest 60 mm/s."""
    s, q = _straight([1.0, 0.5])
    cap = np.full(len(s), 0.06)
    cap[0], cap[-1] = 0.03, 0.045
    tm = time_parameterise(s, q, cap, np.full(2, 3.0), np.full(2, 0.5), start_stop=False)
    assert tm.speed[0] == pytest.approx(0.03, rel=1e-4)
    assert tm.speed[-1] == pytest.approx(0.045, rel=1e-4)


def test_joints_keep_their_speed_limit_on_average_between_waypoints_on_a_staircase():
    """A staircase joint path (1 rad rises between flat steps, 0.1 m apart) has a small spline slope
    at the waypoints but a chord slope of 10 rad/m on each rise: at 3 rad/s the mean speed over a
    rise allows at most 0.3 m/s there, whatever the speeds at the waypoints say."""
    s = np.linspace(0.0, 2.0, 21)
    stairs = np.floor(np.arange(21) / 2.0)  # 0 0 1 1 2 2 ... : a rise every other segment
    q = np.column_stack([stairs, 0.1 * s])
    vlim = np.array([3.0, 3.0])
    tm = time_parameterise(s, q, np.full(len(s), 2.0), vlim, np.full(2, 1e3))
    mean = np.abs(np.diff(q, axis=0)) / np.diff(tm.t)[:, None]
    assert np.all(mean <= vlim * (1 + 1e-6))
    # inside a rise the spline is steeper than its chord: it too keeps the limit
    qd_dense, _ = dense_joint_motion(s, q, tm, per_segment=41)
    assert np.max(np.abs(qd_dense[:, 0])) <= 3.0 * (1 + 1e-6)
    assert np.max(np.abs(qd_dense[:, 0])) >= 3.0 * 0.95  # and it binds
    assert any(seg.reason == "joint velocity (joint 1)" for seg in tm.slow_segments)


@pytest.mark.parametrize(
    ("name", "bad", "message"),
    [
        ("q", (5, 1), "q: contains NaN or infinite values"),
        ("speed_cap", (3,), "speed_cap: contains NaN or infinite values"),
    ],
)
def test_one_non_finite_entry_is_enough_to_refuse_the_input(name, bad, message):
    value = GOOD[name].copy()
    value[bad] = np.inf if name == "speed_cap" else np.nan
    with pytest.raises(InputError, match=message):
        time_parameterise(**{**GOOD, name: value})


def test_a_repeated_arc_length_is_named_by_its_index():
    s = np.r_[0.0, 0.1, 0.2, 0.2, np.linspace(0.3, 1.0, 7)]
    with pytest.raises(InputError, match=r"s\[2\] = 0.2 m, s\[3\] = 0.2 m"):
        time_parameterise(**{**GOOD, "s": s})


def test_the_last_waypoints_acceleration_is_that_of_the_last_segment():
    """Straight in joint space (q'' = 0), so qdd = q' · sddot, sddot = Δ(speed²) / (2 Δs) on the segment
    ending at the last waypoint: here the only one that slows down (50 -> 45 mm/s)."""
    slope = np.array([1.0, 0.5])
    s, q = _straight(slope, n_pts=101)
    cap = np.full(len(s), 0.05)
    cap[-1] = 0.045
    tm = time_parameterise(s, q, cap, np.full(2, 3.0), np.full(2, 50.0), start_stop=False)
    sdd_last = (tm.speed[-1] ** 2 - tm.speed[-2] ** 2) / (2.0 * (s[-1] - s[-2]))
    assert sdd_last < -0.01
    np.testing.assert_allclose(tm.qdd[-1], slope * sdd_last, rtol=1e-6)
    np.testing.assert_allclose(tm.qdd[-2], slope * sdd_last, rtol=1e-6)  # one-sided: the same segment


def test_slow_segments_and_timings_check_their_own_shape():
    from refine.timing import SlowSegment, Timing

    SlowSegment(2, 2, 0.1, 0.1, 0.5, RAMP)
    for start, end in ((3, 2), (-1, 0)):
        with pytest.raises(InputError, match="index_start <= index_end"):
            SlowSegment(start, end, 0.0, 0.0, 0.5, RAMP)
    t = np.arange(4.0)
    with pytest.raises(InputError, match=r"Timing.qd, qdd: expected shape \(4, n\)"):
        Timing(t, t, t, np.zeros((3, 2)), np.zeros((3, 2)), 3.0, (), 0.0, 0.0, 0.0)


def test_a_plan_that_stops_on_the_path_names_where(monkeypatch):
    s, q = _straight([1.0, 0.5], n_pts=101)
    real = timing._solve_path_speed

    def stall(*args):
        speed = real(*args)
        speed[40:42] = 0.0  # standing still over the segment from s[40] to s[41]
        return speed

    monkeypatch.setattr(timing, "_solve_path_speed", stall)
    with pytest.raises(SolverError, match=rf"stopped the path at s = {s[40]:.4f} m"):
        time_parameterise(s, q, np.full(len(s), 0.1), np.ones(2), np.ones(2))


def test_a_free_start_runs_at_its_own_cap_when_the_next_waypoints_cap_is_lower():
    """Straight in joint space (|q'| <= 1 rad/m) with generous limits: starting at the first cap,
    80 mm/s, and slowing to 50 mm/s over the first 10 mm takes sddot = (0.05² - 0.08²) / (2·0.01)
    = -0.195 m/s², joint accelerations under 0.2 rad/s² against a limit of 50, so nothing but the
    cap bounds the start."""
    slope = np.array([1.0, 0.5])
    s, q = _straight(slope, n_pts=101)
    cap = np.full(len(s), 0.05)
    cap[0] = 0.08
    tm = time_parameterise(s, q, cap, np.full(2, 3.0), np.full(2, 50.0), start_stop=False)
    assert tm.speed[0] == pytest.approx(0.08, rel=1e-4)
    assert tm.speed[1] == pytest.approx(0.05, rel=1e-4)
    assert tm.t[1] == pytest.approx((s[1] - s[0]) / 0.065, rel=1e-4)  # constant sddot: the mean speed


def test_a_free_start_above_what_the_path_ahead_allows_starts_at_the_most_it_allows():
    """Straight in joint space, joint 1 at 1 rad/m with 0.5 rad/s² (path deceleration 0.5 m/s²); the
    cap is 1 m/s at the start and 50 mm/s from the next waypoint, 10 mm on. The fastest start that
    can still slow down in time: v0² = 0.05² + 2·0.5·0.01, v0 = 0.1118 m/s."""
    slope = np.array([1.0, 0.5])
    s, q = _straight(slope, n_pts=101)
    cap = np.full(len(s), 0.05)
    cap[0] = 1.0
    tm = time_parameterise(s, q, cap, np.full(2, 3.0), np.full(2, 0.5), start_stop=False)
    assert tm.speed[0] == pytest.approx(np.sqrt(0.05**2 + 2 * 0.5 * 0.01), rel=1e-3)
    assert tm.speed[1] == pytest.approx(0.05, rel=1e-4)


def test_a_timing_that_breaks_a_joint_speed_is_refused_naming_the_joint_and_where(monkeypatch):
    """The plan is checked against the limits after TOPPRA: a path speed 30 % over what joint 2
    allows at s = 0.5 m only (2 rad/m there, 0.2 rad/s: 0.1 m/s allowed, 0.13 m/s planned) is refused."""
    slope = np.array([1.0, 2.0])
    s, q = _straight(slope, n_pts=101)
    solve = timing._solve_path_speed

    def too_fast(instance, sd_start, sd_end):
        sd = solve(instance, sd_start, sd_end)
        sd[50] *= 1.3
        return sd

    monkeypatch.setattr(timing, "_solve_path_speed", too_fast)
    with pytest.raises(
        SolverError,
        match=r"joint 2 velocity 0\.2(599\d*|6) rad/s exceeds its limit 0\.2 rad/s at s = 0\.5000 m",
    ):
        time_parameterise(
            s, q, np.full(len(s), 0.2), np.array([3.0, 0.2]), np.full(2, 50.0), start_stop=False
        )


def test_joint_constraints_kept_between_calls_time_as_toppra_built_afresh():
    """TOPPRA built with the constraint objects of earlier calls (other limits between) equals one built from nothing."""
    s, q = smooth_path(n_pts=201, seed=3)
    cap = np.full(len(s), 0.3)
    vlim, alim = np.full(N_JOINTS, 0.8), np.full(N_JOINTS, 4.0)
    time_parameterise(s, q, cap, vlim, alim)
    time_parameterise(s, q, cap, 2.0 * vlim, 0.5 * alim)  # other limits: other constraint objects
    kept = timing.build_toppra(s, q, cap, vlim, alim)
    other = timing.build_toppra(s, q, cap, 2.0 * vlim, 0.5 * alim)
    # the reference: toppra's own constraints made for this call only, on the same spline and grid
    fresh = toppra.algorithm.TOPPRA(
        [
            toppra.constraint.JointVelocityConstraint(vlim),
            toppra.constraint.JointAccelerationConstraint(
                alim, toppra.constraint.DiscretizationType.Interpolation
            ),
            timing._toppra()[1](s, cap),
        ],
        toppra.SplineInterpolator(s, q),
        gridpoints=s,
        solver_wrapper="seidel",
    )
    sd_fresh = fresh.compute_parameterization(0.0, 0.0)[1]
    sd_kept = kept.compute_parameterization(0.0, 0.0)[1]
    sd_other = other.compute_parameterization(0.0, 0.0)[1]
    np.testing.assert_allclose(sd_kept, sd_fresh, rtol=1e-9, atol=1e-12)
    assert not np.allclose(sd_other, sd_fresh)  # the limits bind: other limits, another timing


def _toppras(s, q, cap, vlim, alim):
    """The lean TOPPRA of a call and toppra's own, on constraints and splines of their own each."""

    def parts():
        return [
            toppra.constraint.JointVelocityConstraint(vlim),
            toppra.constraint.JointAccelerationConstraint(
                alim, toppra.constraint.DiscretizationType.Interpolation
            ),
            timing._toppra()[1](s, cap),
        ], toppra.SplineInterpolator(s, q)

    lean = timing.build_toppra(s, q, cap, vlim, alim)
    assert type(lean) is not toppra.algorithm.TOPPRA and isinstance(lean, toppra.algorithm.TOPPRA)
    constraints, path = parts()
    own = toppra.algorithm.TOPPRA(constraints, path, gridpoints=s, solver_wrapper="seidel")
    return lean, own


def _assert_toppras_own(got, want):
    """The lean passes' (sdd, sd, v, K) against toppra's: the same to 1e-9 relative.

    toppra finds the lower end of a controllable set that rest reaches by a minimisation whose
    answer is 0 to within its rounding (up to a few 1e-16 [m^2/s^2]); the lean passes take 0.
    """
    sdd, sd, v, K = got
    sdd_own, sd_own, v_own, K_own = want
    assert (sd is None) == (sd_own is None)
    if sd is not None:
        np.testing.assert_allclose(sd, sd_own, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(sdd, sdd_own, rtol=1e-9, atol=1e-9 * np.abs(sdd_own).max())
        np.testing.assert_array_equal(v, v_own)
    assert np.array_equal(np.isnan(K), np.isnan(K_own))
    np.testing.assert_allclose(K[:, 1], K_own[:, 1], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(K[:, 0], K_own[:, 0], rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("seed", [0, 3, 7])
def test_the_lean_passes_give_toppras_own_sets_and_timing(seed):
    """From rest to rest and from a start speed to a free end (the glass cell's kinds of call),
    the lean passes' controllable sets, path speeds, accelerations and auxiliary variables are
    toppra's own to 1e-9 relative, with the same return code."""
    s, q = smooth_path(n_pts=301, seed=seed)
    cap = np.full(len(s), 0.4) * (1.0 + 0.3 * np.sin(np.linspace(0.0, 6.0, len(s))))
    vlim, alim = np.full(N_JOINTS, 0.9), np.full(N_JOINTS, 3.0)
    speeds = []
    for start, end in ((0.0, 0.0), (0.05, 0.3)):
        lean, own = _toppras(s, q, cap, vlim, alim)
        got = lean.compute_parameterization(start, end, return_data=True)
        want = own.compute_parameterization(start, end, return_data=True)
        _assert_toppras_own(got, want)
        assert lean.problem_data.return_code == own.problem_data.return_code
        speeds.append(got[1])
    assert np.all(np.isfinite(speeds[0])) and np.all(speeds[0][1:-1] > 0.0)  # rest to rest: a timing


def test_the_lean_passes_stop_where_toppra_does_on_an_end_speed_it_cannot_reach():
    """An end speed far above what the joints allow: the controllable sets break off at the same
    step with the same entries, and both say the path is not controllable."""
    s, q = smooth_path(n_pts=201, seed=5)
    cap = np.full(len(s), 50.0)
    vlim, alim = np.full(N_JOINTS, 0.5), np.full(N_JOINTS, 0.5)
    lean, own = _toppras(s, q, cap, vlim, alim)
    K_lean = lean.compute_controllable_sets(40.0, 40.0)
    K_own = own.compute_controllable_sets(40.0, 40.0)
    assert np.isnan(K_own).any()
    np.testing.assert_array_equal(K_lean, K_own)  # no set reached from rest: the same solves
    assert lean.compute_parameterization(0.0, 40.0)[0] is None
    assert own.compute_parameterization(0.0, 40.0)[0] is None
    assert lean.problem_data.return_code == own.problem_data.return_code


def test_the_timings_spline_gives_toppras_values_and_a_copy_each_call():
    """The spline TOPPRA runs on: at the waypoints (an equal array, not the same object) and
    elsewhere, each order is toppra's own spline's to the bit (and SciPy's not-a-knot cubic
    spline's to rounding), and a caller that writes into what it got changes nothing another
    caller gets."""
    from scipy.interpolate import CubicSpline

    s, q = smooth_path(n_pts=101, seed=4)
    path = timing.build_toppra(s, q, np.full(len(s), 0.3), np.ones(N_JOINTS), np.ones(N_JOINTS)).path
    own = toppra.SplineInterpolator(s, q)
    spline = CubicSpline(s, q, bc_type="not-a-knot")
    elsewhere = np.linspace(s[0], s[-1], 37)
    for order in (0, 1, 2):
        want = own(s, order)
        got = path(s.copy(), order)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_allclose(got, spline(s, order), rtol=1e-13, atol=1e-13 * np.abs(want).max())
        got[:] = np.nan  # the caller's own copy
        np.testing.assert_array_equal(path(s.copy(), order), want)
        np.testing.assert_array_equal(path(elsewhere, order), own(elsewhere, order))
    shifted = s.copy()
    shifted[3] = 0.5 * (s[3] + s[4])  # one position off the waypoints: evaluated there
    np.testing.assert_array_equal(path(shifted, 1), own(shifted, 1))


def test_a_segments_bound_between_waypoints_counts_at_its_faster_end():
    """Against a loop over the segments: each raises the ratio at waypoint k+1 if the speed rises
    there, else at k (ties, falls and NaN speeds at k), keeping the larger."""
    rng = np.random.default_rng(8)
    speed = rng.uniform(0.0, 1.0, 40)
    speed[[5, 6]] = 0.3  # a tie
    speed[20] = np.nan
    ratio = rng.uniform(0.0, 1.0, (40, 3))
    between = rng.uniform(0.0, 1.5, (39, 3))
    want = ratio.copy()
    for k in range(39):
        at = k + 1 if speed[k + 1] > speed[k] else k
        want[at] = np.maximum(want[at], between[k])
    got = ratio.copy()
    timing._at_faster_ends(got, speed, between)
    np.testing.assert_array_equal(got, want)


def test_the_lean_toppra_starts_in_toppras_own_state_and_refuses_what_it_refuses():
    """The state toppra's ``__init__`` leaves (grid, stages, parametrizer, problem data) on
    increasing gridpoints; gridpoints that do not increase or miss the path's ends raise its error."""
    s, q = smooth_path(n_pts=51, seed=2)
    cap, vlim, alim = np.full(len(s), 0.3), np.ones(N_JOINTS), np.ones(N_JOINTS)
    lean, own = _toppras(s, q, cap, vlim, alim)
    np.testing.assert_array_equal(lean.gridpoints, own.gridpoints)
    np.testing.assert_array_equal(lean.problem_data.gridpoints, own.problem_data.gridpoints)
    assert lean.gridpoints is not s and lean.problem_data.gridpoints is not lean.gridpoints
    assert (lean._N, lean.parametrizer) == (own._N, own.parametrizer)
    assert lean.problem_data.return_code == own.problem_data.return_code
    assert lean.problem_data.K is None and lean.problem_data.sd_vec is None
    lean_type = type(lean)
    for grid in (np.concatenate([s[:10], s[9:]]), s[:-1]):
        with pytest.raises(ValueError):
            toppra.algorithm.TOPPRA(lean.constraints, lean.path, gridpoints=grid, solver_wrapper="seidel")
        with pytest.raises(ValueError):
            lean_type(lean.constraints, lean.path, gridpoints=grid, solver_wrapper="seidel")
