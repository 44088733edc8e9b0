"""The dense check's bound arithmetic over whole paths, compiled to C where it can be.

Four expressions of :mod:`refine.collision.carry`, :mod:`refine.collision.advance` and
:mod:`refine.collision.check` run over every waypoint and pair of a path (618 × 63 on the glass
cell) several times a check, each a chain of NumPy passes and temporaries:

* :func:`short_of`: the segment pairs whose end budgets ``b = d - m + tolerance`` do not certify
  the segment, ``b_k < 0 or b_{k+1} < 0 or b_k + b_{k+1} < S`` (:func:`refine.collision.advance.short`);
* :func:`carried`: a previous check's bounds less the motion since and the cell's shift,
  ``B_k - |q_k - q0_k| · R_p - δ``, ``-inf`` where not positive
  (:func:`refine.collision.carry.carried_bounds`);
* :func:`direction_gaps`: every pair's gap along a unit direction per waypoint,
  ``-reach_A(-n) - reach_B(n)``, ``-inf`` where not positive
  (:func:`refine.collision.carry.direction_bounds`; one pass over every pair instead of a loop);
* :func:`box_gaps`: the gaps between the pairs' world-aligned boxes
  (:meth:`refine.collision.model.CollisionModel.box_bounds`).

Each is one small C loop (:data:`refine.collision.bounds_source.SOURCE`), as are the least bound
of each waypoint and of each pair (:func:`row_least`, :func:`column_least`: which waypoints the
check measures, which pairs the known bounds settle), compiled once into a shared library in the
cache folder of :mod:`refine.native` and called through :mod:`ctypes` on C-contiguous float64 arrays.
Only arrays of the very shapes the loops read reach them (outputs also of their dtype, in place;
indices within their axes); any other (a broadcast shape, a strided output, an index out of range)
takes the NumPy expression, which broadcasts or raises as NumPy does.
When the library is loaded its answers are compared once with the NumPy expressions on random
inputs (:data:`CHECK_TOLERANCE`); a difference, ``REFINE_COMPILE=0``, no C compiler or a failed
compilation leave every function on its NumPy expression, which gives the same answers to rounding.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import threading
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from refine.collision.bounds_source import SOURCE
from refine.collision.geometry import world_aabb
from refine.native import cache_dir, cached_library, compiler, compiler_version
from refine.types import Array

log = logging.getLogger(__name__)

PREFIX = "refine_bounds"
CHECK_TOLERANCE = 1e-12
"""The largest relative difference from the NumPy expressions a loaded library may show in its check."""
FLAGS = ("-O3", "-fPIC", "-shared", "-ffp-contract=off")
"""-O3: the loops over pairs and corners vectorised; no fused multiply-adds and no reassociation (no
-ffast-math): each sum rounds term by term, as NumPy's small products do."""
FUNCTIONS = ("short", "carried", "gaps", "boxes", "rows", "columns")


_pointer, _count = ctypes.c_void_p, ctypes.c_longlong
_lock = threading.Lock()
LOOKUP = object()
"""As ``lib``: the library of :func:`library` (None: the NumPy expressions)."""
_state: dict[str, object] = {}  # "lib": the checked library, or None for NumPy


class _Library:
    """The loaded library's functions, called on C-contiguous arrays."""

    def __init__(self, path: Path) -> None:
        self.path = path
        dll = ctypes.CDLL(str(path))
        self.short = dll[f"{PREFIX}_short"]
        self.short.argtypes = [_pointer, _pointer, ctypes.c_double, _pointer, _count, _count, _pointer]
        self.carried = dll[f"{PREFIX}_carried"]
        self.carried.argtypes = [_pointer] * 7 + [_count] * 5 + [_pointer] * 2
        self.gaps = dll[f"{PREFIX}_gaps"]
        self.gaps.argtypes = [_pointer] * 11 + [_count] * 3 + [_pointer]
        self.boxes = dll[f"{PREFIX}_boxes"]
        self.boxes.argtypes = [_pointer] * 7 + [_count] * 3 + [_pointer] * 2
        self.rows = dll[f"{PREFIX}_rows"]
        self.rows.argtypes = [_pointer] * 3 + [_count] * 3 + [_pointer] * 2
        self.columns = dll[f"{PREFIX}_columns"]
        self.columns.argtypes = [_pointer] * 2 + [_count] * 2 + [_pointer] * 3
        for fn in (self.short, self.carried, self.gaps, self.boxes, self.rows, self.columns):
            fn.restype = ctypes.c_int


