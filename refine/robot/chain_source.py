"""The C source of the compiled batch kinematics (:mod:`refine.robot.compiled_chain`).

:class:`~refine.robot.chain.BatchChain`'s recursion for one row (:meth:`BatchChain.row_frame`,
:meth:`BatchChain.row_joint_placements`) on CasADi ``SX`` scalars gives five functions of a joint
row ``q``: ``<prefix>_fk`` (the flange's placement, 16 numbers row-major), ``_fkj`` (that and its
Jacobian, 6 × nv row-major), ``_joints`` (every joint's ``oMi``, universe first), ``_tcp`` and
``_tcpj`` (the TCP's world pose ``B · T · X`` and its Jacobian, with ``B = T_world_base`` and
``X = T_flange_TCP`` two more arguments: :func:`placed`), ``_stat`` and ``_statj`` (a stationary
tool's TCP ``W`` seen from the held part ``X``, ``(B · T · X)⁻¹ · W``, and its Jacobian:
:func:`stationary`). CasADi's code generator writes them; each
gets a loop over the rows in C, ``<name>_rows(q, fixed, out, n)``, which moves the row and output
pointers along with its work memory on the stack (so threads may call at once). A sixth,
hand-written, ``<prefix>_bodies_rows(q, base, joint, local, m, out, n)``, evaluates ``_joints``
per row and places ``m`` bodies ``base · oMi[joint[b]] · local[b]``. Two more, hand-written:
``<prefix>_ik_rows``, a damped least-squares IK step per row toward a TCP target (the pose error as
:func:`refine.robot.kinematics.solve_ik_batch` forms it, its norm and the step ``Jᵀ (J Jᵀ + λ² I)⁻¹ e``
by a 6 × 6 Cholesky factor), ``<prefix>_solve_rows``, that step iterated per row as
:func:`refine.robot.kinematics.solve_ik` or ``solve_ik_batch`` iterate it (the 0.3 rad cap, the
limits, a redundant arm's pull toward mid-range in the task's null space, the batch's stall rule;
a TCP on the flange or a stationary tool; the whole pose or, as ``axis_only``, the tool axis
alone), ``<prefix>_start_rows``, the controller line's IK starts (the joint-linear samples' TCP
poses, their errors toward the line's targets and the interpolated damped Newton step of
:func:`refine.optimise.line_start.newton_start`), and ``<prefix>_det6_rows``, the determinants of 6 × 6 matrices (an LU factorisation with
partial pivoting, as LAPACK's ``getrf``).
"""

from __future__ import annotations

from typing import Any

from refine.robot.chain import BatchChain

PREFIX = "refine_chain"
"""The names' start in the library."""

# a loop over the rows around each generated function: pointers moved along, work memory on the stack
_LOOP = """
int {name}_rows(const casadi_real* q, const casadi_real* const* fixed, casadi_real* const* out, long long n) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{sz_iw}];
  casadi_real w[{sz_w}];
  long long k;
{fixed}
  for (k = 0; k < n; ++k) {{
    arg[0] = q + k * {nq};
{moves}
    if ({name}(arg, res, iw, w, 0)) return 1;
  }}
  return 0;
}}
"""


