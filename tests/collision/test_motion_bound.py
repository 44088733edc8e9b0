"""The per-pair motion bound of the dense check, against motion measured independently.

The references here are built from the robots' own collision shapes (python-fcl objects placed
with Pinocchio frame poses) and plain FCL distance queries at many points along a segment; nothing
from the checker's helpers.
"""

from __future__ import annotations

import fcl
import numpy as np
import pinocchio as pin
import pytest

from refine.collision import CollisionModel, check_path_clearance
from refine.frames import make_transform
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot
from refine.settings import Shape

ROBOTS = ("ur10e", "abb_irb4600_60_205", "kuka_iiwa14_r820")
TCP = make_transform(p=[0.0, 0.0, 0.2])
MARGIN = 0.01


def _q_along(q0, q1, t):
    return q0 + np.asarray(t)[:, None] * (q1 - q0)


def _frame_poses(robot, qs, link):
    """World poses (T, 4, 4) of ``link`` along joint rows qs, straight from Pinocchio."""
    model, data = robot.model, robot.model.createData()
    fid = model.getFrameId(link)
    out = []
    for q in qs:
        pin.forwardKinematics(model, data, q)
        out.append(pin.updateFramePlacement(model, data, fid).homogeneous.copy())
    return np.array(out)


def _shape_points(body):
    """Points whose convex hull holds the body, in its shape frame."""
    if body.kind_params[0] == "convex":
        return np.asarray(body.kind_params[1])
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    return body.centre + corners * body.half_extent


TORCH = Shape("torch", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.1]), radius_m=0.02, length_m=0.2)
FAR = Shape("far", "box", pose=make_transform(p=[50.0, 0.0, 0.0]), size_m=(0.1, 0.1, 0.1))


@pytest.fixture(scope="module", params=ROBOTS)
def arm(request):
    """A robot with a torch, and a cell box far away (so every moving body has a cell pair)."""
    robot = load_robot(request.param)
    model = CollisionModel(robot, np.eye(4), TCP, (TORCH,), (FAR,), margin_m=MARGIN, self_margin_m=0.005)
    return robot, model


def test_no_point_of_a_pair_travels_further_relative_to_the_other_than_its_bound(arm):
    """Along random joint segments, the path length of every corner of a pair's first (distal) body
    as seen from the other body (from the world for a cell object) stays within the pair's bound."""
    robot, model = arm
    _within_bound(robot, model, np.random.default_rng(11))


def test_a_longer_torch_on_the_same_robot_gets_bounds_of_its_own(arm):
    """A second model on the same robot, its torch 0.6 m long where the first's is 0.2 m: its
    bounds are its own (the robot's links' as the first model's) and hold as the first's do."""
    robot, first = arm
    long_torch = Shape("torch", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.3]), radius_m=0.02, length_m=0.6)
    model = CollisionModel(robot, np.eye(4), TCP, (long_torch,), (FAR,), margin_m=MARGIN, self_margin_m=0.005)
    assert first.pairs == model.pairs
    tool = np.array(["tool:" in a for a, _ in model.pairs])
    assert np.array_equal(model.pair_motion[~tool], first.pair_motion[~tool])
    assert np.all(model.pair_motion[tool].sum(axis=1) > first.pair_motion[tool].sum(axis=1))
    _within_bound(robot, model, np.random.default_rng(12))


def _within_bound(robot, model, rng):
    lo, hi = robot.model.lowerPositionLimit, robot.model.upperPositionLimit
    bodies = {b.label: b for b in model.bodies}
    pairs = [(bodies[a], bodies[b]) for a, b in model.pairs]
    assert {a.label for a, b in pairs if b.kind == "cell"} == {
        b.label for b in model.bodies if b.kind != "cell" and b.joint > 0
    }
    motion = model.pair_motion
    assert motion.shape == (len(model.pairs), robot.nq)
    t = np.linspace(0.0, 1.0, 401)
    for _ in range(6):
        q0 = rng.uniform(np.maximum(lo, -2.5), np.minimum(hi, 2.5))
        q1 = np.clip(q0 + rng.normal(scale=0.4, size=robot.nq), lo, hi)
        qs = _q_along(q0, q1, t)
        poses = {
            body.label: _frame_poses(robot, qs, body.link) @ body.link_T_shape
            for body in model.bodies
            if body.kind != "cell"
        }
        for p, (a, b) in enumerate(pairs):
            bound = np.abs(q1 - q0) @ motion[p]
            frame = (
                np.repeat(np.eye(4)[None], len(t), axis=0)
                if b.kind == "cell"
                else np.linalg.inv(poses[b.label])
            )
            pts = _shape_points(a)
            world = poses[a.label][:, :3, :3] @ pts.T + poses[a.label][:, :3, 3:]  # (T, 3, K)
            rel = frame[:, :3, :3] @ world + frame[:, :3, 3:]
            travelled = np.sum(np.linalg.norm(np.diff(rel, axis=0), axis=1), axis=0)
            assert np.max(travelled) <= bound * (1 + 1e-9) + 1e-12, (robot.spec.name, a.label, b.label)


