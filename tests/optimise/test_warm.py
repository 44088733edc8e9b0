"""Re-solving from a previous answer (refine.optimise.warm, refine.collision.carry) through the API."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import refine
from refine.collision import check_path_clearance, margins_proved
from refine.collision.carry import bounds_between, carried_bounds, checked_bounds, measure_least
from refine.collision.model import CollisionModel
from refine.frames import make_transform
from refine.optimise.clearance import ClearanceSource
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot

N = 31
DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
TCP = make_transform(p=[0.0, 0.0, 0.15])


def cell_line():
    """A line 0.3 m above a table on a UR10e with a gun: the table is 0.2 m below the TCP."""
    positions = np.column_stack([np.full(N, 0.6), np.linspace(-0.2, 0.2, N), np.full(N, 0.3)])
    tilt = Rotation.from_euler("x", np.linspace(0.0, 8.0, N)[:, None], degrees=True).as_matrix()
    table = refine.Shape("table", "box", pose=make_transform(p=[0.6, 0.0, 0.05]), size_m=(0.6, 0.8, 0.1))
    part = refine.Shape(
        "part", "box", pose=make_transform(p=[0.6, 0.0, 0.17]), size_m=(0.2, 0.5, 0.04), workpiece=True
    )
    gun = refine.Shape(
        "gun", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.05]), radius_m=0.03, length_m=0.1
    )
    return positions, DOWN @ tilt, (table, part), (gun,)


def moved(positions, rotations, cell, shift_m, turn_deg):
    """The path, its orientations and the workpiece moved rigidly: turned about z through (0.6, 0, 0.3)."""
    c = np.array([0.6, 0.0, 0.3])
    R = Rotation.from_euler("z", turn_deg, degrees=True).as_matrix()
    M = make_transform(p=c - R @ c + np.asarray(shift_m))
    M[:3, :3] = R
    cell = tuple(dataclasses.replace(o, pose=M @ o.pose) if o.workpiece else o for o in cell)
    return positions @ R.T + M[:3, 3], np.einsum("ij,njk->nik", R, rotations), cell, M


def test_a_moved_part_re_solved_from_the_previous_answer_is_the_cold_answer_and_verified():
    positions, R, cell, tool = cell_line()
    common = {
        "speeds": 0.1,
        "tcp_in_flange": TCP,
        "tool_shapes": tool,
        "collision": refine.CollisionSettings(margin_m=0.01),
    }
    first = refine.refine_path("ur10e", positions, R, cell=cell, **common)
    assert first.status == "ok"
    p2, R2, cell2, M = moved(positions, R, cell, [0.002, 0.0, 0.0], 0.3)
    warm = refine.refine_path("ur10e", p2, R2, cell=cell2, previous=first, **common)
    cold = refine.refine_path("ur10e", p2, R2, cell=cell2, **common)
    assert warm.status == cold.status == "ok"
    assert np.abs(warm.joints - cold.joints).max() <= 1e-6
    assert warm.run.timings_s["build"] < 1e-3  # the previous problem kept
    # verified: the TCP on the moved points by plain forward kinematics, the orientation in the cone
    kin = TcpKinematics(warm.run.robot, np.eye(4), TCP)
    poses = kin.poses(warm.joints)
    assert np.abs(poses[:, :3, 3] - p2).max() <= 1e-6
    cos = (np.einsum("kij,kij->k", poses[:, :3, :3], R2) - 1.0) / 2.0
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() <= 3.0 + 1e-6
    # and clear of the moved cell by a dense sampled check of its own (not the bound the warm check used)
    source = ClearanceSource.for_problem(cold.run.problem, cold.run.robot)
    sampled = check_path_clearance(source.model, warm.joints, source.kin, 0.002, method="sample")
    assert sampled.ok and sampled.min_distance_m >= 0.01 - 1e-4
    # the least distance is measured, not a bound: the cold check measures every waypoint
    assert warm.run.first.clearance.waypoint_measured is not None  # the warm check measured only some
    assert abs(warm.metrics["min_clearance_m"] - cold.metrics["min_clearance_m"]) <= 1e-5


def test_carried_bounds_bound_the_distances_after_the_joints_and_a_cell_object_moved():
    """Every carried bound is at most the pair's distance FCL measures after the move.

    The prior holds the exact distances at the first joints; the table then rises 5 mm towards the
    robot and the joints move by up to 0.3 deg, so every distance to the table shrinks by about
    5 mm: a bound that forgot the table's move would stand above it.
    """
    _, _, cell, tool = cell_line()
    robot = load_robot("ur10e")

    def model_of(cell, tool=tool):
        return CollisionModel(robot, np.eye(4), TCP, tool, cell, margin_m=0.01, self_margin_m=0.005)

    q_old = np.tile(np.radians([0.0, -100.0, -100.0, -70.0, 90.0, 0.0]), (5, 1))
    q_old[:, 0] += np.linspace(-0.2, 0.2, 5)
    before = model_of(cell)
    exact = np.array([[before.pair_distance(q, p) for p in range(len(before.pairs))] for q in q_old])
    prior = checked_bounds(before, q_old, exact)
    raised = tuple(dataclasses.replace(o, pose=make_transform(p=[0.0, 0.0, 0.005]) @ o.pose) for o in cell)
    after = model_of(raised)
    q = q_old + np.random.default_rng(3).uniform(-0.005, 0.005, q_old.shape)
    carried = carried_bounds(after, prior, q)
    assert carried is not None
    table = [p for p, pair in enumerate(after.pairs) if "table" in pair]
    assert table and np.isfinite(carried[:, table]).all()
    for k, p in zip(*np.nonzero(np.isfinite(carried)), strict=True):
        assert carried[k, p] <= after.pair_distance(q[k], int(p)) + 1e-9, after.pairs[p]
    # another tool is another body: its pairs keep no bound
    other = model_of(cell, (dataclasses.replace(tool[0], radius_m=0.031),))
    gun = [p for p, pair in enumerate(other.pairs) if "tool:gun" in pair]
    assert gun and np.all(np.isneginf(carried_bounds(other, prior, q_old)[:, gun]))


def test_bounds_between_waypoints_bound_the_distances_of_points_off_the_joint_line():
    """A check's bounds at the waypoints bound every pair's distance at joints between them.

    Each row between two waypoints is moved off their joint line by up to 0.3 deg per joint, as
    the controller's line is: FCL's distance there must not fall below the carried bound. A row
    said to stand at a waypoint but holding other joints, or a moved table, gives no bound.
    """
    _, _, cell, tool = cell_line()
    robot = load_robot("ur10e")
    model = CollisionModel(robot, np.eye(4), TCP, tool, cell, margin_m=0.01, self_margin_m=0.005)
    q = np.tile(np.radians([0.0, -100.0, -100.0, -70.0, 90.0, 0.0]), (4, 1))
    q[:, 0] += np.linspace(-0.2, 0.2, 4)
    exact = np.array([[model.pair_distance(qk, p) for p in range(len(model.pairs))] for qk in q])
    checked = checked_bounds(model, q, exact)
    place = np.array([0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 2.75, 3.0])
    a = np.floor(place).astype(int)
    t = (place - a)[:, None]
    rows = q[a] + t * (q[np.minimum(a + 1, 3)] - q[a])
    inside = place != a
    rows[inside] += np.random.default_rng(5).uniform(-1.0, 1.0, (inside.sum(), 6)) * np.radians(0.3)
    found = bounds_between(model, checked, rows, place)
    assert found is not None and np.isfinite(found).all()
    for k, p in np.ndindex(found.shape):  # FCL's mesh distances repeat to about 1e-7 m
        assert found[k, p] <= model.pair_distance(rows[k], p) + 1e-6, (k, model.pairs[p])
    np.testing.assert_allclose(found[~inside], exact[a[~inside]])  # at a waypoint: its own bound
    wrong = rows.copy()
    wrong[3] += 1e-3
    assert bounds_between(model, checked, wrong, place) is None
    raised = tuple(dataclasses.replace(o, pose=make_transform(p=[0.0, 0.0, 0.005]) @ o.pose) for o in cell)
    other = CollisionModel(robot, np.eye(4), TCP, tool, raised, margin_m=0.01, self_margin_m=0.005)
    assert bounds_between(other, checked, rows, place) is None


def test_margins_proved_from_known_bounds_takes_no_query_and_never_proves_a_broken_margin():
    """Exact distances as the known bounds: with a 1 cm margin (every cell pair further) they prove
    the path without an FCL query; with a margin above the least cell distance no bound may prove it."""
    _, _, cell, tool = cell_line()
    robot = load_robot("ur10e")
    q = np.tile(np.radians([0.0, -100.0, -100.0, -70.0, 90.0, 0.0]), (4, 1))
    q[:, 0] += np.linspace(-0.02, 0.02, 4)
    model = CollisionModel(robot, np.eye(4), TCP, tool, cell, margin_m=0.01, self_margin_m=0.005)
    exact = np.array([[model.pair_distance(qk, p) for p in range(len(model.pairs))] for qk in q])
    assert exact.min() > 0.01  # the path keeps the margins
    before = model.queries
    assert margins_proved(model, q, prior=exact)
    assert model.queries == before
    nearest = min(
        exact[:, p].min() for p, pair in enumerate(model.pairs) if "table" in pair or "part" in pair
    )
    tight = CollisionModel(robot, np.eye(4), TCP, tool, cell, margin_m=nearest + 0.01, self_margin_m=0.005)
    assert tight.pairs == model.pairs  # the bounds' columns are its pairs too
    assert not margins_proved(tight, q, prior=exact)
    assert not margins_proved(tight, q)


def test_measure_least_finds_the_least_figures_and_every_waypoint_a_bound_leaves_unproved():
    # 6 waypoints, 2 pairs with margin 0.01 m; the true distances and lower bounds 1-4 mm under them
    true = np.array([[0.05, 0.2], [0.03, 0.2], [0.04, 0.012], [0.06, 0.2], [0.031, 0.2], [0.08, 0.2]])
    bounds = true - np.array(
        [[0.001, 0.0], [0.002, 0.0], [0.001, 0.004], [0.001, 0.0], [0.003, 0.0], [0.0, 0.0]]
    )
    margins = np.array([0.01, 0.01])
    seen = []

    def measure(k):
        seen.append(k)
        return float(true[k].min()), float((true[k] - margins).min())

    measured = measure_least(bounds, margins, measure)
    # waypoint 2's bound 0.008 m is below the margin: measured first; its clearance 0.002 m is the least
    # (nothing else can be lower: the next clearance bound is 0.018 m); the least distance is waypoint
    # 2's 0.012 m, and no other waypoint's distance bound is below it
    assert seen[0] == 2
    assert measured.tolist() == [False, False, True, False, False, False]


def test_a_kept_clearance_row_asks_for_the_margin_from_where_the_object_moved():
    """The TCP at (0.6, 0, 0.3) pointing down: the gun (flange z 0 to 0.1, the TCP at 0.15) ends
    0.05 m above it, 0.25 m above the table's top face (z = 0.1); raising the table 5 mm shortens
    that by 5 mm, so the refreshed row asks for 5 mm more."""
    from refine.optimise.clearance import BACK_OFF_M
    from refine.optimise.problem import LinearRow
    from refine.robot.kinematics import solve_ik

    _, _, cell, tool = cell_line()
    robot = load_robot("ur10e")
    kin = TcpKinematics(robot, np.eye(4), TCP)
    target = make_transform(p=[0.6, 0.0, 0.3])
    target[:3, :3] = DOWN
    start = np.radians([0.0, -100.0, -100.0, -70.0, 90.0, 0.0])
    q, err = solve_ik(kin, target, start, robot.spec.lower, robot.spec.upper, tol=1e-12, max_iterations=300)
    assert err < 1e-9
    rows = (
        LinearRow(0, 0.0, np.zeros(6), 0.0, "tool:gun / table"),
        LinearRow(0, 0.0, np.zeros(6), 0.0, "nothing / here"),
    )

    def refreshed(cell):
        model = CollisionModel(robot, np.eye(4), TCP, tool, cell, margin_m=0.01, self_margin_m=0.005)
        return ClearanceSource(model, kin, 0.005).refresh_rows(rows, q[None])

    before = refreshed(cell)
    after = refreshed(
        tuple(dataclasses.replace(o, pose=make_transform(p=[0.0, 0.0, 0.005]) @ o.pose) for o in cell)
    )
    assert before[0].lower == pytest.approx(0.01 + BACK_OFF_M - 0.25, abs=1e-6)
    assert after[0].lower - before[0].lower == pytest.approx(0.005, abs=1e-7)
    assert after[1] is rows[1]  # a pair the source does not check is kept


@pytest.fixture(scope="module")
def cell_line_answer():
    """The demonstrated rotations of :func:`cell_line` and the refined answer of that line."""
    positions, R, cell, tool = cell_line()
    return R, refine.refine_path(
        "ur10e", positions, R, cell=cell, speeds=0.1, tcp_in_flange=TCP, tool_shapes=tool
    )


def test_a_warm_seed_hands_back_the_tool_jacobians_at_the_joints_it_returns(cell_line_answer):
    """The Jacobians the projection leaves (moved rows) and takes (kept rows) are those of the seed itself.

    Checked against central differences of forward kinematics (position, and the rotation vector of
    ``R(q + h) R(q)ᵀ``), at waypoints the projection moved and at waypoints it left alone.
    """
    from refine.optimise.outcome import problem_kinematics
    from refine.optimise.warm import WarmStart, warm_seed

    R, first = cell_line_answer
    problem = first.run.first.refinement.problem
    q_prev = first.joints.copy()
    q_prev[::3] += 0.01  # every third waypoint off its pose: projected; the others kept
    J = np.full((N, 6, q_prev.shape[1]), np.nan)
    T = np.full((N, 4, 4), np.nan)
    q = warm_seed(problem, WarmStart(q_prev, R), jacobians_out=J, poses_out=T)
    assert np.abs(q[::3] - q_prev[::3]).max() > 1e-3 and np.array_equal(q[1::3], q_prev[1::3])
    kin = problem_kinematics(problem)
    np.testing.assert_allclose(T, kin.poses(q), rtol=0.0, atol=1e-12)  # the poses of the seed too
    h = 1e-6
    for k in (0, 1, 9, 10, N - 1):
        assert np.abs(J[k] - central_jacobian(kin, q[k], h)).max() <= 1e-6, k


def test_a_warm_seed_of_a_wholly_moved_path_reaches_every_pose_and_hands_back_its_own_kinematics(
    cell_line_answer,
):
    """Every waypoint off its pose: each is projected onto its CAD point at the orientation it had,
    within the seed's tolerance, and the poses and Jacobians handed back are the seed's (forward
    kinematics, central differences)."""
    from refine.optimise.outcome import problem_kinematics
    from refine.optimise.warm import WARM_SEED_TOLERANCE, WarmStart, warm_seed
    from refine.robot.kinematics import rotation_vectors

    R, first = cell_line_answer
    problem = first.run.first.refinement.problem
    kin = problem_kinematics(problem)
    q_prev = first.joints + 0.002 * np.cos(np.arange(first.joints.size)).reshape(first.joints.shape)
    # the orientations the projection keeps: the demonstration did not turn
    kept = kin.poses(q_prev)[:, :3, :3]
    J = np.full((N, 6, q_prev.shape[1]), np.nan)
    T = np.full((N, 4, 4), np.nan)
    q = warm_seed(problem, WarmStart(q_prev, R), jacobians_out=J, poses_out=T)
    reached = kin.poses(q)
    np.testing.assert_allclose(T, reached, rtol=0.0, atol=1e-12)
    error = np.linalg.norm(reached[:, :3, 3] - problem.fused.positions, axis=1) + np.linalg.norm(
        rotation_vectors(kept @ np.transpose(reached[:, :3, :3], (0, 2, 1))), axis=1
    )
    assert error.max() <= WARM_SEED_TOLERANCE and np.abs(q - q_prev).max() > 1e-3
    h = 1e-6
    for k in (0, 7, N - 1):
        assert np.abs(J[k] - central_jacobian(kin, q[k], h)).max() <= 1e-6, k


def test_a_re_solve_after_a_repair_starts_from_the_strict_problem_the_repair_grew_from(monkeypatch):
    """A repaired answer keeps its strict problem; the re-solve takes it (not the elastic one) as its start."""
    from pathlib import Path

    import refine.optimise.solve as solve_module

    problem = refine.load_problem(
        Path(__file__).resolve().parents[2] / "problems" / "unreachable" / "joint_limit"
    )
    first = refine.solve(problem)
    refinement = first.run.first.refinement
    assert first.status == "repaired" and refinement.problem.elastic_deg is not None
    strict = refinement.strict_problem
    assert strict is not None and strict.elastic_deg is None
    assert set(strict.active.singular_waypoints) <= set(refinement.problem.active.singular_waypoints)
    started = []
    reuse = solve_module.reuse_final
    monkeypatch.setattr(
        solve_module, "reuse_final", lambda final, *a: started.append(final) or reuse(final, *a)
    )
    again = refine.solve(problem, previous=first)
    assert (
        len(started) == 1 and started[0] is strict
    )  # kept, and no multipliers of the elastic solve (other rows) with it
    assert again.status == "repaired"
    assert np.abs(again.joints - first.joints).max() <= 1e-6


def test_a_projection_started_from_the_given_first_evaluation_is_the_one_that_evaluates_it():
    """``solve_ik_batch``'s ``start`` (the poses and Jacobians at the start joints) changes nothing.

    The same targets and starts solved with the evaluation handed in and without it give the same
    joints, errors and returned Jacobians and poses, bit for bit; the poses it returns are the
    forward kinematics of its joints.
    """
    from refine.robot.kinematics import solve_ik_batch

    robot = load_robot("ur10e")
    kin = TcpKinematics(robot, np.eye(4), TCP)
    rng = np.random.default_rng(3)
    lower, upper = robot.spec.lower, robot.spec.upper
    q_true = rng.uniform(-1.5, 1.5, (40, 6))
    targets = kin.poses(q_true)
    q0 = q_true + rng.normal(0.0, 0.05, q_true.shape)
    T0, J0 = kin.poses_jacobians(q0)
    outs = []
    for start in (None, (T0[:, :3, 3], T0[:, :3, :3], J0)):
        J, T = np.full((40, 6, 6), np.nan), np.full((40, 4, 4), np.nan)
        q, err = solve_ik_batch(kin, targets, q0, lower, upper, jacobians_out=J, poses_out=T, start=start)
        outs.append((q, err, J, T))
    for a, b in zip(*outs, strict=True):
        assert np.array_equal(a, b)
    np.testing.assert_allclose(outs[0][3], kin.poses(outs[0][0]), rtol=0.0, atol=1e-12)
    assert outs[0][1].max() < 1e-6


def central_jacobian(kin, q, h):
    """The TCP Jacobian (6, n) at ``q`` by central differences of the forward kinematics."""
    from refine.robot.kinematics import rotation_vectors

    numeric = np.zeros((6, len(q)))
    for j in range(len(q)):
        up, down = q.copy(), q.copy()
        up[j] += h
        down[j] -= h
        Tu, Td = kin.poses(np.array([up, down]))
        numeric[:3, j] = (Tu[:3, 3] - Td[:3, 3]) / (2 * h)
        numeric[3:, j] = rotation_vectors((Tu[:3, :3] @ Td[:3, :3].T)[None])[0] / (2 * h)
    return numeric