# bodies on the joints: every row's joints, then T_world_base · oMi[joint] · T_joint_body per body
_BODIES = """
static void {prefix}_product(const casadi_real* a, const casadi_real* b, casadi_real* c) {{
  int r, j, i;
  for (r = 0; r < 4; ++r) {{
    for (j = 0; j < 4; ++j) {{
      casadi_real s = 0;
      for (i = 0; i < 4; ++i) s += a[4 * r + i] * b[4 * i + j];
      c[4 * r + j] = s;
    }}
  }}
}}

int {prefix}_bodies_rows(const casadi_real* q, const casadi_real* base, const long long* joint,
                         const casadi_real* local, long long m, casadi_real* out, long long n) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{sz_iw}];
  casadi_real w[{sz_w}];
  casadi_real oMi[{size}];
  casadi_real placed[16];
  long long k, b;
  for (b = 0; b < m; ++b) {{
    if (joint[b] < 0 || joint[b] >= {njoints}) return 2;
  }}
  for (k = 0; k < n; ++k) {{
    arg[0] = q + k * {nq};
    res[0] = oMi;
    if ({prefix}_joints(arg, res, iw, w, 0)) return 1;
    for (b = 0; b < m; ++b) {{
      {prefix}_product(base, oMi + 16 * joint[b], placed);
      {prefix}_product(placed, local + 16 * b, out + 16 * (k * m + b));
    }}
  }}
  return 0;
}}
"""


