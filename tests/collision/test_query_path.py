"""The query path's shortcuts against FCL called directly and brute-force gaps over the bodies' points."""

from __future__ import annotations

import fcl
import numpy as np
import pytest

import refine.collision.distance as distance_module
from refine.collision.carry import NEAR, checked_bounds, raise_near
from refine.collision.distance import place, signed_distance
from refine.collision.geometry import shape_body
from refine.frames import make_transform
from refine.robot.registry import load_robot
from refine.settings import Shape

CELL = (
    Shape("pillar", "box", pose=make_transform(p=[1.0, -0.4, 1.0]), size_m=(0.2, 0.3, 2.0)),
    Shape("ball", "sphere", pose=make_transform(p=[1.1, 0.5, 0.9]), radius_m=0.08),
)
TOOL = (Shape("nozzle", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.15]), radius_m=0.03, length_m=0.3),)


def _cell_body(name, spec):
    body = shape_body(Shape(name, **spec), name=name, kind="cell", link=None, frame_id=-1, joint=-1)
    place(body, spec["pose"])
    return body


def _fcl_distance(a, T_a, b, T_b):
    """FCL's plain distance of two bodies' geometries placed afresh (no object of the model reused)."""
    o_a = fcl.CollisionObject(a.geometry, fcl.Transform(T_a[:3, :3], T_a[:3, 3]))
    o_b = fcl.CollisionObject(b.geometry, fcl.Transform(T_b[:3, :3], T_b[:3, 3]))
    return fcl.distance(o_a, o_b, fcl.DistanceRequest(enable_nearest_points=True), fcl.DistanceResult())


@pytest.mark.parametrize(
    "spec_b",
    [
        dict(shape="box", size_m=(0.1, 0.2, 0.3)),
        dict(shape="cylinder", radius_m=0.05, length_m=0.3),
    ],
)
def test_a_first_answer_off_its_separating_plane_is_asked_again_and_fcls_distance_kept(monkeypatch, spec_b):
    """The first query made to answer 5 cm too far (its witness points right): the plane through
    them does not separate the bodies by that much, so the query is repeated and FCL's distance of
    the same pair placed afresh is returned, with witness points that far apart."""
    T_a = make_transform(p=[0.0, 0.0, 0.0])
    T_b = make_transform(np.eye(3), [0.45, 0.1, 0.05])
    a = _cell_body("a", dict(shape="box", size_m=(0.2, 0.2, 0.2), pose=T_a))
    b = _cell_body("b", dict(spec_b, pose=T_b))
    truth = _fcl_distance(a, T_a, b, T_b)
    real, calls = distance_module._query, []

    def first_too_far(first, second, turn):
        d, p1, p2 = real(first, second, turn)
        calls.append(turn)
        return (d + 0.05, p1, p2) if len(calls) == 1 else (d, p1, p2)

    monkeypatch.setattr(distance_module, "_query", first_too_far)
    d, p_a, p_b, n = signed_distance(a, T_a, b, T_b)
    assert len(calls) >= 2
    assert truth > 0.1
    assert d == pytest.approx(truth, abs=1e-9)
    assert np.linalg.norm(p_a - p_b) == pytest.approx(truth, abs=1e-9)
    np.testing.assert_allclose(n, (p_a - p_b) / np.linalg.norm(p_a - p_b), atol=1e-12)


def test_a_first_answer_on_its_separating_plane_is_one_fcl_call_with_fcls_distance(monkeypatch):
    """A separated primitive pair whose first answer is confirmed costs one FCL call, FCL's distance."""
    T_a, T_b = make_transform(p=[0.0, 0.0, 0.0]), make_transform(p=[0.0, 0.4, 0.1])
    a = _cell_body("a", dict(shape="cylinder", radius_m=0.05, length_m=0.3, pose=T_a))
    b = _cell_body("b", dict(shape="box", size_m=(0.1, 0.1, 0.1), pose=T_b))
    real, calls = distance_module._query, []
    monkeypatch.setattr(distance_module, "_query", lambda *args: calls.append(args) or real(*args))
    d = signed_distance(a, T_a, b, T_b)[0]
    assert len(calls) == 1
    assert d == pytest.approx(_fcl_distance(a, T_a, b, T_b), abs=1e-9)


def _points(body):
    """Points of a body in its shape frame whose furthest along any direction is its reach (sphere: None)."""
    tag, *dims = body.kind_params
    if tag == "box":
        return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * dims[0]
    if tag == "convex":
        return dims[0]
    if tag == "cylinder":  # two rims, the reach lies within r (1 - cos(pi / 6000)) above them
        t = np.linspace(0.0, 2.0 * np.pi, 6000, endpoint=False)
        rim = np.c_[dims[0] * np.cos(t), dims[0] * np.sin(t)]
        return np.r_[np.c_[rim, np.full(len(t), -dims[1])], np.c_[rim, np.full(len(t), dims[1])]]
    return None


