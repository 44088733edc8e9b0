"""A collision model of a re-solve takes the previous model's pairs, motion bounds and hulls only when they hold.

The references: a fresh model built with nothing kept, and python-fcl's own distance between a tool
cylinder placed by Pinocchio's flange pose and a cell box (nothing from the model's code).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import fcl
import numpy as np
import pinocchio as pin
import pytest

from refine.collision import CollisionModel
from refine.collision import kept as collision_kept
from refine.collision.carry import carried_bounds, checked_bounds
from refine.frames import make_transform
from refine.robot.registry import load_robot
from refine.settings import Shape

BRACKET = Path(__file__).resolve().parents[1] / "data" / "bracket.stl"
TCP = make_transform(p=[0.0, 0.0, 0.35])
PILLAR = Shape("pillar", "box", pose=make_transform(p=[1.5, -0.65, 1.0]), size_m=(0.2, 0.2, 2.0))
BALL = Shape("ball", "sphere", pose=make_transform(p=[1.45, -0.5, 0.5]), radius_m=0.08)
NOZZLE = Shape("nozzle", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.15]), radius_m=0.03, length_m=0.3)


def build(robot, tool=(NOZZLE,), cell=(PILLAR, BALL), margin_m=0.01, self_margin_m=0.005, base=None):
    base = np.eye(4) if base is None else base
    return CollisionModel(robot, base, TCP, tool, cell, margin_m=margin_m, self_margin_m=self_margin_m)


def fresh(robot, **kwargs):
    """The model as built with nothing kept from earlier models."""
    saved = dict(collision_kept.KEPT)
    collision_kept.KEPT.clear()
    try:
        return build(robot, **kwargs)
    finally:
        collision_kept.KEPT.clear()
        collision_kept.KEPT.update(saved)


def path(n=12, seed=3):
    rng = np.random.default_rng(seed)
    start = np.radians([-35.0, 20.0, 15.0, 10.0, 50.0, 30.0])
    return start + np.cumsum(rng.normal(0.0, np.radians(2.0), (n, 6)), axis=0)


def every_pair(model, qs):
    return np.array([[model.pair_distance(q, p) for p in range(len(model.pairs))] for q in qs])


def fcl_nozzle_to(robot, q, box):
    """python-fcl's distance [m] from the nozzle on the flange (pose from Pinocchio) to a cell box."""
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, q)
    fid = robot.model.getFrameId(robot.spec.flange_frame)
    T = pin.updateFramePlacement(robot.model, data, fid).homogeneous @ NOZZLE.pose
    nozzle = fcl.CollisionObject(
        fcl.Cylinder(NOZZLE.radius_m, NOZZLE.length_m), fcl.Transform(T[:3, :3], T[:3, 3])
    )
    other = fcl.CollisionObject(fcl.Box(*box.size_m), fcl.Transform(box.pose[:3, :3], box.pose[:3, 3]))
    return fcl.distance(nozzle, other, fcl.DistanceRequest())


@pytest.fixture(scope="module")
def robot():
    return load_robot("abb_irb4600_60_205")


def test_a_moved_cell_object_or_margin_keeps_pairs_and_motion_bounds_with_a_fresh_models_figures(robot):
    """The part 3 mm away and the cell margin 2 mm up: the new model shares the first's pairs, motion
    bounds and moving hulls, and its distances, margins, motion bounds and carried bounds are a fresh
    model's; the nozzle's distance to the moved pillar is FCL's."""
    first = build(robot)
    first_motion = first.pair_motion
    moved = dataclasses.replace(PILLAR, pose=make_transform(p=[1.503, -0.65, 1.0]))
    for kwargs in ({"cell": (moved, BALL)}, {"margin_m": 0.012}):
        again = build(robot, **kwargs)
        new = fresh(robot, **kwargs)
        assert again._kept is first._kept and new._kept is not first._kept
        assert again.pair_motion is first_motion
        assert np.array_equal(again.pair_motion, new.pair_motion)
        assert again.joint_reach is first.joint_reach and np.array_equal(again.joint_reach, new.joint_reach)
        assert again.pairs == new.pairs and again.excluded == new.excluded
        assert np.array_equal(again.pair_margins, new.pair_margins)
        qs = path()
        assert np.array_equal(every_pair(again, qs), every_pair(new, qs))
        prior = checked_bounds(first, qs, every_pair(first, qs))
        q1 = qs + np.radians(0.2)
        assert np.array_equal(carried_bounds(again, prior, q1), carried_bounds(new, prior, q1))
    assert set(build(robot, margin_m=0.012).pair_margins[~first._self]) == {0.012}
    again = build(robot, cell=(moved, BALL))
    k = again.pairs.index(("tool:nozzle", "pillar"))
    for q in path(4):
        assert again.pair_distance(q, k) == pytest.approx(fcl_nozzle_to(robot, q, moved), abs=1e-9)


