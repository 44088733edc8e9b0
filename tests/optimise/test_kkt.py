"""The null-space Newton step (refine.optimise.kkt.NullSpaceStep) against NumPy's dense solve of the KKT system.

On a small refinement problem the KKT matrix ``[[H, Aᵀ], [A, 0]]`` of the held rows ``A`` is
assembled densely here from the evaluator's nonzeros (``np.add.at`` on their rows and columns, the
Hessian mirrored from its upper triangle) and solved by ``numpy.linalg.solve``: the step's banded
reduced Hessian, its LAPACK factorisation and the per-waypoint null spaces must give the same
step and multipliers.
"""

from __future__ import annotations

import numpy as np
import pytest

import refine
from refine.optimise.kkt import Evaluator, NullSpaceStep
from refine.optimise.problem import ActiveSet, build_refinement
from refine.problem import Tolerances
from refine.synthetic import wave_path

N = 12


def small_problem(irb4600, straight_tool, segment: bool):
    """A 12-waypoint wave; with ``segment`` a singularity row inside segment 5 whose second
    derivatives are in the Hessian: a full block coupling waypoints 5 and 6."""
    active = ActiveSet(singular_segments=((5, 0.4),)) if segment else ActiveSet()
    options = {"active": active, "singularity_hessian": segment, "joint_steps": ()}
    return build_refinement(irb4600, wave_path(N), np.eye(4), straight_tool, Tolerances(), **options)


@pytest.fixture(scope="module")
def answers(irb4600, straight_tool):
    """Per problem (without, with the segment row): IPOPT's answer and multipliers, from the API's answer."""
    fused = wave_path(N)
    first = refine.refine_path("abb_irb4600_60_205", fused.positions, fused.rotations, tcp_in_flange=straight_tool)
    out = {}
    for segment in (False, True):
        p = small_problem(irb4600, straight_tool, segment)
        sol = p.solver(x0=first.joints.ravel(), p=p.params, lbx=p.lbx, ubx=p.ubx, lbg=p.lbg, ubg=p.ubg)
        assert p.solver.stats()["success"]
        out[segment] = p, np.asarray(sol["x"]).ravel(), np.asarray(sol["lam_g"]).ravel()
    return out


def dense(rows, cols, values, shape):
    M = np.zeros(shape)
    np.add.at(M, (rows, cols), values)
    return M


def held_kkt(ev, problem, lam_g, x, rows, bounds):
    """Gradient, dense Hessian of the Lagrangian and the dense held rows (rows, then unit bound rows) at ``x``."""
    grad, _, jac_values = (a.copy() for a in ev.first_order(x))
    nx, ng = len(x), len(problem.lbg)
    upper = dense(ev.hess_row, ev.hess_col, ev.hessian(lam_g), (nx, nx))
    H = upper + np.triu(upper, 1).T
    J = dense(ev.jac_row, ev.jac_col, jac_values, (ng, nx))
    A = np.vstack([J[rows], np.eye(nx)[bounds]])
    return grad, jac_values, H, A


