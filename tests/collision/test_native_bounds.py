"""The compiled bound arithmetic of the dense check against brute-force NumPy on random inputs."""

from __future__ import annotations

import numpy as np
import pytest

from refine.collision import native_bounds as nb
from refine.collision.carry import direction_bounds
from refine.collision.model import CollisionModel
from refine.frames import make_transform
from refine.robot.registry import load_robot
from refine.settings import Shape

lib = nb.compiled()  # as compiled, not through its load check: the tests check the C itself
compiled = pytest.mark.skipif(lib is None, reason="no C compiler (or REFINE_COMPILE=0): NumPy only")


def brute_short(bounds, margins, tol, motion):
    """Segment by segment and pair by pair: the end budgets do not cover the motion."""
    N, P = bounds.shape
    out = np.zeros((N - 1, P), dtype=bool)
    for k in range(N - 1):
        for p in range(P):
            b0, b1 = bounds[k, p] - margins[p] + tol, bounds[k + 1, p] - margins[p] + tol
            out[k, p] = b0 < 0.0 or b1 < 0.0 or b0 + b1 < motion[k, p]
    return out


@compiled
@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_short_segments_are_those_of_a_loop(seed):
    rng = np.random.default_rng(seed)
    bounds = rng.uniform(-0.02, 0.2, (50, 11))
    bounds[rng.random(bounds.shape) < 0.1] = -np.inf
    margins, motion = rng.uniform(0.0, 0.03, 11), rng.uniform(0.0, 0.2, (49, 11))
    expected = brute_short(bounds, margins, 1e-4, motion)
    assert np.array_equal(nb.short_of(bounds, margins, 1e-4, motion, lib), expected)
    assert np.array_equal(nb.short_of(bounds, margins, 1e-4, motion, None), expected)


