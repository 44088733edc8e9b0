"""The refinement's time limit over the coarse copies that seed a redundant arm (``refine.optimise.solve``).

The coarse copies are solved within the refinement's ``time_limit_s``: each copy's IPOPT gets the
time left as ``max_wall_time`` and its refinement the same deadline, and a limit reached in a copy
ends the refinement as ``timeout`` without starting the full solve, its reason saying how long the
seed and each copy took. The time is spent by spies (a sleep until the copy's own deadline, or a
solve that reports IPOPT's wall-time stop, as :class:`refine.optimise.rounds.RoundLoop` does on
``Maximum_WallTime_Exceeded``), so nothing here depends on the machine's speed; the full solve's
start is seen by a spy on its repair.
"""

from __future__ import annotations

import functools
import math
import re
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import refine.optimise.rounds as rounds_module
import refine.optimise.solve as solve_module
from refine.bench.suites import bundled_problem, generated_problem, load_suites
from refine.optimise.outcome import TimeLimitReached
from refine.optimise.problem import Weights
from refine.paths import FusedPath

PROBLEMS = Path(__file__).resolve().parents[2] / "problems"


@functools.cache
def _iiwa(n: int = 200):
    """The generated LBR iiwa wave (the tool on the flange): one 16-waypoint coarse copy."""
    problem = generated_problem("test", "iiwa", load_suites()["generated"]["iiwa"], n)
    return problem, problem.refinement()


@functools.cache
def _puzzle(n: int, wall_time_s: float):
    """The puzzle piece's first ``n`` waypoints, built with ``ipopt.max_wall_time`` (the ladder's two copies)."""
    problem = bundled_problem("test", PROBLEMS / "puzzle_piece")
    f, i = problem.fused, slice(0, n)
    fused = FusedPath(f.s[i], f.positions[i], f.rotations[i], f.speed[i], f.t_demo[i], f.residual[i])
    problem = replace(problem, fused=fused)
    return problem, problem.refinement(solver_options={"ipopt.max_wall_time": wall_time_s})


def _full_solves(monkeypatch, n: int) -> list:
    """Record each start of the full problem's repair (strict solve, then elastic)."""
    started = []
    repair = solve_module.solve_with_repair

    def recording(problem, seed, *args, **kwargs):
        if problem.n_waypoints == n:
            started.append(problem.n_waypoints)
        return repair(problem, seed, *args, **kwargs)

    monkeypatch.setattr(solve_module, "solve_with_repair", recording)
    return started


def _seconds(reason: str, what: str) -> float:
    """The wall time [s] the reason gives for ``what`` ("seeding", "the 16-waypoint coarse copy")."""
    if what == "seeding":
        return float(re.search(r"([0-9.e-]+) s seeding", reason).group(1))
    return float(re.search(rf"{what} ([0-9.e-]+) s", reason).group(1))


def test_the_limit_reached_in_the_coarse_copy_ends_the_refinement_as_timeout(monkeypatch):
    problem, nlp = _iiwa()
    started = _full_solves(monkeypatch, nlp.n_waypoints)
    deadlines = []
    solve = rounds_module.RoundLoop.solve

    def slow_copy(loop, x0, warm=False):  # the copy's solve spends all the time its refinement has
        if loop.problem.n_waypoints == 16:
            deadlines.append((loop.deadline, time.perf_counter()))
            if math.isfinite(loop.deadline):
                time.sleep(max(loop.deadline - time.perf_counter(), 0.0) + 1e-3)
        return solve(loop, x0, warm)

    monkeypatch.setattr(rounds_module.RoundLoop, "solve", slow_copy)
    limit = 1.0
    begun = time.perf_counter()
    result = solve_module.solve_refinement(nlp, home=problem.home, time_limit_s=limit)
    ((deadline, copy_begun),) = deadlines  # the copy's refinement stops at the call's deadline:
    assert begun + limit <= deadline <= copy_begun + limit  # the limit counted from the call's start
    assert result.status == "timeout" and result.time_limit_reached
    assert started == []  # the full solve never started
    assert result.iterations == 0
    assert "time limit of 1 s" in result.reason
    assert "in the coarse copies that seed the full solve, which was not started" in result.reason
    # the seed's time and the copy's, in seconds: at least the limit together (the copy slept to it)
    seeding, copy = _seconds(result.reason, "seeding"), _seconds(result.reason, "the 16-waypoint coarse copy")
    assert 0.0 < seeding < limit and 0.0 < copy
    assert seeding + copy >= limit - 1e-3  # the reason rounds to 3 digits
    # the answer is the seed, on the full path
    assert result.q.shape == (nlp.n_waypoints, nlp.dof)


