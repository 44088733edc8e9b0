"""Exact first and second derivatives of the refinement NLP, assembled from per-waypoint blocks.

CasADi can differentiate the whole problem itself, but at thousands of waypoints finding the sparsity
of the Hessian and colouring it costs seconds, every time the problem is built. The structure is
known in advance: every waypoint's rows depend on its own joints only, the singularity rows on the
joints of one or two neighbouring waypoints, the joint steps and the linearised rows are linear,
and the smoothness cost is a constant quadratic. So the Jacobian of the constraints, the gradient of
the cost and the Hessian of the Lagrangian are built here from small dense per-waypoint blocks (from
the compiled kernels of :func:`waypoint_kernels`, mapped over the waypoints) and placed into their
sparsity pattern by one constant sparse matrix each: ``nonzeros = M · blocks + c``.
"""

from __future__ import annotations

import hashlib
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import scipy.sparse as sps
from numpy.typing import NDArray

from refine.optimise import kinematics
from refine.optimise.compiled import BoundedCache, compiled, compiler
from refine.optimise.kinematics import fk_function, jacobian_function
from refine.types import Array

Index = NDArray[np.int64]

KERNELS_MAX = 64
"""Kernel sets kept in the process (one per robot, base placement and tool), least recently used
dropped first."""
_kernel_cache = BoundedCache(KERNELS_MAX)
"""(robot, kernels) by robot, placement, tool and compiler; shared by the process's threads, under
its lock (:class:`refine.optimise.compiled.BoundedCache`): a set is built once however many threads
ask for it."""


def waypoint_kernels(
    robot, base_in_world: Array, tcp_in_flange: Array, axisymmetric: bool, tool_in_world: Array | None = None
) -> dict[str, ca.Function]:
    """The per-waypoint functions of the refinement, compiled when a C compiler is present.

    * ``waypoint(q, p_ref, R_demo) -> (g, cost)``: ``g`` = [TCP position - p_ref (3), cos θ],
      ``cost`` = 1 - cos θ (θ between reached and demonstrated orientation, or tool axes when
      ``axisymmetric``); ``R_demo`` column-major (9,).
    * ``waypoint_d(q, p_ref, R_demo) -> (g, cost, dg/dq (4, n), dcost/dq (n,))``.
    * ``waypoint_h(q, p_ref, R_demo, lam (4,), w) -> ∇²_q (w·cost + lam·g)`` (n, n).
    * ``singularity(q) -> w``, the scaled manipulability ``sqrt(det(Js Jsᵀ))``;
      ``singularity_d(q) -> (w, ∇w)``; ``singularity_h(q, lam) -> lam·∇²w``.

    Plus ``jac_waypoint``, which CasADi picks up when the symbolic problem is differentiated for
    inspection. The waypoint functions are compiled; the singularity functions run in CasADi's
    virtual machine. With a stationary tool (``tool_in_world``) the pose is the tool's in the held
    part's frame (:func:`refine.optimise.kinematics.fk_function`).
    """
    key = (
        id(robot),
        np.asarray(base_in_world, float).tobytes(),
        np.asarray(tcp_in_flange, float).tobytes(),
        None if tool_in_world is None else np.asarray(tool_in_world, float).tobytes(),
        bool(axisymmetric),
        compiler(),
    )
    return _kernel_cache.get_or_make(
        key, lambda: _make_kernels(robot, base_in_world, tcp_in_flange, axisymmetric, tool_in_world)
    )[1]


def _make_kernels(
    robot, base_in_world: Array, tcp_in_flange: Array, axisymmetric: bool, tool_in_world: Array | None
) -> tuple:
    """(robot, kernels) for :func:`waypoint_kernels`'s cache: the robot is held so its id is not reused."""
    kernels = compiled(
        "refine_kernels",
        _kernel_key(robot, base_in_world, tcp_in_flange, axisymmetric, tool_in_world),
        lambda: _waypoint_kernels(robot, base_in_world, tcp_in_flange, axisymmetric, tool_in_world),
    )
    # the singularity measure's Hessian is a 6x6 determinant differentiated twice, 2 MB of C that
    # takes minutes to compile; its rows are few (where the outer loop adds them), so it runs in
    # CasADi's virtual machine, and is only built when a problem has such rows
    kernels = _Kernels(kernels, lambda: _singularity_kernels(robot, base_in_world, tcp_in_flange))
    return robot, kernels