# one damped least-squares step per row toward a TCP target (6 task rows, nv columns), and a whole solve
_IK = """
/* e (6): the position difference and the rotation vector of R_target R(q)^T (rotation_vectors'
   formula, without its branch near pi); the rotation angle returned */
static casadi_real {prefix}_error(const casadi_real* G, const casadi_real* Tk, casadi_real* ek) {{
  casadi_real M[9], cs, th, scale;
  int i, j;
  for (i = 0; i < 3; ++i) ek[i] = G[4 * i + 3] - Tk[4 * i + 3];
  for (i = 0; i < 3; ++i) {{
    for (j = 0; j < 3; ++j) {{
      M[3 * i + j] = G[4 * i] * Tk[4 * j] + G[4 * i + 1] * Tk[4 * j + 1] + G[4 * i + 2] * Tk[4 * j + 2];
    }}
  }}
  cs = (M[0] + M[4] + M[8] - 1.0) / 2.0;
  cs = cs < -1.0 ? -1.0 : (cs > 1.0 ? 1.0 : cs);
  th = acos(cs);
  scale = th < 1e-6 ? 1.0 + th * th / 6.0 : th / sin(th);
  ek[3] = 0.5 * (M[7] - M[5]) * scale;
  ek[4] = 0.5 * (M[2] - M[6]) * scale;
  ek[5] = 0.5 * (M[3] - M[1]) * scale;
  return th;
}}

/* e (6): the position difference and the rotation vector turning the TCP's z axis onto the target's
   the shortest way (axis_error's: z x z_target scaled to the angle between them, 0 when parallel);
   Ja: J with its angular rows' component about the current z axis taken out, so a step leaves the
   spin about the axis free; the angle between the axes returned */
static casadi_real {prefix}_axis_error(const casadi_real* G, const casadi_real* Tk, const casadi_real* Jk,
                                       casadi_real* Ja, casadi_real* ek) {{
  casadi_real z[3], t[3], sn, th, s;
  int i, c;
  for (i = 0; i < 3; ++i) {{
    ek[i] = G[4 * i + 3] - Tk[4 * i + 3];
    z[i] = Tk[4 * i + 2];
    t[i] = G[4 * i + 2];
  }}
  ek[3] = z[1] * t[2] - z[2] * t[1];
  ek[4] = z[2] * t[0] - z[0] * t[2];
  ek[5] = z[0] * t[1] - z[1] * t[0];
  sn = sqrt(ek[3] * ek[3] + ek[4] * ek[4] + ek[5] * ek[5]);
  th = atan2(sn, z[0] * t[0] + z[1] * t[1] + z[2] * t[2]);
  s = sn > 1e-12 ? th / sn : 0.0;
  for (i = 3; i < 6; ++i) ek[i] *= s;
  for (c = 0; c < 3 * {nv}; ++c) Ja[c] = Jk[c];
  for (c = 0; c < {nv}; ++c) {{
    s = z[0] * Jk[3 * {nv} + c] + z[1] * Jk[4 * {nv} + c] + z[2] * Jk[5 * {nv} + c];
    for (i = 0; i < 3; ++i) Ja[(3 + i) * {nv} + c] = Jk[(3 + i) * {nv} + c] - z[i] * s;
  }}
  return th;
}}

/* the Cholesky factor L (lower, in A) of A = J J^T + damping^2 I; 2 when A is not positive */
static int {prefix}_factor(const casadi_real* Jk, casadi_real damping, casadi_real* A) {{
  casadi_real s;
  int i, j, c;
  for (i = 0; i < 6; ++i) {{
    for (j = 0; j <= i; ++j) {{
      s = 0.0;
      for (c = 0; c < {nv}; ++c) s += Jk[{nv} * i + c] * Jk[{nv} * j + c];
      A[6 * i + j] = s + (i == j ? damping * damping : 0.0);
    }}
  }}
  for (j = 0; j < 6; ++j) {{
    s = A[6 * j + j];
    for (c = 0; c < j; ++c) s -= A[6 * j + c] * A[6 * j + c];
    if (!(s > 0.0)) return 2;
    A[6 * j + j] = sqrt(s);
    for (i = j + 1; i < 6; ++i) {{
      s = A[6 * i + j];
      for (c = 0; c < j; ++c) s -= A[6 * i + c] * A[6 * j + c];
      A[6 * i + j] = s / A[6 * j + j];
    }}
  }}
  return 0;
}}

/* out (nv) = J^T A^-1 b with A's factor L */
static void {prefix}_back(const casadi_real* A, const casadi_real* Jk, const casadi_real* b, casadi_real* out) {{
  casadi_real y[6], s;
  int i, c;
  for (i = 0; i < 6; ++i) {{
    s = b[i];
    for (c = 0; c < i; ++c) s -= A[6 * i + c] * y[c];
    y[i] = s / A[6 * i + i];
  }}
  for (i = 5; i >= 0; --i) {{
    s = y[i];
    for (c = i + 1; c < 6; ++c) s -= A[6 * c + i] * y[c];
    y[i] = s / A[6 * i + i];
  }}
  for (c = 0; c < {nv}; ++c) {{
    s = 0.0;
    for (i = 0; i < 6; ++i) s += Jk[{nv} * i + c] * y[i];
    out[c] = s;
  }}
}}

int {prefix}_ik_rows(const casadi_real* q, const casadi_real* base, const casadi_real* tool,
                     const casadi_real* target, casadi_real damping, casadi_real tol, long long given, casadi_real* T,
                     casadi_real* J, casadi_real* e, casadi_real* norm, casadi_real* dq,
                     casadi_real* theta, long long n) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{sz_iw}];
  casadi_real w[{sz_w}];
  casadi_real A[36];
  long long k;
  int i, c;
  for (k = 0; k < n; ++k) {{
    casadi_real* Tk = T + 16 * k;
    casadi_real* Jk = J + 6 * {nv} * k;
    casadi_real* ek = e + 6 * k;
    casadi_real s;
    if (!given) {{
      arg[0] = q + k * {nq};
      arg[1] = base;
      arg[2] = tool;
      res[0] = Tk;
      res[1] = Jk;
      if ({prefix}_tcpj(arg, res, iw, w, 0)) return 1;
    }}
    theta[k] = {prefix}_error(target + 16 * k, Tk, ek);
    s = 0.0;
    for (i = 0; i < 6; ++i) s += ek[i] * ek[i];
    norm[k] = sqrt(s);
    if (s < tol * tol * (1.0 - 1e-12)) {{  /* then norm * norm < tol * tol in the caller too */
      for (c = 0; c < {nv}; ++c) dq[{nv} * k + c] = 0.0;
      continue;
    }}
    if ({prefix}_factor(Jk, damping, A)) return 2;
    {prefix}_back(A, Jk, ek, dq + {nv} * k);
  }}
  return 0;
}}

/* the damped least-squares IK per row, iterated: solve_ik's iterations (stall == 0) or
   solve_ik_batch's (stall > 0: a row whose error has not fallen below keep * its best for stall
   iterations stops); the TCP on the flange (world == 0) or a stationary tool; a redundant arm's
   pull toward mid-range (gain > 0) in the task's null space; the whole pose or (iopts[4]) the
   position and the tool axis alone, the spin about it free. flag[k] = 1: the rotation error (the
   angle between the axes) came within 1e-3 rad of pi, the row is to be solved another way.
   Chained (iopts[2]): rows first..n-1 in turn (iopts[3]: first; the rows before it solved
   already), each from the last answer plus the last step where no joint moved more than opts[4]
   in it (row 0 from q0's first row); the chain stops at a flagged row, or with flag[k] = 2 after
   a row whose joints moved more than opts[5] from the row before. */
int {prefix}_solve_rows(const casadi_real* q0, const casadi_real* base, const casadi_real* tool,
                        const casadi_real* world, const casadi_real* target, const casadi_real* lower,
                        const casadi_real* upper, const casadi_real* mid, const casadi_real* half,
                        const casadi_real* opts, const long long* iopts, casadi_real* q, casadi_real* err,
                        casadi_real* T, casadi_real* J, long long* flag, long long n) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{sz_iw}];
  casadi_real w[{sz_w}];
  casadi_real A[36], e[6], Jp[6], dq[{nv}], pull[{nv}], back[{nv}], Ja[6 * {nv}];
  const casadi_real damping = opts[0], tol = opts[1], gain = opts[2], keep = opts[3];
  const long long max_it = iopts[0], stall = iopts[1], chained = iopts[2], axis = iopts[4];
  const casadi_real* Jt;  /* the task's Jacobian: for the axis, without the spin's part */
  long long k, it, last;
  int i, c;
  for (k = chained ? iopts[3] : 0; k < n; ++k) {{
    casadi_real* qk = q + {nv} * k;
    casadi_real* Tk = T + 16 * k;
    casadi_real* Jk = J + 6 * {nv} * k;
    const casadi_real* G = target + 16 * k;
    const casadi_real* start = q0 + (chained ? 0 : {nv} * k);
    casadi_real best = INFINITY, s, nrm, step, th;
    flag[k] = 0;
    last = 0;
    if (chained && k > 0) {{  /* the last answer, plus its step where that is small */
      const casadi_real* a = qk - {nv};
      step = 0.0;
      for (c = 0; c < {nv} && k >= 2; ++c) step = fabs(a[c] - a[c - {nv}]) > step ? fabs(a[c] - a[c - {nv}]) : step;
      for (c = 0; c < {nv}; ++c) dq[c] = k >= 2 && step <= opts[4] ? a[c] + (a[c] - a[c - {nv}]) : a[c];
      start = dq;
    }}
    for (c = 0; c < {nv}; ++c) {{
      s = start[c] > lower[c] ? start[c] : lower[c];
      qk[c] = s < upper[c] ? s : upper[c];
    }}
    for (it = 0;; ++it) {{
      arg[0] = qk;
      arg[1] = base;
      arg[2] = tool;
      arg[3] = world;
      res[0] = Tk;
      res[1] = Jk;
      if (world ? {prefix}_statj(arg, res, iw, w, 0) : {prefix}_tcpj(arg, res, iw, w, 0)) return 1;
      th = axis ? {prefix}_axis_error(G, Tk, Jk, Ja, e) : {prefix}_error(G, Tk, e);
      Jt = axis ? Ja : Jk;
      s = 0.0;
      for (i = 0; i < 6; ++i) s += e[i] * e[i];
      nrm = sqrt(s);
      err[k] = nrm;
      if (th > M_PI - 1e-3) {{
        flag[k] = 1;
        break;
      }}
      if (stall > 0) {{
        if (nrm < keep * best) {{
          best = nrm;
          last = it;
        }}
        if (!(nrm * nrm >= tol * tol) || it - last >= stall) break;
      }} else if (s < tol * tol) {{
        break;
      }}
      if (it >= max_it) break;
      if ({prefix}_factor(Jt, damping, A)) return 2;
      {prefix}_back(A, Jt, e, dq);
      if (gain > 0.0) {{
        for (c = 0; c < {nv}; ++c) pull[c] = isfinite(half[c]) ? (mid[c] - qk[c]) / (half[c] * half[c]) : 0.0;
        for (i = 0; i < 6; ++i) {{
          s = 0.0;
          for (c = 0; c < {nv}; ++c) s += Jt[{nv} * i + c] * pull[c];
          Jp[i] = s;
        }}
        {prefix}_back(A, Jt, Jp, back);
        for (c = 0; c < {nv}; ++c) dq[c] += gain * (pull[c] - back[c]);
      }}
      step = 0.0;
      for (c = 0; c < {nv}; ++c) step = fabs(dq[c]) > step ? fabs(dq[c]) : step;
      if (step > 0.3) {{
        s = 0.3 / step;
        for (c = 0; c < {nv}; ++c) dq[c] *= s;
      }}
      for (c = 0; c < {nv}; ++c) {{
        s = qk[c] + dq[c];
        s = s > lower[c] ? s : lower[c];
        qk[c] = s < upper[c] ? s : upper[c];
      }}
    }}
    if (chained && flag[k]) break;
    if (chained && k > 0) {{
      step = 0.0;
      for (c = 0; c < {nv}; ++c) step = fabs(qk[c] - qk[c - {nv}]) > step ? fabs(qk[c] - qk[c - {nv}]) : step;
      if (step > opts[5]) {{
        flag[k] = 2;
        break;
      }}
    }}
  }}
  return 0;
}}

/* the controller line's starts: per row the target (given, line == 0, or written from the row's
   segment's line (36 numbers: the chord's start and step, R, R K, R K^2 row-major, the angle of K,
   1 where the joint-linear wrist's orientation is taken)), the TCP pose T (the flange's, world == 0,
   or a stationary tool's), its error e toward the target as _error forms it (the angle in theta), and the start
   q + dq with dq = P[segment] [e, t e] (P (K, nv, 12) per segment), dq = 0 where a joint's step is
   not within step_max (a NaN too) or P == 0 */
int {prefix}_start_rows(const casadi_real* q, const casadi_real* base, const casadi_real* tool,
                        const casadi_real* world, const casadi_real* line, casadi_real* target, const casadi_real* P,
                        const long long* segment, const casadi_real* t, casadi_real step_max, casadi_real* T,
                        casadi_real* e, casadi_real* theta, casadi_real* start, long long n) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{sz_iw}];
  casadi_real w[{sz_w}];
  casadi_real x[12], dq[{nv}], s, a, b, tk;
  long long k;
  int i, c, ok;
  for (k = 0; k < n; ++k) {{
    const casadi_real* qk = q + {nv} * k;
    const casadi_real* Pk = P ? P + 12 * {nv} * segment[k] : 0;
    const casadi_real* L = line ? line + 36 * segment[k] : 0;
    casadi_real* G = target + 16 * k;
    casadi_real* Tk = T + 16 * k;
    casadi_real* ek = e + 6 * k;
    if (L) {{  /* the chord's point and the slerp R + t a(t th) R K + t^2 b(t th) R K^2 */
      tk = t[k];
      s = tk * L[33];
      a = s < 1e-4 ? 1.0 - s * s / 6.0 + (s * s) * (s * s) / 120.0 : sin(s) / s;
      b = s < 1e-4 ? 0.5 - s * s / 24.0 + (s * s) * (s * s) / 720.0 : 2.0 * ((sin(s / 2.0) / s) * (sin(s / 2.0) / s));
      a *= tk;
      b *= tk * tk;
      for (i = 0; i < 3; ++i) {{
        for (c = 0; c < 3; ++c) G[4 * i + c] = L[6 + 3 * i + c] + a * L[15 + 3 * i + c] + b * L[24 + 3 * i + c];
        G[4 * i + 3] = L[i] + tk * L[3 + i];
        G[12 + i] = 0.0;
      }}
      G[15] = 1.0;
    }}
    arg[0] = qk;
    arg[1] = base;
    arg[2] = tool;
    arg[3] = world;
    res[0] = Tk;
    if (world ? {prefix}_stat(arg, res, iw, w, 0) : {prefix}_tcp(arg, res, iw, w, 0)) return 1;
    for (i = 0; L && L[34] != 0.0 && i < 12; ++i) G[i] = i % 4 == 3 ? G[i] : Tk[i];  /* the wrist's orientation */
    theta[k] = {prefix}_error(G, Tk, ek);
    if (!Pk) {{  /* no Newton step asked for: the start is q */
      for (c = 0; c < {nv}; ++c) start[{nv} * k + c] = qk[c];
      continue;
    }}
    for (i = 0; i < 12; ++i) x[i] = i < 6 ? ek[i] : t[k] * ek[i - 6];
    ok = 1;
    for (c = 0; c < {nv}; ++c) {{
      s = 0.0;
      for (i = 0; i < 12; ++i) s += Pk[12 * c + i] * x[i];
      dq[c] = s;
      ok = ok && fabs(s) <= step_max;  /* false at a NaN too */
    }}
    for (c = 0; c < {nv}; ++c) start[{nv} * k + c] = ok ? qk[c] + dq[c] : qk[c];
  }}
  return 0;
}}

/* P (nv x 6 per row) = J^T (J J^T + damping^2 I)^-1, column by column through the Cholesky factor */
int {prefix}_pinv_rows(const casadi_real* J, casadi_real damping, casadi_real* P, long long n) {{
  casadi_real A[36], b[6], col[{nv}];
  long long k;
  int i, c;
  for (k = 0; k < n; ++k) {{
    if ({prefix}_factor(J + 6 * {nv} * k, damping, A)) return 2;
    for (i = 0; i < 6; ++i) {{
      for (c = 0; c < 6; ++c) b[c] = c == i ? 1.0 : 0.0;
      {prefix}_back(A, J + 6 * {nv} * k, b, col);
      for (c = 0; c < {nv}; ++c) P[6 * {nv} * k + 6 * c + i] = col[c];
    }}
  }}
  return 0;
}}

int {prefix}_det6_rows(const casadi_real* a, casadi_real* det, long long n) {{
  casadi_real L[36];
  long long k;
  int i, j, c, p;
  for (k = 0; k < n; ++k) {{
    casadi_real d = 1.0;
    for (i = 0; i < 36; ++i) L[i] = a[36 * k + i];
    for (j = 0; j < 6; ++j) {{
      p = j;
      for (i = j + 1; i < 6; ++i) {{
        if (fabs(L[6 * i + j]) > fabs(L[6 * p + j])) p = i;
      }}
      if (p != j) {{
        for (c = 0; c < 6; ++c) {{
          casadi_real t = L[6 * j + c];
          L[6 * j + c] = L[6 * p + c];
          L[6 * p + c] = t;
        }}
        d = -d;
      }}
      d *= L[6 * j + j];
      if (L[6 * j + j] == 0.0) continue;
      for (i = j + 1; i < 6; ++i) {{
        casadi_real f = L[6 * i + j] / L[6 * j + j];
        for (c = j + 1; c < 6; ++c) L[6 * i + c] -= f * L[6 * j + c];
      }}
    }}
    det[k] = d;
  }}
  return 0;
}}
"""


