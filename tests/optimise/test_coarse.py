"""The coarse ladder of a held part's long path (``refine.optimise.coarse``, ``refine.optimise.solve``).

A held part (a stationary tool) on a redundant arm solved with IPOPT, on a path of more than 320
waypoints, refines a 16-waypoint copy, then a 160-waypoint copy seeded from it, and seeds the full
solve from the finer answer; any other problem refines the 16-waypoint copy alone. The rule is
checked on stand-ins for each of its conditions and on the puzzle piece cut on both sides of 320
waypoints; the coarse solves are counted by a spy on the refinement's own recursive calls. The
reference for a rung that fails is the route without the ladder (its threshold raised out of
reach): the full solve must start from the same seed, to the bit.
"""

from __future__ import annotations

import functools
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import refine.optimise.coarse as coarse_module
import refine.optimise.solve as solve_module
from refine.bench.suites import bundled_problem, generated_problem, load_suites
from refine.errors import SolverError
from refine.optimise.coarse import ladder_waypoints
from refine.paths import FusedPath

PROBLEMS = Path(__file__).resolve().parents[2] / "problems"


def _stand_in(n: int = 437, dof: int = 7, held: bool = True, solver: str = "ipopt"):
    """What the rule reads of a problem: its size, its arm's joints, its solver and its tool."""
    return SimpleNamespace(
        n_waypoints=n, dof=dof, solver_name=solver, tool_in_world=np.eye(4) if held else None
    )


def test_a_held_part_on_a_long_path_climbs_to_160_evenly_spaced_waypoints():
    idx = ladder_waypoints(_stand_in(437))
    # 436 waypoint steps over 159 rungs: 2.74 apart, so gaps of 2 and 3 from the first to the last
    assert len(idx) == 160 and idx[0] == 0 and idx[-1] == 436
    assert set(np.diff(idx)) == {2, 3}
    np.testing.assert_allclose(idx, np.arange(160) * 436 / 159, atol=0.5)  # each the nearest waypoint
    assert len(ladder_waypoints(_stand_in(321))) == 160  # one waypoint over the threshold


@pytest.mark.parametrize(
    "problem",
    [
        _stand_in(320),  # not more than 320 waypoints
        _stand_in(40),
        _stand_in(dof=6),  # not redundant
        _stand_in(held=False),  # the tool on the flange
        _stand_in(solver="fatrop"),
    ],
    ids=["320-waypoints", "40-waypoints", "six-axis", "tool-on-flange", "fatrop"],
)
def test_no_ladder_for_any_other_problem(problem):
    assert ladder_waypoints(problem) is None


@functools.cache
def _puzzle(n: int | None = None):
    """The puzzle piece (the iiwa holding the part against the grinder), its first ``n`` waypoints."""
    problem = bundled_problem("test", PROBLEMS / "puzzle_piece")
    if n is not None:
        f, i = problem.fused, slice(0, n)
        fused = FusedPath(f.s[i], f.positions[i], f.rotations[i], f.speed[i], f.t_demo[i], f.residual[i])
        problem = replace(problem, fused=fused)
    return problem, problem.refinement()


def _spy(monkeypatch, fail: int | None = None, error: bool = False):
    """Record each coarse copy's solve (size, seed, first options); the copy of size ``fail`` fails.

    With ``error`` the solver fails to run on that copy (``SolverError``) instead of leaving it
    infeasible.
    """
    solves = []
    solve = solve_module.solve_refinement

    def recording(problem, q0=None, **kwargs):
        solves.append((problem.n_waypoints, np.array(q0), kwargs.get("first_options")))
        if error and problem.n_waypoints == fail:
            raise SolverError("IPOPT failed to run: planted")
        answer = solve(problem, q0, **kwargs)
        return replace(answer, status="infeasible") if problem.n_waypoints == fail else answer

    monkeypatch.setattr(solve_module, "solve_refinement", recording)
    return solve, solves


def _full_seed(monkeypatch):
    """Record the seed of the full solves."""
    seeds = []
    solve = solve_module.solve_with_repair

    def recording(problem, seed, *args, **kwargs):
        seeds.append((problem.n_waypoints, np.array(seed)))
        return solve(problem, seed, *args, **kwargs)

    monkeypatch.setattr(solve_module, "solve_with_repair", recording)
    return seeds


