"""fatrop (CasADi's structure-exploiting OCP solver) against IPOPT on the refinement, same NLP, same seed.

fatrop needs the problem as an optimal control problem: stage k holds the state x_k and the control
u_k, consecutive stages are tied only by gap-closing rows ``x_{k+1} - F(x_k, u_k) = 0``, every other
row and every cost term depends on one stage, and the Hessian of the Lagrangian is block diagonal
by stage. The refinement has that shape once the joint step is a control: x_k = (q_k, d_{k-1}),
u_k = d_k = q_{k+1} - q_k, so that the squared second difference d_k - d_{k-1} is a cost of stage
k; the TCP position and orientation rows of waypoint k are the stage's path rows, the joint limits
bound q_k and the joint-step tolerance bounds d_k. This is the same optimisation problem as
:func:`refine.optimise.problem.build_refinement` builds (same cost, same feasible joints) in other
variables, so both solvers must land on the same joints; the script prints how far apart they are.

Both solvers get the problem as one CasADi MX graph over the per-waypoint function mapped over
the stages (CasADi differentiates it), the IK seed of refine's own solve, and the tolerances of
refine's IPOPT settings (``tol`` 1e-9). The figures are process CPU times of the solve call (the
steadier figure on a shared machine), with the solver's iteration count, and refine's own solve
(its assembled derivatives and IPOPT) on the same path for reference.

    python3 benchmarks/fatrop.py [--sizes 100 400 1600] [--family irb4600]
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import casadi as ca
import numpy as np

from refine.bench.suites import generated_problem, load_suites
from refine.optimise.derivatives import orientation_factor
from refine.optimise.problem import IPOPT_DEFAULTS, Weights, joint_bounds, waypoint_function
from refine.optimise.solve import solve_refinement

FATROP_OPTIONS = {"print_level": 0, "tol": 1e-9, "mu_init": 1e-6, "bound_push": 1e-9, "max_iter": 300}
"""fatrop's settings: refine's tolerance; a small initial barrier parameter and bound push, as
IPOPT's warm start from the seed uses (fatrop has no warm-start option of its own)."""


