"""The collision model: pair rules, broad phase, point Jacobians and linearised distances."""

from __future__ import annotations

from dataclasses import replace

import fcl
import numpy as np
import pytest
import trimesh

from refine.collision import CollisionModel, linearised_distance
from refine.errors import InputError
from refine.frames import make_transform
from refine.robot.registry import available_robots, load_robot
from refine.settings import Shape

NEAR_TABLE_DEG = [0.0, 45.0, 40.0, 0.0, 5.0, 0.0]
"""An IRB 4600 pose reaching down with the flange close to the fixture and table."""


def _random_q(robot, rng, scale=1.0):
    mid = 0.5 * (robot.spec.lower + robot.spec.upper)
    half = 0.5 * np.minimum(robot.spec.upper - robot.spec.lower, 2 * np.pi) * scale
    return mid + rng.uniform(-half, half)


def _point_in_link(robot, base, q, link, point_world):
    T = base @ robot.frame_pose(q, link)
    return np.linalg.solve(T, np.append(point_world, 1.0))


def test_the_zero_configuration_of_the_irb4600_has_no_self_collision(irb4600, make_model):
    model = make_model(irb4600)
    d, body, other = model.min_distance(np.zeros(6))
    assert d > 0.1, (body, other)
    assert all(why == "adjacent" or why == "same body" for *_, why in model.excluded)


@pytest.mark.parametrize("name", available_robots())
def test_every_registered_robot_is_clear_of_itself_at_zero(name):
    robot = load_robot(name)
    model = CollisionModel(robot, np.eye(4), np.eye(4), (), (), margin_m=0.01, self_margin_m=0.005)
    assert model.pairs and model.min_distance(np.zeros(robot.nq))[0] > 0.005


def test_folding_the_forearm_into_the_base_is_a_self_collision(irb4600, make_model):
    """Joint 2 far forward and joint 3 fully down fold the forearm and wrist into the foot."""
    model = make_model(irb4600)
    q = np.radians([0.0, 120.0, 75.0, 0.0, 0.0, 0.0])
    hits = {(c.body, c.other): c for c in model.contacts(q, 0.0)}
    assert hits[("link_4", "base_link")].distance_m < -0.1
    assert all(c.self_pair and c.margin_m == 0.005 for c in hits.values())
    d, body, other = model.min_distance(q)
    assert d == min(c.distance_m for c in hits.values()) and (body, other) in hits
    deep = model.contacts(q, -0.1)
    assert deep and {(c.body, c.other) for c in deep} == {k for k, c in hits.items() if c.distance_m < -0.1}


def test_adjacent_links_and_the_tool_on_the_flange_are_not_paired(irb4600, nozzle, make_model):
    model = make_model(irb4600, tool=(nozzle,))
    excluded = {(a, b): why for a, b, why in model.excluded}
    for k in range(1, 6):
        assert excluded[(f"link_{k + 1}/{_SHAPE[k + 1]}", f"link_{k}/{_SHAPE[k]}")] == "adjacent"
    assert excluded[("tool:nozzle", "link_6/flange")] == "same body"
    assert excluded[("tool:nozzle", "link_5/wrist")] == "adjacent"
    assert ("tool:nozzle", "link_4/forearm") in model.pairs
    assert ("link_4/forearm", "base_link/foot") in model.pairs


_SHAPE = {0: "foot", 1: "column", 2: "upper_arm", 3: "elbow", 4: "forearm", 5: "wrist", 6: "flange"}


def test_the_tool_skips_the_workpiece_but_the_links_do_not(cell_model):
    excluded = {(a, b): why for a, b, why in cell_model.excluded}
    assert excluded[("tool:nozzle", "part")] == "workpiece"
    assert ("tool:nozzle", "table") in cell_model.pairs and ("tool:nozzle", "fixture") in cell_model.pairs
    assert all((f"link_{k}/{_SHAPE[k]}", "part") in cell_model.pairs for k in range(1, 7))
    assert excluded[("base_link/foot", "table")] == "fixed link"


