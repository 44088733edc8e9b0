"""A redundant arm's seed chained at the coarse copy's waypoints alone (``refine.optimise.solve``).

The refinement chains IK only where the coarse copy (``coarse_seed``) needs joints, refines the
copy, and projects its answer onto every pose; the whole path's chain is the fallback. Poses are
checked with the robot's own forward kinematics placed by hand, and the answers against those of
the whole chain followed by the coarse seed (the route taken before the chain was cut short).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import refine.optimise.coarse as coarse_module
import refine.optimise.solve as solve_module
from refine.bench.suites import generated_problem, load_suites
from refine.optimise.coarse import coarse_waypoints
from refine.optimise.seed import chained_seed, initial_guess
from refine.optimise.solve import coarse_seed, solve_refinement


@functools.cache
def _iiwa(n: int):
    problem = generated_problem("test", "iiwa", load_suites()["generated"]["iiwa"], n)
    return problem, problem.refinement()


def _assert_on_the_poses(problem, q, every: int = 1):
    """The TCP at the CAD point with the demonstrated orientation at every ``every``-th waypoint."""
    for k in range(0, len(q), every):
        T = problem.base_in_world @ problem.robot.fk(q[k]) @ problem.tcp_in_flange
        np.testing.assert_allclose(T[:3, 3], problem.fused.positions[k], atol=1e-5)  # m
        np.testing.assert_allclose(T[:3, :3], problem.fused.rotations[k], atol=1e-5)


def _seeds_solved(monkeypatch):
    """Record the seed of every full solve, and every call of the whole path's chain."""
    seeds, chains = [], []
    solve, guess = solve_module.solve_with_repair, solve_module.initial_guess

    def recording_solve(problem, seed, *args, **kwargs):
        seeds.append((problem.n_waypoints, np.array(seed)))
        return solve(problem, seed, *args, **kwargs)

    def recording_guess(problem, *args, **kwargs):
        chains.append(problem.n_waypoints)
        return guess(problem, *args, **kwargs)

    monkeypatch.setattr(solve_module, "solve_with_repair", recording_solve)
    monkeypatch.setattr(solve_module, "initial_guess", recording_guess)
    return seeds, chains


def test_the_chain_at_the_coarse_waypoints_is_the_whole_chain_there():
    problem, nlp = _iiwa(400)
    idx = coarse_waypoints(nlp)
    # 400 // 40 = 10 < 16: linspace(0, 399, 16) rounded, 26.6 waypoints apart
    np.testing.assert_array_equal(idx, np.linspace(0, 399, 16).round().astype(int))
    q, errors = chained_seed(nlp, problem.home, at=idx)
    assert q.shape == (16, 7) and errors.shape == (16,)
    assert errors.max() < 1e-5
    for j, k in enumerate(idx):
        T = problem.base_in_world @ problem.robot.fk(q[j]) @ problem.tcp_in_flange
        np.testing.assert_allclose(T[:3, 3], problem.fused.positions[k], atol=1e-5)
        np.testing.assert_allclose(T[:3, :3], problem.fused.rotations[k], atol=1e-5)
    # the waypoints between the chained ones are solved each on its own: the same joints
    np.testing.assert_array_equal(q, initial_guess(nlp, problem.home)[idx])


def test_a_redundant_arm_is_seeded_without_chaining_the_whole_path(monkeypatch):
    problem, nlp = _iiwa(400)
    seeds, chains = _seeds_solved(monkeypatch)
    result = solve_refinement(nlp, home=problem.home)
    assert result.status == "ok"
    assert chains == []  # the whole path was never chained
    (n, seed), *_ = [s for s in seeds if s[0] == 400]
    lower, upper = problem.robot.spec.lower, problem.robot.spec.upper
    assert np.all(seed >= lower - 1e-12) and np.all(seed <= upper + 1e-12)
    _assert_on_the_poses(problem, seed)
    # the answer of the route before: the whole chain, then the coarse seed from it
    before, spent = coarse_seed(nlp, solve_module.initial_guess(nlp, problem.home))
    np.testing.assert_array_equal(seed, before)
    assert result.iterations == spent + solve_refinement(nlp, before, home=problem.home).iterations


@pytest.mark.parametrize("missed", [[0], [57, 58, 59], [399]])
def test_a_projection_that_misses_a_pose_leaves_the_whole_chain_as_the_seed(monkeypatch, missed):
    problem, nlp = _iiwa(400)
    project = coarse_module.solve_ik_batch

    def failing_projection(kin, targets, q, *args, **kwargs):  # a planted failure at ``missed``
        q, err = project(kin, targets, q, *args, **kwargs)
        if len(targets) == 400:
            err = err.copy()
            err[missed] = 1e-3
        return q, err

    monkeypatch.setattr(coarse_module, "solve_ik_batch", failing_projection)
    seeds, chains = _seeds_solved(monkeypatch)
    result = solve_refinement(nlp, home=problem.home)
    assert result.status == "ok"
    assert chains == [400]  # chained once, after the projection failed
    full = [s for n, s in seeds if n == 400]
    np.testing.assert_array_equal(full[0], initial_guess(nlp, problem.home))
    _assert_on_the_poses(problem, full[0])
    coarse = [n for n, _ in seeds if n == 16]
    assert len(coarse) == 1  # the coarse copy was refined once, not again from the whole chain
