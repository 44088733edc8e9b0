"""The redundant arm's seed from a coarse refinement (``refine.optimise.solve.coarse_seed``).

The reference is the refinement solved from the plain chained-IK seed: the coarse seed must lead
to the same answer. Poses are checked with the robot's own forward kinematics, placed by hand.
The coarse copy's waypoints are worked out by hand from the documented rule (every 40th waypoint,
at least 16 of them, evenly spaced and rounded; none under 40 waypoints).
"""

from __future__ import annotations

import functools
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

import refine.optimise.solve as solve_module
from refine.bench.suites import generated_problem, load_suites
from refine.optimise.problem import Weights
from refine.optimise.seed import initial_guess
from refine.optimise.solve import coarse_seed, solve_refinement
from refine.run.stages import REDUNDANT_MID_RANGE_WEIGHT


@functools.cache
def _iiwa(n: int, mid_range: float = 0.0):
    problem = generated_problem("test", "iiwa", load_suites()["generated"]["iiwa"], n)
    problem = replace(problem, weights=Weights(mid_range=mid_range))  # the generated family has 2.0
    return problem, problem.refinement()


@pytest.mark.parametrize(
    ("n", "mid_range"),
    [(200, 0.0), (60, 0.0), (40, 0.0), (40, REDUNDANT_MID_RANGE_WEIGHT)],
    ids=["200", "60", "40", "40-mid-range"],
)
def test_the_coarse_seed_reaches_every_pose_and_leads_to_the_same_answer(n, mid_range):
    problem, nlp = _iiwa(n, mid_range)
    chain = initial_guess(nlp, problem.home)
    seed, spent = coarse_seed(nlp, chain)
    assert spent > 0
    assert seed is not None and seed.shape == chain.shape
    lower, upper = problem.robot.spec.lower, problem.robot.spec.upper
    assert np.all(seed >= lower - 1e-12) and np.all(seed <= upper + 1e-12)
    for k in range(0, len(seed), 7):  # the TCP at the CAD point with the demonstrated orientation
        T = problem.base_in_world @ problem.robot.fk(seed[k]) @ problem.tcp_in_flange
        np.testing.assert_allclose(T[:3, 3], problem.fused.positions[k], atol=1e-5)
        np.testing.assert_allclose(T[:3, :3], problem.fused.rotations[k], atol=1e-5)
    plain = solve_refinement(nlp, chain, home=problem.home)
    smooth = solve_refinement(nlp, seed, home=problem.home)
    assert plain.status == smooth.status == "ok"
    np.testing.assert_allclose(smooth.q, plain.q, atol=1e-5)
    # the coarse seed starts next to the answer, the chain does not (its elbow is 18-66 deg off)
    assert np.abs(seed - plain.q).max() < np.radians(5.0) < np.abs(chain - plain.q).max()
    assert smooth.iterations < plain.iterations
    # the refinement seeded this way counts the coarse copy's iterations with its own
    whole = solve_refinement(nlp, home=problem.home)
    np.testing.assert_allclose(whole.q, smooth.q, atol=1e-9)
    assert whole.iterations == spent + smooth.iterations


@pytest.mark.parametrize(
    ("n", "expected"),
    [
        # linspace(0, 39, 16) = 0, 2.6, 5.2, 7.8, 10.4, 13, 15.6, 18.2, ..., 33.8, 36.4, 39
        (40, [0, 3, 5, 8, 10, 13, 16, 18, 21, 23, 26, 29, 31, 34, 36, 39]),
        (91, list(range(0, 91, 6))),  # 90 / 15 = 6 exactly
    ],
)
def test_a_short_path_is_refined_first_at_sixteen_evenly_spaced_waypoints(monkeypatch, n, expected):
    problem, nlp = _iiwa(n)
    coarse = _coarse_problem(monkeypatch, nlp, initial_guess(nlp, problem.home))
    np.testing.assert_array_equal(coarse.fused.s, problem.fused.s[expected])
    # the joint-step bound grows with the widest coarse step (3 and 6 waypoints at 20 deg each)
    widest = max(np.diff(expected))
    assert coarse.tolerances.joint_step_deg == pytest.approx(widest * nlp.tolerances.joint_step_deg)


def test_a_long_path_is_refined_first_at_every_fortieth_waypoint(monkeypatch):
    problem, nlp = _iiwa(1000)
    coarse = _coarse_problem(monkeypatch, nlp, initial_guess(nlp, problem.home))
    idx = np.searchsorted(problem.fused.s, coarse.fused.s)
    np.testing.assert_array_equal(problem.fused.s[idx], coarse.fused.s)
    # 1000 // 40 = 25 waypoints, 999 / 24 = 41.6 apart: gaps of 41 and 42 from the first to the last
    assert len(idx) == 25 and idx[0] == 0 and idx[-1] == 999
    assert set(np.diff(idx)) == {41, 42}
    assert coarse.tolerances.joint_step_deg == 360.0  # 42 * 20 deg: no bound at all