def _ptr(a: np.ndarray) -> int:
    return a.__array_interface__["data"][0]  # the address a.ctypes.data gives, without its ctypes object


def _shaped(*given: tuple[object, tuple[int, ...]]) -> bool:
    """Every ``(array, shape)`` of ``given`` of that shape exactly (the C loops read no broadcast)."""
    return all(np.shape(a) == shape for a, shape in given)


def _within(index: object, size: int) -> bool:
    """Every entry of ``index`` an index of an axis of ``size`` counted from 0 (no wrap, nothing past it)."""
    index = np.asarray(index)
    return index.dtype.kind in "iu" and (
        index.size == 0 or (int(index.min()) >= 0 and int(index.max()) < size)
    )


def _in_place(a: object, shape: tuple[int, ...], dtype: type, written: bool = True) -> bool:
    """``a`` as the C reads it (and, ``written``, writes it) in place: C-contiguous, of ``dtype`` and ``shape``."""
    return (
        isinstance(a, np.ndarray)
        and a.dtype == dtype
        and a.shape == shape
        and a.flags.c_contiguous
        and (a.flags.writeable or not written)
    )


def library() -> _Library | None:
    """The checked library (compiled and loaded on the first call), or None: the NumPy expressions."""
    key = (os.environ.get("REFINE_COMPILE", "1"), os.environ.get("CC"))  # what decides the compiler
    with _lock:
        if _state.get("key") != key:
            _state["lib"], _state["key"] = _find(), key
        return _state["lib"]  # type: ignore[return-value]


def compiled() -> _Library | None:
    """The library as compiled (from the cache folder, or compiled first), not checked; None without one."""
    cc = compiler()
    if cc is None:
        return None
    h = hashlib.sha256()
    for part in (cc, compiler_version(cc), *FLAGS, SOURCE):
        h.update(part.encode() + b"\0")
    path = cache_dir() / f"{PREFIX}-{h.hexdigest()[:24]}.so"
    try:
        cached_library(cc, lambda: SOURCE, path, list(FUNCTIONS), FLAGS)
        return _Library(path)
    except (OSError, RuntimeError, AttributeError) as e:
        log.warning("compiling the clearance bounds failed (%s); using NumPy's", e)
        return None


def _find() -> _Library | None:
    lib = compiled()
    if lib is None:
        return None
    error = self_check(lib)
    if not error <= CHECK_TOLERANCE:
        log.warning(
            "the compiled clearance bounds %s differ from NumPy's by %.3g (> %g); using NumPy's",
            lib.path,
            error,
            CHECK_TOLERANCE,
        )
        return None
    return lib


# ---- the functions, compiled or NumPy's ------------------------------------------------------