def test_a_nozzle_dipped_into_the_workpiece_is_ignored_but_a_link_there_is_found(
    irb4600, nozzle, make_model, tmp_path
):
    cube = tmp_path / "cube.stl"
    trimesh.creation.box((0.04, 0.04, 0.04)).export(cube)
    q = np.radians(NEAR_TABLE_DEG)
    nozzle_tip = (irb4600.fk(q) @ [0.0, 0.0, 0.28, 1.0])[:3]
    wrist_centre = irb4600.frame_pose(q, "link_5")[:3, 3]

    def hits(at, workpiece, kind="mesh"):
        spec = dict(file=cube) if kind == "mesh" else dict(size_m=(0.04, 0.04, 0.04))
        part = Shape("part", kind, pose=make_transform(p=at), workpiece=workpiece, **spec)
        return {c.body for c in make_model(irb4600, (part,), (nozzle,)).contacts(q, 0.0) if c.other == "part"}

    assert hits(nozzle_tip, workpiece=False, kind="box") == {"tool:nozzle"}
    assert hits(nozzle_tip, workpiece=False) == {"tool:nozzle"}
    assert hits(nozzle_tip, workpiece=True) == set()
    assert "link_5" in hits(wrist_centre, workpiece=True)


def test_always_close_pairs_follow_the_axes_rule(irb4600, make_model):
    """A tool sleeve reaching back through the wrist centre (where axes 5 and 6 meet) is 0.16 m
    from the forearm at every configuration: skipped as always close once the self margin exceeds
    that, and checked below it."""
    sleeve = Shape("sleeve", "cylinder", pose=make_transform(p=[0.0, 0.0, -0.1]), radius_m=0.03, length_m=0.2)
    assert ("tool:sleeve", "link_4/forearm") in make_model(irb4600, tool=(sleeve,)).pairs
    wide = make_model(irb4600, tool=(sleeve,), self_margin_m=0.2)
    assert ("tool:sleeve", "link_4/forearm", "always close") in wide.excluded


def test_a_constant_distance_pair_is_skipped_with_its_reason(primitive_robot):
    """The UR10e's shoulder housing turns about its own axis above its round base: 0.7 mm at every
    configuration, so it can neither be kept 5 mm clear nor be changed by the optimiser."""
    ur10e = primitive_robot("ur10e")
    model = CollisionModel(ur10e, np.eye(4), np.eye(4), (), (), margin_m=0.01, self_margin_m=0.005)
    assert ("link_2/shoulder_housing", "base_link/base", "constant distance") in model.excluded
    shapes = {(s.link, s.name): s for s in ur10e.collision_shapes()}
    rng = np.random.default_rng(2)
    distances = []
    for _ in range(5):
        poses = ur10e.link_poses(_random_q(ur10e, rng))
        housing = shapes[("link_2", "shoulder_housing")].collision_object(poses["link_2"])
        base = shapes[("base_link", "base")].collision_object(poses["base_link"])
        distances.append(fcl.distance(housing, base, fcl.DistanceRequest()))
    # the housing (a horizontal cylinder about joint 2's axis, at the data sheet's d1 = 0.1807 m above
    # the base) hangs over the base cylinder: gap = d1 - housing radius - top of the base
    housing, base = shapes[("link_2", "shoulder_housing")], shapes[("base_link", "base")]
    base_top = base.link_T_shape[2, 3] + 0.5 * base.geometry.lz
    gap = 0.1807 - housing.geometry.radius - base_top
    assert gap == pytest.approx(0.0007, abs=1e-12)  # 0.1807 - 0.09 - 0.09
    assert np.ptp(distances) < 1e-6
    np.testing.assert_allclose(distances, gap, atol=2e-6)


