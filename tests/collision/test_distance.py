"""Signed distances and witness points against analytic geometry, for primitives and meshes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.collision.distance import place, signed_distance
from refine.collision.geometry import shape_body
from refine.frames import make_transform
from refine.settings import Shape

# The IRB 4600's forearm at the zero configuration: a cylinder r 0.10 m along the base x axis,
# from x = 0.325 to 0.975 m, its axis at z = 1.570 m, so its underside is at z = 1.470 m.
FOREARM_BOTTOM_Z = 1.47

SHAPES = {
    "box": dict(shape="box", size_m=(0.1, 0.2, 0.3)),
    "cylinder": dict(shape="cylinder", radius_m=0.08, length_m=0.4),
    "sphere": dict(shape="sphere", radius_m=0.1),
}


def _body(name, spec, T, file=None):
    shape = (
        Shape(name, pose=T, file=file, **spec)
        if file is None
        else Shape(name, "mesh", pose=T, file=file, units="mm")
    )
    body = shape_body(shape, name=name, kind="cell", link=None, frame_id=-1, joint=-1)
    place(body, T)
    return body


def _analytic_sd(spec, T, p):
    """Signed distance from a world point to a primitive (negative inside)."""
    x = T[:3, :3].T @ (p - T[:3, 3])
    if spec["shape"] == "sphere":
        return np.linalg.norm(x) - spec["radius_m"]
    if spec["shape"] == "box":
        q = np.abs(x) - np.asarray(spec["size_m"]) / 2
    else:
        q = np.array([np.hypot(x[0], x[1]) - spec["radius_m"], abs(x[2]) - spec["length_m"] / 2])
    return np.linalg.norm(np.maximum(q, 0.0)) + min(q.max(), 0.0)


def _random_pose(rng, spread):
    return make_transform(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-spread, spread, 3))


def _moved(T, dp):
    T = T.copy()
    T[:3, 3] += dp
    return T


def _distance(a_spec, T_a, b, T_b, file=None):
    a = _body("a", a_spec, T_a, file)
    return signed_distance(a, T_a, b, T_b)


def test_forearm_above_a_box_reads_the_gap_and_the_vertical_normal(irb4600, make_model):
    """A box under the IRB 4600's forearm at known heights: distance = gap, points above each other."""
    for gap in (0.2, 0.05, 0.004, -0.02):
        top = FOREARM_BOTTOM_Z - gap
        box = Shape("block", "box", pose=make_transform(p=[0.75, 0.0, top - 0.05]), size_m=(0.3, 0.3, 0.1))
        model = make_model(irb4600, (box,))
        (c,) = [c for c in model.contacts(np.zeros(6), 0.5) if c.other == "block" and c.body == "link_4"]
        assert c.link == "link_4" and not c.self_pair and c.body_shape == "forearm"
        assert c.distance_m == pytest.approx(gap, abs=1e-6)
        np.testing.assert_allclose(c.normal, [0.0, 0.0, 1.0], atol=1e-6)
        assert c.point_body[2] == pytest.approx(FOREARM_BOTTOM_Z, abs=1e-6)
        assert c.point_other[2] == pytest.approx(top, abs=1e-6)
        assert 0.6 - 1e-9 <= c.point_body[0] <= 0.9 + 1e-9 and abs(c.point_body[1]) < 1e-4
        if gap < 0.1:  # nearer than the forearm to the upper arm (0.131 m)
            d, body, other = model.min_distance(np.zeros(6))
            assert (body, other) == ("link_4", "block") and d == pytest.approx(gap, abs=1e-6)