def short_of(
    bounds: Array, margins: Array, tolerance_m: float, motion: Array, lib: _Library | None | object = LOOKUP
) -> NDArray[np.bool_]:
    """Segment pairs (N-1, P) whose budgets ``bounds - margins + tolerance_m`` do not certify the motion.

    ``bounds`` (N, P) [m] lower bounds at the waypoints, ``margins`` (P,) [m], ``motion`` (N-1, P)
    [m] each pair's motion bound per segment; as ``short(bounds - margins + tolerance_m, motion)``.
    """
    lib = library() if lib is LOOKUP else lib
    N, P = np.shape(bounds) if np.ndim(bounds) == 2 else (0, 0)
    if lib is None or N < 2 or not _shaped((margins, (P,)), (motion, (N - 1, P))):
        budget = bounds - margins + tolerance_m
        return (budget[:-1] < 0.0) | (budget[1:] < 0.0) | (budget[:-1] + budget[1:] < motion)
    bounds, margins, motion = (np.ascontiguousarray(a, dtype=float) for a in (bounds, margins, motion))
    N, P = bounds.shape
    out = np.empty((N - 1, P), dtype=np.bool_)
    lib.short(_ptr(bounds), _ptr(margins), float(tolerance_m), _ptr(motion), N, P, _ptr(out))
    return out


def row_least(
    bounds: Array,
    margins: Array,
    measured: NDArray[np.bool_],
    rows: slice,
    distance: Array,
    clearance: Array,
    lib: _Library | None | object = LOOKUP,
) -> None:
    """Per waypoint of ``rows``, its least bound and least clearance bound into ``distance``, ``clearance`` (N,).

    ``bounds`` (N, P) [m], ``margins`` (P,) [m]; ``inf`` for a waypoint ``measured`` (N,). Exact
    (a least value does not round), so the same whether compiled or not.
    """
    lib = library() if lib is LOOKUP else lib
    lo, hi, step = rows.indices(len(bounds))
    N, P = np.shape(bounds) if np.ndim(bounds) == 2 else (0, 0)
    if (
        lib is None
        or P == 0
        or hi <= lo
        or step != 1
        or not _in_place(bounds, (N, P), np.float64, written=False)
        or not _in_place(measured, (N,), np.bool_, written=False)
        or not _in_place(distance, (N,), np.float64)
        or not _in_place(clearance, (N,), np.float64)
        or not _shaped((margins, (P,)))
    ):
        distance[rows] = np.where(measured[rows], np.inf, bounds[rows].min(axis=1))
        clearance[rows] = np.where(measured[rows], np.inf, (bounds[rows] - margins).min(axis=1))
        return
    margins = np.ascontiguousarray(margins, dtype=float)
    lib.rows(
        _ptr(bounds), _ptr(margins), _ptr(measured), lo, hi, bounds.shape[1], _ptr(distance), _ptr(clearance)
    )


