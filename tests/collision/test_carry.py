"""The dense check from known bounds and witness directions against every waypoint measured."""

from pathlib import Path

import numpy as np
import pytest

import refine
from refine.collision import carry, check_path_clearance
from refine.collision.carry import (
    carried_bounds,
    carried_directions,
    checked_bounds,
    direction_bounds,
    measure_least,
    settled_pairs,
)
from refine.frames import make_transform
from refine.optimise.clearance import ClearanceSource
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot
from refine.run.stages import fused_path
from refine.settings import Shape

ROOT = Path(__file__).resolve().parents[2]
TCP = make_transform(p=[0.0, 0.0, 0.35])


def every_pair(model, q):
    """FCL's distance of every checked pair at every waypoint (N, P) [m]: the brute-force reference."""
    return np.array([[model.pair_distance(qk, p) for p in range(len(model.pairs))] for qk in q])


def least(model, truth):
    """The least distance and the least clearance over the waypoints, with the pairs that hold them."""
    clear = truth - model.pair_margins
    kd, pd = np.unravel_index(int(np.argmin(truth)), truth.shape)
    kc, pc = np.unravel_index(int(np.argmin(clear)), clear.shape)
    return float(truth[kd, pd]), model.pairs[pd], float(clear[kc, pc]), model.pairs[pc]


def reported(check):
    """The same four from a check: its waypoint figures and the pair of its least clearance."""
    k = int(np.argmin(check.waypoint_clearance_m))
    seg = int(np.argmin(check.segment_clearance_m))
    return (
        float(check.waypoint_distance_m.min()),
        float(check.waypoint_clearance_m[k]),
        check.segment_pair[seg],
    )


def cell(shift_m=0.0):
    """A pillar about 5 cm and a ball about 3 cm from the random path's robot, and a nozzle."""
    pillar = Shape(
        "pillar", "box", pose=make_transform(p=[1.5 + shift_m, -0.65, 1.0]), size_m=(0.2, 0.2, 2.0)
    )
    ball = Shape("ball", "sphere", pose=make_transform(p=[1.45, -0.5, 0.5]), radius_m=0.08)
    nozzle = Shape("nozzle", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.15]), radius_m=0.03, length_m=0.3)
    return (pillar, ball), (nozzle,)


def random_path(n=60, seed=4):
    """A random walk of the IRB 4600's joints past a pillar: about 0.6 deg per joint per step."""
    rng = np.random.default_rng(seed)
    start = np.radians([-35.0, 20.0, 15.0, 10.0, 50.0, 30.0])
    return start + np.cumsum(rng.normal(0.0, np.radians(0.6), (n, 6)), axis=0)


def witness_normals(model, q):
    """FCL's witness normal of every pair at every waypoint of ``q`` (N, P, 3)."""
    normals = np.full((len(q), len(model.pairs), 3), np.nan)
    for k, qk in enumerate(q):
        for p in range(len(model.pairs)):
            model.pair_distance(qk, p)
        for p, (_, n) in model.witnesses(qk).items():
            normals[k, p] = n
    return normals


def random_configurations():
    """A model of the robot by the pillar and ball, a random path of 30 waypoints and FCL's distances."""
    shapes, tool = cell()
    model = refine.collision.CollisionModel(
        load_robot("abb_irb4600_60_205"), np.eye(4), TCP, tool, shapes, margin_m=0.01, self_margin_m=0.005
    )
    q = random_path(30, seed=2)
    return model, q, every_pair(model, q)


