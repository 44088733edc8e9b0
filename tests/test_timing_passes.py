"""The lean TOPP-RA passes against toppra's own, on paths where each of their shortcuts binds or fails."""

import numpy as np
import pytest
import toppra

import refine.timing as timing
from refine.timing import time_parameterise

N_JOINTS = 6


def _smooth(n_pts, seed):
    """Waypoints of a smooth 6-joint path over 1 m: random sums of slow sines, |q'| of order 1 rad/m."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, n_pts)
    amp = rng.uniform(0.05, 0.2, (3, N_JOINTS))
    freq = rng.uniform(0.5, 2.0, (3, N_JOINTS)) * 2 * np.pi
    phase = rng.uniform(0, 2 * np.pi, (3, N_JOINTS))
    return s, np.sum(amp * np.sin(freq * s[:, None, None] + phase), axis=1)


def _case(name):
    """A path, its cap and limits on which one shortcut of the passes binds or fails (named)."""
    s, q = _smooth(301, seed=11)
    cap = np.full(len(s), 0.3)
    vlim, alim = np.full(N_JOINTS, 2.0), np.full(N_JOINTS, 5.0)
    if name == "cruise":  # the cap binds nearly everywhere: runs of proved steps, both passes
        pass
    elif name == "slow ramps":  # acceleration limits bind over long ramps: the solver's steps
        alim = np.full(N_JOINTS, 0.05)
    elif name == "velocity dip":  # a joint's speed holds the middle back
        q[:, 3] = 0.3 * np.tanh((s - 0.5) / 0.05)
        vlim[3] = 0.3
    elif name == "still joint and a step down":  # rows without u; braking before the cap's step
        q[:, 0] = 0.2
        cap = np.where(s < 0.5, 0.3, 0.05)
    elif name == "ramped cap":  # the cap ramps to the ends: the forward pass is one run, rest to rest
        cap = 0.3 * np.minimum(1.0, np.minimum(10.0 * s, 10.0 * (1.0 - s))) + 1e-3
    elif name == "creeping joints":  # rows with u's coefficient near 0: ends far out, rounded
        q[:, 0] = 0.2 + 1e-9 * np.sin(3.0 * s)
        q[:, 1] = 1e-12 * s**2
        alim[:2] = 1e-3
    return s, q, cap, vlim, alim


CASES = [
    "cruise",
    "slow ramps",
    "velocity dip",
    "still joint and a step down",
    "creeping joints",
    "ramped cap",
]


class _FreeEnd(toppra.algorithm.TOPPRA):
    """toppra's own TOPPRA with the end speed free up to the one asked for (as the timing's)."""

    def compute_controllable_sets(self, sdmin, sdmax):
        return super().compute_controllable_sets(0.0, sdmax)


def _own_toppra(s, q, speed_cap, velocity_limits, acceleration_limits, *, free_end=False):
    """``timing.build_toppra`` on toppra's own TOPPRA class, constraints made afresh."""
    constraints = [
        toppra.constraint.JointVelocityConstraint(np.asarray(velocity_limits, dtype=float)),
        toppra.constraint.JointAccelerationConstraint(
            np.asarray(acceleration_limits, dtype=float), toppra.constraint.DiscretizationType.Interpolation
        ),
        timing._toppra()[1](s, speed_cap),
    ]
    algorithm = _FreeEnd if free_end else toppra.algorithm.TOPPRA
    return algorithm(constraints, toppra.SplineInterpolator(s, q), gridpoints=s, solver_wrapper="seidel")


@pytest.mark.parametrize("start_stop", [True, False])
@pytest.mark.parametrize("name", CASES)
def test_the_timing_is_the_one_on_toppras_own_passes(monkeypatch, name, start_stop):
    """Times, speeds, joint velocities, cycle time and slow segments equal those of the same timing
    run on toppra's own TOPPRA to 1e-9 relative (rest to rest, and from the cap to a free end)."""
    args = _case(name)
    got = time_parameterise(*args, start_stop=start_stop)
    with monkeypatch.context() as m:
        m.setattr(timing, "build_toppra", _own_toppra)
        want = time_parameterise(*args, start_stop=start_stop)
    np.testing.assert_allclose(got.speed, want.speed, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.t, want.t, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.qd, want.qd, rtol=1e-9, atol=1e-12)
    assert got.cycle_time_s == pytest.approx(want.cycle_time_s, rel=1e-9)
    assert got.slow_segments == want.slow_segments
    assert got.speed_tracking_error_rel == pytest.approx(want.speed_tracking_error_rel, rel=1e-6, abs=1e-12)