def test_contacts_with_the_broad_phase_equal_a_check_of_every_pair(cell_model, irb4600):
    rng = np.random.default_rng(4)
    for _ in range(20):
        q = _random_q(irb4600, rng)
        near = {(c.body_shape, c.other_shape): c.distance_m for c in cell_model.contacts(q, 0.15)}
        every = {(c.body_shape, c.other_shape): c.distance_m for c in cell_model.contacts(q, np.inf)}
        assert len(every) == len(cell_model.pairs)
        assert near == {k: d for k, d in every.items() if d < 0.15}
        d, body, other = cell_model.min_distance(q)
        assert d == pytest.approx(min(every.values()))


def test_point_jacobian_matches_finite_differences(cell_model, irb4600, base_in_world):
    rng = np.random.default_rng(5)
    for _ in range(10):
        q = _random_q(irb4600, rng, 0.5)
        for link in ("link_2", "link_4", "tool0", "base_link"):
            point = base_in_world[:3, 3] + rng.uniform(-1.0, 1.0, 3)
            local = _point_in_link(irb4600, base_in_world, q, link, point)
            J = cell_model.point_jacobian(q, link, point)
            J_fd = np.zeros((3, 6))
            for j in range(6):
                dq = np.zeros(6)
                dq[j] = 1e-6
                plus = (base_in_world @ irb4600.frame_pose(q + dq, link) @ local)[:3]
                minus = (base_in_world @ irb4600.frame_pose(q - dq, link) @ local)[:3]
                J_fd[:, j] = (plus - minus) / 2e-6
            np.testing.assert_allclose(J, J_fd, atol=1e-7)


def test_linearised_distance_predicts_the_change_for_a_small_joint_step(cell_model, irb4600):
    """Against the table, fixture, mesh part and the robot's own links, to first order. Pairs with
    a cylinder get FCL's GJK tolerance on top (its distances scatter by ~2e-5 m)."""
    rng = np.random.default_rng(6)
    checked = set()
    for _ in range(60):
        q = _random_q(irb4600, rng)
        contacts = [c for c in cell_model.contacts(q, 0.3) if abs(c.distance_m) > 1e-3]
        if not contacts:
            continue
        grads = cell_model.distance_gradients(q, contacts)
        dq = rng.normal(size=6)
        dq *= 1e-3 / np.linalg.norm(dq)
        after = {(c.body_shape, c.other_shape): c.distance_m for c in cell_model.contacts(q + dq, np.inf)}
        for c, g in zip(contacts, grads, strict=True):
            J_other = cell_model.point_jacobian(q, c.other_link, c.point_other) if c.other_link else None
            J_body = cell_model.point_jacobian(q, c.link, c.point_body)
            np.testing.assert_allclose(g, linearised_distance(c, J_body, J_other), atol=1e-12)
            change = after[(c.body_shape, c.other_shape)] - c.distance_m
            noise = 5e-5 if {c.body_shape, c.other_shape} & _CYLINDERS else 2e-6
            assert change == pytest.approx(g @ dq, abs=noise + 0.05 * abs(g @ dq)), (c.body, c.other)
            checked.add(c.other if not c.self_pair else "self")
    assert {"table", "fixture", "part", "self"} <= checked


_CYLINDERS = {"foot", "column", "forearm", "wrist", "flange", "nozzle"}


def _cylinder_surface(radius: float, length: float) -> np.ndarray:
    """Points on a cylinder's side (every 0.25 deg, 0.8 mm) and caps, in its frame (axis z) [m]."""
    theta = np.linspace(0.0, 2.0 * np.pi, 1441)[:-1]
    t, z = (a.ravel() for a in np.meshgrid(theta, np.linspace(-length / 2, length / 2, 801), indexing="ij"))
    points = [np.column_stack([radius * np.cos(t), radius * np.sin(t), z])]
    r, t = (a.ravel() for a in np.meshgrid(np.linspace(0.0, radius, 61), theta, indexing="ij"))
    for zc in (-length / 2, length / 2):
        points.append(np.column_stack([r * np.cos(t), r * np.sin(t), np.full(len(r), zc)]))
    return np.vstack(points)