@pytest.mark.parametrize("margin_m", [0.01, None])
def test_a_check_from_carried_bounds_and_directions_reports_what_measuring_every_waypoint_does(
    margin_m, monkeypatch
):
    """A random joint path checked, then moved by up to 0.3 deg per joint with the pillar 3 mm away:
    the check of the moved path from the first check's bounds and witness normals reports the least
    distance, the least clearance, the pair of the least clearance and the runs below the margin
    that a check measuring every waypoint reports, and those equal FCL's distances of every pair at
    every waypoint. ``None``: a margin 5 mm above the least distance, so that runs are broken. Some
    pairs are settled by their carried bounds (certified alone, far above the least) and keep them;
    the same check with none settled reports the same figures, runs and proved segments."""
    robot = load_robot("abb_irb4600_60_205")
    q0 = random_path()
    q1 = q0 + np.random.default_rng(8).uniform(-1.0, 1.0, q0.shape) * np.radians(0.3)
    shapes, tool = cell()
    moved, _ = cell(0.003)
    kin = TcpKinematics(robot, np.eye(4), TCP)

    def model_of(objects, margin):
        return refine.collision.CollisionModel(
            robot, np.eye(4), TCP, tool, objects, margin_m=margin, self_margin_m=0.005
        )

    truth = every_pair(model_of(moved, 0.01), q1)
    cell_pairs = [
        p for p, pair in enumerate(model_of(moved, 0.01).pairs) if "pillar" in pair or "ball" in pair
    ]
    margin = 0.01 if margin_m is not None else float(truth[:, cell_pairs].min()) + 0.005
    first = check_path_clearance(model_of(shapes, margin), q0, kin, 0.005)
    assert first.bounds is not None and first.bounds.normals is not None
    after = model_of(moved, margin)
    prior = carried_bounds(after, first.bounds, q1)
    directions = carried_directions(after, first.bounds, q1)
    assert prior is not None and directions is not None
    before = after.queries
    warm = check_path_clearance(after, q1, kin, 0.005, prior=prior, directions=directions)
    warm_queries = after.queries - before
    cold_model = model_of(moved, margin)
    cold = check_path_clearance(cold_model, q1, kin, 0.005)
    assert warm.waypoint_measured is not None and warm.waypoint_measured.sum() < len(q1)
    d, d_pair, c, c_pair = least(cold_model, truth)
    got_d, got_c, got_pair = reported(warm)
    assert got_d == pytest.approx(d, abs=1e-12) and got_c == pytest.approx(c, abs=1e-12)
    assert (cold.min_distance_m, cold.min_clearance_m) == pytest.approx(
        (warm.min_distance_m, warm.min_clearance_m), abs=1e-12
    )
    k = int(np.argmin(warm.waypoint_clearance_m))
    assert warm.waypoint_measured[k] and (truth[k] - cold_model.pair_margins).min() == pytest.approx(
        c, abs=1e-12
    )
    assert cold.segment_pair[int(np.argmin(cold.segment_clearance_m))] == got_pair
    names = {b.label: b.name for b in after.bodies}
    assert got_pair == (names[c_pair[0]], names[c_pair[1]])
    assert [r.describe() for r in warm.runs] == [r.describe() for r in cold.runs]
    assert bool(warm.runs) == (margin_m is None)
    # every figure not measured is a lower bound, and every bound the check keeps is below FCL's distance
    assert np.all(warm.waypoint_distance_m <= truth.min(axis=1) + 1e-12)
    assert np.all(warm.bounds.bounds <= truth + 1e-9)
    assert warm_queries < cold.queries
    # the directions alone (no carried bound: another base, say) give the same figures
    alone = check_path_clearance(model_of(moved, margin), q1, kin, 0.005, directions=directions)
    assert alone.waypoint_measured is not None
    assert reported(alone)[:2] == pytest.approx((d, c), abs=1e-12) and reported(alone)[2] == got_pair
    assert [r.describe() for r in alone.runs] == [r.describe() for r in cold.runs]
    settled = settled_pairs(after, q1, prior, 1e-4)
    assert settled.any() and not settled.all()
    assert np.array_equal(warm.bounds.bounds[:, settled], prior[:, settled])
    monkeypatch.setattr(carry, "SETTLED_M", np.inf)
    unsettled = check_path_clearance(
        model_of(moved, margin), q1, kin, 0.005, prior=prior, directions=directions
    )
    assert (unsettled.min_distance_m, unsettled.min_clearance_m) == (
        warm.min_distance_m,
        warm.min_clearance_m,
    )
    assert reported(unsettled) == reported(warm) and unsettled.certified_segments == warm.certified_segments
    assert [r.describe() for r in unsettled.runs] == [r.describe() for r in warm.runs]