def test_a_carried_bound_of_a_moved_pillar_takes_off_its_displacement(robot):
    """The pillar 3 mm along x: a pair against it keeps the prior bound less 3 mm (the box's corners all
    move 3 mm), a pair against the ball keeps the whole bound; the robot does not move."""
    first = build(robot)
    qs = path()
    bounds = every_pair(first, qs)
    prior = checked_bounds(first, qs, bounds)
    moved = dataclasses.replace(PILLAR, pose=make_transform(p=[1.503, -0.65, 1.0]))
    again = build(robot, cell=(moved, BALL))
    carried = carried_bounds(again, prior, qs)
    for p, (_, other) in enumerate(again.pairs):
        want = bounds[:, p] - (0.003 if other == "pillar" else 0.0)
        want = np.where(want > 0.0, want, -np.inf)
        assert np.allclose(carried[:, p], want, atol=1e-12), again.pairs[p]


@pytest.mark.parametrize(
    "change",
    [
        {"self_margin_m": 0.02},
        {"tool": (dataclasses.replace(NOZZLE, radius_m=0.05),)},
        {"tool": (dataclasses.replace(NOZZLE, pose=make_transform(p=[0.0, 0.0, 0.25])),)},
        {"base": make_transform(p=[0.0, 0.001, 0.0])},
        {"cell": (dataclasses.replace(PILLAR, workpiece=True), BALL)},
        {"cell": (dataclasses.replace(PILLAR, name="post"), BALL)},
    ],
    ids=["self margin", "tool radius", "tool pose", "base", "workpiece", "cell name"],
)
def test_a_changed_robot_side_or_cell_name_gets_its_own_selection(robot, change):
    """A change the pairs or motion bounds read gives a model of its own, equal to a fresh one."""
    first = build(robot)
    assert first.pair_motion.shape == (len(first.pairs), 6)
    again = build(robot, **change)
    assert again._kept is not first._kept
    new = fresh(robot, **change)
    assert again.pairs == new.pairs and again.excluded == new.excluded
    assert np.array_equal(again.pair_motion, new.pair_motion)
    qs = path(4)
    assert np.array_equal(every_pair(again, qs), every_pair(new, qs))


def test_the_tools_radius_changes_its_motion_bound(robot):
    """A wider nozzle reaches further from the wrist axes: its pairs' bounds grow; about joint 6 (the
    flange z axis, the nozzle's) by the corners of the box around it, 2 cm x sqrt(2) further out."""
    first = build(robot)
    wide = build(robot, tool=(dataclasses.replace(NOZZLE, radius_m=0.05),))
    k = first.pairs.index(("tool:nozzle", "pillar"))
    assert (wide.pair_motion[k] >= first.pair_motion[k]).all()
    # joint 6's reach, kept apart: the nozzle's centre 15 cm out along the flange axis plus its box's half diagonal
    assert wide.joint_reach is not first.joint_reach
    for model, radius in ((first, 0.03), (wide, 0.05)):
        assert model.joint_reach[5] == pytest.approx(0.15 + np.linalg.norm([radius, radius, 0.15]), abs=1e-9)
    assert wide.pair_motion[k, 5] == pytest.approx(first.pair_motion[k, 5] + 0.02 * np.sqrt(2.0), abs=1e-9)


def test_another_robot_gets_its_own_selection(robot):
    """Another robot in the same cell with the same tool shares nothing with the first's model."""
    first = build(robot)
    other = load_robot("ur10e")
    again = build(other)
    assert again._kept is not first._kept and again._kept.robot is other
    assert again.pairs == fresh(other).pairs


def test_a_kept_models_pair_indices_labels_and_flags_are_its_own_bodies(robot):
    """Built again with the pillar moved (the selection kept), and with it renamed (a selection of its
    own): each pair's indices name the bodies of its labels, its self flag says whether the other body
    is a robot link or tool shape, and its mesh and hull flags are those of its two bodies, as a loop
    over the model's own bodies reads them; the kept arrays cannot be written to."""
    first = build(robot)
    moved = dataclasses.replace(PILLAR, pose=make_transform(p=[1.503, -0.65, 1.0]))
    renamed = dataclasses.replace(PILLAR, name="post")
    bracket = Shape("bracket", "mesh", pose=make_transform(p=[1.3, 0.4, 0.6]), file=str(BRACKET), units="mm")
    for cell, shared in (((moved, BALL), True), ((renamed, BALL), False), ((PILLAR, bracket), False)):
        again = build(robot, cell=cell)
        assert (again._kept is first._kept) == shared
        assert ("tool:nozzle", cell[0].name) in again.pairs
        labels = [b.label for b in again.bodies]
        assert len(again.pairs) == len(again._pa) == len(again._pb) == len(again._self)
        for k, (body, other) in enumerate(again.pairs):
            a, b = labels.index(body), labels.index(other)
            assert (int(again._pa[k]), int(again._pb[k])) == (a, b)
            A, B = again.bodies[a], again.bodies[b]
            assert bool(again._self[k]) == (B.kind in ("link", "tool"))
            assert bool(again._bounded[k]) == (A.vertices is None and B.vertices is None)
            assert bool(again._hulled[k]) == (B.hull is not None and B.kind == "cell")
        if cell[1] is bracket:  # a mesh with its hull: its pairs are hulled and not bounded
            near = [k for k, (_, other) in enumerate(again.pairs) if other == "bracket"]
            assert near and again._hulled[near].all() and not again._bounded[near].any()
        for a in (again._pa, again._pb, again._self):
            with pytest.raises(ValueError):
                a[0] = a[0]
