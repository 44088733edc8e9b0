"""The warm re-solve's Newton correction (refine.optimise.correction, refine.optimise.kkt) on the glass cell."""

import dataclasses
import logging

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as sla

import refine
from refine.frames import make_transform
from refine.optimise.correction import (
    RowMultipliers,
    active_rows,
    correct,
    multipliers_in_rows,
    row_layout,
    row_names,
)
from refine.optimise.kkt import Evaluator, NullSpaceStep, solve_banded_kkt
from refine.optimise.problem import ActiveSet, LinearRow, build_refinement
from refine.optimise.rounds import CORRECTED
from refine.problem import Tolerances
from refine.synthetic import wave_path

ROBOT = "abb_irb4600_60_205"


@pytest.fixture(scope="module")
def glass(glass_shift):
    """The glass cell's first answer and the part moved 2 mm, 0.3 deg (``glass_shift`` of conftest)."""
    return glass_shift


def kept_multipliers(problem, multipliers):
    """The multipliers (by row name, and of the bounds) as arrays in ``problem``'s row order."""
    lam_g, lam_x = multipliers
    return np.array([lam_g.get(key, 0.0) for key in row_names(problem)]), np.asarray(lam_x)


def test_a_moved_part_is_corrected_to_the_answer_ipopt_finds_at_a_tight_tolerance(glass):
    warm = refine.refine_path(ROBOT, glass.positions, glass.orientations, previous=glass.first, **glass.part)
    refinement = warm.run.first.refinement
    assert warm.status == "ok"
    assert refinement.solver_status == CORRECTED  # answered by the correction, not IPOPT
    assert refinement.outer_iterations == 1
    # the same kept problem solved by IPOPT from the previous (unmoved) answer, cold, to 1e-12
    problem = refinement.problem
    options = {"ipopt.tol": 1e-12, "ipopt.warm_start_init_point": "no", "ipopt.max_iter": 200}
    tight = dataclasses.replace(problem, solver_options={**problem.solver_options, **options}).rebuilt()
    sol = tight.solver(
        x0=glass.first.joints.ravel(), p=tight.params, lbx=tight.lbx, ubx=tight.ubx, lbg=tight.lbg, ubg=tight.ubg
    )
    assert tight.solver.stats()["success"]
    q_ipopt = np.asarray(sol["x"]).ravel().reshape(warm.joints.shape)
    assert np.abs(warm.joints - q_ipopt).max() <= 1e-6
    assert np.abs(warm.joints - glass.first.joints).max() > 1e-4  # the part did move the answer
    # and a cold solve through the API agrees as closely
    cold = refine.refine_path(ROBOT, glass.positions, glass.orientations, **glass.part)
    assert cold.status == "ok"
    assert np.abs(warm.joints - cold.joints).max() <= 1e-6


def test_a_rebuilt_problem_for_another_tool_is_corrected_from_the_previous_rows_and_multipliers(glass):
    """The TCP 1 mm further along the flange z axis: a new problem, the previous active set and multipliers."""
    tool = {**glass.common, "tcp_in_flange": glass.common["tcp_in_flange"] @ make_transform(p=[0.0, 0.0, 0.001])}
    warm = refine.refine_path(ROBOT, glass.fused.positions, glass.fused.rotations, previous=glass.first, **tool)
    assert warm.run.first.refinement.problem is not glass.first.run.first.refinement.problem
    assert warm.run.first.refinement.solver_status == CORRECTED
    cold = refine.refine_path(ROBOT, glass.fused.positions, glass.fused.rotations, **tool)
    assert warm.status == cold.status == "ok"
    assert np.abs(warm.joints - cold.joints).max() <= 1e-6
    assert np.abs(warm.joints - glass.first.joints).max() > 1e-5  # the tool did move the answer


def test_a_narrower_cone_changes_the_active_set_and_is_solved_by_ipopt_with_the_reason_logged(glass, caplog):
    """At a 0.2 deg cone some waypoints' cone rows bind that did not: the correction breaks them, refused."""
    narrow = {**glass.common, "tolerances": {"orientation_deg": 0.2}}
    with caplog.at_level(logging.DEBUG, logger="refine.optimise.rounds"):
        warm = refine.refine_path(ROBOT, glass.fused.positions, glass.fused.rotations, previous=glass.first, **narrow)
    refused = [r.getMessage() for r in caplog.records if "Newton correction refused" in r.getMessage()]
    assert len(refused) == 1
    assert "below its lower bound" in refused[0] and "the active set changed" in refused[0]
    assert CORRECTED not in warm.run.first.refinement.solver_status
    cold = refine.refine_path(ROBOT, glass.fused.positions, glass.fused.rotations, **narrow)
    assert warm.status == cold.status
    assert np.abs(warm.joints - cold.joints).max() <= 1e-6


