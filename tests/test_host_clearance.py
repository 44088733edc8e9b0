"""The cell pairs' and the self pairs' least distances apart, against every pair measured at every waypoint."""

from __future__ import annotations

import numpy as np
import pytest

import refine
from refine.collision.model import CollisionModel
from refine.frames import make_transform
from refine.run.clearance_kinds import _between_waypoints, kind_minima

N = 15


@pytest.fixture(scope="module")
def with_table():
    positions = np.column_stack([np.full(N, 0.6), np.linspace(-0.1, 0.1, N), np.full(N, 0.25)])  # [m]
    R = np.repeat(np.diag([1.0, -1.0, -1.0])[None], N, axis=0)  # tool z down, towards the table
    table = refine.Shape("table", "box", pose=make_transform(p=[0.6, 0.0, 0.05]), size_m=(0.6, 0.8, 0.1))
    gun = refine.Shape(
        "gun", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.05]), radius_m=0.03, length_m=0.1
    )
    return refine.refine_path(
        "ur10e",
        positions,
        R,
        speeds=0.1,
        tcp_in_flange=make_transform(p=[0.0, 0.0, 0.15]),
        cell=[table],
        tool_shapes=[gun],
        collision=refine.CollisionSettings(margin_m=0.01, self_margin_m=0.002),
    )


def test_each_kind_is_its_least_pair_distance_over_every_waypoint(with_table):
    run = with_table.run
    model = CollisionModel.for_problem(run.problem, run.robot)
    q, clearance = run.first.refinement.q, run.first.clearance
    kinds = {b.label: b.kind for b in model.bodies}
    cell = np.array([kinds[b] == "cell" for _, b in model.pairs])
    assert cell.any() and (~cell).any()
    # every pair at every waypoint, no pruning
    every = np.array([[model.pair_distance(qi, k) for k in range(len(model.pairs))] for qi in q])
    want_cell = min(every[:, cell].min(), _between_waypoints(clearance, kinds, True, 0.01))
    want_self = min(every[:, ~cell].min(), _between_waypoints(clearance, kinds, False, 0.002))
    got = kind_minima(model, q, clearance)
    assert got.cell_m == pytest.approx(want_cell, abs=1e-9)
    assert got.self_m == pytest.approx(want_self, abs=1e-9)
    assert got.queries < every.size  # the bounds spared most queries
    # by hand: the gun spans 0-0.1 m along the flange's z, the TCP sits at 0.15 m, so with the tool
    # pointing down the gun's bottom face is 0.05 m above the TCP (at 0.25 m), 0.30 - 0.10 = 0.20 m
    # over the table top (less at most 0.03 * sin(3 deg) = 1.6 mm for the orientation cone)
    (gun,) = [k for k, (a, b) in enumerate(model.pairs) if a == "tool:gun" and b == "table"]
    np.testing.assert_allclose(every[:, gun], 0.20, atol=2e-3)
    assert got.cell_m <= every[:, gun].min()


def test_result_json_and_the_summary_give_both_kinds(with_table):
    m = with_table.metrics
    assert m["min_clearance_m"] == pytest.approx(
        min(m["min_cell_clearance_m"], m["min_self_clearance_m"]), abs=1e-6
    )
    assert with_table.figures.min_cell_clearance_m == m["min_cell_clearance_m"]
    from refine.run.result import summary_lines

    (line,) = [ln for ln in summary_lines(with_table.run) if ln.startswith("clearance")]
    assert (
        "cell pairs" in line
        and "(margin 10 mm)" in line
        and "self pairs" in line
        and "(self margin 2 mm)" in line
    )


def test_the_verdict_rows_hold_each_kind_to_its_own_margin():
    # the raised glass cell with a 2.5 deg cone, as measured: the least distance of all is a self
    # pair 0.5 mm above the 5 mm self margin; the cell's least is 0.5 mm above its 10 mm margin
    from refine.report.verdict import figure_rows

    metrics = {
        "max_position_error_m": 1e-7,
        "max_orientation_deviation_deg": 4.67,
        "max_slack_deg": 2.17,
        "min_joint_margin_rad": 0.1,
        "min_singularity_measure": 0.1,
        "min_clearance_m": 0.0055,
        "min_cell_clearance_m": 0.0105,
        "min_self_clearance_m": 0.0055,
    }
    tolerances = {
        "position_m": 1e-6,
        "orientation_deg": 2.5,
        "joint_margin_deg": 2.0,
        "singularity_margin": 0.02,
        "clearance_m": 0.010,
        "self_clearance_m": 0.005,
    }
    rows = {
        name: (value, limit, holds)
        for name, value, limit, holds in figure_rows({"metrics": metrics, "tolerances": tolerances})
    }
    assert rows["clearance to the cell (min)"] == ("10.5 mm", ">= 10 mm", True)
    assert rows["clearance between links and tool (min)"] == ("5.5 mm", ">= 5 mm", True)
    assert not any(holds is False for _, _, holds in rows.values())
    # with the cell's least under its margin the row fails, whatever the self pairs do
    metrics["min_cell_clearance_m"] = 0.0095
    rows = {name: holds for name, _, _, holds in figure_rows({"metrics": metrics, "tolerances": tolerances})}
    assert rows["clearance to the cell (min)"] is False