def column_least(
    bounds: Array, margins: Array, lib: _Library | None | object = LOOKUP
) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Per pair of ``bounds`` (N, P) [m]: its least bound, its least ``bound - margin`` [m], all finite, (P,) each."""
    lib = library() if lib is LOOKUP else lib
    N, P = np.shape(bounds) if np.ndim(bounds) == 2 else (0, 0)
    if lib is None or N == 0 or not _shaped((margins, (P,))):
        return bounds.min(axis=0), (bounds - margins).min(axis=0), np.isfinite(bounds).all(axis=0)
    bounds, margins = (np.ascontiguousarray(a, dtype=float) for a in (bounds, margins))
    N, P = bounds.shape
    d, c, finite = np.empty(P), np.empty(P), np.empty(P, dtype=np.bool_)
    lib.columns(_ptr(bounds), _ptr(margins), N, P, _ptr(d), _ptr(c), _ptr(finite))
    return d, c, finite


def carried(
    q: Array,
    q0: Array,
    motion: Array,
    bounds: Array,
    mine: NDArray[np.intp],
    theirs: NDArray[np.intp],
    delta: Array,
    lib: _Library | None | object = LOOKUP,
) -> Array:
    """Bounds (N, P) [m] carried from ``bounds`` (N, P0) at joints ``q0`` (N, n) to joints ``q`` (N, n).

    Column ``mine[c]`` is ``bounds[:, theirs[c]] - |q - q0| · motion[mine[c]] - delta[c]``
    (``motion`` (P, n) [m/rad] per pair and joint), ``-inf`` where that is not positive and in the
    other columns.
    """
    lib = library() if lib is LOOKUP else lib
    N, P = len(q), len(motion)
    C = len(mine)
    fits = np.ndim(q) == 2 and np.ndim(motion) == 2 and np.ndim(bounds) == 2
    if fits:
        n, P0 = np.shape(q)[1], np.shape(bounds)[1]
        fits = _shaped((q0, (N, n)), (motion, (P, n)), (bounds, (N, P0)), (theirs, (C,)), (delta, (C,)))
        fits = fits and _shaped((mine, (C,))) and _within(mine, P) and _within(theirs, P0)
    if lib is None or not fits:
        out = np.full((N, P), -np.inf)
        if len(mine):
            out[:, mine] = bounds[:, theirs] - (np.abs(q - q0) @ motion.T)[:, mine] - delta
        return np.where(out > 0.0, out, -np.inf)
    q, q0, bounds, delta = (np.ascontiguousarray(a, dtype=float) for a in (q, q0, bounds, delta))
    mine, theirs = (np.ascontiguousarray(a, dtype=np.int64) for a in (mine, theirs))
    Rt = np.ascontiguousarray(np.asarray(motion, dtype=float)[mine].T)  # (n, C)
    out, work = np.empty((N, P)), np.empty(max(len(mine), 1))
    lib.carried(
        _ptr(q), _ptr(q0), _ptr(Rt), _ptr(bounds), _ptr(mine), _ptr(theirs), _ptr(delta),
        N, q.shape[1], P, bounds.shape[1], len(mine), _ptr(work), _ptr(out),
    )  # fmt: skip
    return out


def box_gaps(
    poses: Array,
    centre: Array,
    half: Array,
    fixed_centre: Array,
    fixed_half: Array,
    pa: NDArray[np.intp],
    pb: NDArray[np.intp],
    lib: _Library | None | object = LOOKUP,
) -> Array:
    """The gaps (N, C) [m] between the world-aligned boxes of the body pairs (pa, pb) (C,), -inf for none.

    ``poses`` (N, M, 4, 4): the M moving bodies; ``centre``, ``half`` (M, 3) [m]: each one's box in
    its shape frame; ``fixed_centre``, ``fixed_half`` (B, 3) [m]: the world boxes of the bodies past
    the moving ones (read there only). The gap ``|max(|c_a - c_b| - h_a - h_b, 0)|``; overlapping
    boxes (and NaN poses) give ``-inf``.
    """
    lib = library() if lib is LOOKUP else lib
    N, M = poses.shape[:2]
    B, C = len(fixed_centre), len(pa)
    fits = (
        _shaped((poses, (N, M, 4, 4)), (fixed_centre, (B, 3)), (fixed_half, (B, 3)), (pb, (C,)))
        and _shaped((pa, (C,)))
        and np.shape(centre)[1:] == (3,)
        and np.shape(half)[1:] == (3,)
        and min(len(centre), len(half), B) >= M
        and _within(pa, B)
        and _within(pb, B)
    )
    if lib is None or not fits:
        cb, hb = np.empty((2, len(fixed_centre), N, 3))  # body-major: each pair's rows gathered as blocks
        cb[M:], hb[M:] = fixed_centre[M:, None], fixed_half[M:, None]
        used = np.union1d(pa[pa < M], pb[pb < M])  # only the moving bodies of these pairs are boxed
        at = slice(None, M) if len(used) == M else used  # all of them: the poses as they are
        c, h = world_aabb(poses[:, at], centre[at], half[at])
        cb[at], hb[at] = c.transpose(1, 0, 2), h.transpose(1, 0, 2)
        d = cb[pa]  # |c_a - c_b| - h_a - h_b, in place: the same sums without their temporaries
        d -= cb[pb]
        np.abs(d, out=d)
        d -= hb[pa]
        d -= hb[pb]
        np.maximum(d, 0.0, out=d)
        gaps = np.ascontiguousarray(np.sqrt(np.einsum("pni,pni->pn", d, d)).T)
        gaps[~(gaps > 0.0)] = -np.inf
        return gaps
    poses = np.ascontiguousarray(poses, dtype=float)
    centre, half, fixed_centre, fixed_half = (
        np.ascontiguousarray(a, dtype=float) for a in (centre[:M], half[:M], fixed_centre, fixed_half)
    )
    pa, pb = (np.ascontiguousarray(a, dtype=np.int64) for a in (pa, pb))
    out, work = np.empty((N, len(pa))), np.empty((max(M, 1), 6))
    lib.boxes(
        _ptr(poses), _ptr(centre), _ptr(half), _ptr(fixed_centre), _ptr(fixed_half), _ptr(pa), _ptr(pb),
        N, M, len(pa), _ptr(work), _ptr(out),
    )  # fmt: skip
    return out


class Shapes:
    """The bodies of a collision model as the compiled gaps read them: kind, sizes, corners, fixed poses.

    Attributes:
        kind: per body (B,): 0 sphere, 1 box, 2 cylinder, 3 corners (a convex body or a mesh).
        sizes: per body (B, 3) [m]: radius; half sizes; radius and half length.
        start, count: per body (B,), its corners' rows in ``corners``.
        corners: every corner body's corners (V, 3) [m], in its shape frame.
        fixed: every body's pose (B, 4, 4), read for the bodies past the moving ones.
        pa, pb: the pairs' bodies (P,); bounded: the pairs without a mesh (P,) (nor a body with a
            corner or size that is not finite: its gaps bound nothing).
    """

    def __init__(self, bodies: list, fixed: Array, pa: Array, pb: Array, bounded: Array) -> None:
        kinds, sizes, starts, counts, corners, corners_of = [], [], [], [], [], []
        at = 0
        for body in bodies:
            tag, *dims = body.kind_params
            points = body.vertices if body.vertices is not None else dims[0] if tag == "convex" else None
            size = np.zeros(3)
            if points is not None:
                kind = 3
                corners.append(np.asarray(points, dtype=float).reshape(-1, 3))
            elif tag == "sphere":
                kind, size[0] = 0, dims[0]
            elif tag == "box":
                kind, size[:] = 1, dims[0]
            else:
                kind, size[:2] = 2, dims[:2]
            n = len(corners[-1]) if kind == 3 else 0
            corners_of.append(corners[-1] if kind == 3 else size)
            kinds.append(kind)
            sizes.append(size)
            starts.append(at)
            counts.append(n)
            at += n
        self.kind = np.array(kinds, dtype=np.int64)
        self.sizes = np.ascontiguousarray(sizes, dtype=float).reshape(-1, 3)
        self.start = np.array(starts, dtype=np.int64)
        self.count = np.array(counts, dtype=np.int64)
        self.corners = np.ascontiguousarray(np.concatenate(corners) if corners else np.zeros((1, 3)))
        self.fixed = np.ascontiguousarray(fixed, dtype=float)  # read by the C in place
        self.pa, self.pb = (np.ascontiguousarray(a, dtype=np.int64) for a in (pa, pb))
        # a corner that is not finite: no reach to bound a gap by (NumPy's max is NaN, or infinite)
        finite = np.array([np.isfinite(c).all() for c in corners_of], dtype=bool)
        self.bounded = np.asarray(bounded, dtype=bool) & finite[self.pa] & finite[self.pb]


def direction_gaps(
    shapes: Shapes,
    poses: Array,
    normals: Array,
    have: NDArray[np.bool_],
    lib: _Library | None | object = LOOKUP,
) -> Array | None:
    """Per waypoint and pair (N, P) [m], the gap along ``normals`` (N, P, 3) made unit, where ``have``.

    ``poses`` (N, M, 4, 4): the moving bodies at the waypoints. ``-inf`` where the gap is not
    positive, where ``have`` (N, P) is False, for a pair with a mesh and for a pair with a direction
    that is not a number once made unit. None without the compiled library: the caller's NumPy then.
    """
    lib = library() if lib is LOOKUP else lib
    N, P = np.shape(have) if np.ndim(have) == 2 else (0, -1)
    B, M = len(shapes.kind), np.shape(poses)[1] if np.ndim(poses) == 4 else -1
    fits = _shaped((poses, (N, M, 4, 4)), (normals, (N, P, 3)), (shapes.pa, (P,)), (shapes.pb, (P,)))
    fits = fits and _shaped((shapes.fixed, (B, 4, 4))) and _within(shapes.pa, B) and _within(shapes.pb, B)
    if lib is None or not fits:
        return None
    poses, normals = np.ascontiguousarray(poses, dtype=float), np.ascontiguousarray(normals, dtype=float)
    have = np.ascontiguousarray(have & shapes.bounded)
    N, P = have.shape
    out = np.empty((N, P))
    s = shapes
    lib.gaps(
        _ptr(poses), _ptr(s.fixed), _ptr(normals), _ptr(have), _ptr(s.pa), _ptr(s.pb), _ptr(s.kind),
        _ptr(s.sizes), _ptr(s.start), _ptr(s.count), _ptr(s.corners), N, poses.shape[1], P, _ptr(out),
    )  # fmt: skip
    return out


def numpy_gaps(shapes: Shapes, poses: Array, normals: Array, have: NDArray[np.bool_]) -> Array:
    """:func:`direction_gaps` in NumPy, pair by pair: the reference of the load check."""
    N, P = have.shape
    M = poses.shape[1]
    out = np.full((N, P), -np.inf)
    s = shapes
    have = have & s.bounded
    for p in np.flatnonzero(have.any(axis=0)):
        ks = np.flatnonzero(have[:, p])
        n = normals[ks, p]
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        if np.isnan(n).any():
            continue
        gap = np.zeros(len(ks))
        for body, d, sign in ((s.pa[p], -n, -1.0), (s.pb[p], n, -1.0)):
            T = poses[ks, body] if body < M else np.broadcast_to(s.fixed[body], (len(ks), 4, 4))
            lifted = np.einsum("ki,kij->kj", d, T[:, :3, :])
            local, base = lifted[:, :3], lifted[:, 3]
            size, kind = s.sizes[body], s.kind[body]
            if kind == 0:
                r = base + size[0] * np.linalg.norm(d, axis=1)
            elif kind == 1:
                r = base + np.abs(local) @ size
            elif kind == 2:
                r = base + size[1] * np.abs(local[:, 2]) + size[0] * np.hypot(local[:, 0], local[:, 1])
            else:
                r = base + (local @ s.corners[s.start[body] : s.start[body] + s.count[body]].T).max(axis=1)
            gap += sign * r
        out[ks, p] = np.where(gap > 0.0, gap, -np.inf)
    return out


def self_check(lib: _Library, seed: int = 0) -> float:
    """The largest relative difference of ``lib``'s answers from the NumPy expressions on random inputs."""
    rng = np.random.default_rng(seed)
    N, P, n = 40, 9, 6
    # short: the same comparisons of the same sums, so the same verdicts
    bounds = rng.uniform(-0.05, 0.3, (N, P))
    bounds[rng.random((N, P)) < 0.1] = -np.inf
    margins, motion = rng.uniform(0.0, 0.05, P), rng.uniform(0.0, 0.3, (N - 1, P))
    error = float(
        np.any(short_of(bounds, margins, 1e-4, motion, lib) != short_of(bounds, margins, 1e-4, motion, None))
    )
    # carried
    q, q0, R = rng.normal(size=(N, n)), rng.normal(size=(N, n)), rng.uniform(0.0, 0.5, (P, n))
    mine, theirs = np.array([0, 2, 3, 7]), np.array([1, 0, 5, 3])
    delta = rng.uniform(0.0, 0.01, 4)
    b0 = rng.uniform(0.0, 3.0, (N, 6))
    error = max(error, _relative(carried(q, q0, R, b0, mine, theirs, delta, lib),
                                 carried(q, q0, R, b0, mine, theirs, delta, None)))  # fmt: skip
    # gaps: one body of each kind, moving and fixed, apart
    M, B = 3, 5
    bodies = [
        _Fake(("sphere", 0.1)),
        _Fake(("box", np.array([0.1, 0.2, 0.05]))),
        _Fake(("cylinder", 0.07, 0.2)),
        _Fake(("convex", rng.normal(scale=0.1, size=(7, 3)))),
        _Fake(("box", np.array([0.3, 0.1, 0.2]))),
    ]
    fixed = np.array([_pose(rng, 3.0) for _ in range(B)])
    pa, pb = np.array([0, 0, 1, 1, 2, 2, 0, 1, 2]), np.array([1, 2, 2, 3, 3, 4, 4, 4, 1])
    shapes = Shapes(bodies, fixed, pa, pb, np.ones(P, dtype=bool))
    poses = np.array([[_pose(rng, 3.0) for _ in range(M)] for _ in range(N)])
    normals = rng.normal(size=(N, P, 3))
    have = rng.random((N, P)) < 0.8
    error = max(error, _relative(direction_gaps(shapes, poses, normals, have, lib),
                                 numpy_gaps(shapes, poses, normals, have)))  # fmt: skip
    # boxes: moving and fixed bodies, some overlapping
    centre, half = rng.normal(scale=0.1, size=(M, 3)), rng.uniform(0.05, 0.5, (M, 3))
    fixed_centre, fixed_half = rng.uniform(-2.0, 2.0, (B, 3)), rng.uniform(0.05, 0.5, (B, 3))
    error = max(error, _relative(box_gaps(poses, centre, half, fixed_centre, fixed_half, pa, pb, lib),
                                 box_gaps(poses, centre, half, fixed_centre, fixed_half, pa, pb, None)))  # fmt: skip
    # least values per row and per column: exact, so equal
    measured = rng.random(N) < 0.3
    bounds = rng.uniform(-0.05, 0.3, (N, P))  # one -inf, one inf and one NaN: most columns finite
    bounds[3, 2], bounds[5, 4], bounds[7, 6] = np.nan, -np.inf, np.inf
    rows = [np.empty(N) for _ in range(4)]
    row_least(bounds, margins, measured, slice(2, N - 3), rows[0], rows[1], lib)
    row_least(bounds, margins, measured, slice(2, N - 3), rows[2], rows[3], None)
    cut = slice(2, N - 3)
    for a, b in (
        (rows[0][cut], rows[2][cut]),
        (rows[1][cut], rows[3][cut]),
        *zip(column_least(bounds, margins, lib), column_least(bounds, margins, None), strict=True),
    ):
        error = max(error, float(not np.array_equal(a, b, equal_nan=True)))
    return error


def _relative(a: Array | None, b: Array) -> float:
    if a is None or a.shape != b.shape:
        return np.inf
    same = (a == b) | (np.isinf(a) & np.isinf(b) & (np.sign(a) == np.sign(b)))
    finite = np.isfinite(a) & np.isfinite(b)
    if not np.all(same | finite):
        return np.inf
    if not finite.any():
        return 0.0
    return float(np.max(np.abs(a[finite] - b[finite]) / np.maximum(1.0, np.abs(b[finite]))))


class _Fake:
    """A body as :class:`Shapes` reads it, for the load check."""

    def __init__(self, kind_params: tuple) -> None:
        self.kind_params, self.vertices = kind_params, None


def _pose(rng: np.random.Generator, spread: float) -> Array:
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Q * np.sign(np.linalg.det(Q)), rng.uniform(-spread, spread, 3)
    return T
