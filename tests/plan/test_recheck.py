"""A motion planned again, its clearance proved from its earlier check's bounds.

The glass cell's retract line is planned, then planned again from a waypoint 2 mm away, as a
re-solve after the part moved plans it. The expectations come from measuring every pair at every
row (and at dense samples between the rows) with the collision model's own distances, not from
the re-proof; a clamp moved onto the line between the two plans must make the line fail as a
line planned afresh fails.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from refine.collision.carry import carried_bounds
from refine.frames import make_transform
from refine.plan import recheck as recheck_module
from refine.plan.line import plan_line
from refine.plan.recheck import _carried, recheck

from .test_motions import box, checker_with, joint_samples, joints_at, kinematics
from .test_motions import glass as glass  # noqa: F401 - the module's fixture

TOLERANCE = 1e-4  # the dense check's [m]


def _line(problem, robot, checker, x, previous=None):
    q = joints_at(problem, robot, np.array([x, 0.0, 0.66]))
    T = kinematics(problem, robot).pose(q)
    return plan_line(checker, "retract", "retract pass 1", q, T, retract_m=0.1, previous=previous)


@pytest.fixture(scope="module")
def lines(glass):
    """The retract line planned in the glass cell, and its rows planned again 2 mm along x."""
    problem, robot = glass
    checker = checker_with(problem, robot, problem.cell)
    first = _line(problem, robot, checker, 1.2)
    again = _line(problem, robot, checker, 1.202, previous=first)
    assert first.ok and again.ok and again.q.shape == first.q.shape
    return problem, robot, checker, first, again


def test_a_line_planned_again_has_the_least_figures_every_pair_measured_at_every_row_gives(lines):
    _, _, checker, first, again = lines
    model = checker.model
    found = recheck(model, again.q, first.check)
    assert found is not None and found.ok and found.certified_segments == len(again.q) - 1
    d = np.array([[model.pair_distance(q, p) for p in range(len(model.pairs))] for q in again.q])
    clear = d - model.pair_margins
    assert found.waypoint_distance_m.min() == pytest.approx(d.min(), abs=1e-12)
    assert found.waypoint_clearance_m.min() == pytest.approx(clear.min(), abs=1e-12)
    k, p = np.unravel_index(np.argmin(clear), clear.shape)
    named = tuple(label.split("/")[0] for label in model.pairs[p])  # the bodies' names, not their pieces'
    assert found.segment_pair[int(np.argmin(found.segment_clearance_m))] == named
    assert found.min_distance_m <= d.min() + 1e-12  # samples inside a segment count too
    # the line's figures are these
    assert again.min_distance_m == found.min_distance_m and again.min_clearance_m == found.min_clearance_m


def test_a_line_planned_again_keeps_every_margin_between_its_rows(lines):
    """Every pair at dense samples of the joint-interpolated rows keeps its margin (less the tolerance)."""
    _, _, checker, first, again = lines
    model = checker.model
    assert recheck(model, again.q, first.check) is not None
    top = float(model.pair_margins.max())
    for q in joint_samples(again.q, step_rad=0.002):
        assert all(c.clearance_m >= -TOLERANCE for c in model.contacts(q, top))


def test_the_bounds_carried_are_those_of_carried_bounds_with_the_part_moved(lines):
    problem, robot, checker, first, again = lines
    move = make_transform(np.eye(3), [0.002, 0.0, 0.0])
    cell = tuple(dataclasses.replace(o, pose=move @ o.pose) if o.workpiece else o for o in problem.cell)
    moved = checker_with(problem, robot, cell).model
    carried, want = (
        _carried(moved, first.check.bounds, again.q),
        carried_bounds(moved, first.check.bounds, again.q),
    )
    assert carried is not None and want is not None
    got = carried[0]
    np.testing.assert_array_equal(np.isinf(got), np.isinf(want))
    np.testing.assert_allclose(got[np.isfinite(got)], want[np.isfinite(want)], rtol=0.0, atol=1e-15)
    assert np.isfinite(want).any() and (want < first.check.bounds.bounds).any()


def test_a_clamp_moved_onto_the_line_fails_the_line_planned_again_as_one_planned_afresh(glass):
    problem, robot = glass
    q = joints_at(problem, robot, np.array([1.2, 0.0, 0.66]))
    T = kinematics(problem, robot).pose(q)
    on_line = T[:3, 3] - 0.07 * T[:3, 2]  # 70 mm back along the tool axis: on the 100 mm retract
    aside = checker_with(problem, robot, [box("clamp", on_line + [0.0, 0.06, 0.0], (0.03, 0.03, 0.03))])
    first = _line(problem, robot, aside, 1.2)
    assert first.ok, first.reason
    onto = checker_with(problem, robot, [box("clamp", on_line + [0.0, 0.03, 0.0], (0.03, 0.03, 0.03))])
    again = _line(problem, robot, onto, 1.202, previous=first)
    fresh = _line(problem, robot, onto, 1.202)
    assert fresh.status == "failed" and again.status == "failed"
    assert [i.objects for i in again.issues] == [i.objects for i in fresh.issues]
    assert "clamp" in again.issues[0].objects


def test_random_joint_moves_re_proved_agree_with_the_dense_check(glass):
    """Seeded joint moves (2 to 6 rows) near a box, checked, moved by about a milliradian: the re-proof
    gives the dense check's verdict, least figures and pair, or gives way to it where a margin breaks."""
    problem, robot = glass
    rng = np.random.default_rng(20260101)
    lo, hi = 0.5 * robot.spec.lower, 0.5 * robot.spec.upper
    agreed = 0
    for _ in range(6):
        centre = rng.uniform([0.9, -0.5, 0.5], [1.5, 0.5, 1.0])
        checker = checker_with(problem, robot, [*problem.cell, box("clamp", centre, (0.1, 0.1, 0.1))])
        a = rng.uniform(lo, hi)
        rows = a + np.linspace(0.0, 1.0, int(rng.integers(2, 7)))[:, None] * rng.normal(0.0, 0.4, 6)
        first = checker.clearance(rows)
        moved = rows + rng.normal(0.0, 1e-3, rows.shape)
        fresh, found = checker.clearance(moved), recheck(checker.model, moved, first)
        if found is None:
            assert not fresh.ok or not first.ok
            continue
        assert found.ok and fresh.ok
        assert found.min_distance_m == pytest.approx(fresh.min_distance_m, abs=1e-9)
        assert found.min_clearance_m == pytest.approx(fresh.min_clearance_m, abs=1e-9)
        worst = [c.segment_pair[int(np.argmin(c.segment_clearance_m))] for c in (found, fresh)]
        assert worst[0] == worst[1]
        agreed += 1
    assert agreed >= 2