def test_a_distance_fcl_gets_wrong_is_caught_by_the_separating_plane_check(cell_model, irb4600):
    """At this pose FCL's GJK reports the forearm 0.245 m from the upper arm; they are 0.150 m apart.

    The expectation is derived here: points sampled densely on the forearm cylinder's surface, each
    measured to the upper-arm box in closed form. Their least distance is an upper bound of the true
    one and, at this sampling, within 0.1 mm of it.
    """
    q = np.array([1.04542250, -0.21382341, -0.16175982, 0.72269328, 1.17899150, -0.12432522])
    (c,) = [
        c for c in cell_model.contacts(q, np.inf) if (c.body_shape, c.other_shape) == ("forearm", "upper_arm")
    ]
    shapes = {(s.link, s.name): s for s in irb4600.collision_shapes()}
    forearm, upper_arm = shapes[("link_4", "forearm")], shapes[("link_2", "upper_arm")]
    poses = irb4600.link_poses(q)
    T_f = poses["link_4"] @ forearm.link_T_shape
    T_u = poses["link_2"] @ upper_arm.link_T_shape
    points = _cylinder_surface(forearm.geometry.radius, forearm.geometry.lz) @ T_f[:3, :3].T + T_f[:3, 3]
    in_box = (points - T_u[:3, 3]) @ T_u[:3, :3]
    outside = np.maximum(np.abs(in_box) - 0.5 * np.asarray(upper_arm.geometry.side), 0.0)
    sampled = np.linalg.norm(outside, axis=1).min()
    assert 0.14 < sampled < 0.16  # the pose is the one the docstring describes
    assert sampled - 1e-4 <= c.distance_m <= sampled + 1e-9
    assert np.linalg.norm(c.point_body - c.point_other) == pytest.approx(c.distance_m, abs=1e-9)


def test_bad_inputs_are_named(irb4600, make_model, table_cell):
    with pytest.raises(InputError, match="table"):
        make_model(irb4600, table_cell + (Shape("table", "sphere", radius_m=0.1),))
    with pytest.raises(InputError, match="link_3"):
        make_model(irb4600, (Shape("link_3", "sphere", radius_m=0.1),))
    with pytest.raises(InputError, match="margin_m"):
        make_model(irb4600, margin_m=-0.01)
    model = make_model(irb4600)
    with pytest.raises(InputError, match="q must be 6"):
        model.contacts(np.zeros(5), 0.1)
    with pytest.raises(InputError, match="no link 'link_9'"):
        model.point_jacobian(np.zeros(6), "link_9", np.zeros(3))
    with pytest.raises(InputError, match="not found"):
        make_model(irb4600, (Shape("part", "mesh", file="/nonexistent/part.stl"),))


