"""The C of :mod:`refine.collision.native_bounds`: one loop per expression, on C-contiguous arrays.

Every function returns 0; ``idx`` is a 64-bit count. The sums are written term by term in the
order NumPy's small products take them, and compiled without fused multiply-adds or reassociation
(:data:`refine.collision.native_bounds.FLAGS`), so the answers agree with NumPy's to rounding; the
least values (``least``) keep a NaN as NumPy's ``min`` does, and a corner body's largest product
(``reach``) as NumPy's ``max`` does.
"""

SOURCE = r"""
#include <math.h>
#include <stdint.h>

typedef long long idx;

int refine_bounds_short(const double *bounds, const double *margins, double tol, const double *motion,
                        idx N, idx P, uint8_t *out) {
    for (idx k = 0; k + 1 < N; ++k) {
        const double *b0 = bounds + k * P, *b1 = b0 + P, *s = motion + k * P;
        uint8_t *o = out + k * P;
        for (idx p = 0; p < P; ++p) {
            double u = b0[p] - margins[p] + tol, v = b1[p] - margins[p] + tol;
            o[p] = (uint8_t)((u < 0.0) | (v < 0.0) | (u + v < s[p]));
        }
    }
    return 0;
}

int refine_bounds_carried(const double *q, const double *q0, const double *Rt, const double *b0,
                          const idx *mine, const idx *theirs, const double *delta,
                          idx N, idx n, idx P, idx P0, idx C, double *s, double *out) {
    /* Rt (n, C): the carried pairs' motion bounds by joint; s (C,): work memory */
    for (idx k = 0; k < N; ++k) {
        const double *qk = q + k * n, *q0k = q0 + k * n;
        for (idx c = 0; c < C; ++c) s[c] = 0.0;
        for (idx j = 0; j < n; ++j) {  /* each sum term by term over the joints, as a product's */
            const double dq = fabs(qk[j] - q0k[j]), *r = Rt + j * C;
            for (idx c = 0; c < C; ++c) s[c] += dq * r[c];
        }
        double *o = out + k * P;
        const double *bk = b0 + k * P0;
        for (idx p = 0; p < P; ++p) o[p] = -INFINITY;
        for (idx c = 0; c < C; ++c) {
            double v = bk[theirs[c]] - s[c] - delta[c];
            o[mine[c]] = v > 0.0 ? v : -INFINITY;
        }
    }
    return 0;
}

int refine_bounds_boxes(const double *poses, const double *centre, const double *half, const double *cfix,
                        const double *hfix, const idx *pa, const idx *pb, idx N, idx M, idx P,
                        double *work, double *out) {
    /* work (M, 6): per moving body its world box's centre and half sizes at the row */
    for (idx k = 0; k < N; ++k) {
        for (idx m = 0; m < M; ++m) {
            const double *T = poses + 16 * (k * M + m), *ce = centre + 3 * m, *hf = half + 3 * m;
            double *c = work + 6 * m, *h = c + 3;
            for (int i = 0; i < 3; ++i) {
                const double *r = T + 4 * i;
                c[i] = r[3] + (r[0] * ce[0] + r[1] * ce[1] + r[2] * ce[2]);
                h[i] = fabs(r[0]) * hf[0] + fabs(r[1]) * hf[1] + fabs(r[2]) * hf[2];
            }
        }
        double *o = out + k * P;
        for (idx p = 0; p < P; ++p) {
            idx a = pa[p], b = pb[p];
            const double *ca = a < M ? work + 6 * a : cfix + 3 * a, *ha = a < M ? work + 6 * a + 3 : hfix + 3 * a;
            const double *cb = b < M ? work + 6 * b : cfix + 3 * b, *hb = b < M ? work + 6 * b + 3 : hfix + 3 * b;
            double s = 0.0;
            for (int i = 0; i < 3; ++i) {
                double d = fabs(ca[i] - cb[i]) - ha[i] - hb[i];
                d = d < 0.0 ? 0.0 : d;  /* NaN stays NaN, as NumPy's maximum keeps it */
                s += d * d;
            }
            double g = sqrt(s);
            o[p] = g > 0.0 ? g : -INFINITY;
        }
    }
    return 0;
}

static inline double least(double m, double x) { return (x < m || isnan(x)) ? x : m; }  /* NaN kept */

int refine_bounds_rows(const double *bounds, const double *margins, const uint8_t *measured, idx lo, idx hi,
                       idx P, double *d, double *c) {
    for (idx k = lo; k < hi; ++k) {
        const double *b = bounds + k * P;
        double md = b[0], mc = b[0] - margins[0];
        for (idx p = 1; p < P; ++p) {
            md = least(md, b[p]);
            mc = least(mc, b[p] - margins[p]);
        }
        d[k] = measured[k] ? INFINITY : md;
        c[k] = measured[k] ? INFINITY : mc;
    }
    return 0;
}

int refine_bounds_columns(const double *bounds, const double *margins, idx N, idx P, double *d, double *c,
                          uint8_t *finite) {
    for (idx p = 0; p < P; ++p) {
        d[p] = bounds[p];
        c[p] = bounds[p] - margins[p];
        finite[p] = 1;
    }
    for (idx k = 0; k < N; ++k) {
        const double *b = bounds + k * P;
        for (idx p = 0; p < P; ++p) {
            d[p] = least(d[p], b[p]);
            c[p] = least(c[p], b[p] - margins[p]);
            finite[p] &= (uint8_t)isfinite(b[p]);
        }
    }
    return 0;
}

/* the largest d . x over the body placed at T (row-major 4 x 4) */
static double reach(const double *T, const double *d, idx kind, const double *par,
                    const double *verts, idx nv) {
    double l[4];
    for (int j = 0; j < 4; ++j) l[j] = d[0] * T[j] + d[1] * T[4 + j] + d[2] * T[8 + j];
    if (kind == 0) return l[3] + par[0] * sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (kind == 1) return l[3] + (fabs(l[0]) * par[0] + fabs(l[1]) * par[1] + fabs(l[2]) * par[2]);
    if (kind == 2) return l[3] + par[1] * fabs(l[2]) + par[0] * hypot(l[0], l[1]);
    double best = -INFINITY;
    if (isfinite(l[0]) && isfinite(l[1]) && isfinite(l[2])) {  /* finite corners (Shapes): finite products */
        for (idx v = 0; v < nv; ++v) {
            double x = l[0] * verts[3 * v] + l[1] * verts[3 * v + 1] + l[2] * verts[3 * v + 2];
            if (x > best) best = x;
        }
    } else {  /* a pose not a number or infinite: a NaN product kept, as NumPy's max keeps it */
        for (idx v = 0; v < nv; ++v) {
            double x = l[0] * verts[3 * v] + l[1] * verts[3 * v + 1] + l[2] * verts[3 * v + 2];
            if (x > best || isnan(x)) best = x;
        }
    }
    return l[3] + best;
}

int refine_bounds_gaps(const double *poses, const double *fixed, const double *normals, const uint8_t *have,
                       const idx *pa, const idx *pb, const idx *kind, const double *par, const idx *voff,
                       const idx *vcount, const double *verts, idx N, idx M, idx P, double *out) {
    for (idx i = 0; i < N * P; ++i) out[i] = -INFINITY;
    for (idx p = 0; p < P; ++p) {
        idx a = pa[p], b = pb[p];
        int whole = 1;  /* a NaN direction anywhere leaves the pair without bounds, as NumPy's */
        for (idx k = 0; k < N && whole; ++k) {
            if (!have[k * P + p]) continue;
            const double *n = normals + 3 * (k * P + p);
            double s = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            for (int i = 0; i < 3; ++i) if (isnan(n[i] / s)) whole = 0;
        }
        if (!whole) continue;
        for (idx k = 0; k < N; ++k) {
            if (!have[k * P + p]) continue;
            const double *n = normals + 3 * (k * P + p);
            double s = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            double u[3] = {n[0] / s, n[1] / s, n[2] / s}, w[3] = {-u[0], -u[1], -u[2]};
            const double *Ta = a < M ? poses + 16 * (k * M + a) : fixed + 16 * a;
            const double *Tb = b < M ? poses + 16 * (k * M + b) : fixed + 16 * b;
            double g = -reach(Ta, w, kind[a], par + 3 * a, verts + 3 * voff[a], vcount[a])
                       - reach(Tb, u, kind[b], par + 3 * b, verts + 3 * voff[b], vcount[b]);
            out[k * P + p] = g > 0.0 ? g : -INFINITY;
        }
    }
    return 0;
}
"""