def test_a_limit_spent_by_the_seed_leaves_the_coarse_copy_unstarted(monkeypatch):
    problem, nlp = _iiwa()
    started = _full_solves(monkeypatch, nlp.n_waypoints)
    copies = []
    solve = solve_module.solve_refinement
    chain = solve_module.chained_seed

    def slow_chain(*args, **kwargs):
        answer = chain(*args, **kwargs)
        time.sleep(0.3)  # past the limit below
        return answer

    def recording(problem, q0=None, **kwargs):
        copies.append(problem.n_waypoints)
        return solve(problem, q0, **kwargs)

    monkeypatch.setattr(solve_module, "chained_seed", slow_chain)
    monkeypatch.setattr(solve_module, "solve_refinement", recording)
    result = solve(nlp, home=problem.home, time_limit_s=0.2)
    assert result.status == "timeout"
    assert copies == [] and started == []
    assert "the 16-waypoint coarse copy not started" in result.reason
    assert _seconds(result.reason, "seeding") >= 0.3


def test_each_coarse_copy_gets_the_time_left_as_ipopts_wall_time_limit(monkeypatch):
    problem, nlp = _iiwa()
    copies = []
    solve = solve_module.solve_refinement

    def recording(problem, q0=None, **kwargs):
        copies.append((problem.solver_options.get("ipopt.max_wall_time"), problem.given_options, kwargs))
        return solve(problem, q0, **kwargs)

    monkeypatch.setattr(solve_module, "solve_refinement", recording)
    limited = solve(nlp, home=problem.home, time_limit_s=600.0)
    ((wall, given, kwargs),) = copies
    assert limited.status == "ok"
    assert 0.0 < wall < 600.0  # what was left when the copy started
    assert given["ipopt.max_wall_time"] == wall  # a given option: every round of the copy keeps it
    assert 0.0 < kwargs["time_limit_s"] <= wall
    copies.clear()
    unlimited = solve(nlp, home=problem.home)
    ((wall, given, kwargs),) = copies
    assert wall == nlp.solver_options.get("ipopt.max_wall_time")  # the problem's own (IPOPT's default)
    assert "ipopt.max_wall_time" not in given and kwargs["time_limit_s"] is None
    np.testing.assert_array_equal(unlimited.q, limited.q)  # a limit not reached changes nothing


def test_ipopts_wall_time_stop_in_the_ladders_finer_copy_ends_the_refinement_as_timeout(monkeypatch):
    """No ``time_limit_s``, the problem built with ``ipopt.max_wall_time``: the limit IPOPT keeps."""
    problem, nlp = _puzzle(321, 30.0)
    started = _full_solves(monkeypatch, 321)
    solve = rounds_module.RoundLoop.solve

    def stopped(loop, x0, warm=False):
        if loop.problem.n_waypoints == 160:
            raise TimeLimitReached  # as on IPOPT's Maximum_WallTime_Exceeded
        return solve(loop, x0, warm)

    monkeypatch.setattr(rounds_module.RoundLoop, "solve", stopped)
    result = solve_module.solve_refinement(nlp, home=problem.home)
    assert result.status == "timeout" and started == []
    assert result.reason.startswith("IPOPT's wall-time limit of 30.0 s (ipopt.max_wall_time) reached")
    assert _seconds(result.reason, "the 16-waypoint coarse copy") > 0.0
    assert _seconds(result.reason, "the 160-waypoint coarse copy") >= 0.0


def test_a_solve_started_with_little_time_left_stops_at_the_deadline_whatever_its_wall_time_limit(monkeypatch):
    """The iiwa from its chained seed without a mid-range cost (no coarse copy): IPOPT needs over 50
    iterations (:mod:`refine.optimise.coarse`: 120-220); each made to
    take at least 20 ms, so at most 25 fit in a 0.5 s limit, and the iteration callback stops the
    solve at the first past it although the problem's ``ipopt.max_wall_time`` is IPOPT's default."""
    import refine.optimise.watch as watch_module
    from refine.optimise.seed import initial_guess

    problem = replace(_iiwa(60)[0], weights=Weights(mid_range=0.0))  # the generated family has 2.0
    nlp = problem.refinement()
    assert "ipopt.max_wall_time" not in nlp.solver_options  # IPOPT's default, 1e20 s
    seed = initial_guess(nlp, problem.home)
    free = solve_module.solve_refinement(nlp, seed, home=problem.home)
    assert free.status == "ok" and free.iterations > 50
    calls = []
    report = watch_module.solver_iteration

    def slow(iteration, **figures):
        calls.append(iteration)
        time.sleep(0.02)
        return report(iteration, **figures)

    monkeypatch.setattr(watch_module, "solver_iteration", slow)
    result = solve_module.solve_refinement(nlp, seed, home=problem.home, time_limit_s=0.5)
    assert result.status == "timeout" and result.time_limit_reached
    assert 0 < len(calls) <= 26  # 0.5 s / 20 ms, and the one that stops it
