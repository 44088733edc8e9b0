"""The proof of a line between checked waypoints against FCL's distances along it."""

import dataclasses

import numpy as np

import refine
from refine.collision import margins_proved
from refine.collision.carry import bounds_between, checked_bounds, proved_between
from refine.collision.model import CollisionModel
from refine.frames import make_transform
from refine.robot.registry import load_robot

TCP = make_transform(p=[0.0, 0.0, 0.15])
SUB = 4  # FCL samples per segment between rows
MARGIN = 0.01  # [m]
WAYPOINTS = 9


def setup(deviation_deg):
    """A UR10e with a gun 2-7 cm over a table, 9 waypoints and 3 rows inside each waypoint segment off their joint line.

    The rows leave the joint line by up to ``deviation_deg`` per joint, as the controller's line does.
    """
    table = refine.Shape("table", "box", pose=make_transform(p=[0.75, -0.15, 0.3]), size_m=(0.4, 0.8, 0.1))
    part = refine.Shape(
        "part", "box", pose=make_transform(p=[0.6, 0.0, 0.17]), size_m=(0.2, 0.5, 0.04), workpiece=True
    )
    gun = refine.Shape(
        "gun", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.05]), radius_m=0.03, length_m=0.1
    )
    model = CollisionModel(
        load_robot("ur10e"), np.eye(4), TCP, (gun,), (table, part), margin_m=MARGIN, self_margin_m=0.0
    )
    q = np.tile(np.radians([0.0, -100.0, -100.0, -70.0, 90.0, 0.0]), (WAYPOINTS, 1))
    q[:, 0] += np.linspace(-0.04, 0.04, WAYPOINTS)
    q[1::2, 1] += np.radians(0.5)
    exact = np.array([[model.pair_distance(qk, p) for p in range(len(model.pairs))] for qk in q])
    checked = checked_bounds(model, q, exact)
    place = np.linspace(0.0, WAYPOINTS - 1, 4 * (WAYPOINTS - 1) + 1)
    a = np.minimum(np.floor(place).astype(int), WAYPOINTS - 2)
    t = (place - a)[:, None]
    rows = q[a] + t * (q[a + 1] - q[a])
    inside = (t[:, 0] > 0.0) & (t[:, 0] < 1.0)
    bump = np.sin(np.pi * t[inside]) * np.radians(deviation_deg)  # shoulder and elbow: < 0 dips
    rows[inside] += bump * np.array([0.0, 1.0, 0.6, 0.0, 0.0, 0.0])
    return model, checked, rows, place, (gun,), (table, part)


def least_clearance(model, rows):
    """FCL's least distance minus margin over every pair along the joint segments between the rows [m]."""
    margins = model.pair_margins
    t = np.linspace(0.0, 1.0, SUB + 1)[:, None]
    points = np.concatenate([r0 + t * (r1 - r0) for r0, r1 in zip(rows[:-1], rows[1:], strict=True)])
    return min(model.pair_distance(qk, p) - margins[p] for qk in points for p in range(len(model.pairs)))


def test_a_proof_between_waypoints_holds_along_the_line_and_implies_the_known_bounds_proof():
    """Tolerances swept from a clear line to one the line breaks: wherever the proof holds, FCL finds
    every pair at least its margin less the tolerance along the rows (between samples, to the
    sampling's resolution), and the bounds of ``bounds_between`` prove the margins too.
    The sweep reaches far enough that the proof refuses, and starts where it holds."""
    model, checked, rows, place, _, _ = setup(-1.0)
    least = least_clearance(model, rows)
    waypoints = float((checked.bounds - model.pair_margins).min())
    assert least < waypoints - 0.005  # the line dips below the waypoints' least clearance
    proved = []
    for tolerance in np.linspace(-waypoints, 0.06, 73):
        ok = proved_between(model, checked, rows, place, tolerance_m=tolerance)
        proved.append(ok)
        if ok:
            assert least >= -tolerance - 1e-4, tolerance  # sampled between rows: 1e-4 m of slack
            prior = bounds_between(model, checked, rows, place)
            assert margins_proved(model, rows, prior=prior, tolerance_m=tolerance)
    assert proved[-1] and not proved[0]


def test_a_proof_between_waypoints_refuses_another_model_and_rows_off_their_waypoints():
    model, checked, rows, place, tool, cell = setup(0.0)
    assert proved_between(model, checked, rows, place)
    wrong = rows.copy()
    wrong[0] += 1e-3  # said to be at waypoint 0
    assert not proved_between(model, checked, wrong, place)
    assert not proved_between(model, checked, rows[:1], place[:1])
    raised = tuple(dataclasses.replace(o, pose=make_transform(p=[0.0, 0.0, 0.005]) @ o.pose) for o in cell)
    other = CollisionModel(model.robot, np.eye(4), TCP, tool, raised, margin_m=MARGIN, self_margin_m=0.0)
    assert not proved_between(other, checked, rows, place)
