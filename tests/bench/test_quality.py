"""The shared quality evaluation (objective, KKT residuals), the provenance columns and the report's
figures (shifted geometric mean, performance ratios, growth), each against a figure made by hand."""

from __future__ import annotations

import ast
import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from scipy import sparse

from refine.bench import contenders as contenders_module
from refine.bench.contenders import verify
from refine.bench.figures import growth, performance_ratios, profile_curve, shifted_geometric_mean
from refine.bench.provenance import blas_threads, fixed_threads, git_commit, solver_versions
from refine.bench.quality import _dual_residual, evaluate
from refine.bench.suites import generated_problem
from refine.optimise.verify import check_path
from refine.robot.kinematics import TcpKinematics


@pytest.fixture(scope="module")
def wave(wave_spec):
    """A 20-waypoint, 0.3 m sine wave in front of the IRB 4600 (a generated family of the suites)."""
    return generated_problem("tiny", "wave", wave_spec, 20)


def test_dual_residual_of_a_one_variable_problem_by_hand():
    """min (x - 2)² with the row g = x: at x = 1, ∇f = -2, so stationarity needs λ = 2 on the row."""
    grad = np.array([-2.0])
    jac = sparse.csc_matrix(np.array([[1.0]]))
    x, free = np.array([1.0]), (np.array([-np.inf]), np.array([np.inf]))
    # g <= 1 active: an upper bound takes λ >= 0, λ = 2 cancels the gradient
    assert _dual_residual(grad, jac, x, np.array([-np.inf]), np.array([1.0]), x, *free) < 1e-12
    # with the gradient the other way (f falls as x falls) the upper bound cannot hold it: residual 2
    assert _dual_residual(-grad, jac, x, np.array([-np.inf]), np.array([1.0]), x, *free) == pytest.approx(2.0)
    # g >= 1 active instead: a lower bound takes λ <= 0, the best is λ = 0 and the residual |∇f| = 2
    assert _dual_residual(grad, jac, x, np.array([1.0]), np.array([np.inf]), x, *free) == pytest.approx(2.0)
    # the row 0.5 from its bound carries nothing: the residual is |∇f|
    assert _dual_residual(grad, jac, x, np.array([-np.inf]), np.array([1.5]), x, *free) == pytest.approx(2.0)
    # an equality row takes either sign
    assert _dual_residual(-grad, jac, x, np.array([1.0]), np.array([1.0]), x, *free) < 1e-12
    # a variable bound x <= 1 does the same as the row
    none = (np.array([-np.inf]), np.array([np.inf]))
    assert _dual_residual(grad, jac, x, *none, x, np.array([-np.inf]), np.array([1.0])) < 1e-12


def test_the_objective_of_constant_joints_is_the_orientation_term_alone(wave):
    """Joints that do not move have no velocity or acceleration cost: the objective is the mean of
    2(1 - cos θ)·(180/π)² over the waypoints (Weights' definition), θ from the verification."""
    q = np.tile(contenders_module.greedy_ik(wave).q[0], (wave.n_waypoints, 1))
    kin = TcpKinematics(wave.robot, wave.base_in_world, wave.tcp_in_flange, wave.tool_in_world)
    theta = np.radians(
        check_path(kin, q, wave.fused, wave.tolerances, wave.axisymmetric).orientation_deviation_deg
    )
    assert wave.weights.mid_range == 0.0
    by_hand = wave.weights.orientation * np.mean(2.0 * (1.0 - np.cos(theta))) * (180.0 / np.pi) ** 2
    assert evaluate(wave, q).objective == pytest.approx(by_hand, rel=1e-9)


def test_residuals_tell_the_refined_optimum_from_a_feasible_ik_chain(wave):
    refined = contenders_module.refine_assembled(wave)
    chained = contenders_module.greedy_ik(wave)
    at_optimum, at_chain = evaluate(wave, refined.q), evaluate(wave, chained.q)
    # IPOPT's answer to this very NLP (tol 1e-9): stationary and feasible
    assert at_optimum.primal_residual < 1e-8 and at_optimum.dual_residual < 1e-6
    # the chain keeps the demonstrated orientation, so only the TCP position rows (metres) are off:
    # the largest component of an error vector lies between its length / sqrt(3) and its length
    error = verify(wave, chained.q).max_position_error_m
    assert error / math.sqrt(3) - 1e-15 <= at_chain.primal_residual <= error + 1e-15
    # and it is no optimum: the refinement lowers the objective from it
    assert at_chain.dual_residual > 1e-4 and at_optimum.objective < at_chain.objective
    # no joints, or joints of the wrong shape: no figures
    assert math.isnan(evaluate(wave, None).objective) and math.isnan(
        evaluate(wave, chained.q[:5]).dual_residual
    )


def test_provenance_names_the_commit_the_solvers_and_the_threads():
    commit = git_commit()
    assert commit == "" or len(commit.split("-")[0]) == 40
    versions = solver_versions()
    assert versions.startswith("casadi ") and "ipopt 3." in versions and "mumps 5." in versions
    before = blas_threads()
    for count in (1, 2, 1):  # each setting holds inside, whatever came before
        with fixed_threads(count) as inside:
            assert inside == blas_threads()
            counts = [part.split()[1] for part in inside.split("; ")]
            assert counts and set(counts) == {str(count)}
    assert blas_threads() == before