def _coarse_problem(monkeypatch, nlp, chain):
    """The coarse problem coarse_seed builds, caught at its solve (answered as failed: no seed)."""
    caught = []

    def fake_solve(problem, q0, **_):
        caught.append((problem, q0))
        return SimpleNamespace(status="infeasible", iterations=0)

    monkeypatch.setattr(solve_module, "solve_refinement", fake_solve)
    assert coarse_seed(nlp, chain) == (None, 0)
    ((coarse, q0),) = caught
    assert q0.shape == (coarse.n_waypoints, nlp.dof)
    return coarse


@pytest.mark.parametrize(("family", "n"), [("irb4600", 200), ("iiwa", 39)])
def test_no_coarse_seed_for_a_six_axis_arm_or_a_short_path(family, n):
    problem = generated_problem("test", family, load_suites()["generated"][family], n)
    nlp = problem.refinement()
    assert coarse_seed(nlp, initial_guess(nlp, problem.home)) == (None, 0)


@functools.cache
def _puzzle_start():
    """The first 120 waypoints of the puzzle piece: the LBR iiwa holds the part against a standing grinder."""
    from pathlib import Path

    from refine.bench.suites import bundled_problem
    from refine.paths import FusedPath

    problem = bundled_problem("test", Path(__file__).resolve().parents[2] / "problems" / "puzzle_piece")
    f, i = problem.fused, slice(0, 120)
    return replace(problem, fused=FusedPath(f.s[i], f.positions[i], f.rotations[i], f.speed[i], f.t_demo[i], f.residual[i]))


def test_a_held_part_starts_its_first_full_solve_from_the_coarse_seed_at_a_small_barrier(monkeypatch):
    from refine.bench.contenders import solve_as_refine

    problem = _puzzle_start()
    small, _, _, _ = solve_as_refine(problem, "assembled")
    assert small.status == "ok"
    assert small.first_options["ipopt.mu_init"] == pytest.approx(1e-4)
    # IPOPT's own default initial barrier, 0.1 (IPOPT's options reference), for comparison
    monkeypatch.setattr(solve_module, "COARSE_SEEDED_MU_INIT", 0.1)
    default, _, _, _ = solve_as_refine(problem, "assembled")
    assert default.status == "ok" and default.first_options["ipopt.mu_init"] == pytest.approx(0.1)
    assert small.iterations < default.iterations
    assert np.degrees(np.abs(small.q - default.q).max()) < 1e-3  # the same answer
    # a given option is the caller's: it holds in the first solve too
    given, _, _, _ = solve_as_refine(replace(problem, solver_options={"ipopt.mu_init": 0.01}), "assembled")
    assert given.first_options["ipopt.mu_init"] == pytest.approx(0.01)


def test_a_tool_on_the_flange_keeps_ipopts_initial_barrier():
    problem, nlp = _iiwa(60, REDUNDANT_MID_RANGE_WEIGHT)
    result = solve_refinement(nlp, home=problem.home)
    assert result.status == "ok" and result.first_options
    assert "ipopt.mu_init" not in result.first_options


@pytest.mark.slow
def test_a_redundant_arm_stopping_at_its_first_acceptable_iterate_keeps_the_answer_of_ipopts_default():
    """At 6,400 waypoints the iiwa's full solve cannot reach IPOPT's 1e-9 and ends at its acceptable
    level; the answer is the one IPOPT's own default (15 acceptable iterations in a row) gives, and
    every pose is held as the robot's forward kinematics, placed by hand, measures it."""
    problem = generated_problem("test", "iiwa", load_suites()["generated"]["iiwa"], 6400)
    ours = solve_refinement(problem.refinement(), home=problem.home)
    default = solve_refinement(
        problem.refinement(solver_options={"ipopt.acceptable_iter": 15}), home=problem.home
    )
    assert ours.status == default.status == "ok"
    assert ours.solver_status == "Solved_To_Acceptable_Level"
    assert ours.iterations < default.iterations
    np.testing.assert_allclose(ours.q, default.q, atol=1e-7)  # rad
    for k in range(0, len(ours.q), 97):
        T = problem.base_in_world @ problem.robot.fk(ours.q[k]) @ problem.tcp_in_flange
        np.testing.assert_allclose(T[:3, 3], problem.fused.positions[k], atol=1e-9)  # m