def test_joint_moves_re_proved_from_the_earlier_samples_inside_agree_with_the_dense_check(glass):
    """Seeded wrist unwinds near a box, checked, moved by about a milliradian: where the earlier
    check's samples inside prove a pair (fewer queries than re-proving without them), the least
    figures and pair are still the dense check's of the moved rows, and every pair keeps its margin
    at dense samples between the rows."""
    problem, robot = glass
    rng = np.random.default_rng(20260312)
    lo, hi = 0.5 * robot.spec.lower, 0.5 * robot.spec.upper
    spared = 0
    for _ in range(4):
        centre = rng.uniform([0.9, -0.5, 0.5], [1.5, 0.5, 1.0])
        checker = checker_with(problem, robot, [*problem.cell, box("clamp", centre, (0.1, 0.1, 0.1))])
        a = rng.uniform(lo, hi)
        step = rng.normal(0.0, 0.3, 6)
        step[5] = rng.choice([-1.0, 1.0]) * rng.uniform(2.0, 5.0)  # the wrist unwinds
        rows = np.stack([a, a + step])
        first = checker.clearance(rows)
        if not first.ok or not first.inner_samples:
            continue
        moved = rows + rng.normal(0.0, 1e-3, rows.shape)
        fresh, found = checker.clearance(moved), recheck(checker.model, moved, first)
        bare = recheck(checker.model, moved, dataclasses.replace(first, inner_samples=None))
        if found is None or bare is None:
            assert (found is None) == (bare is None)
            continue
        assert found.ok and fresh.ok
        assert found.min_distance_m == pytest.approx(fresh.min_distance_m, abs=1e-9)
        assert found.min_clearance_m == pytest.approx(fresh.min_clearance_m, abs=1e-9)
        worst = [c.segment_pair[int(np.argmin(c.segment_clearance_m))] for c in (found, fresh)]
        assert worst[0] == worst[1]
        if found.queries < bare.queries:
            spared += 1
            top = float(checker.model.pair_margins.max())
            for q in joint_samples(moved, step_rad=0.05):
                assert all(c.clearance_m >= -TOLERANCE for c in checker.model.contacts(q, top))
    assert spared >= 2, spared