def ipopt_answer(problem, x0, **bounds):
    """IPOPT's answer of ``problem`` with other bounds: joints and multipliers (x, lam_g, lam_x)."""
    b = {"lbx": problem.lbx, "ubx": problem.ubx, "lbg": problem.lbg, "ubg": problem.ubg, **bounds}
    sol = problem.solver(x0=x0, p=problem.params, **b)
    assert problem.solver.stats()["success"]
    return tuple(np.asarray(sol[k]).ravel() for k in ("x", "lam_g", "lam_x"))


def test_a_bound_or_row_that_lets_go_has_a_multiplier_of_the_wrong_sign_and_is_refused(glass):
    """Joint 1 held 1 mrad under its previous value at three waypoints (a bound, then a linear row),
    then the bound moved 1 mrad above: held there it pulls instead of pushing, refused."""
    refinement = glass.first.run.first.refinement
    problem = refinement.problem
    x = glass.first.joints.ravel()
    lam_g, lam_x = kept_multipliers(problem, refinement.multipliers)
    found, reason = correct(problem, x, lam_g, lam_x)
    assert reason == "" and np.abs(found.x - x).max() <= 1e-6  # the previous answer is its own correction
    assert found.stationarity <= 1e-9 and found.violation <= 1e-10
    n, waypoints = problem.dof, [300, 301, 302]
    j = [k * n for k in waypoints]
    under, over = problem.ubx.copy(), problem.ubx.copy()
    under[j], over[j] = x[j] - 1e-3, x[j] + 1e-3
    xb, lgb, lxb = ipopt_answer(problem, x, ubx=under)
    assert np.all(lxb[j] > 1e-3)  # the bound holds the joint: an upper bound's multiplier is positive
    found, reason = correct(dataclasses.replace(problem, ubx=under), xb + 1e-6, lgb, lxb)
    assert reason == "" and np.abs(found.x - xb).max() <= 1e-6
    found, reason = correct(dataclasses.replace(problem, ubx=over), xb, lgb, lxb)
    assert found is None and "bound multiplier" in reason and "wrong sign" in reason
    # the same as linear rows -q_k,1 >= -(q_k,1 - 1 mrad): a lower bound, its multiplier negative
    gradient = -np.eye(n)[0]
    rows = tuple(LinearRow(k, 0.0, gradient, -(x[k * n] - 1e-3)) for k in waypoints)
    held = problem.rebuilt(active=ActiveSet(linear_rows=rows))
    xr, lgr, lxr = ipopt_answer(held, x)
    assert np.all(lgr[-3:] < -1e-3) and np.abs(xr - xb).max() <= 1e-6
    found, reason = correct(held, xr + 1e-6, lgr, lxr)
    assert reason == "" and np.abs(found.x - xr).max() <= 1e-6
    moved = held.lbg.copy()
    moved[-3:] = -(x[j] + 1e-3)
    found, reason = correct(dataclasses.replace(held, lbg=moved), xr, lgr, lxr)
    assert found is None and "('row', 300, 0.0, '')" in reason and "wrong sign" in reason