def test_the_gap_along_any_direction_bounds_every_distance_and_along_the_witness_normal_nearly_equals_it():
    """At random configurations: the gap along random unit directions never exceeds FCL's distance;
    along the pair's witness normal measured at joints up to 0.2 deg away it is within 50 um of it
    for half the pairs and within 5 mm for all (where the nearest features change, the normal
    turns faster than the joints)."""
    model, q, truth = random_configurations()
    rng = np.random.default_rng(1)
    poses = model.moving_poses(q)
    random = rng.normal(size=(len(q), len(model.pairs), 3))
    random /= np.linalg.norm(random, axis=2, keepdims=True)
    bounds = direction_bounds(model, poses, random)
    assert np.isfinite(bounds).sum() > 100  # many directions separate the pair
    assert np.all(bounds <= truth + 1e-9)
    near = q + rng.uniform(-1.0, 1.0, q.shape) * np.radians(0.2)
    normals = witness_normals(model, near)
    tight = direction_bounds(model, poses, normals)
    assert np.all(tight <= truth + 1e-9)
    apart = truth > 0.02
    assert np.isfinite(tight[apart]).all()
    short = (truth - tight)[apart]
    assert np.median(short) <= 5e-5 and short.max() <= 5e-3


def test_carried_directions_take_the_nearest_waypoints_normal_and_follow_the_pairs_by_name():
    robot = load_robot("abb_irb4600_60_205")
    shapes, tool = cell()
    model = refine.collision.CollisionModel(
        robot, np.eye(4), TCP, tool, shapes, margin_m=0.01, self_margin_m=0.005
    )
    q = random_path(6)
    normals = np.full((6, len(model.pairs), 3), np.nan)
    normals[1, 0] = [1.0, 0.0, 0.0]
    normals[4, 0] = [0.0, 1.0, 0.0]
    checked = checked_bounds(model, q, np.zeros((6, len(model.pairs))), normals)
    got = carried_directions(model, checked, q)
    # waypoints 0-2 nearest to 1, 3-5 nearest to 4 (a tie at 2.5 does not arise with integers)
    assert got[:3, 0].tolist() == [[1.0, 0.0, 0.0]] * 3 and got[3:, 0].tolist() == [[0.0, 1.0, 0.0]] * 3
    assert np.isnan(got[:, 1:]).all()
    # without the ball: the pillar's pairs keep their columns by name
    fewer = refine.collision.CollisionModel(
        robot, np.eye(4), TCP, tool, shapes[:1], margin_m=0.01, self_margin_m=0.005
    )
    assert fewer.pairs[0] == model.pairs[0]
    assert np.array_equal(carried_directions(fewer, checked, q)[:, 0], got[:, 0])
    assert carried_directions(model, checked, q[:5]) is None


def test_carried_directions_on_random_masks_are_the_brute_force_nearest_with_ties_to_the_earlier():
    """Normals known at random waypoints of each pair (some pairs none, some one, one all but a
    tie-making gap): every waypoint takes the normal at the nearest known waypoint, the earlier of
    two as near, found by a plain search over every known waypoint."""
    from types import SimpleNamespace

    from refine.collision.carry import CheckedBounds

    rng = np.random.default_rng(3)
    n, pairs = 30, [(f"a{i}", f"b{i}") for i in range(7)]
    normals = rng.normal(size=(n, len(pairs), 3))
    mask = rng.random((n, len(pairs))) < 0.15
    mask[:, 0] = False  # no normal at all
    mask[:, 1] = False
    mask[17, 1] = True  # a single one
    mask[:, 2] = True
    mask[10, 2] = False  # 9 and 11 equally near 10: the earlier
    mask[[3, 5], 3] = True
    mask[4, 3] = False
    normals[~mask] = np.nan
    prior = CheckedBounds(np.zeros((n, 6)), tuple(pairs), np.zeros((n, len(pairs))), {}, np.eye(4), normals)
    model = SimpleNamespace(pairs=[pairs[i] for i in (4, 2, 0, 6, 1, 3, 5)] + [("new", "pair")])
    got = carried_directions(model, prior, np.zeros((n, 6)))
    for p, pair in enumerate(model.pairs):
        k = pairs.index(pair) if pair in pairs else None
        known = [] if k is None else [j for j in range(n) if mask[j, k]]
        for row in range(n):
            if not known:
                assert np.isnan(got[row, p]).all()
                continue
            near = min(known, key=lambda j: (abs(j - row), j))
            assert np.array_equal(got[row, p], normals[near, k]), (pair, row)
    assert np.array_equal(got[10, model.pairs.index(pairs[2])], normals[9, 2])
    assert np.array_equal(got[4, model.pairs.index(pairs[3])], normals[3, 3])