def test_a_move_passing_a_box_re_proved_from_its_samples_has_the_dense_checks_least_inside(glass):
    """The TCP sweeps 30 mm over a box between two rows 50 mm clear of it: the least distance lies
    inside the segment, where the dense check of the rows moved 10 µrad samples it; re-proved from the
    earlier samples, the move has the same least figures and pair."""
    problem, robot = glass
    kin = kinematics(problem, robot)
    a = joints_at(problem, robot, np.array([1.2, -0.25, 0.8]))
    b = joints_at(problem, robot, np.array([1.2, 0.25, 0.8]), a)
    below = kin.pose((a + b) / 2)[:3, 3] - [0.0, 0.0, 0.055]  # 30 mm gap to the top of a 50 mm box
    checker = checker_with(problem, robot, [*problem.cell, box("clamp", below, (0.05, 0.05, 0.05))])
    rows = np.stack([a, b])
    first = checker.clearance(rows)
    moved = rows + np.random.default_rng(3).normal(0.0, 1e-5, rows.shape)
    fresh, found = checker.clearance(moved), recheck(checker.model, moved, first)
    assert first.ok and first.inner_samples and found is not None and found.ok
    assert fresh.min_distance_m < fresh.waypoint_distance_m.min() - 0.01  # the least is inside
    assert found.min_distance_m == pytest.approx(fresh.min_distance_m, abs=1e-9)
    assert found.min_clearance_m == pytest.approx(fresh.min_clearance_m, abs=1e-9)
    assert found.segment_pair == fresh.segment_pair


def _every_pair(model, rows):
    """Every pair's distance [m] at every row, (K, P), each measured by the model's own FCL query."""
    return np.array([[model.pair_distance(q, p) for p in range(len(model.pairs))] for q in rows])


def test_a_clamp_moved_closer_gets_its_own_distances_not_those_the_same_rows_had_before_it_moved(glass):
    """The retract line is planned beside a clamp and again from 2 mm away (its rows measured on that
    model); on the model of the clamp moved 10 mm closer, the same rows planned again have the least
    figures every pair measured at every row on the moved model gives, 4 mm and more below the first's."""
    problem, robot = glass
    q = joints_at(problem, robot, np.array([1.2, 0.0, 0.66]))
    T = kinematics(problem, robot).pose(q)
    on_line = T[:3, 3] - 0.07 * T[:3, 2]  # 70 mm back along the tool axis: on the 100 mm retract
    near = checker_with(problem, robot, [box("clamp", on_line + [0.0, 0.08, 0.0], (0.03, 0.03, 0.03))])
    first = _line(problem, robot, near, 1.2)
    again = _line(problem, robot, near, 1.202, previous=first)
    assert again.ok and again.check.waypoint_measured.any()
    closer = checker_with(problem, robot, [box("clamp", on_line + [0.0, 0.07, 0.0], (0.03, 0.03, 0.03))])
    found = recheck(closer.model, again.q, first.check)
    assert found is not None and found.ok
    d = _every_pair(closer.model, again.q)
    clear = d - closer.model.pair_margins
    assert found.waypoint_distance_m.min() == pytest.approx(d.min(), abs=1e-12)
    assert found.waypoint_clearance_m.min() == pytest.approx(clear.min(), abs=1e-12)
    assert d.min() < again.min_distance_m - 0.004


def test_a_motion_checked_again_on_its_model_takes_the_rows_measured_and_finds_what_measuring_finds(
    glass, monkeypatch
):
    """The retract line planned again, re-proved twice on one model, then with its wrist turned 1 mrad
    (the last joint alone): the second time its rows measured are taken as they were (fewer FCL
    queries), and every figure and bound of the three is, bit for bit, what the same re-proofs give on
    a model of the same cell that keeps no row."""
    problem, robot = glass

    def re_proofs():
        checker = checker_with(problem, robot, problem.cell)
        first = _line(problem, robot, checker, 1.2)
        rows = _line(problem, robot, checker, 1.2, previous=first).q + 2e-5  # planned again, moved
        turned = rows.copy()
        turned[:, -1] += 1e-3
        return [recheck(checker.model, x, first.check) for x in (rows, rows, turned)]

    kept = re_proofs()
    monkeypatch.setattr(recheck_module, "MEASURED_ROWS", 0)
    bare = re_proofs()
    assert all(c is not None and c.ok for c in (*kept, *bare))
    assert kept[1].queries < bare[1].queries and kept[1].queries < kept[0].queries
    for a, b in zip(kept, bare, strict=True):
        for field in dataclasses.fields(a):
            if field.name in ("queries", "time_s", "bounds", "inner_samples"):
                continue
            x, y = getattr(a, field.name), getattr(b, field.name)
            if isinstance(x, np.ndarray):
                np.testing.assert_array_equal(x, y, err_msg=field.name)
            else:
                assert x == y, field.name
        np.testing.assert_array_equal(a.bounds.bounds, b.bounds.bounds)
        np.testing.assert_array_equal(a.bounds.normals, b.bounds.normals)
        assert a.inner_samples == b.inner_samples