def test_the_null_space_step_and_the_banded_kkt_solve_solve_the_kkt_system(glass):
    """Both steps against SciPy's sparse LU of the whole KKT matrix, on the glass cell's problem."""
    refinement = glass.first.run.first.refinement
    problem = refinement.problem
    N, n = problem.n_waypoints, problem.dof
    lam_g, lam_x = kept_multipliers(problem, refinement.multipliers)
    cone = np.zeros(len(problem.lbg), dtype=bool)
    cone[3 : 4 * N : 4] = True
    active = active_rows(problem.lbg, problem.ubg, lam_g, problem.lbx, problem.ubx, lam_x, cone)
    assert len(active.rows) >= 3 * N and not active.bounds.size  # the positions; cone rows at cos = 1 not held
    # held besides the positions: the cone rows of the three waypoints furthest from the
    # demonstration (at their lower bound) and three joint limits: 3 to 5 rows per waypoint
    rows = np.sort(np.r_[np.arange(4 * N).reshape(N, 4)[:, :3].ravel(), 4 * np.array([96, 128, 180]) + 3])
    bounds = np.array([128 * n + 1, 300 * n, 400 * n + 2])
    lam_g = lam_g * np.isin(np.arange(len(lam_g)), rows)
    ev = Evaluator(problem)
    x = glass.first.joints.ravel() + 1e-4 * np.sin(np.arange(len(problem.lbx)))
    grad, g, jac_values = ev.first_order(x)
    hess_values = ev.hessian(lam_g)
    H = ev.hessian_matrix(hess_values)
    nx = len(x)
    fixed = sp.csr_matrix((np.ones(3), (np.arange(3), bounds)), shape=(3, nx))
    A = sp.vstack([ev.jacobian(jac_values)[rows], fixed], format="csr")
    r = np.cos(np.arange(len(rows))) * 1e-5
    z = sla.spsolve(sp.bmat([[H, A.T], [A, None]], format="csc"), np.concatenate([-grad, r, np.zeros(3)]))
    step = NullSpaceStep(ev, rows, bounds, N, n)
    assert (step.m_min, step.m_max) == (3, 5)
    dx, lam, factors = step.step(grad, jac_values, hess_values, r)
    assert np.array_equal(step.solve(factors, grad, r)[0], dx)
    assert np.abs(dx - z[:nx]).max() <= 1e-9 * max(1.0, np.abs(z[:nx]).max())
    assert np.abs(lam - z[nx:]).max() <= 1e-6 * max(1.0, np.abs(z[nx:]).max())
    # a row coupling two neighbouring waypoints: the banded LU of the whole matrix
    coupling = sp.csr_matrix(
        (np.r_[np.ones(n), -np.ones(n)], (np.zeros(2 * n, dtype=int), np.r_[np.arange(n) + 10 * n, np.arange(n) + 11 * n])),
        shape=(1, nx),
    )
    A2 = sp.vstack([A, coupling], format="csr")
    rhs = np.concatenate([-grad, r, np.zeros(3), [1e-6]])
    z2 = sla.spsolve(sp.bmat([[H, A2.T], [A2, None]], format="csc"), rhs)
    banded = solve_banded_kkt(H, A2, rhs, n)
    assert np.abs(banded - z2).max() <= 1e-6 * max(1.0, np.abs(z2).max())


def test_held_joint_step_rows_are_corrected_through_the_whole_banded_kkt_matrix(glass, caplog):
    """Joint 1's steps after waypoints 200-202 held at half their size: rows of two waypoints each."""
    refinement = glass.first.run.first.refinement
    q = glass.first.joints
    N, n = q.shape
    waypoints = (200, 201, 202)
    problem = refinement.problem.rebuilt(joint_steps=tuple(k * n for k in waypoints))
    rows = 4 * N + np.arange(3)  # the three joint-step rows, after the path rows
    steps = np.array([q[k + 1, 0] - q[k, 0] for k in waypoints])
    lbg, ubg = problem.lbg.copy(), problem.ubg.copy()
    lbg[rows] = np.where(steps < 0, 0.5 * steps, lbg[rows])
    ubg[rows] = np.where(steps > 0, 0.5 * steps, ubg[rows])
    x, lam_g, lam_x = ipopt_answer(problem, q.ravel(), lbg=lbg, ubg=ubg)
    assert np.all(np.abs(lam_g[rows]) > 1e-3)  # held
    halved = dataclasses.replace(problem, lbg=lbg, ubg=ubg)
    with caplog.at_level(logging.DEBUG, logger="refine.optimise.correction"):
        found, reason = correct(halved, x + 1e-6, lam_g, lam_x)
    assert any("the whole KKT matrix is factorised" in r.getMessage() for r in caplog.records)
    assert reason == "" and np.abs(found.x - x).max() <= 1e-6
    assert np.abs(np.diff(found.x.reshape(N, n)[:, 0])[list(waypoints)] - 0.5 * steps).max() <= 1e-10