def test_measure_least_with_tightened_and_raised_bounds_stays_exact():
    """Random distances and bounds up to 1 cm under them; each measurement raises its neighbours'
    bounds to within 0.1 mm of the truth, and a tightening raises the rest to within 1 mm once: the
    least figures are those of every waypoint, with fewer waypoints measured than without."""
    rng = np.random.default_rng(7)
    truth = rng.uniform(0.02, 0.06, (200, 3))
    margins = np.array([0.01, 0.01, 0.005])
    plain = truth - rng.uniform(0.0, 0.01, truth.shape)
    bounds = plain.copy()

    def measure(k):
        near = slice(max(k - 5, 0), k + 6)
        bounds[near] = np.maximum(bounds[near], truth[near] - 1e-4)
        bounds[k] = truth[k]
        return float(truth[k].min()), float((truth[k] - margins).min())

    tightened = []

    def tighten(k):
        if tightened:
            return False
        tightened.append(k)
        np.maximum(bounds, truth - 1e-3, out=bounds)
        return True

    measured = measure_least(bounds, margins, measure, window=5, tighten=tighten)
    assert np.all(bounds <= truth)
    seen = np.flatnonzero(measured)
    assert min(truth[k].min() for k in seen) == truth.min()
    assert min((truth[k] - margins).min() for k in seen) == (truth - margins).min()
    before = plain.copy()
    again = measure_least(
        before, margins, lambda k: (float(truth[k].min()), float((truth[k] - margins).min()))
    )
    assert measured.sum() < again.sum()


def test_the_warm_glass_check_reports_the_least_distance_and_pair_of_every_waypoint_measured(glass_shift):
    """The glass cell's part moved 2 mm and turned 0.3 deg, re-solved from the first answer: the warm
    dense check (from the first check's bounds and witness normals, a few waypoints measured)
    reports the least distance, the least clearance and its pair that FCL gives over every pair at
    every waypoint of the answer's joints."""
    s = glass_shift
    warm = refine.refine_path("abb_irb4600_60_205", s.positions, s.orientations, previous=s.first, **s.part)
    assert warm.status == "ok"
    check = warm.run.first.clearance
    assert check.waypoint_measured is not None and check.waypoint_measured.sum() < 60
    assert np.array_equal(check.bounds.q, warm.joints)
    model = ClearanceSource.for_problem(warm.run.problem, warm.run.robot).model
    truth = every_pair(model, warm.joints)
    d, d_pair, c, c_pair = least(model, truth)
    got_d, got_c, got_pair = reported(check)
    assert got_d == pytest.approx(d, abs=1e-12) and got_c == pytest.approx(c, abs=1e-12)
    k = int(np.argmin(check.waypoint_clearance_m))
    assert check.segment_pair[int(np.argmin(check.segment_clearance_m))] == got_pair
    names = {b.label: b.name for b in model.bodies}
    assert got_pair == (names[c_pair[0]], names[c_pair[1]]) and check.waypoint_measured[k]
    assert np.all(check.bounds.bounds <= truth + 1e-9)


