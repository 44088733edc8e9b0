"""The dense clearance check between waypoints."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

from refine.collision import check_path_clearance, joint_reach, margins_proved
from refine.errors import InputError
from refine.frames import make_transform
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot
from refine.settings import Shape

PILLAR = Shape("pillar", "box", pose=make_transform(p=[1.0, 0.0, 1.0]), size_m=(0.2, 0.2, 2.0))


@pytest.fixture(scope="module")
def pillar_model(irb4600, nozzle, make_model):
    return make_model(irb4600, (PILLAR,), (nozzle,))


def _swing(deg_from, deg_to, n=2):
    q = np.zeros((n, 6))
    q[:, 0] = np.radians(np.linspace(deg_from, deg_to, n))
    return q


def test_a_swing_through_a_pillar_between_two_clear_waypoints_is_found(pillar_model, kin):
    q = _swing(-45.0, 45.0)
    queries_before, start = pillar_model.queries, time.perf_counter()
    result = check_path_clearance(pillar_model, q, kin, step_m=0.01)
    wall_s = time.perf_counter() - start
    assert np.all(result.waypoint_clearance_m > 0.1)  # both waypoints are well clear
    assert not result.ok and len(result.runs) == 1
    run = result.runs[0]
    assert (run.index_start, run.index_end) == (0, 1)
    assert run.min_clearance_m < -0.05 and run.min_distance_m == pytest.approx(run.min_clearance_m + 0.01)
    assert "pillar" in run.objects and "link_4" in run.objects and "pillar" in run.worst_pair
    assert result.segment_pair[0] == run.worst_pair
    summary = result.summary()
    assert "waypoints 0-1" in summary and "pillar" in summary and "below the margin" in summary
    # every checked configuration (2 waypoints, m - 1 sub-steps) asks FCL for at least its nearest pair
    assert result.queries == pillar_model.queries - queries_before
    assert result.queries >= 2 + result.segment_samples[0] - 1
    assert 0.0 < result.time_s <= wall_s


def test_a_path_that_stays_clear_passes(pillar_model, kin):
    result = check_path_clearance(pillar_model, _swing(-80.0, -45.0, 5), kin, step_m=0.01)
    assert result.ok and not result.runs
    assert 0.0 < result.min_clearance_m < result.min_distance_m
    assert len(result.segment_distance_m) == 4 and len(result.waypoint_distance_m) == 5
    assert np.all(
        result.segment_distance_m
        <= np.minimum(result.waypoint_distance_m[:-1], result.waypoint_distance_m[1:]) + 1e-12
    )
    assert "every margin kept" in result.summary()


def test_runs_split_where_the_path_is_clear_again(pillar_model, kin):
    """Swinging through the pillar and back out the other way gives one run per pass."""
    q = _swing(0.0, 0.0, 4)
    q[:, 0] = np.radians([-45.0, 45.0, 90.0, -45.0])
    result = check_path_clearance(pillar_model, q, kin, step_m=0.02)
    assert [(r.index_start, r.index_end) for r in result.runs] == [(0, 1), (2, 3)]


def test_a_single_waypoint_in_collision_is_one_run(pillar_model, kin):
    result = check_path_clearance(pillar_model, _swing(0.0, 0.0, 1), kin, step_m=0.01)
    assert len(result.segment_distance_m) == 0
    assert [(r.index_start, r.index_end) for r in result.runs] == [(0, 0)]
    assert "pillar" in result.runs[0].objects


def test_sub_steps_bound_the_tcp_step_and_every_link_point_step(pillar_model, kin):
    q = np.array([[0.3, 0.2, -0.1, 0.5, 0.4, 0.0], [0.35, 0.25, -0.05, 0.6, 0.5, 2.0]])
    result = check_path_clearance(pillar_model, q, kin, step_m=0.004, link_step_m=0.005, method="sample")
    sweep = np.abs(q[1] - q[0]) @ joint_reach(pillar_model)
    assert result.segment_samples[0] >= sweep / 0.005


def test_the_tcp_moves_at_most_one_step_between_checks_on_a_curved_segment(pillar_model, kin):
    """A 60 deg swing of joint 1 moves the TCP on an arc 5 % longer than its chord."""
    q = _swing(-120.0, -60.0)
    step = 0.01
    result = check_path_clearance(pillar_model, q, kin, step_m=step, link_step_m=10.0, method="sample")
    m = int(result.segment_samples[0])
    chord = np.linalg.norm(np.diff(kin.poses(q)[:, :3, 3], axis=0))
    assert m > chord / step
    tcp = kin.poses(q[0] + np.linspace(0.0, 1.0, m + 1)[:, None] * (q[1] - q[0]))[:, :3, 3]
    assert np.max(np.linalg.norm(np.diff(tcp, axis=0), axis=1)) <= step


def test_a_wrist_flip_with_the_tcp_still_is_sampled_by_the_joint_bound(pillar_model, kin):
    """Joint 6 turns the tool about its own axis: the TCP stays put but the check still sub-steps."""
    q = np.zeros((2, 6))
    q[1, 5] = np.pi
    result = check_path_clearance(pillar_model, q, kin, step_m=0.001, method="sample")
    chord = np.linalg.norm(np.diff(kin.poses(q)[:, :3, 3], axis=0))
    assert chord < 1e-9 and result.segment_samples[0] > 10


def test_the_motion_bound_certifies_clear_segments_with_few_queries(pillar_model, kin):
    q = _swing(-80.0, -45.0, 8)
    bound = check_path_clearance(pillar_model, q, kin, step_m=0.001, method="bound")
    dense = check_path_clearance(pillar_model, q, kin, step_m=0.001, method="sample")
    assert bound.ok and dense.ok
    assert bound.certified_segments == 7 and dense.certified_segments == 0
    assert bound.queries < dense.queries / 5
    # the densely sampled least distance is never below the bound's figure minus twice the largest
    # body motion between the bound's samples (here, it is simply no lower than the margin)
    assert dense.min_clearance_m >= -1e-4


@pytest.mark.parametrize("offset", [0.04, 0.05, 0.06, 0.08, 0.11])
def test_the_bound_and_dense_sampling_agree_on_near_misses(offset, irb4600, nozzle, make_model, kin):
    """Joint 1 swings the nozzle past a 3 cm cube set ``offset`` beyond the nozzle's mid-swing axis.

    Contact needs an offset under 3 cm (nozzle radius) + 1.5 cm (half the cube) + 1 cm (margin), so
    the offsets straddle it: the motion bound's verdict equals that of sampling every 2 mm.
    """
    q = np.radians([[-50.0, 10, 10, 0, 60, 0], [50.0, 10, 10, 0, 60, 0]])
    T = kin.pose(q.mean(axis=0))
    centre = T[:3, 3] - 0.2 * T[:3, 2]  # on the nozzle axis, 0.15 m from the flange
    radial = np.array([centre[0], centre[1], 0.0]) / np.linalg.norm(centre[:2])
    cube = Shape("cube", "box", pose=make_transform(p=centre + offset * radial), size_m=(0.03, 0.03, 0.03))
    model = make_model(irb4600, (cube,), (nozzle,))
    bound = check_path_clearance(model, q, kin, step_m=0.1, method="bound")
    dense = check_path_clearance(model, q, kin, step_m=0.1, link_step_m=0.002, method="sample")
    assert bound.ok == dense.ok == (offset > 0.055)
    if offset > 0.065:
        assert bound.certified_segments == 1 and bound.queries < dense.queries / 3


def test_joint_reach_bounds_the_motion_of_every_body_point(pillar_model, irb4600):
    rng = np.random.default_rng(3)
    reach = joint_reach(pillar_model)
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
    for _ in range(20):
        q = rng.uniform(-2.0, 2.0, 6)
        dq = rng.normal(size=6) * 1e-3
        bound = np.abs(dq) @ reach
        for body in pillar_model.bodies:
            if body.kind == "cell":
                continue
            local = body.centre + corners * body.half_extent
            moved = [
                (irb4600.frame_pose(qq, body.link) @ body.link_T_shape)[:3, :3] @ local.T
                + (irb4600.frame_pose(qq, body.link) @ body.link_T_shape)[:3, 3:]
                for qq in (q, q + dq)
            ]
            assert np.max(np.linalg.norm(moved[1] - moved[0], axis=0)) <= bound + 1e-12, body.label


def test_bad_paths_are_rejected_naming_the_value(pillar_model, kin):
    with pytest.raises(InputError, match=r"q_path must be \(N, 6\)"):
        check_path_clearance(pillar_model, np.zeros((3, 5)), kin, step_m=0.01)
    with pytest.raises(InputError, match="step_m"):
        check_path_clearance(pillar_model, np.zeros((3, 6)), kin, step_m=0.0)
    with pytest.raises(InputError, match="method"):
        check_path_clearance(pillar_model, np.zeros((3, 6)), kin, step_m=0.01, method="fast")
    other_tool = TcpKinematics(kin.robot, kin.base_in_world, make_transform(p=[0.0, 0.0, 0.2]))
    with pytest.raises(InputError, match="tcp_in_flange"):
        check_path_clearance(pillar_model, np.zeros((3, 6)), other_tool, step_m=0.01)


def test_the_clearance_source_reuses_an_earlier_check_of_the_same_path(pillar_model, kin):
    """The solver may return a path it checked before another one; the report's figures then
    come from that check, without checking again."""
    from refine.optimise.clearance import ClearanceSource

    source = ClearanceSource(pillar_model, kin, 0.01)
    first, second = _swing(-80.0, -45.0, 5), _swing(-70.0, -40.0, 5)
    a = source.clearance(first)
    b = source.clearance(second)
    queries = pillar_model.queries
    assert source.clearance(first.copy()) is a and source.clearance(second) is b
    assert pillar_model.queries == queries and source.last is b
    assert source.clearance(_swing(-80.0, -45.0, 6)) is not a  # another path is checked


def test_the_proof_alone_proves_a_clear_swing_and_not_one_through_the_pillar(pillar_model, kin):
    """The pillar (x 0.9-1.1 m, |y| <= 0.1 m) subtends about 6 deg from the base: a swing of joint 1
    from -80 to -45 deg keeps the arm well away, a swing from -45 to 45 deg sweeps it through."""
    assert margins_proved(pillar_model, _swing(-80.0, -45.0, 8))
    assert not margins_proved(pillar_model, _swing(-45.0, 45.0))  # both waypoints clear, not between
    assert not margins_proved(pillar_model, _swing(-80.0, 45.0, 3))  # a clear segment, then through
    assert not margins_proved(pillar_model, _swing(0.0, 0.0, 1))  # one waypoint: decides nothing
    with pytest.raises(InputError, match=r"q_path must be \(N, 6\)"):
        margins_proved(pillar_model, np.zeros((3, 5)))


@pytest.mark.parametrize(("offset", "proved"), [(0.04, False), (0.05, False), (0.08, True), (0.11, True)])
def test_the_proof_alone_follows_the_near_miss_geometry(offset, proved, irb4600, nozzle, make_model, kin):
    """The nozzle (radius 3 cm) swings past a 3 cm cube: the margin of 1 cm breaks below 5.5 cm."""
    q = np.radians([[-50.0, 10, 10, 0, 60, 0], [50.0, 10, 10, 0, 60, 0]])
    T = kin.pose(q.mean(axis=0))
    centre = T[:3, 3] - 0.2 * T[:3, 2]
    radial = np.array([centre[0], centre[1], 0.0]) / np.linalg.norm(centre[:2])
    cube = Shape("cube", "box", pose=make_transform(p=centre + offset * radial), size_m=(0.03, 0.03, 0.03))
    assert margins_proved(make_model(irb4600, (cube,), (nozzle,)), q) is proved


def test_the_clearance_source_needs_no_dense_check_for_a_clear_seed(pillar_model, kin):
    """A seed proved clear gets no rows and no dense check; a seed that swings through the pillar
    between two clear waypoints gets a row inside that segment, as from the dense check."""
    from refine.optimise.clearance import ClearanceSource

    source = ClearanceSource(pillar_model, kin, 0.01)
    assert source.rows(None, _swing(-80.0, -45.0, 5)) == ()
    assert source.last is None  # proved without the dense check's figures
    rows = source.rows(None, _swing(-45.0, 45.0))
    assert source.last is not None and not source.last.ok
    assert any(r.k == 0 and r.f == 0.5 and "pillar" in r.label for r in rows)


def test_a_path_the_proof_alone_passes_keeps_its_margins_at_every_sample(irb4600, nozzle, make_model, kin):
    """Near misses of the nozzle and a 3 cm cube (contact below 5.5 cm offset, see above) at random
    offsets and wrist angles: on each path proved clear, every pair with the cube measured alone by
    FCL at samples 1 deg of joint 1 apart keeps the 1 cm margin; both verdicts occur."""
    rng = np.random.default_rng(7)
    verdicts = []
    for _ in range(10):
        ends = np.radians([[-50.0, 10, 10, 0, 60, 0], [50.0, 10, 10, 0, 60, 0]])
        ends[:, 3:] += np.radians(rng.uniform(-3.0, 3.0, 3))
        q = ends[0] + np.linspace(0.0, 1.0, 201)[:, None] * (ends[1] - ends[0])  # 0.5 deg apart
        T = kin.pose(q.mean(axis=0))
        centre = T[:3, 3] - 0.2 * T[:3, 2]
        radial = np.array([centre[0], centre[1], 0.0]) / np.linalg.norm(centre[:2])
        offset = rng.uniform(0.045, 0.1)
        cube = Shape(
            "cube", "box", pose=make_transform(p=centre + offset * radial), size_m=(0.03, 0.03, 0.03)
        )
        model = make_model(irb4600, (cube,), (nozzle,))
        proved = margins_proved(model, q)
        verdicts.append(proved)
        if proved:
            pairs = [k for k, pair in enumerate(model.pairs) if "cube" in pair]
            for t in np.linspace(0.0, 1.0, 101):
                qt = ends[0] + t * (ends[1] - ends[0])
                assert min(model.pair_distance(qt, k) for k in pairs) >= 0.01 - 1e-4, (offset, t)
    assert any(verdicts) and not all(verdicts)


@pytest.mark.parametrize("links", ["primitives", "convex pieces"])
def test_the_proofs_bounds_are_those_waypoint_by_waypoint_and_below_every_distance(
    links, irb4600, nozzle, make_model
):
    """The proof bounds the short pairs pair by pair along the path, the gaps along a normal taken
    at many waypoints at once, a pair measured where its gap does not keep its margin. Reference:
    a fresh model bounding the same pairs waypoint by waypoint (the gap along the pair's last
    normal, kept when above the margin, else FCL; ``pair_bound`` for a pair without a normal), and
    FCL's distance of every pair."""
    from refine.collision import advance
    from refine.collision import check as check_module

    sphere = Shape("ball", "sphere", pose=make_transform(p=[1.05, -0.3, 1.1]), radius_m=0.08)
    cell = (PILLAR, sphere)
    rng = np.random.default_rng(11)
    q = np.radians([-80.0, 5.0, 10.0, 0.0, 40.0, 0.0]) + np.linspace(0.0, 1.0, 40)[:, None] * np.radians(
        [70.0, 10.0, -5.0, 30.0, 20.0, 90.0]
    )
    q += rng.normal(0.0, np.radians(0.3), q.shape)
    robot = irb4600 if links == "primitives" else load_robot("abb_irb4600_60_205")
    model = make_model(robot, cell, (nozzle,))
    poses, boxes, bounds, exact = check_module._waypoint_bounds(model, q, 1e-4, True, plane=True)
    reference = make_model(robot, cell, (nozzle,))
    motion = advance.pair_motion(reference, q)
    short = advance.short(boxes - reference.pair_margins + 1e-4, motion)
    need = np.zeros(boxes.shape, dtype=bool)
    need[:-1] |= short
    need[1:] |= short
    assert need.sum() > 50  # the path passes close enough for many pairs to need more than boxes
    expected, expected_exact = boxes.copy(), np.zeros(boxes.shape, dtype=bool)
    margins = reference.pair_margins
    for k in range(len(q)):
        for p in np.flatnonzero(need[k]):
            gap = reference.plane_bounds(int(p), poses[k : k + 1])
            if gap is None:
                expected[k, p], expected_exact[k, p] = reference.pair_bound(
                    q[k], int(p), poses[k], plane=True
                )
            elif gap[0] > margins[p]:
                expected[k, p] = max(expected[k, p], gap[0])
            else:
                expected[k, p], expected_exact[k, p] = reference.pair_distance(q[k], int(p), poses[k]), True
    np.testing.assert_array_equal(exact, expected_exact)
    np.testing.assert_allclose(bounds, expected, rtol=0.0, atol=1e-12)
    truth = np.array([[reference.pair_distance(qk, p) for p in range(len(reference.pairs))] for qk in q])
    assert np.all(bounds <= truth + 1e-9)
    np.testing.assert_allclose(bounds[exact], truth[exact], atol=1e-12)