@pytest.mark.slow
def test_the_raised_glass_cell_with_a_narrow_cone_keeps_every_tolerance_it_is_repaired_under():
    import dataclasses

    from refine.optimise.moves import moved_problem
    from refine.report.verdict import figure_rows

    problem = refine.load_problem("problems/glass_adhesive")
    up = make_transform(p=[0.0, 0.0, 0.6])  # the part and its demonstration 600 mm higher
    raised = moved_problem(problem, up)
    raised = dataclasses.replace(
        raised, tolerances=dataclasses.replace(raised.tolerances, orientation_deg=2.5), repair=problem.repair
    )
    result = refine.solve(raised)
    doc = result.to_dict()
    assert result.status in {"ok", "repaired", "infeasible"}
    m, tol = doc["metrics"], doc["tolerances"]
    if result.status in {"ok", "repaired"}:
        # an executable verdict: every figure with a tolerance holds, each clearance kind its own
        assert m["min_cell_clearance_m"] >= tol["clearance_m"] - 1e-6
        assert m["min_self_clearance_m"] >= tol["self_clearance_m"] - 1e-6
        assert not [row for row in figure_rows(doc) if row[3] is False]


def test_the_bounds_are_visited_in_a_stable_sort_s_order_however_many_and_with_ties():
    from itertools import islice

    from refine.run.clearance_kinds import SORTED_FIRST, ascending

    rng = np.random.default_rng(3)
    for size in (0, 1, SORTED_FIRST, SORTED_FIRST + 1, 5000):
        values = rng.integers(0, 7, size).astype(float)  # many ties
        values[rng.random(size) < 0.1] = -np.inf  # boxes overlapping
        values[rng.random(size) < 0.05] = np.inf
        values[rng.random(size) < 0.05] = np.nan
        expected = np.argsort(values, kind="stable").tolist()  # numpy's own stable sort
        assert list(ascending(values.reshape(-1, 5) if size % 5 == 0 else values)) == expected
        assert list(islice(ascending(values), 3)) == expected[:3]


def test_the_least_distance_between_the_waypoints_is_a_loop_over_the_segments_pairs():
    """Random segments' least clearances (some NaN, some -inf), pairs of either kind or none, and
    sub-step counts (1: nothing inside): each kind's least distance is the least clearance plus the
    margin over the segments with something inside whose pair is of the kind, as a plain loop finds."""
    from types import SimpleNamespace

    kinds = {"table": "cell", "post": "cell", "link_3/0": "robot", "link_5/0": "robot", "tool:gun": "tool"}
    names = list(kinds)
    rng = np.random.default_rng(11)

    def by_loop(check, cell, margin):
        best = np.inf
        samples = getattr(check, "segment_samples", None)
        for k, (body, other) in enumerate(check.segment_pair):
            if samples is not None and samples[k] == 1:
                continue
            if body and ((kinds[other] == "cell" or kinds[body] == "cell") == cell):
                value = float(check.segment_clearance_m[k]) + margin
                best = value if value < best else best
        return best

    for size in (0, 1, 2, 40, 617):
        clear = rng.normal(0.02, 0.02, size)
        clear[rng.random(size) < 0.1] = np.nan
        clear[rng.random(size) < 0.05] = -np.inf
        pairs = tuple(
            ("", "") if rng.random() < 0.1 else (names[i], names[j])
            for i, j in rng.integers(0, len(names), (size, 2))
        )
        samples = rng.integers(1, 4, size)
        for check in (
            SimpleNamespace(segment_clearance_m=clear, segment_pair=pairs, segment_samples=samples),
            SimpleNamespace(segment_clearance_m=clear, segment_pair=pairs),
        ):
            for cell, margin in ((True, 0.01), (False, 0.002)):
                assert _between_waypoints(check, kinds, cell, margin) == by_loop(check, cell, margin)