@pytest.mark.parametrize("margin_m", [0.01, 0.034])
def test_a_check_measuring_only_the_waypoints_that_can_hold_the_least_reports_the_full_checks_figures(
    margin_m,
):
    """``every_waypoint=False`` (the planned motions' lines) on the random path, with a margin kept
    and one broken at some waypoints: the least distance, the least clearance, its pair and the runs
    are those of the check measuring every waypoint, with fewer FCL queries."""
    robot = load_robot("abb_irb4600_60_205")
    shapes, tool = cell()
    q = random_path()
    kin = TcpKinematics(robot, np.eye(4), TCP)

    def check(every):
        model = refine.collision.CollisionModel(
            robot, np.eye(4), TCP, tool, shapes, margin_m=margin_m, self_margin_m=0.005
        )
        return check_path_clearance(model, q, kin, 0.005, every_waypoint=every)

    full, least_only = check(True), check(False)
    assert least_only.waypoint_measured is not None and least_only.waypoint_measured.sum() < len(q)
    assert least_only.min_distance_m == full.min_distance_m
    assert least_only.min_clearance_m == full.min_clearance_m
    assert reported(least_only) == reported(full)
    assert [r.describe() for r in least_only.runs] == [r.describe() for r in full.runs]
    assert bool(full.runs) == (margin_m > 0.03)
    assert least_only.queries < full.queries
    inside = np.flatnonzero(least_only.segment_samples > 1)  # a segment sampled inside: exact ends
    assert least_only.waypoint_measured[inside].all() and least_only.waypoint_measured[inside + 1].all()
    assert np.array_equal(least_only.waypoint_distance_m[inside], full.waypoint_distance_m[inside])


def test_the_cold_glass_check_measures_few_waypoints_and_reports_what_fcl_gives_over_every_pair():
    """A cold glass run's dense check measures only the waypoints that can hold the least figures
    (or end a segment sampled inside): the least distance and clearance are FCL's over every pair at
    every waypoint, a measured waypoint's figures are FCL's, every other one's are at most FCL's,
    and the cell and self pairs' least distances are FCL's least over the pairs of each kind."""
    p = refine.load_problem(ROOT / "problems" / "glass_adhesive")
    f = fused_path(p)
    r = refine.refine_path(
        "abb_irb4600_60_205",
        f.positions,
        f.rotations,
        speeds=f.speed,
        arc_length=f.s,
        tcp_in_flange=p.tool.tcp_in_flange,
        base_in_world=p.robot.base_in_world,
        cell=p.cell,
        tool_shapes=p.tool.collision,
        collision=p.collision,
    )
    assert r.status == "ok"
    check = r.run.first.clearance
    measured = check.waypoint_measured
    assert measured is not None and measured.sum() < len(r.joints) // 4
    model = ClearanceSource.for_problem(r.run.problem, r.run.robot).model
    truth = every_pair(model, r.joints)
    d, _, c, _ = least(model, truth)
    assert check.waypoint_distance_m.min() == pytest.approx(d, abs=1e-12)
    assert check.waypoint_clearance_m.min() == pytest.approx(c, abs=1e-12)
    per_waypoint = truth.min(axis=1)
    assert np.allclose(check.waypoint_distance_m[measured], per_waypoint[measured], atol=1e-12, rtol=0.0)
    assert np.all(check.waypoint_distance_m <= per_waypoint + 1e-12)
    inside = np.flatnonzero(check.segment_samples > 1)
    assert measured[inside].all() and measured[inside + 1].all()
    kinds = {b.label: b.kind for b in model.bodies}
    is_cell = np.array([kinds[a] == "cell" or kinds[b] == "cell" for a, b in model.pairs])
    found = r.run.first.clearance_kinds
    assert found.cell_m == pytest.approx(truth[:, is_cell].min(), abs=1e-12)
    assert found.self_m == pytest.approx(truth[:, ~is_cell].min(), abs=1e-12)