def test_multipliers_kept_in_row_order_read_by_row_name_and_move_to_a_grown_problems_rows(
    irb4600, straight_tool
):
    """The rounds' multipliers (values in row order, named by the rows' layout) are the mapping of row names."""
    N, n = 8, 6
    small = ActiveSet((3,), ((5, 0.5),), (LinearRow(2, 0.0, np.ones(n), 0.0, "a / b"),))
    grown = ActiveSet((1, 3), ((2, 0.5), (5, 0.5)), small.linear_rows)
    built = [
        build_refinement(
            irb4600, wave_path(N), np.eye(4), straight_tool, Tolerances(), active=a, joint_steps=steps
        )
        for a, steps in ((small, (4, 9)), (grown, (4, 7, 9)))
    ]
    base = [("path", i) for i in range(4 * N)]
    names = [  # by hand: path rows, joint-step rows, singular waypoints, segment points, linear rows
        base
        + [("step", 4), ("step", 9), ("singular", 3, 0.0), ("singular", 5, 0.5), ("row", 2, 0.0, "a / b")],
        base
        + [("step", 4), ("step", 7), ("step", 9)]
        + [("singular", 1, 0.0), ("singular", 3, 0.0), ("singular", 2, 0.5), ("singular", 5, 0.5)]
        + [("row", 2, 0.0, "a / b")],
    ]
    assert [len(b.lbg) for b in built] == [len(k) for k in names]
    values = np.random.default_rng(3).normal(size=len(names[0]))
    kept = RowMultipliers(row_layout(built[0]), values)
    by_name = dict(zip(names[0], values.tolist(), strict=True))
    assert dict(kept) == by_name and kept.get(("step", 7), 0.0) == 0.0
    # in the grown problem's rows: by name, 0 for a row the small problem did not have
    expected = np.array([by_name.get(k, 0.0) for k in names[1]])
    moved = kept.in_rows_of(row_layout(built[1]))
    assert np.array_equal(moved, expected)
    assert np.array_equal(multipliers_in_rows(by_name, row_layout(built[1])), expected)
    # the same rows: the values themselves, a copy
    same = kept.in_rows_of(row_layout(built[0].rebuilt()))
    assert np.array_equal(same, values) and same is not kept.values
    assert row_layout(built[0]) != row_layout(built[1])
    with pytest.raises(ValueError, match="multipliers"):
        RowMultipliers(row_layout(built[1]), values)


def test_the_batched_householder_qr_is_a_complete_qr_of_every_block_padded_rows_left_alone():
    """Qᵀ orthogonal, Q[:, :m] R = Aᵀ, A Q[:, m:] = 0 and |R| = LAPACK's, block by block; zero rows stay zero."""
    from refine.optimise.kkt import householder_qr

    rng = np.random.default_rng(3)
    A = rng.normal(size=(40, 5, 7))
    A[::3, 3:] = 0.0  # padded rows: two held rows fewer at every third block
    A[1, 0] *= -1.0
    Qt, R = householder_qr(A)
    Q = np.transpose(Qt, (0, 2, 1))
    assert np.abs(Qt @ Q - np.eye(7)).max() <= 1e-13
    assert np.abs(Q[:, :, :5] @ R - np.transpose(A, (0, 2, 1))).max() <= 1e-13
    assert np.all(np.tril(R, -1) == 0.0)
    for k in range(40):
        count = 3 if k % 3 == 0 else 5
        assert np.abs(A[k, :count] @ Q[k, :, count:]).max() <= 1e-13  # the null space of the held rows
        R_ref = np.linalg.qr(A[k, :count].T, mode="r")
        assert np.allclose(np.abs(R[k, :count, :count]), np.abs(R_ref), atol=1e-12)
        assert np.all(R[k, count:, count:] == 0.0)


def test_an_evaluator_kept_for_the_same_derivatives_evaluates_another_paths_parameters(glass):
    """The thread's kept evaluator, handed a problem with the same functions and another path, gives
    what a fresh evaluator of that problem gives; another thread gets its own."""
    import threading

    from refine.optimise.kkt import evaluator_for
    from refine.optimise.problem import path_params

    problem = glass.first.run.first.refinement.problem
    moved = dataclasses.replace(problem, params=path_params(glass.fused) + 1e-3)
    x = glass.first.joints.ravel()
    ev = evaluator_for(problem)
    ev.first_order(x)
    again = evaluator_for(moved)
    assert again is ev
    got = [a.copy() for a in again.first_order(x)]
    fresh = Evaluator(moved).first_order(x)
    assert all(np.array_equal(a, b) for a, b in zip(got, fresh, strict=True))
    assert not np.array_equal(got[1], Evaluator(problem).first_order(x)[1])
    other = []
    thread = threading.Thread(target=lambda: other.append(evaluator_for(moved)))
    thread.start()
    thread.join()
    assert other[0] is not ev