@pytest.mark.parametrize("kind", ["box", "sphere", "cylinder", "convex"])
def test_a_bodys_reach_at_many_poses_is_its_support_point_along_the_direction(
    kind, irb4600, nozzle, make_model
):
    box = Shape("b", "box", pose=make_transform(p=[1.0, 0.0, 0.5]), size_m=(0.2, 0.1, 0.4))
    ball = Shape("s", "sphere", pose=make_transform(p=[1.0, 0.0, 0.5]), radius_m=0.07)
    robot = load_robot("abb_irb4600_60_205") if kind == "convex" else irb4600  # links: convex pieces
    model = make_model(robot, (box, ball), (nozzle,))
    body = next(b for b in model.bodies if b.kind_params[0] == kind)
    rng = np.random.default_rng(2)
    from scipy.spatial.transform import Rotation

    turns = Rotation.random(25, random_state=3).as_matrix()
    Ts = np.array([make_transform(R, rng.normal(size=3)) for R in turns])
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    got = body.reach_many(Ts, direction)
    if kind == "convex":  # the corners placed in the world: the support is the furthest of them
        corners = body.kind_params[1]
        expected = [max(direction @ (T[:3, :3] @ c + T[:3, 3]) for c in corners) for T in Ts]
    else:
        expected = [direction @ body.support(T, direction) for T in Ts]
    np.testing.assert_allclose(got, expected, atol=1e-12)