def _kernel_key(
    robot, base_in_world: Array, tcp_in_flange: Array, axisymmetric: bool | str, tool_in_world: Array | None = None
) -> str:
    """Everything the kernels are made from: the code making them and the numbers of the chain."""
    model = robot.model
    frame = model.frames[robot.flange_id]
    parts = [
        Path(__file__).read_text(),
        Path(kinematics.__file__).read_text(),
        str(axisymmetric),
        repr(robot.spec.reach_m),
        repr(model.nq),
        repr(model.nv),
        np.asarray(base_in_world, float).tobytes().hex(),
        np.asarray(tcp_in_flange, float).tobytes().hex(),
        np.asarray(frame.placement.homogeneous).tobytes().hex(),
    ]
    if tool_in_world is not None:
        parts.append("stationary " + np.asarray(tool_in_world, float).tobytes().hex())
    for jid in list(model.supports[frame.parentJoint])[1:]:
        joint = model.joints[jid]
        parts += [
            joint.shortname(),
            repr((joint.idx_q, joint.idx_v)),
            np.asarray(model.jointPlacements[jid].homogeneous).tobytes().hex(),
        ]
        if joint.shortname() == "JointModelRevoluteUnaligned":
            parts.append(np.asarray(joint.extract().axis, float).tobytes().hex())
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _waypoint_kernels(
    robot, base_in_world: Array, tcp_in_flange: Array, axisymmetric: bool, tool_in_world: Array | None = None
) -> list[ca.Function]:
    n = robot.nq
    q = ca.SX.sym("q", n)
    p_ref = ca.SX.sym("p_ref", 3)
    r_demo = ca.SX.sym("R_demo", 9)
    lam = ca.SX.sym("lam", 4)
    weight = ca.SX.sym("w")
    p, R = fk_function(robot, base_in_world, tcp_in_flange, tool_in_world)(q)
    R_demo = ca.reshape(r_demo, 3, 3)
    if axisymmetric:
        cos_theta = ca.dot(R[:, 2], R_demo[:, 2])
    else:
        cos_theta = (ca.trace(ca.mtimes(R_demo.T, R)) - 1.0) / 2.0
    g = ca.vertcat(p - p_ref, cos_theta)
    cost = 1.0 - cos_theta
    waypoint = ca.Function("waypoint", [q, p_ref, r_demo], [g, cost], ["q", "p_ref", "R_demo"], ["g", "cost"])
    waypoint_d = ca.Function(
        "waypoint_d",
        [q, p_ref, r_demo],
        [g, cost, ca.densify(ca.jacobian(g, q)), ca.densify(ca.gradient(cost, q))],
    )
    hess, _ = ca.hessian(weight * cost + ca.dot(lam, g), q)
    waypoint_h = ca.Function("waypoint_h", [q, p_ref, r_demo, lam, weight], [ca.densify(hess)])
    return [waypoint, waypoint.jacobian(), waypoint_d, waypoint_h]


def _singularity_kernels(robot, base_in_world: Array, tcp_in_flange: Array) -> list[ca.Function]:
    q = ca.SX.sym("q", robot.nq)
    J = jacobian_function(robot, base_in_world, tcp_in_flange)(q)
    Js = ca.vertcat(J[:3, :] / robot.spec.reach_m, J[3:, :])
    w = ca.sqrt(ca.det(ca.mtimes(Js, Js.T)) + 1e-12)
    mu = ca.SX.sym("lam")
    singularity = ca.Function("singularity", [q], [w], ["q"], ["w"])
    singularity_d = ca.Function("singularity_d", [q], [w, ca.densify(ca.gradient(w, q))])
    hess_w, _ = ca.hessian(mu * w, q)
    singularity_h = ca.Function("singularity_h", [q, mu], [ca.densify(hess_w)])
    return [singularity, singularity_d, singularity_h]


class _Kernels(dict):
    """The compiled waypoint functions, with the singularity functions built on first use."""

    def __init__(self, functions: dict[str, ca.Function], more: Callable[[], list[ca.Function]]) -> None:
        super().__init__(functions)
        self._more = more
        self._lock = threading.Lock()  # two threads asking at once build them once

    def __missing__(self, name: str) -> ca.Function:
        with self._lock:
            if name not in self:
                self.update({f.name(): f for f in self._more()})
        if name not in self:
            raise KeyError(name)
        return self[name]


