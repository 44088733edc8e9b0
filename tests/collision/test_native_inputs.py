"""The compiled bound arithmetic given arrays its loops cannot read as they are: NumPy's answers.

The C loops read C-contiguous float64 (or int64, bool) arrays of the shapes their callers pass;
broadcast shapes, float32 arrays, strided outputs or indices out of range must leave the answer
NumPy's (its broadcasting, its rounding of float32, its IndexError), not memory past the arrays.
The expectations are NumPy's own expressions written out here.
"""

from __future__ import annotations

import numpy as np
import pytest

from refine.collision import native_bounds as nb

lib = nb.compiled()
compiled = pytest.mark.skipif(lib is None, reason="no C compiler (or REFINE_COMPILE=0): NumPy only")


def numpy_short(bounds, margins, tol, motion):
    b = bounds - margins + tol
    return (b[:-1] < 0.0) | (b[1:] < 0.0) | (b[:-1] + b[1:] < motion)


@compiled
@pytest.mark.parametrize("motion_shape", [(7, 1), (5,), ()], ids=["per segment", "per pair", "one"])
def test_a_broadcast_motion_is_read_as_numpy_broadcasts_it(motion_shape):
    rng = np.random.default_rng(3)
    bounds, margins = rng.uniform(-0.05, 0.3, (8, 5)), rng.uniform(0.0, 0.05, 5)
    motion = rng.uniform(0.0, 0.3, motion_shape)
    got = nb.short_of(bounds, margins, 1e-4, motion, lib)
    assert np.array_equal(got, numpy_short(bounds, margins, 1e-4, motion))


@compiled
def test_a_broadcast_margin_is_read_as_numpy_broadcasts_it():
    rng = np.random.default_rng(4)
    bounds, motion = rng.uniform(-0.05, 0.3, (8, 5)), rng.uniform(0.0, 0.3, (7, 5))
    got = nb.short_of(bounds, 0.02, 1e-4, motion, lib)
    assert np.array_equal(got, numpy_short(bounds, 0.02, 1e-4, motion))


@compiled
def test_the_least_of_float32_rows_and_strided_outputs_are_numpys():
    rng = np.random.default_rng(5)
    bounds = rng.uniform(-0.05, 0.3, (9, 4))
    margins = rng.uniform(0.0, 0.05, 4)
    measured = np.zeros(9, dtype=bool)
    measured[[2, 6]] = True
    for b in (bounds.astype(np.float32), bounds):
        out = np.full((9, 2), 7.0)  # the columns strided: written where NumPy writes, nowhere else
        clear = np.full((9, 2), 7.0)
        nb.row_least(b, margins, measured, slice(1, 8), out[:, 0], clear[:, 0], lib)
        want = np.where(measured, np.inf, b.min(axis=1))
        want_clear = np.where(measured, np.inf, (b - margins).min(axis=1))
        assert np.array_equal(out[1:8, 0], want[1:8])
        assert np.array_equal(clear[1:8, 0], want_clear[1:8])
        assert np.all(out[[0, 8], 0] == 7.0) and np.all(out[:, 1] == 7.0)
        assert np.all(clear[[0, 8], 0] == 7.0) and np.all(clear[:, 1] == 7.0)


@compiled
def test_rows_taken_by_a_stride_are_those_alone():
    rng = np.random.default_rng(6)
    bounds, margins = rng.uniform(-0.05, 0.3, (9, 4)), rng.uniform(0.0, 0.05, 4)
    measured = np.zeros(9, dtype=bool)
    distance, clearance = np.full(9, 7.0), np.full(9, 7.0)
    nb.row_least(bounds, margins, measured, slice(0, 9, 2), distance, clearance, lib)
    assert np.array_equal(distance[0::2], bounds[0::2].min(axis=1))
    assert np.all(distance[1::2] == 7.0) and np.all(clearance[1::2] == 7.0)


@compiled
def test_carried_bounds_from_one_earlier_row_broadcast_as_numpy_does():
    rng = np.random.default_rng(7)
    N, n, P = 6, 3, 4
    q, q0 = rng.normal(size=(N, n)), rng.normal(size=n)  # one earlier row for every row
    R = rng.uniform(0.0, 0.4, (P, n))
    bounds = rng.uniform(1.0, 4.0, (N, 2))
    mine, theirs, delta = np.array([0, 3]), np.array([1, 0]), np.array([0.01, 0.02])
    want = np.full((N, P), -np.inf)
    want[:, mine] = bounds[:, theirs] - np.abs(q - q0) @ R[mine].T - delta
    want[~(want > 0.0)] = -np.inf
    got = nb.carried(q, q0, R, bounds, mine, theirs, delta, lib)
    assert np.allclose(got, want, rtol=1e-14, atol=0.0)


@compiled
def test_a_carried_column_out_of_range_raises_as_numpy_does():
    rng = np.random.default_rng(8)
    q, q0, R = rng.normal(size=(5, 3)), rng.normal(size=(5, 3)), rng.uniform(0.0, 0.4, (4, 3))
    bounds = rng.uniform(1.0, 4.0, (5, 2))
    with pytest.raises(IndexError):
        nb.carried(q, q0, R, bounds, np.array([0, 1]), np.array([1, 2]), np.zeros(2), lib)


@compiled
def test_a_box_pair_past_the_bodies_raises_as_numpy_does():
    rng = np.random.default_rng(9)
    poses = np.tile(np.eye(4), (3, 2, 1, 1))
    poses[:, :, :3, 3] = rng.normal(size=(3, 2, 3))
    centre, half = np.zeros((2, 3)), np.full((2, 3), 0.1)
    fixed_centre, fixed_half = rng.uniform(-2.0, 2.0, (3, 3)), np.full((3, 3), 0.1)
    with pytest.raises(IndexError):
        nb.box_gaps(poses, centre, half, fixed_centre, fixed_half, np.array([0, 1]), np.array([2, 3]), lib)


@compiled
def test_fixed_poses_in_another_layout_are_read_as_poses():
    """The bodies' fixed poses given transposed or strided in memory: the gaps NumPy reads from them."""
    rng = np.random.default_rng(10)
    bodies = [nb._Fake(("sphere", 0.1)), nb._Fake(("box", np.array([0.1, 0.2, 0.05])))]
    poses = np.array([nb._pose(rng, 1.0) for _ in range(2)])
    poses[1, :3, 3] += [2.0, 0.0, 0.0]
    pa, pb = np.array([0]), np.array([1])
    moving = poses[:1][None].repeat(4, axis=0)  # (4, 1, 4, 4): the sphere at every row
    normals = rng.normal(size=(4, 1, 3))
    have = np.ones((4, 1), dtype=bool)
    want = nb.numpy_gaps(nb.Shapes(bodies, poses, pa, pb, np.ones(1, bool)), moving, normals, have)
    wide = np.zeros((2, 4, 8))
    wide[..., ::2] = poses
    for fixed in (np.asfortranarray(poses), wide[..., ::2]):  # transposed in memory, strided
        shapes = nb.Shapes(bodies, fixed, pa, pb, np.ones(1, bool))
        assert np.array_equal(nb.direction_gaps(shapes, moving, normals, have, lib), want)
