"""The bodies' reach along directions at many poses against the furthest of their points, placed one by one."""

import numpy as np

from refine.frames import make_transform, matrix_from_fixed_xyz
from refine.settings import Shape

CELL = (
    Shape("pillar", "box", pose=make_transform(p=[1.0, 0.0, 1.0]), size_m=(0.2, 0.3, 2.0)),
    Shape("ball", "sphere", pose=make_transform(p=[1.2, -0.5, 0.5]), radius_m=0.08),
)


def points(body, count=720):
    """Points of the body in its shape frame (S, 3) whose furthest along any direction is its reach.

    Box and convex corners, mesh vertices; for a cylinder its two rims, ``count`` points each (the
    reach lies within ``radius (1 - cos(pi / count))`` above them); None for a sphere.
    """
    tag, *dims = body.kind_params
    if body.vertices is not None:
        return body.vertices
    if tag == "box":
        return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * dims[0]
    if tag == "convex":
        return dims[0]
    if tag == "cylinder":
        t = np.linspace(0.0, 2.0 * np.pi, count, endpoint=False)
        rim = np.c_[dims[0] * np.cos(t), dims[0] * np.sin(t)]
        return np.r_[np.c_[rim, np.full(count, -dims[1])], np.c_[rim, np.full(count, dims[1])]]
    return None


def furthest(body, T, d):
    """Largest d . x over the body's points x placed at T (4, 4), one pose at a time [m]."""
    if body.kind_params[0] == "sphere" and body.vertices is None:
        return float(d @ T[:3, 3] + body.kind_params[1] * np.linalg.norm(d))
    world = points(body) @ T[:3, :3].T + T[:3, 3]
    return float((world @ d).max())


def test_reach_at_many_poses_is_the_furthest_point_at_each(irb4600, nozzle, make_model):
    model = make_model(irb4600, CELL, (nozzle,))
    rng = np.random.default_rng(3)
    K = 9
    Ts = np.array(
        [
            make_transform(matrix_from_fixed_xyz(rng.uniform(-180, 180, 3)), rng.normal(size=3))
            for _ in range(K)
        ]
    )
    rows = rng.normal(size=(K, 3))
    one = rng.normal(size=3)
    kinds = set()
    for body in model.bodies:
        kinds.add(body.kind_params[0] if body.vertices is None else "mesh")
        slack = (
            body.kind_params[1] * (1.0 - np.cos(np.pi / 720)) * 2.0
            if body.kind_params[0] == "cylinder"
            else 0.0
        )
        for direction in (rows, one):
            got = body.reach_many(Ts, direction)
            d = np.broadcast_to(direction, (K, 3))
            want = np.array([furthest(body, Ts[k], d[k]) for k in range(K)])
            assert np.all(got >= want - 1e-12) and np.all(
                got <= want + slack * np.linalg.norm(d, axis=1) + 1e-12
            ), body.label
    assert {"box", "sphere", "cylinder"} <= kinds


def test_the_gap_at_chosen_rows_is_the_gap_between_the_furthest_points(irb4600, nozzle, make_model):
    model = make_model(irb4600, CELL, (nozzle,))
    rng = np.random.default_rng(5)
    q = rng.uniform(-1.0, 1.0, (7, irb4600.nq))
    poses = model.moving_poses(q)
    rows = np.array([6, 1, 4])
    normals = rng.normal(size=(len(rows), 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)

    def placed(k, body):  # a moving body's pose at waypoint k, a cell object's own
        return poses[k, body] if body < poses.shape[1] else model.bodies[body].link_T_shape

    checked = 0
    for p in range(len(model.pairs)):
        gaps = model.plane_bounds(p, poses, normals, rows)
        if gaps is None:
            continue
        a, b = model.pair_bodies(p)
        A, B = model.bodies[a], model.bodies[b]
        want = [
            -furthest(A, placed(k, a), -n) - furthest(B, placed(k, b), n)
            for k, n in zip(rows.tolist(), normals, strict=True)
        ]
        slack = sum(
            body.kind_params[1] * (1.0 - np.cos(np.pi / 720)) * 2.0
            for body in (A, B)
            if body.vertices is None and body.kind_params[0] == "cylinder"
        )
        assert np.all(gaps <= np.array(want) + 1e-12) and np.all(gaps >= np.array(want) - slack - 1e-12)
        checked += 1
    assert checked > len(model.pairs) // 2
