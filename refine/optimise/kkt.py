"""The Newton step of the refinement's KKT system with an active set held: evaluation and linear algebra.

:class:`Evaluator` evaluates the problem's own derivatives (those of the ``grad_f``, ``jac_g`` and
``hess_lag`` it gives IPOPT, from one call per point:
:class:`refine.optimise.derivatives.NewtonFunctions`) into NumPy buffers, without CasADi
matrices. The step
``[[H, Aᵀ], [A, 0]] (dx, λ) = (-∇f, r)`` of the held rows ``A`` is solved in one of two ways:

* :class:`NullSpaceStep`, when every held row touches one waypoint (the position and cone rows,
  singularity bounds and clearance rows at a waypoint, joint limits): per waypoint a QR
  factorisation of its held rows' Jacobian ``A_kᵀ = [Y_k Z_k] R_k`` (Householder reflections, each
  applied to every waypoint at once: :func:`householder_qr`), the particular step
  ``Y_k R_k⁻ᵀ r_k``, and the reduced Hessian ``ZᵀHZ``, banded because the Hessian couples a
  waypoint to the next two only, solved by a banded Cholesky factorisation (LAPACK's
  ``dpbtrf``/``dpbtrs``). A reduced Hessian that is not positive definite (no strict minimum with
  this active set) is refused;
* :func:`solve_banded_kkt` otherwise (a held row of a segment: a joint step, a point inside a
  segment): the whole KKT matrix, variables and rows interleaved waypoint by waypoint, by banded LU.
"""

from __future__ import annotations

import threading

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from refine.optimise.problem import RefinementNLP
from refine.types import Array

MAX_BANDWIDTH = 400
"""A KKT matrix wider than this (a row coupling distant waypoints) is not banded: refused."""


HESSIAN_REACH = 2
"""The Hessian couples waypoint k to k ± 2 at most (the second differences of the smoothness)."""


class NotLocal(ValueError):
    """A held row or a Hessian entry couples waypoints further apart than the null-space step allows."""