def test_sphere_sphere_distance_points_and_penetration_are_exact():
    b = _body("b", SHAPES["sphere"], make_transform(p=[1.0, 0.0, 0.0]))
    for x, expected in ((0.5, 0.3), (0.15, -0.05), (0.0, -0.2)):  # centres x apart; the last concentric
        d, p_a, p_b, n = _distance(
            SHAPES["sphere"], make_transform(p=[1.0 - x, 0.0, 0.0]), b, make_transform(p=[1.0, 0.0, 0.0])
        )
        assert d == pytest.approx(expected, abs=1e-12)
        assert np.linalg.norm(n) == pytest.approx(1.0)
        if x > 0.0:
            np.testing.assert_allclose(n, [-1.0, 0.0, 0.0], atol=1e-12)
            np.testing.assert_allclose(p_a, [1.0 - x + 0.1, 0.0, 0.0], atol=1e-12)
            np.testing.assert_allclose(p_b, [0.9, 0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("kind_a", list(SHAPES))
@pytest.mark.parametrize("kind_b", list(SHAPES))
def test_primitive_witness_points_lie_on_both_surfaces_and_the_normal_opens_the_gap(kind_a, kind_b):
    """Random poses, apart and overlapping: points on the surfaces, |p_a - p_b| = |d|, and moving
    the body 1 mm along the normal adds 1 mm (a first-order check that the sign is right)."""
    rng = np.random.default_rng(7)
    penetrating = 0
    for _ in range(40):
        T_a, T_b = _random_pose(rng, 0.2), _random_pose(rng, 0.2)
        b = _body("b", SHAPES[kind_b], T_b)
        d, p_a, p_b, n = _distance(SHAPES[kind_a], T_a, b, T_b)
        penetrating += d < 0
        assert _analytic_sd(SHAPES[kind_a], T_a, p_a) == pytest.approx(0.0, abs=5e-4)
        assert _analytic_sd(SHAPES[kind_b], T_b, p_b) == pytest.approx(0.0, abs=5e-4)
        assert np.linalg.norm(p_a - p_b) == pytest.approx(abs(d), abs=1e-9)
        if abs(d) > 2e-3:
            d_moved = _distance(SHAPES[kind_a], _moved(T_a, 1e-3 * n), b, T_b)[0]
            assert d_moved - d == pytest.approx(1e-3, abs=2e-4)
    assert 0 < penetrating < 40


def test_penetration_depth_is_negative_and_matches_the_overlap():
    """A cylinder sunk 2 cm into a box: distance -0.02 m, normal up out of the box."""
    T_box = make_transform(p=[0.0, 0.0, -0.5])
    box = _body("box", dict(shape="box", size_m=(1.0, 1.0, 1.0)), T_box)
    T_cyl = make_transform(Rotation.from_euler("y", 90, degrees=True).as_matrix(), [0.1, 0.0, 0.08 - 0.02])
    d, p_a, p_b, n = _distance(SHAPES["cylinder"], T_cyl, box, T_box)
    assert d == pytest.approx(-0.02, abs=1e-5)
    np.testing.assert_allclose(n, [0.0, 0.0, 1.0], atol=1e-4)
    assert p_a[2] == pytest.approx(-0.02, abs=1e-5) and p_b[2] == pytest.approx(0.0, abs=1e-5)


@pytest.mark.parametrize("kind", list(SHAPES))
def test_mesh_distances_and_witness_points_match_the_same_solid_as_a_primitive(kind, box_mesh_file):
    """python-fcl returns mesh/primitive nearest points swapped or in local frames; ours are right.

    The mesh is the STL of a 300 x 300 x 100 mm box; the same box as an FCL primitive is the
    reference. Bodies are apart here; penetration into meshes is tested below.
    """
    rng = np.random.default_rng(11)
    box_spec = dict(shape="box", size_m=(0.3, 0.3, 0.1))
    for _ in range(30):
        T_m = _random_pose(rng, 0.1)
        mesh = _body("mesh", None, T_m, file=box_mesh_file)
        prim = _body("prim", box_spec, T_m)
        u = rng.normal(size=3)
        T_a = make_transform(
            Rotation.random(random_state=rng).as_matrix(),
            T_m[:3, 3] + u / np.linalg.norm(u) * rng.uniform(0.45, 0.6),
        )
        d, p_a, p_m, n = _distance(SHAPES[kind], T_a, mesh, T_m)
        d_ref = _distance(SHAPES[kind], T_a, prim, T_m)[0]
        assert d > 0.0 and d == pytest.approx(d_ref, abs=1e-4)  # libccd's GJK: ~5e-5 m for cylinders
        assert _analytic_sd(SHAPES[kind], T_a, p_a) == pytest.approx(0.0, abs=1e-4)
        assert _analytic_sd(box_spec, T_m, p_m) == pytest.approx(0.0, abs=1e-9)
        assert np.linalg.norm(p_a - p_m) == pytest.approx(d, abs=1e-9)
        d_moved = _distance(SHAPES[kind], _moved(T_a, 1e-3 * n), mesh, T_m)[0]
        assert d_moved - d == pytest.approx(1e-3, abs=2e-4)


@pytest.mark.parametrize("kind", list(SHAPES))
def test_penetration_into_a_mesh_is_measured_through_the_face_crossed(kind, box_mesh_file):
    """FCL gives no depth for meshes; the face-plane measure gives the depth below the top face."""
    T_m = make_transform(p=[0.0, 0.0, -0.05])  # the mesh box's top face at z = 0
    mesh = _body("mesh", None, T_m, file=box_mesh_file)
    for depth in (0.005, 0.03):
        spec = SHAPES[kind]
        lowest = {"box": 0.15, "cylinder": 0.2, "sphere": 0.1}[kind]  # the shape's half height
        T_a = make_transform(p=[0.02, -0.01, lowest - depth])
        d, p_a, p_m, n = _distance(spec, T_a, mesh, T_m)
        assert d == pytest.approx(-depth, abs=1e-6)
        np.testing.assert_allclose(n, [0.0, 0.0, 1.0], atol=1e-9)
        assert p_a[2] == pytest.approx(-depth, abs=1e-6) and p_m[2] == pytest.approx(0.0, abs=1e-9)


def test_a_mesh_body_against_a_primitive_keeps_the_roles(box_mesh_file):
    """The mesh as the first body (a tool mesh): points and normal belong to the right bodies."""
    T_m = make_transform(p=[0.0, 0.0, 0.5])  # bottom face at z = 0.45
    mesh = _body("mesh", None, T_m, file=box_mesh_file)
    T_s = make_transform(p=[0.0, 0.0, 0.3])
    sphere = _body("s", SHAPES["sphere"], T_s)
    d, p_m, p_s, n = signed_distance(mesh, T_m, sphere, T_s)
    assert d == pytest.approx(0.05, abs=1e-5)
    np.testing.assert_allclose(n, [0.0, 0.0, 1.0], atol=1e-4)
    assert p_m[2] == pytest.approx(0.45, abs=1e-9) and p_s[2] == pytest.approx(0.4, abs=1e-5)