def _brute_force(robot, q0, q1, body, obstacle, steps=2000):
    """Least FCL distance between one moving body and a world obstacle at ``steps`` + 1 points."""
    t = np.linspace(0.0, 1.0, steps + 1)
    poses = _frame_poses(robot, _q_along(q0, q1, t), body.link) @ body.link_T_shape
    geometry = body.geometry
    least = np.inf
    request = fcl.DistanceRequest()
    for T in poses:
        obj = fcl.CollisionObject(geometry, fcl.Transform(T[:3, :3], T[:3, 3]))
        d = fcl.distance(obj, obstacle, request, fcl.DistanceResult())
        least = min(least, d)
    return least


@pytest.mark.parametrize("seed", range(4))
def test_a_link_passing_through_a_ball_only_between_two_clear_waypoints_is_found(seed):
    """A ball sits where a corner of a link's shape passes at mid-segment; both ends are clear of
    it by more than the margin. The check must report the segment, as fine sampling does."""
    robot = load_robot("ur10e")
    rng = np.random.default_rng(100 + seed)
    lo, hi = robot.model.lowerPositionLimit, robot.model.upperPositionLimit
    probe = CollisionModel(robot, np.eye(4), TCP, (), (), margin_m=MARGIN, self_margin_m=0.005)
    movers = [b for b in probe.bodies if b.kind == "link" and b.joint >= 3]
    for _ in range(200):
        q0 = rng.uniform(np.maximum(lo, -2.0), np.minimum(hi, 2.0))
        q1 = q0 + rng.choice([-1, 1], robot.nq) * rng.uniform(0.15, 0.35, robot.nq)
        body = movers[rng.integers(len(movers))]
        corner = _shape_points(body)[rng.integers(len(_shape_points(body)))]
        T_mid = _frame_poses(robot, [(q0 + q1) / 2], body.link)[0] @ body.link_T_shape
        centre = T_mid[:3, :3] @ corner + T_mid[:3, 3]
        ball = Shape("ball", "sphere", pose=make_transform(p=centre), radius_m=0.02)
        obstacle = fcl.CollisionObject(fcl.Sphere(0.02), fcl.Transform(np.eye(3), centre))
        ends = min(
            _brute_force(robot, q, q, b, obstacle, steps=0)
            for q in (q0, q1)
            for b in probe.bodies
            if b.kind == "link"
        )
        if ends > MARGIN + 0.01:
            break
    else:
        pytest.fail("no segment with clear ends found")
    assert _brute_force(robot, q0, q1, body, obstacle) < 0.0  # the reference: contact mid-segment
    model = CollisionModel(robot, np.eye(4), TCP, (), (ball,), margin_m=MARGIN, self_margin_m=0.005)
    kin = TcpKinematics(robot, np.eye(4), TCP)
    result = check_path_clearance(model, np.array([q0, q1]), kin, step_m=1.0)
    assert np.all(result.waypoint_clearance_m > 0.0)
    assert not result.ok and "ball" in result.runs[0].objects
    assert result.runs[0].min_clearance_m < 0.0