@dataclass
class _Entries:
    """Triplets (row, col) of a sparse matrix whose value is ``coef · blocks[src]`` (or ``coef`` for src < 0)."""

    rows: list[Index]
    cols: list[Index]
    src: list[Index]
    coef: list[Array]

    def add(self, rows, cols, src, coef) -> None:
        rows, cols, src, coef = np.broadcast_arrays(
            np.asarray(rows, dtype=np.int64),
            np.asarray(cols, dtype=np.int64),
            np.asarray(src, dtype=np.int64),
            np.asarray(coef, dtype=float),
        )
        self.rows.append(rows.ravel())
        self.cols.append(cols.ravel())
        self.src.append(src.ravel())
        self.coef.append(coef.ravel())

    def matrix(self, shape: tuple[int, int], blocks: ca.MX, n_blocks: int) -> ca.MX:
        """The sparse matrix: duplicates summed, pattern in CasADi's column-major order."""
        rows, cols = np.concatenate(self.rows), np.concatenate(self.cols)
        src, coef = np.concatenate(self.src), np.concatenate(self.coef)
        linear = cols * shape[0] + rows
        unique, nz = np.unique(linear, return_inverse=True)
        colind = np.concatenate([[0], np.cumsum(np.bincount(unique // shape[0], minlength=shape[1]))])
        sparsity = ca.Sparsity(shape[0], shape[1], colind.tolist(), (unique % shape[0]).tolist())
        var = src >= 0
        const = np.bincount(nz[~var], weights=coef[~var], minlength=len(unique))
        M = sps.csc_matrix((coef[var], (nz[var], src[var])), shape=(len(unique), n_blocks))
        M.sum_duplicates()
        M_dm = ca.DM(ca.Sparsity(M.shape[0], M.shape[1], M.indptr.tolist(), M.indices.tolist()), M.data)
        values = ca.densify(ca.mtimes(M_dm, blocks) + ca.DM(const)) if n_blocks else ca.MX(ca.DM(const))
        return ca.sparsity_cast(values, sparsity)


def _entries() -> _Entries:
    return _Entries([], [], [], [])


def difference_matrices(N: int) -> tuple[ca.DM, ca.DM]:
    """First (N-1, N) and second (N-2, N) difference matrices along the waypoints."""
    eye1, eye2 = ca.DM.eye(N - 1), ca.DM.eye(N - 2)
    D1 = ca.horzcat(ca.DM(N - 1, 1), eye1) - ca.horzcat(eye1, ca.DM(N - 1, 1))
    D2 = ca.horzcat(eye2, ca.DM(N - 2, 2)) - 2 * ca.horzcat(ca.DM(N - 2, 1), eye2, ca.DM(N - 2, 1))
    D2 += ca.horzcat(ca.DM(N - 2, 2), eye2)
    return D1, D2


def smoothness_matrix(
    n: int, N: int, h: float, velocity: float, acceleration: float, mid_range: float, half: Array
) -> ca.DM:
    """The constant Hessian K (nN, nN) of the smoothness and mid-range cost (before dividing by N).

    The cost is ``½ qᵀ K q + bᵀ q + c`` with q = vec(Q) (waypoint by waypoint): the squared joint
    steps per metre of path, the squared second differences per metre², and the squared distance
    from mid-range relative to the half range.
    """
    D1, D2 = difference_matrices(N)
    eye = ca.DM.eye(n)
    K = 2 * velocity / h**2 * ca.kron(ca.mtimes(D1.T, D1), eye)
    if N > 2:
        K += 2 * acceleration / h**4 * ca.kron(ca.mtimes(D2.T, D2), eye)
    if mid_range > 0:
        K += 2 * mid_range * ca.kron(ca.DM.eye(N), ca.diag(ca.DM(1.0 / half**2)))
    return K


def derivative_functions(
    kernels: dict[str, ca.Function],
    *,
    N: int,
    n: int,
    x: ca.MX,
    p: ca.MX,
    f: ca.MX,
    g: ca.MX,
    orientation_coef: float,
    K: ca.DM,
    b: Array,
    elastic_weight: float | None,
    singular_points: list[tuple[int, float]],
    linear_rows: list[tuple[int, float, Array]],
    singularity_hessian: bool = False,
    step_rows: Index | None = None,
    path_values: tuple[ca.MX, ca.MX] | None = None,
) -> dict[str, ca.Function]:
    """``grad_f``, ``jac_g`` and ``hess_lag`` of the refinement NLP, in CasADi's nlpsol signatures.

    Without slack variables also ``newton``, the same derivatives a point at a time for the Newton
    correction (:class:`NewtonFunctions`, not an nlpsol option).

    Args:
        kernels: from :func:`waypoint_kernels`.
        N: waypoints.
        n: joints.
        x: the NLP's variables [vec(Q), σ].
        p: the NLP's parameters [vec(P_ref), vec(R_demo)].
        f: the NLP's objective (its value is returned with the gradient).
        g: the NLP's constraints (their values are returned with the Jacobian).
        orientation_coef: the cost's factor on Σ (1 - cos θ_k).
        K: the constant Hessian of the quadratic part of the cost ½ qᵀKq + bᵀq, (nN, nN).
        b: its linear term, (nN,).
        elastic_weight: the cost per unit of slack σ_k, None without slack variables.
        singular_points: (k, f) of every singularity row, in row order.
        linear_rows: (k, f, gradient) of every linear row, in row order.
        singularity_hessian: include the singularity rows' second derivatives in the Hessian of
            the Lagrangian. Off by default: evaluated in CasADi's virtual machine they cost about
            0.24 ms per row and iteration, ten times the rest of an iteration at a hundred rows,
            while leaving them out (an inexact Newton step; the Jacobian stays exact, so the
            answer meets the same KKT conditions) costs about 1.4 times the iterations.
        step_rows: the joint-step rows the problem holds, as indices ``k·n + j`` in row order;
            None for all ``n·(N-1)``.
        path_values: the outputs ``(G (4, N), cost (1, N))`` of the mapped ``waypoint`` kernel that
            ``f`` and ``g`` are built from. Given, ``grad_f`` and ``jac_g`` return ``f`` and ``g``
            computed from the same outputs of ``waypoint_d``, which they evaluate anyway for the
            derivatives, instead of evaluating the waypoint kernel a second time (the two compiled
            kernels compute these outputs by the same operations: the same values, bit for bit).
    """
    nq = N * n
    ns = N if elastic_weight is not None else 0
    ng = g.shape[0]
    Q = ca.reshape(x[:nq], n, N)
    P_ref = ca.reshape(p[: 3 * N], 3, N)
    R_demo = ca.reshape(p[3 * N :], 9, N)
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", ng)
    S = len(singular_points)
    ks = np.array([k for k, _ in singular_points], dtype=np.int64)
    fs = np.array([fr for _, fr in singular_points], dtype=float)
    Qs = None
    if S:
        kb = np.minimum(ks + 1, N - 1)
        Qs = Q[:, ks.tolist()] + (Q[:, kb.tolist()] - Q[:, ks.tolist()]) * ca.repmat(ca.DM(fs).T, n, 1)

    # ---- gradient of the cost
    G, cost, Jg, grad_cost = kernels["waypoint_d"].map(N)(Q, P_ref, R_demo)
    f_d, g_d = (f, g) if path_values is None else ca.graph_substitute([f, g], list(path_values), [G, cost])
    grad = orientation_coef * ca.vec(grad_cost) + ca.mtimes(K, x[:nq]) + ca.DM(b)
    if ns:
        grad = ca.vertcat(grad, ca.DM.ones(ns) * elastic_weight)
    grad_f = ca.Function("grad_f", [x, p], [f_d, grad], ["x", "p"], ["f", "grad_f_x"])

    # ---- Jacobian of the constraints: rows are 4 per waypoint, n per segment, singularity, linear.
    # The per-waypoint blocks side by side, in CasADi's column-major order, are the nonzeros of the
    # block-diagonal matrix in its own order, so they are placed without a permutation.
    D1, _ = difference_matrices(N)
    steps = ca.kron(D1, ca.DM.eye(n))
    if step_rows is not None and len(step_rows) < n * (N - 1):
        steps = steps[np.asarray(step_rows).tolist(), :] if len(step_rows) else ca.DM(0, nq)
    blocks = [ca.sparsity_cast(ca.vec(Jg), ca.kron(ca.DM.eye(N), ca.DM.ones(4, n)).sparsity()), steps]
    if S:
        _, grad_w = kernels["singularity_d"].map(S)(Qs)
        rows = _entries()
        s, j = np.meshgrid(np.arange(S), np.arange(n), indexing="ij")
        rows.add(s, ks[s] * n + j, s * n + j, (1 - fs)[s])
        inner = fs[s] > 0
        rows.add(s[inner], ((ks[s] + 1) * n + j)[inner], (s * n + j)[inner], fs[s][inner])
        blocks.append(rows.matrix((S, nq), ca.vec(grad_w), n * S))
    if linear_rows:
        rows = _entries()
        for r, (kr, fr, gradient) in enumerate(linear_rows):
            rows.add(np.full(n, r), kr * n + np.arange(n), -1, (1 - fr) * gradient)
            if fr > 0:
                rows.add(np.full(n, r), (kr + 1) * n + np.arange(n), -1, fr * gradient)
        blocks.append(rows.matrix((len(linear_rows), nq), ca.MX(0, 1), 0))
    jac = ca.vertcat(*blocks)
    if ns:  # cos θ_k + σ_k: a one in row 4k+3 of slack column k
        slack = ca.kron(ca.DM.eye(N), ca.DM([0.0, 0.0, 0.0, 1.0]))
        jac = ca.horzcat(jac, ca.vertcat(slack, ca.DM(ng - 4 * N, N)))
    jac_g = ca.Function("jac_g", [x, p], [g_d, jac], ["x", "p"], ["g", "jac_g_x"])

    # ---- Hessian of the Lagrangian, upper triangle
    lam4 = ca.reshape(lam_g[: 4 * N], 4, N)
    Hwp = kernels["waypoint_h"].map(N)(Q, P_ref, R_demo, lam4, lam_f * orientation_coef)
    diagonal = ca.kron(ca.DM.eye(N), ca.DM.ones(n, n)).sparsity()
    hess = ca.triu(ca.sparsity_cast(ca.vec(Hwp), diagonal)) + lam_f * ca.triu(K)
    if S and singularity_hessian:
        first = 4 * N + steps.shape[0]
        Hs = kernels["singularity_h"].map(S)(Qs, lam_g[first : first + S].T)
        terms = _entries()
        iu, ju = np.triu_indices(n)
        s = np.arange(S)[:, None]
        terms.add(ks[s] * n + iu, ks[s] * n + ju, (s * n + ju) * n + iu, (1 - fs[s]) ** 2)
        inner = np.flatnonzero(fs > 0)[:, None]
        if inner.size:
            ia, ja = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
            terms.add(
                ks[inner] * n + ia,
                (ks[inner] + 1) * n + ja,
                (inner * n + ja) * n + ia,
                fs[inner] * (1 - fs[inner]),
            )
            terms.add(
                (ks[inner] + 1) * n + iu, (ks[inner] + 1) * n + ju, (inner * n + ju) * n + iu, fs[inner] ** 2
            )
        hess += terms.matrix((nq, nq), ca.vec(Hs), n * n * S)
    if ns:
        hess = ca.diagcat(hess, ca.DM(ns, ns))
    hess_lag = ca.Function(
        "hess_lag", [x, p, lam_f, lam_g], [hess], ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"]
    )
    functions: dict = {"grad_f": grad_f, "jac_g": jac_g, "hess_lag": hess_lag}
    if not ns:
        # the path rows from the same kernel call as their Jacobian; the other rows are g's own
        # (a slice of the concatenation, which CasADi evaluates without the path rows)
        rows_g = ca.vertcat(ca.vec(G), g[4 * N :])
        functions["newton"] = NewtonFunctions(
            [x, p, lam_g], grad, rows_g, jac, ca.substitute(hess, lam_f, ca.MX(1.0))
        )
    return functions


class NewtonFunctions:
    """The derivatives a Newton step of the KKT system needs, each set from one evaluation.

    ``first(x, p) -> (∇f, g, J)`` and ``start(x, p, lam_g) -> (∇f, g, J, H)``, H the upper triangle
    of the Hessian of the Lagrangian with ``lam_f = 1``: the values of ``grad_f``, ``jac_g`` and
    ``hess_lag`` at the same point (the path rows ``g[:4N]`` from the kernel that also gives their
    Jacobian: the same expression as the problem's own path rows, to rounding), with the
    per-waypoint kernel mapped once where ``grad_f`` and ``jac_g`` each map it and evaluate the
    objective or the rows once more. Built on first use (a cold solve never asks for them).
    """

    def __init__(self, inputs: list[ca.MX], grad: ca.MX, g: ca.MX, jac: ca.MX, hess: ca.MX) -> None:
        self._made: dict[str, ca.Function] = {}
        self._parts = inputs, grad, g, jac, hess
        self._lock = threading.Lock()

    def _function(self, name: str) -> ca.Function:
        with self._lock:
            if name not in self._made:
                (x, p, lam_g), grad, g, jac, hess = self._parts
                outs = [grad, g, jac] + ([hess] if name == "start" else [])
                ins = [x, p] + ([lam_g] if name == "start" else [])
                self._made[name] = ca.Function(f"newton_{name}", ins, outs)
            return self._made[name]

    @property
    def first(self) -> ca.Function:
        """``(x, p) -> (grad_f_x, g, jac_g_x)``."""
        return self._function("first")

    @property
    def start(self) -> ca.Function:
        """``(x, p, lam_g) -> (grad_f_x, g, jac_g_x, hess_gamma_x_x)`` with ``lam_f = 1``."""
        return self._function("start")


def orientation_factor(weight: float, N: int) -> float:
    """The cost's factor on Σ (1 - cos θ_k): ``2(1 - cos θ)`` in squared degrees, averaged."""
    return weight * 2.0 * (180.0 / math.pi) ** 2 / N
