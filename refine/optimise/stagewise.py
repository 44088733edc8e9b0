"""The refinement NLP posed stage by stage, for fatrop (CasADi's structure-exploiting OCP solver).

The refinement couples waypoints only through their neighbours (the joint steps and second
differences of the smoothness cost), the shape optimal-control solvers exploit: fatrop factorises
its KKT system by a Riccati recursion over stages instead of a general sparse factorisation. It
needs the problem as an optimal control problem, which the refinement becomes once the joint step
is a control:

* stage k holds the state ``x_k = (q_k, d_{k-1})`` (``x_0 = q_0``) and the control
  ``u_k = d_k = q_{k+1} - q_k`` (none at the last stage), plus the repair slack ``σ_k`` as a
  control when the problem is elastic;
* consecutive stages are tied only by the gap-closing rows ``x_{k+1} = (q_k + d_k, d_k)``;
* every other row depends on one stage: the TCP position and orientation rows of waypoint k, a
  singularity bound or linearised clearance row at ``q_k + f·d_k`` (a point inside segment k);
* the joint-step rows are bounds on ``d_k``, the joint limits bounds on ``q_k``;
* the cost is a sum of stage terms: orientation and mid-range at ``q_k``, ``|d_k|²``, and the
  second difference ``|d_k - d_{k-1}|²``, so the Hessian of the Lagrangian is block diagonal.

It is the problem :func:`refine.optimise.problem.build_refinement` builds for IPOPT, in other
variables. :class:`StagewiseSolver` takes and returns that problem's variables, rows and
multipliers, so :func:`refine.optimise.solve.solve_refinement` runs either solver unchanged.
CasADi differentiates the stage-wise problem itself (the per-waypoint functions in its virtual
machine).

Measured against IPOPT (benchmarks/SPEED.md, ``refine bench run --contender refine-fatrop``):
fatrop has no warm start, so it needs 15-30 iterations where IPOPT from the seed needs a handful,
and CasADi's fatrop interface lays out its block sparsity in time growing with the square of the
stages. IPOPT stays the default; fatrop is offered up to :data:`MAX_FATROP_WAYPOINTS` waypoints.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from refine.errors import InputError
from refine.types import Array

Index = NDArray[np.int64]

MAX_FATROP_WAYPOINTS = 2000
"""The most waypoints a problem may have for fatrop: CasADi's fatrop interface takes time growing
with the square of the stages to set the problem up (1,600 waypoints: 12 s of the solver's
construction alone, against 0.1 s for IPOPT's whole refinement)."""

FATROP_DEFAULTS: dict[str, Any] = {
    "print_level": 0,
    "tol": 1e-9,
    "constr_viol_tol": 1e-10,
    "max_iter": 300,
    "mu_init": 1e-10,
    "bound_push": 1e-9,
}
"""fatrop's settings: the tolerances of :data:`refine.optimise.problem.IPOPT_DEFAULTS`; a tiny
initial barrier parameter and bound push, because the first solve starts from the IK seed, usually
next to the answer (fatrop has no warm-start option of its own). Iterations on the generated
IRB 4600 wave at 100 waypoints, same answer to 4e-8 rad: 54 with fatrop's ``mu_init`` of 0.1,
22 with 1e-6, 9 with 1e-8, 4 with 1e-10. Rounds after the first and the repair start further
from their answer and use 1e-6 (:data:`refine.optimise.rounds.WARM_START_OPTIONS`,
:data:`refine.optimise.rounds.ELASTIC_OPTIONS`): with 1e-10 there, the repair of ``wrist_flip``
took 436 iterations instead of 155."""

FATROP_BOUND_RELAX = 1e-8
"""How far fatrop lets an answer pass an inequality bound (measured: 9.9999e-9 on every bound that
binds, for bounds of magnitude up to 1; the relative form is assumed beyond). The stage-wise problem's
inequality bounds are drawn in by this much times ``max(1, |bound|)``, so that its answers keep the
refinement's own bounds as the verification checks them (joint steps to 1e-9 rad, for example); the
answer moves by as little."""

FATROP_PREFIX = "fatrop."
"""Options of :func:`refine.optimise.problem.build_refinement` meant for fatrop carry this prefix
(``"fatrop.max_iter"``); IPOPT's (``"ipopt.…"``) are ignored by fatrop."""


@dataclass(frozen=True)
class StageLayout:
    """Where the refinement's variables and rows sit in the stage-wise problem.

    Attributes:
        N, n: waypoints and joints.
        elastic: whether each waypoint has a repair slack σ_k.
        q_index: (N, n) position of ``q_k`` in the stage-wise vector.
        dp_index: (N, n) position of ``d_{k-1}`` (row 0 unused, -1).
        d_index: (N, n) position of ``d_k`` (last row unused, -1).
        sigma_index: (N,) position of σ_k (-1 when not elastic).
        nx, nu, ng: fatrop's stage sizes (length N).
    """

    N: int
    n: int
    elastic: bool
    q_index: Index
    dp_index: Index
    d_index: Index
    sigma_index: Index
    nx: tuple[int, ...]
    nu: tuple[int, ...]

    @property
    def size(self) -> int:
        """Length of the stage-wise vector."""
        return int(sum(self.nx) + sum(self.nu))

    def pack(self, x: Array) -> Array:
        """The stage-wise vector of the refinement's variables ``x`` (vec(Q), then σ when elastic)."""
        N, n = self.N, self.n
        x = np.asarray(x, dtype=float).ravel()
        q = x[: N * n].reshape(N, n)
        d = np.diff(q, axis=0)
        z = np.zeros(self.size)
        z[self.q_index] = q
        z[self.d_index[:-1]] = d
        z[self.dp_index[1:]] = d
        if self.elastic:
            z[self.sigma_index] = x[N * n :]
        return z

    def standard(self) -> Index:
        """Positions in the stage-wise vector of the refinement's variables, in their order."""
        parts = [self.q_index.ravel()]
        if self.elastic:
            parts.append(self.sigma_index)
        return np.concatenate(parts)


def stage_layout(N: int, n: int, elastic: bool) -> StageLayout:
    """The stage-wise layout of ``N`` waypoints of ``n`` joints (see the module docstring)."""
    s = 1 if elastic else 0
    nx = (n,) + (2 * n,) * (N - 1)
    nu = (n + s,) * (N - 1) + (s,)
    q_index = np.full((N, n), -1, dtype=np.int64)
    dp_index = np.full((N, n), -1, dtype=np.int64)
    d_index = np.full((N, n), -1, dtype=np.int64)
    sigma_index = np.full(N, -1, dtype=np.int64)
    at = 0
    for k in range(N):
        q_index[k] = at + np.arange(n)
        if k > 0:
            dp_index[k] = at + n + np.arange(n)
        at += nx[k]
        if k < N - 1:
            d_index[k] = at + np.arange(n)
        if elastic:
            sigma_index[k] = at + nu[k] - 1
        at += nu[k]
    return StageLayout(N, n, elastic, q_index, dp_index, d_index, sigma_index, nx, nu)


@dataclass(frozen=True)
class StageRows:
    """The rows one stage holds beyond its waypoint's four, as positions in the refinement's rows.

    Attributes:
        singular: (k, f, row) per singularity bound, ``row`` its index among the refinement's rows.
        linear: (k, f, gradient, row) per linearised row.
        steps: the joint-step rows as (row, k, j): bounds on ``d_{k,j}``.
    """

    singular: tuple[tuple[int, float, int], ...]
    linear: tuple[tuple[int, float, Array, int], ...]
    steps: tuple[tuple[int, int, int], ...]


class StagewiseSolver:
    """fatrop on the stage-wise refinement, called with the refinement's own variables and rows.

    Calling it (``x0``, ``p``, ``lbx``, ``ubx``, ``lbg``, ``ubg`` of the refinement; ``lam_g0`` and
    ``lam_x0`` are accepted and ignored, since fatrop starts its multipliers itself) returns ``x``,
    ``f``, ``g``, ``lam_x`` and ``lam_g`` in the refinement's order, as CasADi's IPOPT solver does;
    :meth:`stats` gives fatrop's statistics with IPOPT's keys (``return_status``, ``success``,
    ``iter_count``).
    """

    def __init__(
        self,
        waypoint: ca.Function,
        singularity: ca.Function,
        *,
        N: int,
        n: int,
        orientation_coef: float,
        velocity: float,
        acceleration: float,
        mid_range: float,
        h: float,
        mid: Array,
        half: Array,
        elastic_weight: float | None,
        rows: StageRows,
        n_rows: int,
        options: dict[str, Any],
    ) -> None:
        elastic = elastic_weight is not None
        lay = stage_layout(N, n, elastic)
        self.layout, self.rows, self.n_rows = lay, rows, n_rows
        z = ca.MX.sym("z", lay.size)
        Q = ca.reshape(z[lay.q_index.ravel().tolist()], n, N)
        D = ca.reshape(z[lay.d_index[:-1].ravel().tolist()], n, N - 1)
        DP = ca.reshape(z[lay.dp_index[1:].ravel().tolist()], n, N - 1)  # d_{k-1} held by stage k
        pp = ca.MX.sym("p", 12 * N)
        P_ref = ca.reshape(pp[: 3 * N], 3, N)
        R_demo = ca.reshape(pp[3 * N :], 9, N)
        G, cost = waypoint.map(N)(Q, P_ref, R_demo)
        if elastic:
            G = ca.vertcat(G[:3, :], G[3, :] + z[lay.sigma_index.tolist()].T)
        f = (
            orientation_coef * ca.sum2(cost)
            + velocity / h**2 / N * ca.sumsqr(D)
            + acceleration / h**4 / N * ca.sumsqr(D[:, 1:] - DP[:, : N - 2])
        )
        if mid_range > 0:
            scaled = (Q - ca.repmat(ca.DM(mid), 1, N)) / ca.repmat(ca.DM(half), 1, N)
            f += mid_range / N * ca.sumsqr(scaled)
        if elastic:
            f += elastic_weight * ca.sum1(z[lay.sigma_index.tolist()])

        # the rows of each stage: gap-closing rows (to the next stage), then the waypoint's four, then
        # its singularity bounds and linearised rows; g_rows[i] is the refinement's row of stage row i
        def point(k: int, frac: float) -> ca.MX:
            q = Q[:, k]
            return q if frac == 0.0 or k == N - 1 else q + frac * D[:, k]

        per_stage: list[list[tuple[ca.MX, int]]] = [[] for _ in range(N)]
        for k, frac, row in rows.singular:
            per_stage[k].append((singularity(point(k, frac)), row))
        for k, frac, gradient, row in rows.linear:
            per_stage[k].append((ca.dot(ca.DM(gradient), point(k, frac)), row))
        g_parts: list[ca.MX] = []
        g_rows: list[int] = []
        ng: list[int] = []
        for k in range(N):
            if k < N - 1:
                g_parts.append(ca.vertcat(Q[:, k + 1] - Q[:, k] - D[:, k], DP[:, k] - D[:, k]))
                g_rows.extend([-1] * (2 * n))
            g_parts.append(G[:, k])
            g_rows.extend(range(4 * k, 4 * k + 4))
            for expr, row in per_stage[k]:
                g_parts.append(expr)
                g_rows.append(row)
            ng.append(4 + len(per_stage[k]))
        self.g_rows = np.array(g_rows, dtype=np.int64)
        self.is_row = self.g_rows >= 0
        fatrop = {**FATROP_DEFAULTS, **options}
        self.solver = ca.nlpsol(
            "refine_fatrop",
            "fatrop",
            {"x": z, "p": pp, "f": f, "g": ca.vertcat(*g_parts)},
            {
                "structure_detection": "manual",
                "N": N - 1,
                "nx": list(lay.nx),
                "nu": list(lay.nu),
                "ng": ng,
                "fatrop": fatrop,
                "print_time": False,
            },
        )
        step_rows = np.array([r for r, _, _ in rows.steps], dtype=np.int64)
        self.step_rows = step_rows
        self.step_vars = np.array([lay.d_index[k, j] for _, k, j in rows.steps], dtype=np.int64)
        self.options = fatrop

    def __call__(self, *, x0, p, lbx, ubx, lbg, ubg, lam_g0=None, lam_x0=None) -> dict[str, Array]:
        """Solve from ``x0`` with the refinement's bounds; the answer in the refinement's variables.

        ``p`` holds the CAD points and demonstrated rotations, as the refinement's parameters; the
        multipliers' start is fatrop's own.
        """
        lay = self.layout
        std = lay.standard()
        lbz, ubz = np.full(lay.size, -np.inf), np.full(lay.size, np.inf)
        lbz[std], ubz[std] = np.asarray(lbx, float).ravel(), np.asarray(ubx, float).ravel()
        lbg, ubg = np.asarray(lbg, float).ravel(), np.asarray(ubg, float).ravel()
        lbz[self.step_vars], ubz[self.step_vars] = lbg[self.step_rows], ubg[self.step_rows]
        lbs, ubs = np.zeros(len(self.g_rows)), np.zeros(len(self.g_rows))
        lbs[self.is_row], ubs[self.is_row] = lbg[self.g_rows[self.is_row]], ubg[self.g_rows[self.is_row]]
        lbz, ubz = _inset(lbz, ubz)
        lbs, ubs = _inset(lbs, ubs)
        z0 = np.clip(lay.pack(x0), lbz, ubz)
        sol = self.solver(x0=z0, p=p, lbx=lbz, ubx=ubz, lbg=lbs, ubg=ubs)
        z = np.asarray(sol["x"]).ravel()
        lam_z = np.asarray(sol["lam_x"]).ravel()
        lam_s = np.asarray(sol["lam_g"]).ravel()
        g_s = np.asarray(sol["g"]).ravel()
        lam_g, g = np.zeros(self.n_rows), np.zeros(self.n_rows)
        lam_g[self.g_rows[self.is_row]] = lam_s[self.is_row]
        g[self.g_rows[self.is_row]] = g_s[self.is_row]
        lam_g[self.step_rows] = lam_z[self.step_vars]
        g[self.step_rows] = z[self.step_vars]
        return {"x": z[std], "f": sol["f"], "g": g, "lam_x": lam_z[std], "lam_g": lam_g}

    def stats(self) -> dict[str, Any]:
        """The last solve's statistics (fatrop's), with ``return_status`` in words and IPOPT's keys."""
        stats = dict(self.solver.stats())
        flag = stats.get("fatrop", {}).get("return_flag", stats.get("return_status"))
        success = bool(stats.get("success", False))
        stats["return_status"] = "solved" if success else f"not solved (return flag {flag})"
        stats["iter_count"] = int(stats.get("iter_count", 0))
        return stats


def check_size(N: int) -> None:
    """Refuse a path too long for fatrop (:data:`MAX_FATROP_WAYPOINTS`)."""
    if N > MAX_FATROP_WAYPOINTS:
        raise InputError(
            f"[optimise] solver = 'fatrop' takes at most {MAX_FATROP_WAYPOINTS} waypoints, the path has {N}: "
            "CasADi's fatrop interface needs time growing with the square of the waypoints to set up "
            "(1,600 waypoints: 12 s); use solver = 'ipopt'"
        )


def _inset(lower: Array, upper: Array) -> tuple[Array, Array]:
    """Inequality bounds drawn in by :data:`FATROP_BOUND_RELAX` (equalities and infinite bounds kept)."""
    lo_fin, hi_fin = np.isfinite(lower), np.isfinite(upper)
    lo_step = FATROP_BOUND_RELAX * np.maximum(1.0, np.abs(np.where(lo_fin, lower, 0.0)))
    hi_step = FATROP_BOUND_RELAX * np.maximum(1.0, np.abs(np.where(hi_fin, upper, 0.0)))
    room = (upper - lower) > 4.0 * np.maximum(lo_step, hi_step)  # true where a bound is infinite
    lo, hi = lower.copy(), upper.copy()
    lo[room & lo_fin] += lo_step[room & lo_fin]
    hi[room & hi_fin] -= hi_step[room & hi_fin]
    return lo, hi


def fatrop_options(options: dict[str, Any]) -> dict[str, Any]:
    """The fatrop settings among ``options`` (``"fatrop.NAME"`` keys, prefix removed)."""
    return {k[len(FATROP_PREFIX) :]: v for k, v in options.items() if k.startswith(FATROP_PREFIX)}


def stage_rows(
    steps: Array, N: int, n: int, singular_points: list[tuple[int, float]], linear: list, first_extra_row: int
) -> StageRows:
    """The refinement's rows beyond the waypoints' four, assigned to stages.

    ``steps``: the joint-step rows held (indices ``k·n + j``), in row order after the 4N waypoint rows;
    ``singular_points``: (k, f) in row order after the steps; ``linear``: the active set's
    :class:`~refine.optimise.problem.LinearRow` in row order after those; ``first_extra_row``:
    the index of the first row after the steps.
    """
    step_list = tuple((4 * N + i, int(s) // n, int(s) % n) for i, s in enumerate(np.asarray(steps).tolist()))
    row = first_extra_row
    singular = []
    for k, frac in singular_points:
        singular.append((int(k), float(frac), row))
        row += 1
    linear_rows = []
    for r in linear:
        linear_rows.append((int(r.k), float(r.f), np.asarray(r.gradient, dtype=float), row))
        row += 1
    return StageRows(tuple(singular), tuple(linear_rows), step_list)