@pytest.mark.parametrize("robot_name", ROBOTS)
def test_the_verdict_agrees_with_fine_sampling_at_random_near_misses(robot_name):
    """Balls placed near the path of a shape corner, at random offsets: whenever fine sampling with
    plain FCL finds the margin broken, the check does too; when the check passes, fine sampling
    finds every sampled distance at least the margin (less the tolerance)."""
    robot = load_robot(robot_name)
    rng = np.random.default_rng(7)
    lo, hi = robot.model.lowerPositionLimit, robot.model.upperPositionLimit
    probe = CollisionModel(robot, np.eye(4), TCP, (), (), margin_m=MARGIN, self_margin_m=0.005)
    movers = [b for b in probe.bodies if b.kind == "link" and b.joint >= 2]
    kin = TcpKinematics(robot, np.eye(4), TCP)
    broken = kept = 0
    for _ in range(16):
        q0 = rng.uniform(np.maximum(lo, -2.0), np.minimum(hi, 2.0))
        q1 = np.clip(q0 + rng.normal(scale=0.15, size=robot.nq), lo, hi)
        body = movers[rng.integers(len(movers))]
        pts = _shape_points(body)
        s = rng.uniform(0.2, 0.8)
        T = _frame_poses(robot, [q0 + s * (q1 - q0)], body.link)[0] @ body.link_T_shape
        corner = pts[rng.integers(len(pts))]
        outward = corner - pts.mean(axis=0)  # off the shape, by up to 12 cm
        corner = corner + outward / np.linalg.norm(outward) * rng.uniform(0.0, 0.12)
        centre = T[:3, :3] @ corner + T[:3, 3]
        ball = Shape("ball", "sphere", pose=make_transform(p=centre), radius_m=0.015)
        obstacle = fcl.CollisionObject(fcl.Sphere(0.015), fcl.Transform(np.eye(3), centre))
        model = CollisionModel(robot, np.eye(4), TCP, (), (ball,), margin_m=MARGIN, self_margin_m=0.005)
        result = check_path_clearance(model, np.array([q0, q1]), kin, step_m=1.0)
        balls = [i for i, (a, b) in enumerate(model.pairs) if b == "ball"]
        reference = min(
            _brute_force(robot, q0, q1, model.bodies[model._pa[i]], obstacle, steps=400) for i in balls
        )
        ball_broken = any("ball" in r.objects for r in result.runs)
        if reference < MARGIN - 1e-4:
            assert ball_broken, (reference, result.summary())
            broken += 1
        if not ball_broken:
            assert reference >= MARGIN - 1e-4
            kept += 1
    assert broken >= 2 and kept >= 2  # both outcomes were exercised


@pytest.mark.parametrize(
    ("robot_name", "joint"), [("ur10e", 0), ("abb_irb4600_60_205", 0), ("kuka_iiwa14_r820", 1)]
)
def test_one_joint_swinging_the_torch_tip_through_a_ball_is_found(robot_name, joint):
    """One joint swings 0.8 rad; a ball sits where the torch tip passes at mid-swing, 20 cm
    or more from it at both ends. Here the bound is nearly tight (the arm is stretched, one joint
    moves), so a bound too small by half would certify the segment from its two ends alone."""
    robot = load_robot(robot_name)
    q_mid = np.zeros(robot.nq)
    q_mid[1 if joint == 0 else 3] = 0.3  # a slight bend: the tip off the swinging axis
    q0, q1 = q_mid.copy(), q_mid.copy()
    q0[joint], q1[joint] = -0.4, 0.4
    tip = _frame_poses(robot, [q_mid], robot.spec.flange_frame)[0] @ TCP
    centre = tip[:3, 3]
    ball = Shape("ball", "sphere", pose=make_transform(p=centre), radius_m=0.01)
    model = CollisionModel(robot, np.eye(4), TCP, (TORCH,), (ball,), margin_m=MARGIN, self_margin_m=0.005)
    torch = next(b for b in model.bodies if b.name == "tool:torch")
    obstacle = fcl.CollisionObject(fcl.Sphere(0.01), fcl.Transform(np.eye(3), centre))
    ends = [_brute_force(robot, q, q, torch, obstacle, steps=0) for q in (q0, q1)]
    assert min(ends) > 0.2 and _brute_force(robot, q0, q1, torch, obstacle) < 0.0
    result = check_path_clearance(
        model, np.array([q0, q1]), TcpKinematics(robot, np.eye(4), TCP), step_m=10.0
    )
    assert np.all(result.waypoint_clearance_m > 0.0)
    assert not result.ok and "ball" in result.runs[0].objects


def test_advancement_never_certifies_a_segment_where_some_motion_within_the_bound_breaks_the_margin():
    """The budget f(t) = slope |t - t*| - depth, slope <= S, changes no faster than S, as a pair's
    budget does, and dips below zero only around t*. Whatever t* and the depth, advancement must not certify
    [0, 1]; with the dip lifted above zero it must, within its sample limit."""
    from refine.collision.advance import MAX_ADVANCE, advance

    rng = np.random.default_rng(5)
    for _ in range(2000):
        S = rng.uniform(0.001, 0.1)
        t_star = rng.uniform(0.0, 1.0)
        depth = S * 10.0 ** rng.uniform(-4.0, -1.0)
        slope = S * rng.uniform(0.3, 1.0)
        calls = []

        def dip(t, slope=slope, t_star=t_star, depth=depth, calls=calls):
            calls.append(t)
            return slope * abs(t - t_star) - depth

        b0, b1 = dip(0.0), dip(1.0)
        if min(b0, b1) < 0.0:
            continue
        assert not advance(dip, b0, b1, S), (S, t_star, depth, calls)

        def lifted(t, slope=slope, t_star=t_star, S=S):
            return slope * abs(t - t_star) + 0.3 * S

        assert advance(lifted, lifted(0.0), lifted(1.0), S)
        assert len(calls) <= 2 + 2 * MAX_ADVANCE