def test_shifted_geometric_mean_by_hand():
    # (1.1 * 10.1)^(1/2) - 0.1 with the default shift of 0.1 s
    assert shifted_geometric_mean([1.0, 10.0]) == pytest.approx(math.sqrt(1.1 * 10.1) - 0.1)
    assert shifted_geometric_mean([4.0, 4.0, 4.0], shift=1.0) == pytest.approx(4.0)
    assert math.isnan(shifted_geometric_mean([]))


def _r(problem, contender, cpu, success=True):
    return {"problem": problem, "contender": contender, "cpu_s": str(cpu), "success": str(success),
            "detected_infeasible": "False"}  # fmt: skip


def test_performance_ratios_and_profile_by_hand():
    rows = [
        _r("p1", "a", 1.0), _r("p1", "b", 2.0),
        _r("p2", "a", 3.0), _r("p2", "b", 1.5),
        _r("p3", "a", 5.0, success=False), _r("p3", "b", 4.0),
        _r("p4", "a", 1.0, success=False),  # b has no row on p4 (not posed), a failed: nobody solved it
    ]  # fmt: skip
    ratios = performance_ratios(rows)
    assert ratios["a"] == [1.0, 2.0, math.inf, math.inf]
    assert ratios["b"] == [2.0, 1.0, 1.0]  # p4 is left out of b's ratios
    curve = profile_curve(ratios["b"], np.array([1.0, 1.9, 2.0, 1e9]))
    assert curve.tolist() == pytest.approx([2 / 3, 2 / 3, 1.0, 1.0])


def test_a_kkt_profile_takes_its_ratios_against_the_best_row_within_it(tmp_path):
    """a is fastest but its answers are no optimum (dual residual 1e-2): within kkt-1e-4 the best on
    p1 is b, so b's ratio there is 1, not 2; a counts nowhere."""
    from refine.bench.figures import PROFILE_TESTS, plot_profile

    def r(problem, contender, cpu, dual):
        return {**_r(problem, contender, cpu), "primal_residual": "1e-9", "dual_residual": str(dual)}

    rows = [
        r("p1", "a", 1.0, 1e-2),
        r("p1", "b", 2.0, 1e-7),
        r("p2", "a", 1.0, 1e-2),
        r("p2", "b", 3.0, 1e-7),
    ]
    assert performance_ratios(rows, passes=PROFILE_TESTS["verified"]) == {"a": [1.0, 1.0], "b": [2.0, 3.0]}
    kkt = performance_ratios(rows, passes=PROFILE_TESTS["kkt-1e-4"])
    assert kkt == {"a": [math.inf, math.inf], "b": [1.0, 1.0]}
    # the plot holds one panel per profile
    png, svg = plot_profile(rows, "t", tmp_path / "profile")
    assert png.stat().st_size > 1000 and svg.read_text().count("profile kkt-1e-") == 2


def test_growth_of_a_power_law_with_a_kink():
    n = [100, 200, 400, 800]
    t = [1.0, 2.0, 4.0, 32.0]  # slopes 1, 1, then 3
    fit = growth(n, t)
    assert fit["local"] == pytest.approx([1.0, 1.0, 3.0])
    # least squares of log t on log n: x = 0, 1, 2, 3 (units of log 2), y = 0, 1, 2, 5
    assert fit["exponent"] == pytest.approx(1.6)
    assert fit["low"] < 1.6 < fit["high"]
    exact = growth([100, 1000, 10000], [0.5, 5.0, 50.0])
    assert exact["exponent"] == pytest.approx(1.0) and exact["high"] - exact["low"] == pytest.approx(
        0.0, abs=1e-9
    )


def test_a_blas_first_loaded_inside_the_limit_runs_at_the_limit():
    # a fresh interpreter that has not loaded SciPy's own OpenBLAS: after the block is entered, a run
    # (here, the child of a fork, as the bench isolates runs) imports scipy.linalg for the first time;
    # threadpoolctl itself reads every BLAS's thread count in the child
    script = textwrap.dedent(
        """
        import os, sys
        import numpy
        from threadpoolctl import threadpool_info
        from refine.bench.provenance import fixed_threads
        assert "scipy.linalg" not in sys.modules
        with fixed_threads(1):
            pid = os.fork()
            if pid == 0:
                import scipy.linalg
                counts = {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}
                print(sorted(counts.values()), flush=True)
                os._exit(0)
            os.waitpid(pid, 0)
        """
    )
    if (os.cpu_count() or 1) < 2:
        pytest.skip("one core: a BLAS starts at one thread anyway, so the limit shows nothing")
    env = dict(os.environ)
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.pop(name, None)  # as a user starts it: one BLAS thread per core by default
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    counts = ast.literal_eval(done.stdout.strip().splitlines()[-1])
    assert len(counts) >= 2 and set(counts) == {1}  # NumPy's and SciPy's OpenBLAS both at one thread