@compiled
@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_carried_bounds_are_the_bound_less_the_motion(seed):
    rng = np.random.default_rng(seed)
    N, n, P, P0 = 30, 6, 8, 10
    q, q0 = rng.normal(size=(N, n)), rng.normal(size=(N, n))
    R = rng.uniform(0.0, 0.4, (P, n))
    bounds = rng.uniform(0.0, 4.0, (N, P0))
    mine, theirs = np.array([1, 2, 5, 6]), np.array([9, 0, 4, 4])
    delta = rng.uniform(0.0, 0.01, 4)
    expected = np.full((N, P), -np.inf)
    for k in range(N):
        for c, p in enumerate(mine):
            v = bounds[k, theirs[c]] - sum(abs(q[k, j] - q0[k, j]) * R[p, j] for j in range(n)) - delta[c]
            expected[k, p] = v if v > 0.0 else -np.inf
    for way in (lib, None):
        got = nb.carried(q, q0, R, bounds, mine, theirs, delta, way)
        assert np.array_equal(np.isinf(got), np.isinf(expected))
        finite = np.isfinite(expected)
        assert np.allclose(got[finite], expected[finite], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_the_least_bounds_per_waypoint_and_per_pair_are_those_of_loops(seed):
    rng = np.random.default_rng(seed)
    N, P = 40, 9
    bounds = rng.uniform(-0.05, 0.5, (N, P))
    bounds[rng.integers(0, N, 3), rng.integers(0, P, 3)] = -np.inf  # most rows and columns finite
    bounds[rng.integers(0, N, 2), rng.integers(0, P, 2)] = np.inf
    margins, measured = rng.uniform(0.0, 0.05, P), rng.random(N) < 0.3
    d_rows = [min(bounds[k]) for k in range(N)]
    c_rows = [min(bounds[k, p] - margins[p] for p in range(P)) for k in range(N)]
    d_cols = [min(bounds[:, p]) for p in range(P)]
    c_cols = [min(bounds[k, p] - margins[p] for k in range(N)) for p in range(P)]
    finite = [all(np.isfinite(bounds[:, p])) for p in range(P)]
    for way in ([lib] if lib is not None else []) + [None]:
        d, c = np.full(N, 7.0), np.full(N, 7.0)
        nb.row_least(bounds, margins, measured, slice(3, N + 5), d, c, way)
        assert np.all(d[:3] == 7.0) and np.all(c[:3] == 7.0)  # rows outside the slice untouched
        for k in range(3, N):
            assert d[k] == (np.inf if measured[k] else d_rows[k])
            assert c[k] == (np.inf if measured[k] else c_rows[k])
        least, clear, every = nb.column_least(bounds, margins, way)
        assert list(least) == d_cols and list(clear) == c_cols and list(every) == finite


def rotation(rng):
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return Q * np.sign(np.linalg.det(Q))


def sampled_reach(kind, dims, T, d, rng):
    """The largest d . x over many points of the shape (dense samples of its surface) placed at T."""
    if kind == "sphere":
        u = rng.normal(size=(20000, 3))
        x = dims[0] * u / np.linalg.norm(u, axis=1, keepdims=True)
    elif kind == "box":
        x = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * dims[0]
    elif kind == "cylinder":
        a = np.linspace(0.0, 2 * np.pi, 20000)
        ring = np.stack([dims[0] * np.cos(a), dims[0] * np.sin(a), np.zeros_like(a)], axis=1)
        x = np.concatenate([ring + [0, 0, dims[1]], ring - [0, 0, dims[1]]])
    else:
        x = dims[0]
    return float(((x @ T[:3, :3].T + T[:3, 3]) @ d).max())


@compiled
@pytest.mark.parametrize("seed", range(3))
def test_the_compiled_gaps_are_the_sampled_gaps_between_the_shapes(seed):
    """Gap along n: least n . (a - b), from the shapes' points, not from the support formulas."""
    rng = np.random.default_rng(seed)
    kinds = [
        ("sphere", 0.1),
        ("box", np.array([0.1, 0.2, 0.05])),
        ("cylinder", 0.07, 0.2),
        ("convex", rng.normal(scale=0.1, size=(9, 3))),
        ("box", np.array([0.3, 0.1, 0.2])),
    ]
    bodies = [nb._Fake(k) for k in kinds]
    M, N = 3, 6
    fixed = np.array([np.eye(4)] * 5)
    for T in fixed:
        T[:3, :3], T[:3, 3] = rotation(rng), rng.uniform(-2.0, 2.0, 3)
    pa, pb = np.array([0, 1, 2, 0, 1]), np.array([3, 4, 1, 4, 2])
    shapes = nb.Shapes(bodies, fixed, pa, pb, np.ones(5, dtype=bool))
    poses = np.tile(np.eye(4), (N, M, 1, 1))
    for k in range(N):
        for m in range(M):
            poses[k, m, :3, :3], poses[k, m, :3, 3] = rotation(rng), rng.uniform(-2.0, 2.0, 3)
    normals = rng.normal(size=(N, 5, 3)) * 3.0  # not unit: made unit by the gaps
    have = rng.random((N, 5)) < 0.8
    got = nb.direction_gaps(shapes, poses, normals, have, lib)
    for k in range(N):
        for p in range(5):
            if not have[k, p]:
                assert got[k, p] == -np.inf
                continue
            n = normals[k, p] / np.linalg.norm(normals[k, p])
            a, b = pa[p], pb[p]
            Ta = poses[k, a] if a < M else fixed[a]
            Tb = poses[k, b] if b < M else fixed[b]
            gap = -sampled_reach(kinds[a][0], kinds[a][1:], Ta, -n, rng) - sampled_reach(
                kinds[b][0], kinds[b][1:], Tb, n, rng
            )
            # the samples reach no further than the shapes, and a sphere's 20000 of them to within 0.1 mm
            if gap > 1e-4:
                assert gap - 1e-4 <= got[k, p] <= gap + 1e-12
            elif gap < 0.0:
                assert got[k, p] == -np.inf
    assert nb._relative(got, nb.numpy_gaps(shapes, poses, normals, have)) <= 1e-12


@pytest.mark.parametrize("seed", range(3))
def test_the_box_gaps_are_the_distances_between_the_boxes_of_the_corners(seed):
    """Each moving box's world box from its 8 corners placed, the gap as the per-axis separation's norm."""
    rng = np.random.default_rng(seed)
    N, M, B = 7, 3, 6
    centre, half = rng.normal(scale=0.1, size=(M, 3)), rng.uniform(0.05, 0.6, (M, 3))
    fixed_centre, fixed_half = rng.uniform(-1.5, 1.5, (B, 3)), rng.uniform(0.05, 0.6, (B, 3))
    poses = np.tile(np.eye(4), (N, M, 1, 1))
    for k in range(N):
        for m in range(M):
            poses[k, m, :3, :3], poses[k, m, :3, 3] = rotation(rng), rng.uniform(-1.5, 1.5, 3)
    pa, pb = np.array([0, 0, 1, 2, 1, 0]), np.array([1, 3, 4, 5, 2, 5])
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    expected = np.full((N, len(pa)), -np.inf)
    for k in range(N):
        lo, hi = fixed_centre - fixed_half, fixed_centre + fixed_half
        lo, hi = lo.copy(), hi.copy()
        for m in range(M):
            x = (centre[m] + signs * half[m]) @ poses[k, m, :3, :3].T + poses[k, m, :3, 3]
            lo[m], hi[m] = x.min(axis=0), x.max(axis=0)
        for c, (a, b) in enumerate(zip(pa, pb, strict=True)):
            apart = np.maximum(np.maximum(lo[b] - hi[a], lo[a] - hi[b]), 0.0)
            if np.linalg.norm(apart) > 0.0:
                expected[k, c] = np.linalg.norm(apart)
    assert np.isfinite(expected).any() and np.isinf(expected).any()
    for way in ([lib] if lib is not None else []) + [None]:
        got = nb.box_gaps(poses, centre, half, fixed_centre, fixed_half, pa, pb, way)
        assert np.array_equal(np.isfinite(got), np.isfinite(expected))
        finite = np.isfinite(expected)
        assert np.allclose(got[finite], expected[finite], rtol=1e-12, atol=1e-12)


def glass_free_model():
    """The IRB 4600 by a pillar and a ball with a nozzle (boxes, a sphere, cylinders, convex links)."""
    pillar = Shape("pillar", "box", pose=make_transform(p=[1.5, -0.65, 1.0]), size_m=(0.2, 0.2, 2.0))
    ball = Shape("ball", "sphere", pose=make_transform(p=[1.45, -0.5, 0.5]), radius_m=0.08)
    nozzle = Shape("nozzle", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.15]), radius_m=0.03, length_m=0.3)
    return CollisionModel(
        load_robot("abb_irb4600_60_205"),
        np.eye(4),
        make_transform(p=[0.0, 0.0, 0.35]),
        (nozzle,),
        (pillar, ball),
        margin_m=0.01,
        self_margin_m=0.005,
    )