@pytest.mark.parametrize("segment", [False, True], ids=["diagonal neighbour blocks", "a full neighbour block"])
def test_the_null_space_step_is_numpys_dense_solve_of_the_kkt_system(answers, segment):
    """Near IPOPT's answer, 3 to 5 rows held per waypoint."""
    problem, x, lam = answers[segment]
    n, ng = problem.dof, len(problem.lbg)
    rng = np.random.default_rng(5)
    x = x + rng.normal(scale=1e-3, size=x.shape)
    # held: the positions, the cone rows of waypoints 2 and 7, joint limits at 4 and 7: 3 to 5 per waypoint
    rows = np.sort(np.r_[np.arange(4 * N).reshape(N, 4)[:, :3].ravel(), 4 * 2 + 3, 4 * 7 + 3])
    bounds = np.array([4 * n + 1, 7 * n + 2])
    lam_g = np.zeros(ng)
    lam_g[rows] = lam[rows]
    if segment:
        lam_g[-1] = 1e-3  # the segment row's curvature in the Hessian
    ev = Evaluator(problem)
    grad, jac_values, H, A = held_kkt(ev, problem, lam_g, x, rows, bounds)
    step = NullSpaceStep(ev, rows, bounds, N, n)
    assert (step.m_min, step.m_max, step.reach) == (3, 5, 2)
    assert step.diagonal == [False, not segment, True]
    if segment:
        assert np.abs(H[5 * n : 6 * n, 6 * n : 7 * n] - np.diag(np.diag(H[5 * n : 6 * n, 6 * n : 7 * n]))).max() > 1e-6
    kkt = np.block([[H, A.T], [A, np.zeros((len(A), len(A)))]])
    r = rng.normal(scale=1e-4, size=len(rows))
    expected = np.linalg.solve(kkt, np.concatenate([-grad, r, np.zeros(len(bounds))]))
    dx, lam, factors = step.step(grad, jac_values, ev.hessian(lam_g), r)
    close(dx, lam, expected)
    # the kept factors solve the same matrix for another gradient and residual
    g2, r2 = grad + rng.normal(scale=1e-3, size=grad.shape), rng.normal(scale=1e-4, size=len(rows))
    expected = np.linalg.solve(kkt, np.concatenate([-g2, r2, np.zeros(len(bounds))]))
    close(*step.solve(factors, g2, r2), expected)


def close(dx, lam, expected):
    """The step and the multipliers those of ``expected`` (dense) within 1e-11 of their own size."""
    nx = len(dx)
    assert np.abs(dx - expected[:nx]).max() <= 1e-11 * np.abs(expected[:nx]).max()
    assert np.abs(lam - expected[nx:]).max() <= 1e-11 * np.abs(expected[nx:]).max()


def test_a_reduced_hessian_that_is_not_positive_definite_is_refused(answers):
    """The Hessian negated: ZᵀHZ negative definite (NumPy's eigenvalues), LAPACK's factorisation fails."""
    problem, x, lam = answers[False]
    n = problem.dof
    rows = np.arange(4 * N).reshape(N, 4)[:, :3].ravel()
    ev = Evaluator(problem)
    lam_g = np.zeros(len(problem.lbg))
    lam_g[rows] = lam[rows]
    grad, jac_values, H, A = held_kkt(ev, problem, lam_g, x, rows, np.array([], dtype=int))
    null = np.linalg.svd(A)[2][len(A) :].T  # a basis of the held rows' null space
    assert np.linalg.eigvalsh(null.T @ H @ null).min() > 0.0
    assert np.linalg.eigvalsh(null.T @ -H @ null).max() < 0.0
    step = NullSpaceStep(ev, rows, np.array([], dtype=int), N, n)
    step.step(grad, jac_values, ev.hessian(lam_g), np.zeros(len(rows)))
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        step.step(grad, jac_values, -ev.hessian(lam_g), np.zeros(len(rows)))