def stagewise(problem, weights: Weights) -> tuple:
    """The refinement as a stage-wise OCP.

    Returns:
        the NLP dict, fatrop's structure options, lbx, ubx, lbg, ubg, joints (N, n) -> x, and
        x -> joints (N, n).
    """
    robot, fused, tol = problem.robot, problem.fused, problem.tolerances
    n, N = robot.nq, len(fused)
    wf = waypoint_function(robot, problem.base_in_world, problem.tcp_in_flange, problem.axisymmetric)
    h = float(np.mean(np.diff(fused.s)))
    coef = orientation_factor(weights.orientation, N)
    spec = robot.spec
    mid, half = 0.5 * (spec.lower + spec.upper), 0.5 * (spec.upper - spec.lower)
    lower, upper = joint_bounds(robot, tol)
    step = math.radians(tol.joint_step_deg)
    cos_a = math.cos(math.radians(tol.orientation_deg))
    # layout: [q_0, d_0 | (q_k, dp_k, d_k) for k = 1..N-2 | q_{N-1}, dp_{N-1}]
    x = ca.MX.sym("x", 2 * n + 3 * n * (N - 2) + 2 * n)
    Z = ca.reshape(x[2 * n : 2 * n + 3 * n * (N - 2)], 3 * n, N - 2)
    last = x[2 * n + 3 * n * (N - 2) :]
    Q = ca.horzcat(x[:n], Z[:n, :], last[:n])  # (n, N)
    DP = ca.horzcat(Z[n : 2 * n, :], last[n:])  # d_{k-1} held by stage k = 1..N-1
    D = ca.horzcat(x[n : 2 * n], Z[2 * n :, :])  # d_k of stage k = 0..N-2
    P_ref = ca.DM(fused.positions.T)
    R_demo = ca.DM(np.transpose(fused.rotations, (0, 2, 1)).reshape(N, 9).T)
    G, cost = wf.map(N)(Q, P_ref, R_demo)
    gap = ca.vertcat(Q[:, 1:] - Q[:, :-1] - D, DP - D)  # x_{k+1} - F(x_k, u_k), stage k = 0..N-2
    g = ca.vertcat(ca.vec(ca.vertcat(gap, G[:, : N - 1])), G[:, N - 1])
    f = (
        coef * ca.sum2(cost)
        + weights.velocity / h**2 / N * ca.sumsqr(D)
        + weights.acceleration / h**4 / N * ca.sumsqr(D[:, 1:] - DP[:, : N - 2])
        + weights.mid_range / N * ca.sumsqr((Q - ca.repmat(ca.DM(mid), 1, N)) / ca.repmat(ca.DM(half), 1, N))
    )
    free = np.full(n, np.inf)
    steps = np.full(n, step)
    lbx = np.concatenate([lower, -steps, np.tile(np.concatenate([lower, -free, -steps]), N - 2)])
    lbx = np.concatenate([lbx, lower, -free])
    ubx = np.concatenate([upper, steps, np.tile(np.concatenate([upper, free, steps]), N - 2), upper, free])
    stage_lb, stage_ub = np.array([0.0, 0.0, 0.0, cos_a]), np.array([0.0, 0.0, 0.0, 1.0 + 1e-9])
    lbg = np.concatenate([np.tile(np.concatenate([np.zeros(2 * n), stage_lb]), N - 1), stage_lb])
    ubg = np.concatenate([np.tile(np.concatenate([np.zeros(2 * n), stage_ub]), N - 1), stage_ub])
    structure = {
        "structure_detection": "manual",
        "N": N - 1,
        "nx": [n] + [2 * n] * (N - 1),
        "nu": [n] * (N - 1) + [0],
        "ng": [4] * N,
    }

    def pack(q: np.ndarray) -> np.ndarray:
        d = np.diff(q, axis=0)
        mids = [np.concatenate([q[k], d[k - 1], d[k]]) for k in range(1, N - 1)]
        return np.concatenate([q[0], d[0], *mids, q[-1], d[-1]])

    def joints(xv: np.ndarray) -> np.ndarray:
        xv = np.asarray(xv).ravel()
        Zv = xv[2 * n : 2 * n + 3 * n * (N - 2)].reshape(N - 2, 3 * n)
        return np.vstack([xv[:n], Zv[:, :n], xv[2 * n + 3 * n * (N - 2) :][:n]])

    return {"x": x, "f": f, "g": g}, structure, lbx, ubx, lbg, ubg, pack, joints


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 400, 1600])
    parser.add_argument("--family", default="irb4600", help="a [generated.NAME] of benchmarks/suites.toml")
    args = parser.parse_args()
    data = load_suites()
    print(
        f"{'N':>6s} {'solver':24s} {'iter':>5s} {'solve CPU s':>12s} {'build CPU s':>12s} "
        "status; max |q - q_refine| [rad]"
    )
    for N in args.sizes:
        problem = generated_problem("fatrop", args.family, data["generated"][args.family], N)
        weights = problem.weights or Weights()
        ref = problem.refinement()
        c0 = time.process_time()
        answer = solve_refinement(ref, home=problem.home)
        q_seed = answer.q_seed
        whole = time.process_time() - c0
        print(
            f"{N:6d} {'refine (IPOPT, assembled)':24s} {answer.iterations:5d} {'':>12s} {'':>12s} "
            f"{answer.status} (whole refinement {whole:.3f} s CPU)"
        )
        nlp, structure, lbx, ubx, lbg, ubg, pack, joints = stagewise(problem, weights)
        ipopt_options = dict(IPOPT_DEFAULTS)
        for name, plugin, options in (
            ("fatrop, stage-wise", "fatrop", {**structure, "fatrop": FATROP_OPTIONS, "print_time": False}),
            ("IPOPT, stage-wise", "ipopt", ipopt_options),
        ):
            c0 = time.process_time()
            try:
                solver = ca.nlpsol("s", plugin, nlp, options)
            except RuntimeError as e:
                print(f"{N:6d} {name:24s} could not be built: {str(e).splitlines()[-1]}")
                continue
            build = time.process_time() - c0
            c0 = time.process_time()
            try:
                sol = solver(x0=pack(q_seed), lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
            except RuntimeError as e:
                print(f"{N:6d} {name:24s} failed: {str(e).splitlines()[-1]}")
                continue
            cpu = time.process_time() - c0
            stats = solver.stats()
            gap = float(np.abs(joints(sol["x"]) - answer.q).max())
            print(
                f"{N:6d} {name:24s} {int(stats.get('iter_count', -1)):5d} {cpu:12.3f} {build:12.3f} "
                f"{stats.get('return_status')}; {gap:.1e}"
            )
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