def _assert_on_the_poses(problem, q, at=None):
    """The grinder's TCP, standing in the world, at the part's CAD point with the demonstrated axis.

    ``q`` (len(at), n) [rad] at the waypoints ``at`` (every one when None).
    """
    at = np.arange(len(q)) if at is None else at
    for j in range(0, len(q), 5):
        k = at[j]
        # the part on the flange: T_world_part = base · fk · tcp_in_flange; the point in the world
        T_part = problem.base_in_world @ problem.robot.fk(q[j]) @ problem.tcp_in_flange
        point = T_part[:3, :3] @ problem.fused.positions[k] + T_part[:3, 3]
        axis = T_part[:3, :3] @ problem.fused.rotations[k][:, 2]
        np.testing.assert_allclose(point, problem.tool_in_world[:3, 3], atol=1e-5)  # m
        np.testing.assert_allclose(axis, problem.tool_in_world[:3, 2], atol=1e-5)


def test_the_puzzle_piece_over_320_waypoints_is_seeded_from_the_160_waypoint_copy(monkeypatch):
    problem, nlp = _puzzle(321)
    solve = solve_module.solve_refinement
    seeds = _full_seed(monkeypatch)
    # the route without the ladder, for reference
    monkeypatch.setattr(coarse_module, "COARSE_LADDER_MIN_PATH", 10**9)
    without = solve(nlp, home=problem.home)
    seed_without = next(s for n, s in seeds if n == 321)
    monkeypatch.setattr(coarse_module, "COARSE_LADDER_MIN_PATH", 320)
    seeds.clear()
    _, solves = _spy(monkeypatch)
    result = solve(nlp, home=problem.home)
    assert result.status == without.status == "ok"
    assert [n for n, _, _ in solves] == [16, 160]
    (_, _, first16), (_, seed160, first160) = solves
    assert not first16  # the first copy starts at IPOPT's own barrier
    assert first160 == {"ipopt.mu_init": pytest.approx(1e-4)}
    # the finer copy starts on its poses: 320 waypoint steps over 159 rungs, each the nearest waypoint
    _assert_on_the_poses(problem, seed160, np.round(np.arange(160) * 320 / 159).astype(int))
    seed = next(s for n, s in seeds if n == 321)
    _assert_on_the_poses(problem, seed)
    lower, upper = nlp.lbx[: nlp.dof], nlp.ubx[: nlp.dof]
    assert np.all(seed >= lower - 1e-12) and np.all(seed <= upper + 1e-12)
    # the same answer, from a seed nearer to it (17 deg at most against 83)
    np.testing.assert_allclose(result.q, without.q, atol=1e-6)  # rad
    assert np.abs(seed - result.q).max() < np.abs(seed_without - result.q).max()


def test_the_puzzle_piece_of_320_waypoints_refines_the_16_waypoint_copy_alone(monkeypatch):
    problem, nlp = _puzzle(320)
    solve, solves = _spy(monkeypatch)
    assert solve(nlp, home=problem.home).status == "ok"
    assert [n for n, _, _ in solves] == [16]


def test_a_tool_on_the_flange_refines_the_16_waypoint_copy_alone(monkeypatch):
    problem = generated_problem("test", "iiwa", load_suites()["generated"]["iiwa"], 400)
    solve, solves = _spy(monkeypatch)
    assert solve(problem.refinement(), home=problem.home).status == "ok"
    assert [n for n, _, _ in solves] == [16]


@pytest.mark.parametrize("failure", ["infeasible", "projection", "solver error"])
def test_a_failing_rung_leaves_the_seed_of_the_16_waypoint_copy(monkeypatch, failure):
    problem, nlp = _puzzle(321)
    solve = solve_module.solve_refinement
    seeds = _full_seed(monkeypatch)
    monkeypatch.setattr(coarse_module, "COARSE_LADDER_MIN_PATH", 10**9)
    without = solve(nlp, home=problem.home)
    reference = next(s for n, s in seeds if n == 321)
    monkeypatch.setattr(coarse_module, "COARSE_LADDER_MIN_PATH", 320)
    seeds.clear()
    if failure == "infeasible":  # the 160-waypoint copy has no answer
        _, solves = _spy(monkeypatch, fail=160)
    elif failure == "solver error":  # the solver fails to run on the 160-waypoint copy
        _, solves = _spy(monkeypatch, fail=160, error=True)
    else:  # its answer's projection onto the full path misses a pose
        _, solves = _spy(monkeypatch)
        project = solve_module.projected

        def missing(problem, idx, q, at=None):
            q, missed = project(problem, idx, q, at)
            return q, (1 if len(idx) == 160 else missed)

        monkeypatch.setattr(solve_module, "projected", missing)
    result = solve(nlp, home=problem.home)
    assert [n for n, _, _ in solves] == [16, 160]  # the rung was tried
    assert result.status == "ok"
    seed = next(s for n, s in seeds if n == 321)
    np.testing.assert_array_equal(seed, reference)  # the seed of the route without the ladder
    np.testing.assert_array_equal(result.q, without.q)