def _furthest(body, T, d):
    if body.kind_params[0] == "sphere":
        return float(d @ T[:3, 3]) + body.kind_params[1]
    return float(((_points(body) @ T[:3, :3].T + T[:3, 3]) @ d).max())


def test_raise_near_lifts_the_window_to_the_brute_force_gaps_along_the_measured_normals(irb4600, make_model):
    """Waypoint k's measured pairs, their FCL normals there: every other waypoint within NEAR of k
    takes the larger of its bound and the gap between the bodies' points along that normal (where
    positive); waypoint k, the pairs not measured and the waypoints further away keep theirs."""
    model = make_model(irb4600, cell=CELL, tool=TOOL)
    rng = np.random.default_rng(3)
    start = np.radians([-20.0, 25.0, 10.0, 15.0, 40.0, 20.0])
    q = start + np.cumsum(rng.normal(0.0, np.radians(0.8), (70, 6)), axis=0)
    poses = model.moving_poses(q)
    k = 30
    chosen = [p for p in range(len(model.pairs)) if p % 3 == 0]
    for p in chosen:
        model.pair_distance(q[k], p, poses[k])
    found = model.witnesses(q[k])
    assert set(found) == set(chosen)
    bounds = rng.uniform(-0.05, 0.05, (len(q), len(model.pairs)))
    before = bounds.copy()
    raise_near(model, poses, bounds, k, found)
    expected = before.copy()
    for j in range(max(k - NEAR, 0), min(k + NEAR + 1, len(q))):
        if j == k:
            continue
        for p, (_, n) in found.items():
            a, b = model.pair_bodies(p)
            A, B = model.bodies[a], model.bodies[b]
            T_a = poses[j, a]
            T_b = poses[j, b] if b < len(poses[j]) else B.link_T_shape
            gap = -_furthest(A, T_a, -n) - _furthest(B, T_b, n)
            if gap > 0.0:
                expected[j, p] = max(expected[j, p], gap)
    np.testing.assert_allclose(bounds, expected, rtol=0.0, atol=1e-7)  # the rims: < 1e-7 m
    assert (bounds > before).sum() > 10  # the window was raised somewhere
    untouched = np.ones(len(q), dtype=bool)
    untouched[max(k - NEAR, 0) : k + NEAR + 1] = False
    untouched[k] = True
    assert np.array_equal(bounds[untouched], before[untouched])


def test_checked_bounds_copy_the_callers_arrays_unless_told_they_are_its_own(irb4600, make_model):
    """By default the bounds and normals are copies; with ``copy=False`` the arrays as given."""
    model = make_model(irb4600, cell=CELL, tool=TOOL)
    q = np.zeros((4, 6))
    bounds = np.full((4, len(model.pairs)), 0.2)
    normals = np.full((4, len(model.pairs), 3), np.nan)
    copied = checked_bounds(model, q, bounds, normals)
    kept = checked_bounds(model, q, bounds, normals, copy=False)
    assert not np.shares_memory(copied.bounds, bounds) and not np.shares_memory(copied.normals, normals)
    assert kept.bounds is bounds and kept.normals is normals
    np.testing.assert_array_equal(copied.bounds, kept.bounds)


def test_reach_of_every_kind_of_body_is_its_furthest_point(irb4600, make_model):
    """Body.reach (the separating-plane check's and the last-normal bound's) at random poses and
    directions: the largest n . x over the body's corners, rims or sphere, placed one by one
    (the registry's IRB 4600 has convex link pieces, the test robot cylinders)."""
    convex = make_model(load_robot("abb_irb4600_60_205"), cell=CELL, tool=TOOL)
    model = make_model(irb4600, cell=CELL, tool=TOOL)
    model.bodies = model.bodies + convex.bodies
    rng = np.random.default_rng(5)
    kinds = set()
    for body in model.bodies:
        kinds.add(body.kind_params[0])
        for _ in range(20):
            R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            T = make_transform(R * np.sign(np.linalg.det(R)), rng.uniform(-2.0, 2.0, 3))
            n = rng.normal(size=3)
            n /= np.linalg.norm(n)
            assert body.reach(T, n) == pytest.approx(_furthest(body, T, n), abs=1e-7)
    assert kinds >= {"box", "sphere", "cylinder", "convex"}