@pytest.mark.parametrize("reach", [0, 1, 2])
def test_random_banded_kkt_systems_with_unsymmetric_neighbour_blocks_are_solved_as_numpy_solves_them(reach):
    """9 waypoints of 4 joints, 1 to 3 held rows or bounds each, a Hessian with full (unsymmetric)
    blocks to the next waypoint and diagonal ones to the one after (up to ``reach``): the patterns
    only, no problem."""
    from types import SimpleNamespace

    rng = np.random.default_rng(7)
    n, N9 = 4, 9
    nx = n * N9
    counts = np.array([1, 3, 2, 1, 2, 3, 3, 1, 2])
    bounds = np.array([0 * n + 2, 4 * n + 1, 8 * n + 3])  # one of the held per waypoint 0, 4, 8
    row_k = np.repeat(np.arange(N9), counts - np.isin(np.arange(N9), bounds // n))
    jac_row = np.repeat(np.arange(len(row_k)), n)
    jac_col = (row_k[:, None] * n + np.arange(n)).ravel()
    extra = np.array([len(row_k)] * 3)  # a row not held, across two waypoints
    jac_row, jac_col = np.r_[jac_row, extra], np.r_[jac_col, [5, 9, 14]]
    ng = len(row_k) + 1
    upper = np.zeros((nx, nx))
    for k in range(N9):
        block = rng.normal(size=(n, n))
        upper[k * n : (k + 1) * n, k * n : (k + 1) * n] = np.triu(block + block.T) + 8.0 * np.eye(n)
        if k + 1 < N9 and reach >= 1:
            upper[k * n : (k + 1) * n, (k + 1) * n : (k + 2) * n] = rng.normal(scale=0.5, size=(n, n))
        if k + 2 < N9 and reach >= 2:
            upper[k * n : (k + 1) * n, (k + 2) * n : (k + 3) * n] = np.diag(rng.normal(scale=0.5, size=n))
    hess_row, hess_col = np.nonzero(upper)
    ev = SimpleNamespace(ng=ng, jac_row=jac_row, jac_col=jac_col, hess_row=hess_row, hess_col=hess_col)
    rows = np.arange(len(row_k))
    step = NullSpaceStep(ev, rows, bounds, N9, n)
    assert (step.m_min, step.m_max, step.reach) == (1, 3, reach)
    assert step.diagonal == [False, False, True][: reach + 1]
    jac_values = rng.normal(size=len(jac_row))
    J = dense(jac_row, jac_col, jac_values, (ng, nx))
    H = upper + np.triu(upper, 1).T
    A = np.vstack([J[rows], np.eye(nx)[bounds]])
    kkt = np.block([[H, A.T], [A, np.zeros((len(A), len(A)))]])
    grad, r = rng.normal(size=nx), rng.normal(size=len(rows))
    expected = np.linalg.solve(kkt, np.concatenate([-grad, r, np.zeros(len(bounds))]))
    dx, lam, factors = step.step(grad, jac_values, upper[hess_row, hess_col], r)
    close(dx, lam, expected)


def test_every_joint_held_at_every_waypoint_leaves_the_step_the_rows_fix():
    """6 waypoints of 4 joints, 4 held rows or bounds at each: no null space (``nz`` 0), the step
    ``A dx = r`` and the multipliers of ``H dx + g + Aᵀλ = 0`` alone, as NumPy's dense solve gives them."""
    from types import SimpleNamespace

    rng = np.random.default_rng(11)
    n, N6 = 4, 6
    nx = n * N6
    bounds = np.array([0 * n + 2, 3 * n + 1])
    row_k = np.repeat(np.arange(N6), n - np.bincount(bounds // n, minlength=N6))
    jac_row = np.repeat(np.arange(len(row_k)), n)
    jac_col = (row_k[:, None] * n + np.arange(n)).ravel()
    upper = np.zeros((nx, nx))
    for k in range(N6):
        block = rng.normal(size=(n, n))
        upper[k * n : (k + 1) * n, k * n : (k + 1) * n] = np.triu(block + block.T) + 8.0 * np.eye(n)
        if k + 1 < N6:
            upper[k * n : (k + 1) * n, (k + 1) * n : (k + 2) * n] = np.diag(rng.normal(scale=0.5, size=n))
    hess_row, hess_col = np.nonzero(upper)
    ev = SimpleNamespace(
        ng=len(row_k), jac_row=jac_row, jac_col=jac_col, hess_row=hess_row, hess_col=hess_col
    )
    rows = np.arange(len(row_k))
    step = NullSpaceStep(ev, rows, bounds, N6, n)
    assert step.nz == 0
    jac_values = rng.normal(size=len(jac_row))
    J = dense(jac_row, jac_col, jac_values, (len(row_k), nx))
    A = np.vstack([J, np.eye(nx)[bounds]])
    H = upper + np.triu(upper, 1).T
    kkt = np.block([[H, A.T], [A, np.zeros((len(A), len(A)))]])
    grad, r = rng.normal(size=nx), rng.normal(size=len(rows))
    expected = np.linalg.solve(kkt, np.concatenate([-grad, r, np.zeros(len(bounds))]))
    dx, lam, factors = step.step(grad, jac_values, upper[hess_row, hess_col], r)
    close(dx, lam, expected)
    g2, r2 = rng.normal(size=nx), rng.normal(size=len(rows))
    expected = np.linalg.solve(kkt, np.concatenate([-g2, r2, np.zeros(len(bounds))]))
    close(*step.solve(factors, g2, r2), expected)
