"""A re-solve's shortcuts: the kept problem's reuse test and the least distances from the check's own bounds.

Each shortcut is held to what it stands for: the reuse test to ``reuse_for`` itself, the least
distances to every pair measured at every waypoint.
"""

from __future__ import annotations

import dataclasses
import types

import numpy as np
import pytest

from refine.collision.carry import CheckedBounds
from refine.collision.model import CollisionModel
from refine.optimise.problem import ActiveSet, LinearRow, reuse_for
from refine.optimise.warm import _reusable
from refine.run.clearance_kinds import kind_minima
from tests.test_host_clearance import with_table

over_table = with_table  # a UR10e line 0.2 m above a table, with a gun, solved once per module


def test_the_reuse_test_agrees_with_reuse_for_on_every_kind_of_problem(over_table):
    built = over_table.run.first.nlp
    fused, tol = built.fused, built.tolerances
    assert built.elastic_deg is None and built.active == ActiveSet()
    row = LinearRow(3, 0.0, np.ones(built.dof), 0.0, "a row")
    stretched = dataclasses.replace(fused, s=fused.s * 1.5)  # another spacing: a new smoothness cost
    cases = [
        (built, fused, True),
        (built, dataclasses.replace(fused), True),  # an equal path, not the same object
        (built, stretched, False),
        (dataclasses.replace(built, elastic_deg=1.0), fused, False),
        (dataclasses.replace(built, active=ActiveSet(singular_waypoints=(2,))), fused, False),
        (dataclasses.replace(built, active=ActiveSet(singular_segments=((2, 0.5),))), fused, False),
        (dataclasses.replace(built, active=ActiveSet(linear_rows=(row,))), fused, False),
    ]
    for problem, path, reusable in cases:
        assert (reuse_for(problem, path, tol) is not None) is reusable  # the cases are what they say
        assert _reusable(problem, path, tol) is reusable


def test_bounds_carried_for_other_joints_are_not_taken_for_these(over_table):
    """A check's bounds of other joints say nothing here: the least distances are those of every pair."""
    run = over_table.run
    model = CollisionModel.for_problem(run.problem, run.robot)
    q, clearance = run.first.refinement.q, run.first.clearance
    q_other = q + np.radians(0.5)
    far = np.full((len(q), len(model.pairs)), 10.0)  # bounds true of nothing here: 10 m
    stale = types.SimpleNamespace(
        bounds=CheckedBounds(q_other, tuple(model.pairs), far, {}, model.base_in_world),
        segment_pair=(),
        segment_clearance_m=np.zeros(0),
        segment_samples=None,
    )
    kinds = {b.label: b.kind for b in model.bodies}
    cell = np.array([kinds[a] == "cell" or kinds[b] == "cell" for a, b in model.pairs])
    every = np.array([[model.pair_distance(qi, k) for k in range(len(model.pairs))] for qi in q])
    got = kind_minima(model, q, stale)
    assert got.cell_m == pytest.approx(every[:, cell].min(), abs=1e-9)
    assert got.self_m == pytest.approx(every[:, ~cell].min(), abs=1e-9)
    # the check's own bounds of these joints give the same figures (the between-waypoint figures aside)
    own = types.SimpleNamespace(
        bounds=clearance.bounds, segment_pair=(), segment_clearance_m=np.zeros(0), segment_samples=None
    )
    assert np.array_equal(clearance.bounds.q, q)
    kept = kind_minima(model, q, own)
    assert kept.cell_m == pytest.approx(every[:, cell].min(), abs=1e-9)
    assert kept.self_m == pytest.approx(every[:, ~cell].min(), abs=1e-9)