@pytest.mark.parametrize(("offset", "proved"), [(0.05, False), (0.11, True)])
def test_the_proof_from_known_bounds_bounds_only_what_they_leave_short_and_follows_the_geometry(
    offset, proved, irb4600, nozzle, make_model, kin
):
    """The near miss above on a path of 20 waypoints whose closest pass falls between waypoints 9
    and 10 (both clear of the margin), from known bounds: FCL's distance of every pair at every
    waypoint, none (-inf) for the cube's pairs at waypoint 9, so only the two segments about it are
    left short. Reference: FCL's distance of the cube's pairs at 400 samples along the path (the
    margin of 1 cm broken below 5.5 cm, kept above)."""
    ends = np.radians([[-50.0, 10, 10, 0, 60, 0], [50.0, 10, 10, 0, 60, 0]])
    q = ends[0] + np.linspace(0.0, 1.0, 20)[:, None] * (ends[1] - ends[0])
    T = kin.pose(ends.mean(axis=0))
    centre = T[:3, 3] - 0.2 * T[:3, 2]
    radial = np.array([centre[0], centre[1], 0.0]) / np.linalg.norm(centre[:2])
    cube = Shape("cube", "box", pose=make_transform(p=centre + offset * radial), size_m=(0.03, 0.03, 0.03))
    model = make_model(irb4600, (cube,), (nozzle,))
    cubes = [k for k, pair in enumerate(model.pairs) if "cube" in pair]
    prior = np.array([[model.pair_distance(qk, p) for p in range(len(model.pairs))] for qk in q])
    assert prior[[9, 10]][:, cubes].min() > 0.01  # the waypoints keep the margin
    prior[9, cubes] = -np.inf
    samples = ends[0] + np.linspace(0.0, 1.0, 401)[:, None] * (ends[1] - ends[0])
    least = min(model.pair_distance(qt, k) for qt in samples for k in cubes)
    assert (least >= 0.01 - 1e-4) is proved
    assert margins_proved(model, q, prior=prior) is proved
    assert margins_proved(model, q, prior=prior, directions=np.full((*prior.shape, 3), np.nan)) is proved