def test_a_self_pairs_carried_normal_turned_with_its_other_body_bounds_the_distance_closer_than_one_fixed():
    """Every pair measured at random configurations, then the joints moved up to 0.5 deg: along the
    carried witness normals turned with a self pair's other body the gaps never exceed FCL's distance
    and fall short of it by at most half as much as along the normals kept fixed in the world
    (median over the self pairs more than 1 cm apart), closer far more often than not; a cell pair's
    normal is carried as it was."""
    model, q, truth = random_configurations()
    found_at = q + np.random.default_rng(1).uniform(-1.0, 1.0, q.shape) * np.radians(0.5)
    normals = witness_normals(model, found_at)
    exact = np.ones(truth.shape, dtype=bool)
    measured = checked_bounds(
        model, found_at, every_pair(model, found_at), normals, model.moving_poses(found_at), exact
    )
    fixed_normals = carried_directions(model, measured, q)
    turned_normals = carried_directions(model, measured, q, turned=True)
    own = model.self_pairs
    assert np.array_equal(turned_normals[:, ~own], fixed_normals[:, ~own])
    poses = model.moving_poses(q)
    fixed, turned = (
        direction_bounds(model, poses, fixed_normals),
        direction_bounds(model, poses, turned_normals),
    )
    assert np.all(turned <= truth + 1e-9)
    apart = truth[:, own] > 0.01
    lost_fixed, lost_turned = ((truth - b)[:, own][apart] for b in (fixed, turned))
    assert np.isfinite(lost_turned).all() and np.median(lost_turned) <= 0.5 * np.median(lost_fixed)
    assert (lost_turned < lost_fixed - 1e-9).sum() >= 4 * (lost_turned > lost_fixed + 1e-9).sum()


def test_box_bounds_of_some_pairs_are_those_of_every_pair():
    """The box gaps of a few pairs (placing only their bodies' boxes) equal those columns of every pair's."""
    robot = load_robot("abb_irb4600_60_205")
    shapes, tool = cell()
    model = refine.collision.CollisionModel(
        robot, np.eye(4), TCP, tool, shapes, margin_m=0.01, self_margin_m=0.005
    )
    poses = np.array(model.moving_poses(random_path(20)))  # writeable: not kept
    other = np.array(model.moving_poses(random_path(20, seed=9)))
    every = model.box_bounds(poses)
    rng = np.random.default_rng(3)
    for size in (1, 2, 3, 10, len(model.pairs)):
        for _ in range(5):
            columns = rng.choice(len(model.pairs), size, replace=False)
            model.box_bounds(other)  # what the memory freed last held: another path's boxes
            assert np.array_equal(model.box_bounds(poses, columns), every[:, columns])


def test_carried_bounds_of_one_check_into_two_cells_are_each_cells_own():
    """One check's bounds carried into a model with the pillar 3 mm away, into one with it in place,
    and into the first again: each is below FCL's distances in its own cell, the pillar's pairs lower
    by the 3 mm in the moved one, and the first answer given again."""
    robot = load_robot("abb_irb4600_60_205")
    q0 = random_path()
    q1 = q0 + np.radians(0.1)
    shapes, tool = cell()
    moved, _ = cell(0.003)
    kin = TcpKinematics(robot, np.eye(4), TCP)

    def model_of(objects):
        return refine.collision.CollisionModel(
            robot, np.eye(4), TCP, tool, objects, margin_m=0.01, self_margin_m=0.005
        )

    first = check_path_clearance(model_of(shapes), q0, kin, 0.005).bounds
    a, b = model_of(moved), model_of(shapes)
    in_a, in_b, again = (
        carried_bounds(a, first, q1),
        carried_bounds(b, first, q1),
        carried_bounds(a, first, q1),
    )
    assert np.array_equal(in_a, again)
    assert np.all(in_a <= every_pair(a, q1) + 1e-9) and np.all(in_b <= every_pair(b, q1) + 1e-9)
    pillar = [p for p, pair in enumerate(a.pairs) if "pillar" in pair and np.isfinite(in_a[:, p]).all()]
    assert pillar and np.allclose(in_b[:, pillar] - in_a[:, pillar], 0.003, atol=1e-12)
