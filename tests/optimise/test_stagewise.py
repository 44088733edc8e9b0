"""fatrop on the refinement posed stage by stage (``refine.optimise.stagewise``).

The references are independent of the stage-wise formulation: the layout is checked against
indices worked by hand; the answers against IPOPT on the refinement as
:func:`~refine.optimise.problem.build_refinement` poses it; the multipliers fatrop returns, mapped
back to the refinement's rows, against the refinement's own optimality condition
``∇f + Jᵀλ_g + λ_x = 0``, differentiated by CasADi from the refinement's (not the stage-wise) graph.
"""

from __future__ import annotations

import functools
import math

import casadi as ca
import numpy as np
import pytest

from refine.bench.suites import generated_problem, load_suites, problems
from refine.errors import InputError
from refine.optimise.problem import ActiveSet, LinearRow
from refine.optimise.solve import solve_refinement
from refine.optimise.stagewise import MAX_FATROP_WAYPOINTS, _inset, stage_layout
from refine.settings import OptimiseSettings


@functools.cache
def _generated(family: str, n: int):
    return generated_problem("test", family, load_suites()["generated"][family], n)


def _build(problem, solver: str, **options):
    """The refinement of a bench problem for ``solver``, with every joint-step row unless told."""
    return problem.refinement(solver=solver, **{"joint_steps": "all", **options})


def test_the_layout_puts_each_variable_where_the_stages_hold_it():
    # 3 waypoints of 2 joints, elastic: stage 0 = [q0 (2) | d0 (2), σ0], stage 1 = [q1, d0 | d1, σ1],
    # stage 2 = [q2, d1 | σ2]
    lay = stage_layout(3, 2, elastic=True)
    assert lay.nx == (2, 4, 4) and lay.nu == (3, 3, 1) and lay.size == 17
    np.testing.assert_array_equal(lay.q_index, [[0, 1], [5, 6], [12, 13]])
    np.testing.assert_array_equal(lay.d_index, [[2, 3], [9, 10], [-1, -1]])
    np.testing.assert_array_equal(lay.dp_index, [[-1, -1], [7, 8], [14, 15]])
    np.testing.assert_array_equal(lay.sigma_index, [4, 11, 16])
    x = np.array([1.0, 2.0, 4.0, 7.0, 11.0, 16.0, 0.1, 0.2, 0.3])  # q0, q1, q2, then σ
    z = lay.pack(x)
    expected = [1, 2, 3, 5, 0.1, 4, 7, 3, 5, 7, 9, 0.2, 11, 16, 7, 9, 0.3]
    np.testing.assert_allclose(z, expected)
    np.testing.assert_allclose(z[lay.standard()], x)
    strict = stage_layout(3, 2, elastic=False)
    assert strict.nu == (2, 2, 0) and strict.size == 14


