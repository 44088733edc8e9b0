"""The clearance source's bounds and normals carried from a previous check, kept per joint path."""

import numpy as np
import pytest

import refine
from refine.collision import check_path_clearance
from refine.collision.carry import carried_bounds, carried_directions
from refine.frames import make_transform
from refine.optimise.clearance import ClearanceSource
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot
from refine.settings import Shape

TCP = make_transform(p=[0.0, 0.0, 0.35])


def cell(shift_m=0.0):
    """A pillar and a ball a few centimetres from the path's robot, and a nozzle on the flange."""
    pillar = Shape(
        "pillar", "box", pose=make_transform(p=[1.5 + shift_m, -0.65, 1.0]), size_m=(0.2, 0.2, 2.0)
    )
    ball = Shape("ball", "sphere", pose=make_transform(p=[1.45, -0.5, 0.5]), radius_m=0.08)
    nozzle = Shape("nozzle", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.15]), radius_m=0.03, length_m=0.3)
    return (pillar, ball), (nozzle,)


def test_carried_bounds_are_those_of_the_path_asked_for_and_a_check_from_them_reports_a_fresh_checks_figures():
    """A random IRB 4600 path checked with the pillar in place; the pillar moved 3 mm, two other
    paths near it (up to 0.3 deg per joint away) asked for in turn, then the first again, then with
    another prior: each time the source hands out exactly :func:`carried_bounds` and
    :func:`carried_directions` of that path and prior (computed here on their own), read-only, and
    its dense check of each path reports the least distance, clearance and runs of a check of a
    fresh model with nothing carried, and FCL's least distance over every pair at every waypoint."""
    robot = load_robot("abb_irb4600_60_205")
    rng = np.random.default_rng(3)
    start = np.radians([-35.0, 20.0, 15.0, 10.0, 50.0, 30.0])
    q0 = start + np.cumsum(rng.normal(0.0, np.radians(0.6), (40, 6)), axis=0)
    q1 = q0 + rng.uniform(-1.0, 1.0, q0.shape) * np.radians(0.3)
    q2 = q0 + rng.uniform(-1.0, 1.0, q0.shape) * np.radians(0.3)
    shapes, tool = cell()
    moved, _ = cell(0.003)
    kin = TcpKinematics(robot, np.eye(4), TCP)

    def model_of(objects):
        return refine.collision.CollisionModel(
            robot, np.eye(4), TCP, tool, objects, margin_m=0.01, self_margin_m=0.005
        )

    first = check_path_clearance(model_of(shapes), q0, kin, 0.005)
    other = check_path_clearance(model_of(shapes), q2, kin, 0.005)
    model = model_of(moved)
    source = ClearanceSource(model, kin, 0.005)
    assert source._from_prior(q1) == (None, None)
    source.carry_from(first)
    for q, prior in ((q1, first), (q1, first), (q2, first), (q1, first), (q1, other)):
        if source.prior is not prior.bounds:
            source.carry_from(prior)
        bounds, directions = source._from_prior(q)
        want_b = carried_bounds(model_of(moved), prior.bounds, q)
        want_d = carried_directions(model_of(moved), prior.bounds, q)
        np.testing.assert_array_equal(bounds, want_b)
        np.testing.assert_array_equal(directions, want_d)
        for a in (bounds, directions):
            with pytest.raises(ValueError):
                a[0, 0] = 0.0
    for q in (q1, q2):
        source.forget()
        source.carry_from(first)
        got = source.clearance(q)
        fresh_model = model_of(moved)
        fresh = check_path_clearance(fresh_model, q, kin, 0.005)
        assert (got.min_distance_m, got.min_clearance_m) == pytest.approx(
            (fresh.min_distance_m, fresh.min_clearance_m), abs=1e-12
        )
        assert [r.describe() for r in got.runs] == [r.describe() for r in fresh.runs]
        truth = min(fresh_model.pair_distance(qk, p) for qk in q for p in range(len(fresh_model.pairs)))
        assert float(got.waypoint_distance_m.min()) == pytest.approx(truth, abs=1e-12)
