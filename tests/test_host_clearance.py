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