def chain_source(chain: BatchChain, flange_id: int, prefix: str = PREFIX) -> str:
    """The C of the chain's row functions and their row loops (module notes), names starting ``prefix``.

    Args:
        chain: the NumPy chain whose one-row recursion is written out.
        flange_id: the frame of the flange (Pinocchio's frame index).
        prefix: a C identifier the functions' names start with, e.g. ``"refine_chain"``.
    """
    import casadi as ca  # only when a library is written

    q = ca.SX.sym("q", chain.nq)
    base, tool = ca.SX.sym("base", 16), ca.SX.sym("tcp", 16)  # row-major 4 × 4
    qs = [q[i] for i in range(chain.nq)]
    fid = flange_id

    def flat(*matrices: list) -> list[ca.SX]:
        return [ca.densify(ca.vertcat(*[x for row in m for x in row])) for m in matrices]

    T, J = chain.row_frame(qs, fid, ca.cos, ca.sin)
    oMi = chain.row_joint_placements(qs, ca.cos, ca.sin)
    B = [[base[4 * r + c] for c in range(4)] for r in range(4)]
    X = [[tool[4 * r + c] for c in range(4)] for r in range(4)]
    T_tcp, J_tcp = placed(T, J, B, X)
    world = ca.SX.sym("world", 16)  # a stationary tool's T_world_TCP, row-major
    W = [[world[4 * r + c] for c in range(4)] for r in range(4)]
    T_part, J_part = stationary(T, J, B, X, W)
    functions = [
        ca.Function(f"{prefix}_fk", [q], flat(T)),
        ca.Function(f"{prefix}_fkj", [q], flat(T, J)),
        ca.Function(f"{prefix}_joints", [q], [ca.vertcat(*flat(*oMi))]),
        ca.Function(f"{prefix}_tcp", [q, base, tool], flat(T_tcp)),
        ca.Function(f"{prefix}_tcpj", [q, base, tool], flat(T_tcp, J_tcp)),
        ca.Function(f"{prefix}_stat", [q, base, tool, world], flat(T_part)),
        ca.Function(f"{prefix}_statj", [q, base, tool, world], flat(T_part, J_part)),
    ]
    gen = ca.CodeGenerator(f"{prefix}.c", {"with_header": False})
    for f in functions:
        gen.add(f)
    loops = []
    for f in functions:
        loops.append(
            _LOOP.format(
                name=f.name(),
                sz_arg=max(f.sz_arg(), 1),
                sz_res=max(f.sz_res(), 1),
                sz_iw=max(f.sz_iw(), 1),
                sz_w=max(f.sz_w(), 1),
                nq=chain.nq,
                fixed="\n".join(f"  arg[{i}] = fixed[{i - 1}];" for i in range(1, f.n_in())),
                moves="\n".join(f"    res[{i}] = out[{i}] + k * {f.nnz_out(i)};" for i in range(f.n_out())),
            )
        )
    joints = functions[2]
    bodies = _BODIES.format(
        prefix=prefix,
        sz_arg=max(joints.sz_arg(), 1),
        sz_res=max(joints.sz_res(), 1),
        sz_iw=max(joints.sz_iw(), 1),
        sz_w=max(joints.sz_w(), 1),
        size=joints.nnz_out(0),
        njoints=len(oMi),
        nq=chain.nq,
    )
    tcpj = functions[4]
    ik = _IK.format(
        prefix=prefix,
        sz_arg=max(*(f.sz_arg() for f in functions[3:]), 4),
        sz_res=max(*(f.sz_res() for f in functions[3:]), 2),
        sz_iw=max(*(f.sz_iw() for f in functions[3:]), 1),
        sz_w=max(*(f.sz_w() for f in functions[3:]), 1),
        nq=chain.nq,
        nv=tcpj.nnz_out(1) // 6,
    )
    return gen.dump() + "".join(loops) + bodies + ik