def _bind(function, args: list[Array]) -> tuple[object, object, list[Array]]:  # noqa: ANN001 - casadi.Function
    """``function`` evaluated from ``args`` into new arrays of its outputs' nonzeros, by its buffer."""
    buf, trigger = function.buffer()
    for i, a in enumerate(args):
        buf.set_arg(i, memoryview(a))
    outs = [np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
    for i, o in enumerate(outs):
        buf.set_res(i, memoryview(o))
    return buf, trigger, outs


_PATTERNS: dict[tuple[int, int], tuple[object, tuple[Array, Array]]] = {}
"""The nonzero patterns of the last functions read, by their id (the function is kept with them)."""


def _pattern(function, i: int) -> tuple[Array, Array]:  # noqa: ANN001 - casadi.Function
    """Row and column of every nonzero of output ``i`` of ``function``."""
    key = (id(function), i)
    kept = _PATTERNS.get(key)
    if kept is not None and kept[0] is function:
        return kept[1]
    colind, row = function.sparsity_out(i).get_ccs()
    colind = np.asarray(colind, dtype=np.int64)
    pattern = np.asarray(row, dtype=np.int64), np.repeat(np.arange(len(colind) - 1), np.diff(colind))
    if len(_PATTERNS) >= 16:
        _PATTERNS.clear()
    _PATTERNS[key] = (function, pattern)
    return pattern


class Evaluator:
    """The derivatives of ``problem`` at a point, in NumPy arrays (see the module docstring).

    Attributes:
        jac_row, jac_col: the constraint Jacobian's nonzero pattern (row, column per nonzero).
        hess_row, hess_col: the upper triangle of the Hessian of the Lagrangian, likewise.
    """

    def __init__(self, problem: RefinementNLP) -> None:
        d = problem.derivatives
        self.nx, self.ng = len(problem.lbx), len(problem.lbg)
        self.x = np.zeros(self.nx)
        self.p = np.array(problem.params, dtype=float)
        self.lam = np.zeros(self.ng)
        self.one = np.ones(1)
        self._hess = _bind(d["hess_lag"], [self.x, self.p, self.one, self.lam])
        newton = d.get("newton")
        if newton is not None:  # one evaluation for the gradient, the rows and the Jacobian
            self._first = _bind(newton.first, [self.x, self.p])
            self._start = _bind(newton.start, [self.x, self.p, self.lam])
        else:
            self._grad = _bind(d["grad_f"], [self.x, self.p])
            self._jac = _bind(d["jac_g"], [self.x, self.p])
            self._first = self._start = None
        self.grad_rows = _pattern(d["grad_f"], 1)[0]
        self.g_rows = _pattern(d["jac_g"], 0)[0]
        self.jac_row, self.jac_col = _pattern(d["jac_g"], 1)
        if newton is not None:  # its gradient and Jacobian are grad_f's and jac_g's expressions
            self.g_rows = _pattern(newton.first, 1)[0]
        self.hess_row, self.hess_col = _pattern(d["hess_lag"], 0)
        self._hess_values: Array | None = None
        # Jᵀ in CSR form: the Jacobian's nonzeros are in column order (CasADi's compressed columns)
        self._jac_t = None
        if np.all(np.diff(self.jac_col) >= 0):
            indptr = np.concatenate([[0], np.cumsum(np.bincount(self.jac_col, minlength=self.nx))])
            self._jac_t = sp.csr_array(
                (np.zeros(len(self.jac_row)), self.jac_row, indptr), shape=(self.nx, self.ng)
            )

    def first_order(self, x: Array, lam_g: Array | None = None) -> tuple[Array, Array, Array]:
        """At ``x``: the cost gradient (nx,), the rows (ng,), the Jacobian's nonzeros (a view).

        With ``lam_g``, the Hessian of the Lagrangian at ``x`` with these multipliers is evaluated in
        the same call, for the next :meth:`hessian` of the same multipliers.
        """
        self.x[:] = x
        self._hess_values = None
        if self._first is None:
            self._grad[1]()
            self._jac[1]()
            grad_nz, g_nz, jac_nz = self._grad[2][1], self._jac[2][0], self._jac[2][1]
        elif lam_g is None:
            self._first[1]()
            grad_nz, g_nz, jac_nz = self._first[2]
        else:
            self.lam[:] = lam_g
            self._start[1]()
            grad_nz, g_nz, jac_nz, self._hess_values = self._start[2]
        grad, g = np.zeros(self.nx), np.zeros(self.ng)
        grad[self.grad_rows] = grad_nz
        g[self.g_rows] = g_nz
        return grad, g, jac_nz

    def hessian(self, lam_g: Array) -> Array:
        """The nonzeros of the Hessian of the Lagrangian's upper triangle at the last ``x`` (a view)."""
        if self._hess_values is not None and np.array_equal(lam_g, self.lam):
            return self._hess_values
        self.lam[:] = lam_g
        self._hess[1]()
        return self._hess[2][0]

    def jacobian_t_times(self, values: Array, lam: Array) -> Array:
        """``Jᵀ lam`` (nx,) for the Jacobian of nonzeros ``values``."""
        if self._jac_t is not None:
            self._jac_t.data = values
            return self._jac_t @ lam
        return np.bincount(self.jac_col, weights=values * lam[self.jac_row], minlength=self.nx)

    def jacobian(self, values: Array) -> sp.csr_matrix:
        """The Jacobian (ng, nx) from its nonzeros ``values``."""
        return sp.csr_matrix((values, (self.jac_row, self.jac_col)), shape=(self.ng, self.nx))

    def hessian_matrix(self, values: Array) -> sp.csc_matrix:
        """The whole symmetric Hessian (nx, nx) from its upper triangle's nonzeros ``values``."""
        upper = sp.csc_matrix((values, (self.hess_row, self.hess_col)), shape=(self.nx, self.nx))
        return (upper + sp.triu(upper, 1).T).tocsc()


_EVALUATORS = threading.local()
"""This thread's last :class:`Evaluator`, with the derivatives it evaluates (``last``)."""


def evaluator_for(problem: RefinementNLP) -> Evaluator:
    """An :class:`Evaluator` of ``problem``: this thread's last one where it evaluates the same derivatives.

    A re-solve keeps its problem's functions (:func:`refine.optimise.warm.reuse_final`), so the
    evaluator bound to their buffers serves again with the new parameters; evaluators hold no
    result between calls (:meth:`Evaluator.first_order` starts afresh), and each thread has its own.
    """
    kept = getattr(_EVALUATORS, "last", None)
    params = np.asarray(problem.params, dtype=float).ravel()
    if kept is not None and kept[0] is problem.derivatives:
        ev = kept[1]
        if (ev.nx, ev.ng, ev.p.size) == (len(problem.lbx), len(problem.lbg), params.size):
            ev.p.reshape(-1)[:] = params  # in place: the buffers read this memory
            return ev
    ev = Evaluator(problem)
    _EVALUATORS.last = (problem.derivatives, ev)
    return ev


_LAST_STEP: list = [None]
"""The last null-space step built, with what it was built for, ``(key, step)``: a re-solve of the
same problem holds the same rows again, and its index maps are kept. The step holds nothing of a
solve (its factors are the caller's), and the entry is replaced whole, so threads may share it."""


def null_space_step(ev: Evaluator, rows: Array, bounds: Array, N: int, n: int) -> NullSpaceStep:
    """:class:`NullSpaceStep` for these rows, the last one built where its patterns and rows are these."""
    key = (ev.jac_row, ev.jac_col, ev.hess_row, ev.hess_col, N, n)
    last = _LAST_STEP[0]
    if last is not None:
        kept, step = last
        if (
            all(a is b for a, b in zip(kept[:4], key[:4], strict=True))
            and kept[4:6] == key[4:]
            and np.array_equal(kept[6], rows)
            and np.array_equal(kept[7], bounds)
        ):
            return step
    step = NullSpaceStep(ev, rows, bounds, N, n)
    _LAST_STEP[0] = ((*key, rows.copy(), bounds.copy()), step)
    return step


class NullSpaceStep:
    """The Newton step by per-waypoint null spaces and a banded reduced Hessian (module docstring).

    Built once for an active set: ``rows`` (held constraint rows) and ``bounds`` (variables held at
    a bound), with the problem's sizes ``N`` waypoints of ``n`` joints and the evaluator's patterns.
    The per-waypoint blocks are kept with the waypoints on the last axis (``(…, N)``, contiguous),
    so that each contraction is one :func:`numpy.einsum` over all waypoints at once. The Hessian is
    kept as its blocks ``H_{k,k+d}`` for the reach ``d = 0..reach`` its pattern has (at most
    :data:`HESSIAN_REACH`), a neighbour block (``d > 0``) whose pattern is its diagonal (the
    smoothness terms, joint by joint) as that diagonal only.

    Raises:
        NotLocal: a held row touches two waypoints, or the Hessian reaches beyond
            :data:`HESSIAN_REACH` waypoints.
    """

    def __init__(self, ev: Evaluator, rows: Array, bounds: Array, N: int, n: int) -> None:
        self.N, self.n = N, n
        held = np.full(ev.ng, -1, dtype=np.int64)
        held[rows] = np.arange(len(rows))
        inside = held[ev.jac_row] >= 0
        k_of = ev.jac_col // n
        first = np.full(len(rows), N, dtype=np.int64)
        last = np.full(len(rows), -1, dtype=np.int64)
        np.minimum.at(first, held[ev.jac_row[inside]], k_of[inside])
        np.maximum.at(last, held[ev.jac_row[inside]], k_of[inside])
        if np.any(first != last):
            raise NotLocal("a held row touches two waypoints or none")
        k = np.concatenate([first, bounds // n])  # the waypoint of every held row, then bound
        order = np.argsort(k, kind="stable")
        count = np.bincount(k, minlength=N)
        start = np.concatenate([[0], np.cumsum(count)[:-1]])
        slot = np.empty(len(k), dtype=np.int64)
        slot[order] = np.arange(len(k)) - start[k[order]]
        self.k, self.slot, self.count = k, slot, count
        self.m_max, self.m_min = int(count.max()), int(count.min())
        if self.m_max > n:
            raise NotLocal(f"{self.m_max} rows held at one waypoint of {n} joints")
        m, self.nz = self.m_max, n - self.m_min
        R = len(rows)
        # where each held row's Jacobian nonzeros go in [Aᵀ | I] (n, m + n, N) (householder_qr's)
        self.src = np.flatnonzero(inside)
        h = held[ev.jac_row[self.src]]
        qr_shape = (n, m + n, N)
        self.dst = np.ravel_multi_index((ev.jac_col[self.src] - n * k[h], slot[h], k[h]), qr_shape)
        b = np.arange(R, R + len(bounds))
        self.bound_dst = np.ravel_multi_index((bounds - n * k[b], slot[b], k[b]), qr_shape)
        self.ymask = np.arange(m)[:, None] < count[None, :]  # (m, N): a held row in this slot
        self.pad = np.nonzero(~self.ymask)  # (slot, waypoint) of no row
        self.zpad = (self.m_min + np.arange(self.nz))[:, None] < count[None, :]  # (nz, N): padded columns
        # where each Hessian nonzero goes in the blocks H_{k,k+d}[a, c] (n, n, N) one after the other,
        # a diagonal one's diagonal only (n, N)
        ki, kj = ev.hess_row // n, ev.hess_col // n
        d = kj - ki
        if np.any((d < 0) | (d > HESSIAN_REACH)):
            raise NotLocal("the Hessian couples waypoints more than two apart")
        self.reach = int(d.max(initial=0))
        a, c = ev.hess_row - n * ki, ev.hess_col - n * kj
        self.diagonal = [e > 0 and bool(np.all(a[d == e] == c[d == e])) for e in range(self.reach + 1)]
        sizes = [n * N if diagonal else n * n * N for diagonal in self.diagonal]
        offset = np.concatenate([[0], np.cumsum(sizes)])
        self.h_offset = offset
        full = ~np.asarray(self.diagonal)[d]
        self.h_dst = offset[d] + np.where(full, (a * n + c) * N, a * N) + ki
        lower = (d == 0) & (a != c)
        self.h_mirror_src = np.flatnonzero(lower)
        self.h_mirror_dst = (c[lower] * n + a[lower]) * N + ki[lower]
        self.width = (self.reach + 1) * self.nz - 1  # the reduced Hessian's lower bandwidth

    def _hess_blocks(self, values: Array) -> list[Array]:
        """The blocks ``H_{k,k+d}`` (n, n, N - d) of the Hessian, the diagonal (n, N - d) of a diagonal one."""
        N, n = self.N, self.n
        blocks = np.zeros(self.h_offset[-1])
        blocks[self.h_dst] = values
        blocks[self.h_mirror_dst] = values[self.h_mirror_src]
        shapes = [(n, N) if diagonal else (n, n, N) for diagonal in self.diagonal]
        return [
            blocks[self.h_offset[d] : self.h_offset[d + 1]].reshape(shape)[..., : N - d]
            for d, shape in enumerate(shapes)
        ]

    def _hess_times(self, H: list[Array], v: Array) -> Array:
        """``H v`` for ``v`` (n, N), the waypoints on the last axis, with ``H`` from :meth:`_hess_blocks`."""
        N = self.N
        out = np.einsum("ijk,jk->ik", H[0], v)
        for d in range(1, self.reach + 1):
            if self.diagonal[d]:
                out[:, : N - d] += H[d] * v[:, d:]
                out[:, d:] += H[d] * v[:, : N - d]
            else:
                out[:, : N - d] += np.einsum("ijk,jk->ik", H[d], v[:, d:])
                out[:, d:] += np.einsum("jik,jk->ik", H[d], v[:, : N - d])
        return out

    def _reduced_band(self, Zt: Array, H: list[Array]) -> Array:
        """The reduced Hessian ``ZᵀHZ`` in LAPACK's lower band storage (width + 1, N·nz), Fortran order.

        Its blocks ``B_{k,k+d} = Z_kᵀ H_{k,k+d} Z_{k+d}`` (nz, nz, N - d); variable ``k·nz + a`` is
        column ``a`` of ``Z_k``, and entry (i, j), i >= j, of the matrix is band entry (i - j, j).
        """
        N, nz = self.N, self.nz
        band = np.zeros((N, nz, self.width + 1))  # [k, a, i - j]: the transpose of the Fortran array
        for d in range(self.reach + 1):
            if self.diagonal[d]:
                B = np.einsum("aik,bik->abk", Zt[:, :, : N - d] * H[d], Zt[:, :, d:])
            else:
                B = np.einsum("aik,ibk->abk", Zt[:, :, : N - d], np.einsum("ijk,bjk->ibk", H[d], Zt[:, :, d:]))
            for a in range(nz):  # entries (k + d, b), b from a on for d = 0: band rows d·nz + b - a
                b = a if d == 0 else 0
                band[: N - d, a, d * nz + b - a : (d + 1) * nz - a] = B[a, b:].T
        band[:, :, 0] += self.zpad.T  # the padded null-space columns: unit diagonal
        return band.reshape(N * nz, self.width + 1).T

    def step(
        self, grad: Array, jac_values: Array, hess_values: Array, residual: Array
    ) -> tuple[Array, Array, tuple]:
        """The step dx (nx,), the multipliers of the held rows, then bounds, for ``residual`` = r, and the factors.

        ``grad``: the cost gradient; ``jac_values``, ``hess_values``: the nonzeros of the Jacobian
        and of the Hessian of the Lagrangian's upper triangle (:class:`Evaluator`), factorised here;
        the factors for :meth:`solve` (kept by the caller: a step built once serves any thread).

        Raises:
            numpy.linalg.LinAlgError: the held rows at a waypoint are dependent, or the reduced
                Hessian is not positive definite.
        """
        N, n, m = self.N, self.n, self.m_max
        values = jac_values[self.src]
        M = np.zeros((n, m + n, N))
        flat = M.reshape(-1)
        flat[self.dst] = values
        flat[self.bound_dst] = 1.0
        scale = max(1.0, float(np.abs(values).max(initial=0.0)))
        M[np.arange(n), m + np.arange(n)] = 1.0
        _householder(M, m)  # [Aᵀ | I] -> [R; 0 | Qᵀ], block k in M[..., k]
        R, Qt = M[:m, :m], M[:, m:]
        if np.any(np.abs(R[np.arange(m), np.arange(m)])[self.ymask] <= 1e-12 * scale):
            raise np.linalg.LinAlgError("the held rows at a waypoint are dependent")
        R[self.pad[0], self.pad[0], self.pad[1]] = 1.0
        Zt = Qt[self.m_min :] if self.m_min == m else Qt[self.m_min :] * ~self.zpad[:, None, :]
        Zt = np.ascontiguousarray(Zt)  # (nz, n, N): row b of Z_kᵀ in Zt[b, :, k]
        H = self._hess_blocks(hess_values)
        factor = None  # every joint held at every waypoint (nz 0): no reduced Hessian, the rows fix the step
        if self.nz:
            factor, info = scipy.linalg.lapack.dpbtrf(self._reduced_band(Zt, H), lower=1, overwrite_ab=1)
            if info > 0:
                raise np.linalg.LinAlgError(
                    f"{info}-th leading minor of the reduced Hessian not positive definite"
                )
            if info < 0:
                raise ValueError(f"illegal value in {-info}-th argument of dpbtrf")
        # the least-norm step onto the held rows, Y R⁻ᵀ, as its transpose P = R⁻¹ Yᵀ (m, n, N):
        # row a of R P = Yᵀ, from the rows below it
        P = np.empty((m, n, N))
        for a in range(m - 1, -1, -1):
            P[a] = (Qt[a] - np.einsum("ck,cjk->jk", R[a, a + 1 :], P[a + 1 :])) / R[a, a]
        factors = (P, Zt, H, factor)
        return (*self.solve(factors, grad, residual), factors)

    def solve(self, factors: tuple, grad: Array, residual: Array) -> tuple[Array, Array]:
        """:meth:`step` with the ``factors`` a step returned: for ``grad`` (nx,) and ``residual``."""
        N, n, m = self.N, self.n, self.m_max
        P, Zt, H, factor = factors
        r = np.zeros((m, N))
        r[self.slot[: len(residual)], self.k[: len(residual)]] = residual  # the bounds': 0, met
        dx_y = np.einsum("ajk,ak->jk", P, r)
        g = grad.reshape(N, n).T
        dx = dx_y
        if factor is not None:
            w = g + self._hess_times(H, dx_y)
            rhs = -np.einsum("bik,ik->kb", Zt, w).reshape(-1, 1)  # variable k·nz + b
            p_z, info = scipy.linalg.lapack.dpbtrs(factor, rhs, lower=1, overwrite_b=1)
            if info != 0:
                raise ValueError(f"illegal value in {-info}-th argument of dpbtrs")
            dx = dx_y + np.einsum("bik,kb->ik", Zt, p_z.reshape(N, self.nz))
        w = g + self._hess_times(H, dx)
        lam = -np.einsum("ajk,jk->ak", P, w)
        return dx.T.reshape(-1), lam[self.slot, self.k]


def householder_qr(A: Array) -> tuple[Array, Array]:
    """The complete QR factorisation ``A_kᵀ = Q_k [R_k; 0]`` of every block of ``A`` (N, m, n), m <= n.

    Returns ``Qᵀ`` (N, n, n), orthogonal, and ``R`` (N, m, m), upper triangular (its diagonal of
    either sign): :func:`_householder` on the blocks.
    """
    N, m, n = A.shape
    M = np.zeros((n, m + n, N))  # [Aᵀ | I], block k in M[..., k]; the reflections turn it into [R; 0 | Qᵀ]
    M[:, :m] = np.transpose(A, (2, 1, 0))
    M[np.arange(n), m + np.arange(n)] = 1.0
    _householder(M, m)
    R = np.triu(np.transpose(M[:m, :m], (2, 0, 1)))
    return np.ascontiguousarray(np.transpose(M[:, m:], (2, 0, 1))), R


def _householder(M: Array, m: int) -> None:
    """Householder reflections of the first ``m`` columns of every block of ``M`` (n, m + n, N), in place.

    Block k is ``M[..., k]``, the blocks on the last axis (N long, contiguous); the reflections,
    each applied to all N blocks at once, turn ``[Aᵀ | I]`` into ``[R; 0 | Qᵀ]`` (below the diagonal
    of R: rounding errors, not zeros). For the few rows and joints of a waypoint about three times
    as fast as NumPy's batched LAPACK QR (618 blocks of 3 × 6: 0.11 against 0.36 ms). A column that is
    zero where its reflection would act (a padded row) is left as it is, with a zero on the diagonal
    of ``R``.
    """
    for j in range(m):
        x = M[j:, j]  # (n - j, N)
        norm = np.sqrt(np.einsum("iN,iN->N", x, x))
        alpha = np.where(x[0] >= 0.0, -norm, norm)  # the sign that avoids cancellation in v[0]
        v = x.copy()
        v[0] -= alpha
        vv = 2.0 * norm * (norm + np.abs(x[0]))  # |x - alpha e_1|²
        scale = np.divide(2.0, vv, out=np.zeros_like(vv), where=vv > 0.0)
        rest = M[j:, j:]
        rest -= v[:, None] * (np.einsum("iN,icN->cN", v, rest) * scale)[None]


def _band_order(nx: int, n: int, rows: sp.csr_matrix) -> Array:
    """The order of variables and rows that keeps the KKT matrix banded.

    Each waypoint's n variables, then the rows whose last variable is among them (a row of
    waypoint k, or of the segment that ends there).
    """
    coo = rows.tocoo()
    last = np.zeros(rows.shape[0], dtype=np.int64)
    np.maximum.at(last, coo.row, coo.col)
    stage = np.concatenate([np.arange(nx) // n, last // n])
    kind = np.concatenate([np.zeros(nx, dtype=np.int64), np.ones(rows.shape[0], dtype=np.int64)])
    return np.lexsort((np.arange(len(stage)), kind, stage))


def solve_banded_kkt(hess: sp.csc_matrix, rows: sp.csr_matrix, rhs: Array, n: int) -> Array:
    """The solution of ``[[H, Aᵀ], [A, 0]] z = rhs``, ``A`` = ``rows``, in band form.

    Raises:
        numpy.linalg.LinAlgError: the matrix is singular or not banded (a row coupling distant
            waypoints, bandwidth over :data:`MAX_BANDWIDTH`).
    """
    nx, m = hess.shape[0], rows.shape[0]
    kkt = sp.bmat([[hess, rows.T], [rows, None]], format="coo")
    order = _band_order(nx, n, rows)
    position = np.empty_like(order)
    position[order] = np.arange(len(order))
    i, j = position[kkt.row], position[kkt.col]
    lower, upper = int(max(0, (i - j).max())), int(max(0, (j - i).max()))
    if max(lower, upper) > MAX_BANDWIDTH:
        raise np.linalg.LinAlgError(f"KKT matrix not banded (bandwidth {max(lower, upper)})")
    band = np.zeros((lower + upper + 1, nx + m))
    np.add.at(band, (upper + i - j, j), kkt.data)
    z = scipy.linalg.solve_banded((lower, upper), band, rhs[order], check_finite=False)
    out = np.empty_like(z)
    out[order] = z
    return out
