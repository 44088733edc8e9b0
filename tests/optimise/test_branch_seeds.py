"""IK branches tried after the first: a branch whose seed is one whose elastic repair failed is not solved.

On ``joint_wrap_infeasible`` (the IRB 4600 spinning a nozzle 2.6 turns, repair on) the first branch
is infeasible even repaired, and of the two other branches ranked the second chains onto the first
branch's joints. The seeds are compared here with NumPy from the refinement's own calls (a spy on
the repair it runs per branch); the reference is the same refinement with the comparison switched
off (every branch solved), whose verdict and joints the skip must keep.
"""

from __future__ import annotations

import functools
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import refine.optimise.solve as solve_module
from refine.bench.suites import bundled_problem
from refine.optimise.outcome import TimeLimitReached

FOLDER = Path(__file__).resolve().parents[2] / "problems" / "unreachable"


@functools.cache
def _joint_wrap_infeasible():
    problem = bundled_problem("test", FOLDER / "joint_wrap_infeasible")
    return problem, problem.refinement()


def _refine(problem, nlp, **kwargs):
    return solve_module.solve_refinement(
        nlp,
        home=problem.home,
        sources=problem.sources,
        repair_max_slack_deg=problem.repair_max_slack_deg,
        max_rounds=problem.max_rounds,
        **kwargs,
    )


def _spy(monkeypatch):
    """Record the seed of each repair the refinement runs (one per IK branch solved)."""
    seeds = []
    solve = solve_module.solve_with_repair

    def recording(problem, seed, *args, **kwargs):
        seeds.append(np.array(seed))
        return solve(problem, seed, *args, **kwargs)

    monkeypatch.setattr(solve_module, "solve_with_repair", recording)
    return seeds


def test_a_branch_with_the_seed_of_a_failed_branch_is_not_solved_and_the_verdict_stays(monkeypatch):
    problem, nlp = _joint_wrap_infeasible()
    seeds = _spy(monkeypatch)
    monkeypatch.setattr(solve_module, "SAME_SEED_RAD", -1.0)  # no seed is within -1 rad: all solved
    every = _refine(problem, nlp)
    solved_all = list(seeds)
    assert every.status == "infeasible" and every.reason.endswith("(3 IK branch(es) tried)")
    assert len(solved_all) == 3
    # the third branch's seed is the first's, the second's another (NumPy on the seeds themselves)
    assert np.abs(solved_all[2] - solved_all[0]).max() <= 1e-6
    assert np.abs(solved_all[1] - solved_all[0]).max() > 1.0

    monkeypatch.setattr(solve_module, "SAME_SEED_RAD", 1e-6)
    seeds.clear()
    result = _refine(problem, nlp)
    assert len(seeds) == 2  # the third branch is not solved again
    for got, want in zip(seeds, solved_all[:2], strict=True):
        np.testing.assert_array_equal(got, want)
    assert result.status == every.status == "infeasible"
    np.testing.assert_array_equal(result.q, every.q)  # the first branch's verdict, as before
    np.testing.assert_array_equal(result.check.ok, every.check.ok)
    note = "(3 IK branch(es) tried, 1 skipped: branch 3 has the same seed as branch 1)"
    assert result.reason == every.reason.removesuffix("(3 IK branch(es) tried)") + note


def test_the_time_limit_note_stays_after_a_skipped_branch(monkeypatch):
    """Branch 2 given the first branch's seed (skipped), branch 3 stopped by the time limit."""
    problem, nlp = _joint_wrap_infeasible()
    seeds = _spy(monkeypatch)
    rank = solve_module.rank_chains

    def first_again(kin, targets, lower, upper, chains):
        return [seeds[0].copy(), rank(kin, targets, lower, upper, chains)[0]]

    monkeypatch.setattr(solve_module, "rank_chains", first_again)
    solve = solve_module.solve_with_repair
    stopped = []

    def out_of_time_after_the_first(problem, seed, *args, **kwargs):
        if seeds:
            stopped.append(np.array(seed))
            raise TimeLimitReached
        return solve(problem, seed, *args, **kwargs)

    monkeypatch.setattr(solve_module, "solve_with_repair", out_of_time_after_the_first)
    result = _refine(problem, nlp, time_limit_s=600.0)
    assert len(seeds) == 1 and len(stopped) == 1  # branch 2 skipped, branch 3 started and stopped
    assert np.abs(stopped[0] - seeds[0]).max() > 1.0
    assert result.status == "infeasible"
    assert result.reason.endswith(
        "(IK branches after the first 2 not tried: time limit 600 s reached)"
        " (1 skipped: branch 2 has the same seed as branch 1)"
    )


@pytest.mark.parametrize("repair", [True, False], ids=["repair", "no-repair"])
def test_a_branch_with_the_seed_of_a_later_failed_branch_is_skipped_with_repair_on_only(monkeypatch, repair):
    """Branches 2 and 3 given the same seed (another than the first's): the verdict known is the
    elastic repair's, so with repair off every branch is solved."""
    problem, nlp = _joint_wrap_infeasible()
    seeds = _spy(monkeypatch)
    rank = solve_module.rank_chains

    def twice(kin, targets, lower, upper, chains):
        best = rank(kin, targets, lower, upper, chains)[0]
        return [best, best.copy()]

    monkeypatch.setattr(solve_module, "rank_chains", twice)
    result = _refine(problem if repair else replace(problem, repair_max_slack_deg=None), nlp)
    assert result.status == "infeasible"
    assert np.abs(seeds[1] - seeds[0]).max() > 1.0
    if repair:
        assert len(seeds) == 2
        assert result.reason.endswith("(3 IK branch(es) tried, 1 skipped: branch 3 has the same seed as branch 2)")
    else:
        assert len(seeds) == 3
        np.testing.assert_array_equal(seeds[2], seeds[1])
        assert result.reason.endswith("(3 IK branch(es) tried)")


def test_without_repair_the_first_branchs_seed_is_solved_again(monkeypatch):
    problem, nlp = _joint_wrap_infeasible()
    seeds = _spy(monkeypatch)
    result = _refine(replace(problem, repair_max_slack_deg=None), nlp)
    assert result.status == "infeasible" and result.reason.endswith("(3 IK branch(es) tried)")
    assert len(seeds) == 3
    assert np.abs(seeds[2] - seeds[0]).max() <= 1e-6  # the first branch's seed, solved strictly again