def test_inequality_bounds_are_drawn_in_and_equalities_kept():
    lower = np.array([0.02, -2.0, 0.5, -np.inf, 1.0])
    upper = np.array([np.inf, 3.0, 0.5, np.inf, 1.0 + 1e-9])
    lo, hi = _inset(lower, upper)
    np.testing.assert_allclose(lo, [0.02 + 1e-8, -2.0 + 2e-8, 0.5, -np.inf, 1.0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(hi, [np.inf, 3.0 - 3e-8, 0.5, np.inf, 1.0 + 1e-9], rtol=0, atol=1e-15)


@pytest.mark.parametrize("family", ["irb4600", "ur10e_obstacles", "iiwa"])
def test_fatrop_finds_ipopts_answer(family):
    problem = _generated(family, 60)
    answers = {}
    for solver in ("ipopt", "fatrop"):
        answers[solver] = solve_refinement(
            _build(problem, solver, joint_steps=()), home=problem.home, sources=problem.sources
        )
    assert answers["ipopt"].status == answers["fatrop"].status == "ok"
    assert answers["fatrop"].check.ok
    np.testing.assert_allclose(answers["fatrop"].q, answers["ipopt"].q, atol=1e-6)


def _with_every_kind_of_row(problem, solver: str, q: np.ndarray, elastic: bool):
    """A problem holding singularity bounds, linear rows and some joint-step rows, some of them binding."""
    N, n = q.shape
    k = N // 2
    # a row that binds: joint 1 at waypoint k pushed 0.1 deg past where the free answer has it (fatrop
    # fails from a start 0.5 deg off: return flag 2), and one inside segment k + 3 that holds already
    rows = (
        LinearRow(k, 0.0, np.eye(n)[0], float(q[k, 0]) + math.radians(0.1), "push joint 1"),
        LinearRow(k + 3, 0.25, -np.eye(n)[1], -float(q[k + 3, 1]) - 1.0, "loose"),
    )
    active = ActiveSet((k - 2, k + 5), ((k + 1, 0.5),), rows)
    steps = tuple(range(0, n * (N - 1), 7))
    return _build(problem, solver, active=active, joint_steps=steps, elastic_deg=5.0 if elastic else None)


@pytest.mark.parametrize("elastic", [False, True])
def test_fatrops_multipliers_meet_the_refinements_optimality_condition(elastic):
    problem = _generated("irb4600", 40)
    free = solve_refinement(_build(problem, "ipopt"), home=problem.home)
    assert free.status == "ok"
    answers = {}
    for solver in ("ipopt", "fatrop"):
        nlp = _with_every_kind_of_row(problem, solver, free.q, elastic)
        x0 = np.concatenate([free.q.ravel(), np.zeros(len(nlp.lbx) - free.q.size)])
        sol = nlp.solver(x0=x0, p=nlp.params, lbx=nlp.lbx, ubx=nlp.ubx, lbg=nlp.lbg, ubg=nlp.ubg)
        assert bool(nlp.solver.stats()["success"])
        answers[solver] = {key: np.asarray(sol[key]).ravel() for key in ("x", "lam_g", "lam_x", "g")}
    ref = _with_every_kind_of_row(problem, "ipopt", free.q, elastic)
    x_sym, p_sym = ref.nlp["x"], ref.nlp["p"]
    grad = ca.Function("gradient_f", [x_sym, p_sym], [ca.gradient(ref.nlp["f"], x_sym)])
    jac = ca.Function("jacobian_g", [x_sym, p_sym], [ca.jacobian(ref.nlp["g"], x_sym)])
    fat, ipo = answers["fatrop"], answers["ipopt"]
    np.testing.assert_allclose(fat["x"], ipo["x"], atol=1e-6)
    g_ref = np.asarray(ca.Function("rows", [x_sym, p_sym], [ref.nlp["g"]])(fat["x"], ref.params)).ravel()
    np.testing.assert_allclose(fat["g"], g_ref, atol=1e-9)  # the rows come back in the refinement's order
    stationarity = (
        np.asarray(grad(fat["x"], ref.params)).ravel()
        + np.asarray(jac(fat["x"], ref.params)).T @ fat["lam_g"]
        + fat["lam_x"]
    )
    scale = max(1.0, float(np.abs(fat["lam_g"]).max()))
    assert np.abs(stationarity).max() < 1e-5 * scale
    # the pushed row binds, with the same multiplier as IPOPT's
    pushed = len(ref.lbg) - 2
    assert abs(ipo["lam_g"][pushed]) > 1e-3
    np.testing.assert_allclose(fat["lam_g"][pushed], ipo["lam_g"][pushed], rtol=1e-3)


def test_fatrop_repairs_what_ipopt_repairs():
    problem = next(p for p in problems(load_suites(), "unreachable") if p.name == "wrist_flip")
    slack = {}
    for solver in ("ipopt", "fatrop"):
        answer = solve_refinement(
            problem.refinement(solver=solver),
            home=problem.home,
            sources=problem.sources,
            repair_max_slack_deg=problem.repair_max_slack_deg,
            max_rounds=problem.max_rounds,
        )
        assert answer.status == "repaired" and answer.check.ok, answer.reason
        slack[solver] = answer.slack_deg
    np.testing.assert_allclose(slack["fatrop"], slack["ipopt"], atol=1e-3)


def test_an_unknown_solver_and_too_long_a_path_are_refused():
    with pytest.raises(InputError, match="optimise.solver must be one of 'ipopt', 'fatrop', got 'snopt'"):
        OptimiseSettings(solver="snopt")
    with pytest.raises(InputError, match=f"at most {MAX_FATROP_WAYPOINTS} waypoints, the path has 2001"):
        _build(_generated("irb4600", MAX_FATROP_WAYPOINTS + 1), "fatrop")


def test_a_path_refined_with_fatrop_says_so_and_matches_ipopts(tmp_path):
    import json

    import refine

    N = 41
    positions = np.column_stack([np.full(N, 0.6), np.linspace(-0.2, 0.2, N), np.full(N, 0.3)])  # [m]
    down = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    orientations = np.array([down @ _about_y(a) for a in np.radians(np.linspace(-10.0, 10.0, N))])
    results = {
        solver: refine.refine_path(
            "ur10e",
            positions,
            orientations,
            speeds=0.1,
            tcp_in_flange=np.eye(4),
            optimise=OptimiseSettings(solver=solver),
        )
        for solver in ("ipopt", "fatrop")
    }
    assert results["ipopt"].status == results["fatrop"].status == "ok"
    np.testing.assert_allclose(results["fatrop"].joints, results["ipopt"].joints, atol=1e-6)
    results["fatrop"].write(tmp_path, programs=(), report=True)
    doc = json.loads((tmp_path / "result.json").read_text())
    assert doc["solver"]["name"] == "fatrop"
    assert doc["solver"]["status"] == "solved"


def _about_y(angle: float) -> np.ndarray:
    """The rotation by ``angle`` [rad] about y."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def test_an_infeasible_verdict_after_fatrop_failed_says_it_may_be_the_solvers():
    """fatrop cannot repair tool_through_fixture (the seed passes through the clamp: the clearance
    rows start broken), which IPOPT repairs; the verdict must not read as the problem's alone."""
    problem = next(p for p in problems(load_suites(), "unreachable") if p.name == "tool_through_fixture")
    answers = {
        solver: solve_refinement(
            problem.refinement(solver=solver),
            home=problem.home,
            sources=problem.sources,
            repair_max_slack_deg=problem.repair_max_slack_deg,
            max_rounds=problem.max_rounds,
        )
        for solver in ("ipopt", "fatrop")
    }
    assert answers["ipopt"].status == "repaired" and "fatrop" not in answers["ipopt"].reason
    assert answers["fatrop"].status == "infeasible"
    assert "may be the solver's, not the problem's" in answers["fatrop"].reason
    assert "[optimise] solver = 'ipopt'" in answers["fatrop"].reason