def placed(T: list, J: list, B: list, X: list) -> tuple[list, list]:
    """The TCP's pose ``B · T · X`` (4 × 4) and Jacobian (6 × nv) from the flange's, nested lists of scalars.

    ``T``, ``J``: the flange's placement in the base and its Jacobian (base axes, linear rows first);
    ``B``: ``T_world_base``; ``X``: ``T_flange_TCP``. The TCP's linear velocity is the flange's plus
    ``ω × r`` with ``r = R_world_flange · p(X)``, both halves turned into world axes by ``R(B)``.
    """
    T_wf = _product(B, T)
    T_wt = _product(T_wf, X)
    RB = [row[:3] for row in B[:3]]
    Jv, Jw = _product(RB, J[:3]), _product(RB, J[3:])
    r = [sum_terms([T_wf[i][k] * X[k][3] for k in range(3)]) for i in range(3)]
    cross = [
        [r[1] * Jw[2][j] - r[2] * Jw[1][j] for j in range(len(J[0]))],
        [r[2] * Jw[0][j] - r[0] * Jw[2][j] for j in range(len(J[0]))],
        [r[0] * Jw[1][j] - r[1] * Jw[0][j] for j in range(len(J[0]))],
    ]
    return T_wt, [[Jv[i][j] - cross[i][j] for j in range(len(J[0]))] for i in range(3)] + Jw