@pytest.mark.parametrize("name", CASES)
def test_the_lean_passes_give_toppras_sets_and_speeds(name):
    """The controllable sets and path speeds of the lean passes are toppra's own to 1e-9 relative;
    on the path that runs at its cap, nearly every step is proved rather than solved."""
    s, q, cap, vlim, alim = _case(name)
    lean = timing.build_toppra(s, q, cap, vlim, alim)
    own = _own_toppra(s, q, cap, vlim, alim)
    solves = []
    wrapper = lean.solver_wrapper

    class Counting:
        def __getattr__(self, key):
            return getattr(wrapper, key)

        def solve_stagewise_optim(self, *args):
            solves.append(args[0])
            return wrapper.solve_stagewise_optim(*args)

    lean.solver_wrapper = Counting()
    sdd, sd, _, K = lean.compute_parameterization(0.0, 0.0, return_data=True)
    sdd_own, sd_own, _, K_own = own.compute_parameterization(0.0, 0.0, return_data=True)
    np.testing.assert_allclose(sd, sd_own, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(sdd, sdd_own, rtol=1e-9, atol=1e-9 * np.abs(sdd_own).max())
    np.testing.assert_allclose(K, K_own, rtol=1e-9, atol=1e-15)
    if name == "cruise":
        assert len(solves) < 0.1 * len(s)


def test_the_stage_rows_are_each_gridpoints_constraints_stacked():
    """``stage_rows`` against the rows built gridpoint by gridpoint from their definition
    ``F (a u + b x + c) <= h`` (F per gridpoint or shared), then ``-u <= -u_lo`` and ``u <= u_hi``
    with ``[u_lo, u_hi]`` the bounds on ``u`` intersected with +-1e8; ``x``'s bounds intersected."""
    from refine.timing_passes import stage_rows

    rng = np.random.default_rng(5)
    n = 7
    shared = (rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
    F2, h2 = rng.normal(size=(4, 3)), rng.normal(size=4)
    per_point = (rng.normal(size=(n, 2)), rng.normal(size=(n, 2)), rng.normal(size=(n, 2)))
    F3, h3 = rng.normal(size=(n, 5, 2)), rng.normal(size=(n, 5))
    ub = np.column_stack([-rng.uniform(1, 2, n), rng.uniform(1, 2, n)])
    xb = np.column_stack([rng.uniform(0, 1, n), rng.uniform(2, 3, n)])
    xb2 = np.column_stack([rng.uniform(0, 1, n), rng.uniform(2, 3, n)])
    params = [
        (None, None, None, None, None, None, xb),
        (*shared, F2, h2, None, None),
        (*per_point, F3, h3, ub, xb2),
    ]
    A, B, C, x_bounds = stage_rows(params, n)
    for i in range(n):
        want_A, want_B, want_C = [], [], []
        for (a, b, c), F, h in ((shared, F2, h2[None].repeat(n, 0)), (per_point, None, h3)):
            Fi = F2 if F is not None else F3[i]
            want_A += list(Fi @ a[i])
            want_B += list(Fi @ b[i])
            want_C += list(Fi @ c[i] - h[i])
        u_lo, u_hi = max(-1e8, ub[i, 0]), min(1e8, ub[i, 1])
        np.testing.assert_allclose(A[i], want_A + [-1.0, 1.0], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(B[i], want_B + [0.0, 0.0], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(C[i], want_C + [u_lo, -u_hi], rtol=1e-12, atol=1e-14)
        assert x_bounds[i].tolist() == [max(xb[i, 0], xb2[i, 0]), min(xb[i, 1], xb2[i, 1])]