def test_the_gap_along_a_witness_normal_bounds_the_distance_and_meets_it_where_it_was_taken(
    irb4600, nozzle, make_model
):
    """For convex bodies the gap along any direction is at most their distance, and along the
    witness normal of a query it is the distance (the separating plane theorem). FCL's distance is
    the reference, at the query's configuration and after a small move of every joint."""
    model = make_model(irb4600, tool=(nozzle,))
    bounded = [k for k in range(len(model.pairs)) if model._bounded[k]]
    assert bounded
    rng = np.random.default_rng(5)
    tight = moved = 0
    for _ in range(8):
        q = _random_q(irb4600, rng, 0.4)
        for k in bounded[:: max(1, len(bounded) // 12)]:
            d = model.pair_distance(q, k)
            if d <= 1e-3:
                continue
            here = model._plane_bound(k)
            assert d - 2e-5 <= here <= d + 1e-9, (model.pairs[k], d, here)  # GJK stops within ~1e-6
            tight += 1
            q2 = q + rng.normal(0.0, np.radians(2.0), q.shape)
            bound, _ = model.pair_bound(q2, k, plane=True)
            assert bound <= model.pair_distance(q2, k) + 1e-9, model.pairs[k]
            model.pair_distance(q, k)  # back to the first configuration for the next pair
            moved += 1
    assert tight >= 20 and moved >= 20


def test_threads_placing_one_model_get_each_their_own_joints_poses(cell_model, base_in_world):
    """Eight threads call ``moving_poses`` on one model at once, with single rows (Pinocchio's loop)
    and paths long enough to be kept: every answer is the bodies' poses from a Pinocchio data of
    the test's own (``oMf`` of the body's frame), the threads switching every microsecond."""
    import sys
    import threading

    import pinocchio as pin

    model = cell_model
    moving = [b for b in model.bodies if b.kind != "cell"]
    pm = model.robot.model
    rng = np.random.default_rng(11)
    paths = [[_random_q(model.robot, rng, 0.5)[None] for _ in range(6)] for _ in range(8)]
    paths = [
        rows + [np.vstack([_random_q(model.robot, rng, 0.5) for _ in range(120)]) for _ in range(3)]
        for rows in paths
    ]

    def expected(qs):
        data = pm.createData()
        out = np.empty((len(qs), len(moving), 4, 4))
        for k, q in enumerate(qs):
            pin.framesForwardKinematics(pm, data, q)
            out[k] = [base_in_world @ data.oMf[b.frame_id].homogeneous @ b.link_T_shape for b in moving]
        return out

    truth = [[expected(qs) for qs in rows] for rows in paths]
    got: dict[int, list] = {}
    errors: list[BaseException] = []

    def work(i):
        try:
            got[i] = [np.array(model.moving_poses(qs)) for _ in range(20) for qs in paths[i]]
        except BaseException as e:  # noqa: BLE001 - handed to the main thread
            errors.append(e)

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        threads = [threading.Thread(target=work, args=(i,)) for i in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        sys.setswitchinterval(interval)
    assert not errors, errors
    for i, rows in enumerate(truth):
        for k, poses in enumerate(got[i]):
            np.testing.assert_allclose(poses, rows[k % len(rows)], atol=1e-12, rtol=0.0)


def _world_boxes(model, robot, base, q):
    """World-aligned boxes (low and high corners) [m] of every body at joints q, from Pinocchio and
    each body's box corners."""
    import pinocchio as pin

    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    lo, hi = [], []
    signs = np.array(list(np.ndindex(2, 2, 2))) * 2.0 - 1.0
    for b in model.bodies:
        T = b.link_T_shape if b.kind == "cell" else base @ data.oMf[b.frame_id].homogeneous @ b.link_T_shape
        corners = (b.centre + signs * b.half_extent) @ T[:3, :3].T + T[:3, 3]
        lo.append(corners.min(axis=0))
        hi.append(corners.max(axis=0))
    return np.array(lo), np.array(hi)


def _box_gaps(model, robot, base, q):
    """Every pair's box gap [m] at joints q (P,), -inf where the boxes overlap: the brute-force reference."""
    lo, hi = _world_boxes(model, robot, base, q)
    index = {b.label: i for i, b in enumerate(model.bodies)}
    out = []
    for a, b in model.pairs:
        i, j = index[a], index[b]
        gap = np.linalg.norm(np.maximum(0.0, np.maximum(lo[j] - hi[i], lo[i] - hi[j])))
        out.append(gap if gap > 0.0 else -np.inf)
    return np.array(out)


def test_the_box_bounds_kept_with_a_paths_poses_are_its_own_and_not_another_paths_or_cells(
    irb4600, table_cell, nozzle, base_in_world, make_model
):
    """The box bounds of the poses :meth:`moving_poses` keeps for a path are given again (read-only)
    for the same joints; another path, a pair subset, or a model whose fixture moved gets its own.
    Reference: boxes around each body's box corners placed by Pinocchio, gap by gap."""
    rng = np.random.default_rng(3)
    q1 = np.radians(NEAR_TABLE_DEG) + rng.normal(0.0, 0.05, (6, 6))
    q2 = q1 + 0.1
    model = make_model(irb4600, table_cell, (nozzle,), base=base_in_world)
    boxes = model.box_bounds(model.moving_poses(q1))
    assert not boxes.flags.writeable
    assert model.box_bounds(model.moving_poses(q1.copy())) is boxes  # the same joints: the same answer
    for q, found in ((q1, boxes), (q2, model.box_bounds(model.moving_poses(q2)))):
        want = np.array([_box_gaps(model, irb4600, base_in_world, qk) for qk in q])
        np.testing.assert_array_equal(np.isinf(found), np.isinf(want))
        np.testing.assert_allclose(found[np.isfinite(want)], want[np.isfinite(want)], rtol=0.0, atol=1e-9)
    columns = np.array([0, len(model.pairs) - 1, 3])
    subset = model.box_bounds(model.moving_poses(q2), columns)
    np.testing.assert_array_equal(subset, model.box_bounds(model.moving_poses(q2))[:, columns])
    moved = tuple(
        replace(s, pose=make_transform(p=[1.3, 0.35, 0.62])) if s.name == "fixture" else s for s in table_cell
    )
    other = make_model(irb4600, moved, (nozzle,), base=base_in_world)
    found = other.box_bounds(other.moving_poses(q1))
    want = np.array([_box_gaps(other, irb4600, base_in_world, qk) for qk in q1])
    np.testing.assert_array_equal(np.isinf(found), np.isinf(want))
    np.testing.assert_allclose(found[np.isfinite(want)], want[np.isfinite(want)], rtol=0.0, atol=1e-9)
    fixture = [k for k, pair in enumerate(model.pairs) if "fixture" in pair]
    assert not np.array_equal(found[:, fixture], boxes[:, fixture])


def test_the_nearest_pairs_are_those_of_a_check_of_every_pair_near_the_table(
    irb4600, table_cell, nozzle, base_in_world, make_model
):
    """The pair of least distance and the pair of least clearance the search finds, on a model kept
    from one pose to the next (witness normals of the last pose in play), are those of measuring
    every pair: each pair's distance from a model of its own, the least taken by hand."""
    rng = np.random.default_rng(8)
    model = make_model(irb4600, table_cell, (nozzle,), base=base_in_world)
    for _ in range(25):
        q = np.radians(NEAR_TABLE_DEG) + rng.normal(0.0, 0.08, 6)
        fresh = make_model(irb4600, table_cell, (nozzle,), base=base_in_world)
        every = [fresh.pair_distance(q, p) for p in range(len(fresh.pairs))]
        kinds = {b.label: b.kind for b in fresh.bodies}  # a pair with a cell body keeps the cell margin
        margins = [
            fresh.margin_m if "cell" in (kinds[a], kinds[b]) else fresh.self_margin_m for a, b in fresh.pairs
        ]
        by_distance, by_clearance = model.nearest_pairs(q)
        assert by_distance.distance_m == pytest.approx(min(every), abs=1e-12)
        assert by_clearance.clearance_m == pytest.approx(
            min(d - m for d, m in zip(every, margins, strict=True)), abs=1e-12
        )


@pytest.mark.parametrize("clash", ["link_3", "table"])
def test_a_cell_object_named_as_a_robot_link_or_another_object_is_an_input_error_naming_it(irb4600, clash):
    def model(*cell):
        return CollisionModel(irb4600, np.eye(4), np.eye(4), (), cell, margin_m=0.01, self_margin_m=0.005)

    table = Shape("table", "box", make_transform(p=[1.5, 0.0, -0.3]), size_m=(1.0, 1.0, 0.1))
    assert "link_3" in {b.name for b in model(table).bodies if b.kind == "link"}
    with pytest.raises(InputError, match=f"the name '{clash}' is used twice"):
        model(table, Shape(clash, "box", make_transform(p=[1.5, 1.5, -0.3]), size_m=(0.2, 0.2, 0.2)))