def stationary(T: list, J: list, B: list, X: list, W: list) -> tuple[list, list]:
    """A stationary tool's TCP seen from the held part, ``(B · T · X)⁻¹ · W`` (4 × 4), and its Jacobian (6 × nv).

    ``T``, ``J``: the flange's placement in the base and its Jacobian (base axes, linear rows
    first); ``B``: ``T_world_base``; ``X``: ``T_flange_part``; ``W``: ``T_world_TCP``. As
    :meth:`refine.robot.kinematics.TcpKinematics.poses_jacobians` composes it: the point of the
    flange at the tool's TCP moves with ``v = v_flange - r × ω``, ``r = p(W) - p(B · T)`` (world
    axes), and the TCP moves in the part's frame backwards, ``-R_world_partᵀ (v, ω)``.
    """
    T_wf = _product(B, T)
    T_wp = _product(T_wf, X)
    RB = [row[:3] for row in B[:3]]
    Jv, Jw = _product(RB, J[:3]), _product(RB, J[3:])
    r = [W[i][3] - T_wf[i][3] for i in range(3)]
    n = len(J[0])
    point = [
        [Jv[0][j] - (r[1] * Jw[2][j] - r[2] * Jw[1][j]) for j in range(n)],
        [Jv[1][j] - (r[2] * Jw[0][j] - r[0] * Jw[2][j]) for j in range(n)],
        [Jv[2][j] - (r[0] * Jw[1][j] - r[1] * Jw[0][j]) for j in range(n)],
    ]
    Rt = [[T_wp[k][i] for k in range(3)] for i in range(3)]
    shift = [-sum_terms([Rt[i][k] * T_wp[k][3] for k in range(3)]) for i in range(3)]
    inverse = [Rt[i] + [shift[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]
    J_out = [[-x for x in row] for row in _product(Rt, point) + _product(Rt, Jw)]
    return _product(inverse, W), J_out


def _product(A: list, B: list) -> list:
    """The matrix product of nested lists of scalars; a float factor 0 adds no term, a float 1 no product."""
    return [
        [sum_terms([_times(A[i][k], B[k][j]) for k in range(len(B))]) for j in range(len(B[0]))]
        for i in range(len(A))
    ]


def _times(a: Any, b: Any) -> Any:
    for x, y in ((a, b), (b, a)):
        if isinstance(x, float):
            if x == 0.0:
                return 0.0
            if x == 1.0:
                return y
    return a * b


def sum_terms(terms: list) -> Any:
    """``Σ terms`` leaving out the float zeros (0.0 when nothing is left)."""
    total: Any = 0.0
    for t in terms:
        if isinstance(t, float) and t == 0.0:
            continue
        total = t if isinstance(total, float) and total == 0.0 else total + t
    return total