def test_a_models_direction_bounds_are_its_pairs_plane_bounds_and_below_fcls_distances(monkeypatch):
    """Compiled or not (``REFINE_COMPILE=0``): each pair's gap as the model's own per-pair
    :meth:`CollisionModel.plane_bounds` gives it, and never above FCL's distance."""
    model = glass_free_model()
    rng = np.random.default_rng(5)
    q = np.radians([-35.0, 20.0, 15.0, 10.0, 50.0, 30.0]) + rng.normal(0.0, 0.3, (20, 6))
    poses = model.moving_poses(q)
    normals = rng.normal(size=(20, len(model.pairs), 3))
    normals[rng.random((20, len(model.pairs))) < 0.3] = np.nan
    expected = np.full((20, len(model.pairs)), -np.inf)
    for p in range(len(model.pairs)):
        for k in range(20):
            if not np.isnan(normals[k, p, 0]):
                n = normals[k, p] / np.linalg.norm(normals[k, p])
                gap = model.plane_bounds(p, poses[k : k + 1], n)
                if gap is not None and gap[0] > 0.0:
                    expected[k, p] = gap[0]
    truth = np.array([[model.pair_distance(qk, p) for p in range(len(model.pairs))] for qk in q])
    assert np.isfinite(expected).sum() > 50
    found = direction_bounds(model, poses, normals)
    monkeypatch.setenv("REFINE_COMPILE", "0")
    assert nb.library() is None
    numpy = direction_bounds(model, poses, normals)
    for got in (found, numpy):
        assert np.array_equal(np.isfinite(got), np.isfinite(expected))
        finite = np.isfinite(expected)
        assert np.allclose(got[finite], expected[finite], rtol=1e-12, atol=1e-12)
        assert np.all(got <= truth + 1e-9)


def test_the_load_check_catches_a_wrong_library():
    """A library that answers differently is refused by the load check."""

    class Wrong:
        def __init__(self, real):
            self.real = real

        def __getattr__(self, name):
            return getattr(self.real, name)

        def gaps(self, *args):
            self.real.gaps(*args)
            out = np.ctypeslib.as_array((nb.ctypes.c_double * (args[-4] * args[-2])).from_address(args[-1]))
            out[np.isfinite(out)] *= 1.0 + 1e-9

    if lib is None:
        pytest.skip("no C compiler (or REFINE_COMPILE=0)")
    assert nb.self_check(lib) <= nb.CHECK_TOLERANCE
    assert nb.library() is not None  # the library passes its load check and is used
    assert not nb.self_check(Wrong(lib)) <= nb.CHECK_TOLERANCE
