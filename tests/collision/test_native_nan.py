"""The compiled gaps along a direction given a pose or a corner that is not a number: no bound, as NumPy's.

A corner body's reach along a direction is the largest of its corners' products: NumPy's ``max``
is NaN when any product is, and a NaN gap bounds nothing (``-inf``). A body whose rotation is NaN
but whose translation is finite (a link turned by a joint that is NaN, its shape at the joint's
origin) must then give no bound, not an infinite one.
"""

from __future__ import annotations

import numpy as np
import pytest

from refine.collision import native_bounds as nb

lib = nb.compiled()
compiled = pytest.mark.skipif(lib is None, reason="no C compiler (or REFINE_COMPILE=0): NumPy only")

CORNERS = np.array([[0.1, 0, 0], [-0.1, 0, 0], [0, 0.1, 0], [0, -0.1, 0], [0, 0, 0.1], [0, 0, -0.1]])


def octahedron_and_ball(corners=CORNERS):
    """A moving corner body (an octahedron of half size 0.1 m) and a fixed ball (0.05 m) 2 m along x."""
    bodies = [nb._Fake(("convex", corners)), nb._Fake(("sphere", 0.05))]
    fixed = np.array([np.eye(4), np.eye(4)])
    fixed[1, :3, 3] = [2.0, 0.0, 0.0]
    return nb.Shapes(bodies, fixed, np.array([0]), np.array([1]), np.ones(1, dtype=bool))


@compiled
def test_a_rotation_not_a_number_bounds_nothing():
    shapes = octahedron_and_ball()
    poses = np.tile(np.eye(4), (3, 1, 1, 1))
    poses[1, 0, :3, :3] = np.nan  # its translation finite
    poses[2, 0, 1, 2] = np.nan
    normals = np.tile([-1.0, 0.0, 0.0], (3, 1, 1))  # from the ball towards the octahedron
    have = np.ones((3, 1), dtype=bool)
    got = nb.direction_gaps(shapes, poses, normals, have, lib)[:, 0]
    # row 0: the planes x = 0.1 and x = 1.95 between them, 1.85 m apart
    assert got[0] == pytest.approx(1.85, abs=1e-15)
    assert np.all(got[1:] == -np.inf)
    assert np.array_equal(got, nb.numpy_gaps(shapes, poses, normals, have)[:, 0])


@compiled
def test_a_corner_not_a_number_bounds_nothing():
    corners = CORNERS.copy()
    corners[3, 1] = np.nan
    shapes = octahedron_and_ball(corners)
    poses, normals = np.eye(4)[None, None], np.array([[[-1.0, 0.0, 0.0]]])
    have = np.ones((1, 1), dtype=bool)
    assert nb.direction_gaps(shapes, poses, normals, have, lib)[0, 0] == -np.inf
    assert nb.numpy_gaps(shapes, poses, normals, have)[0, 0] == -np.inf
