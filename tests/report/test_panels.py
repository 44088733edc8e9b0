"""The clearance panel says which of its figures are lower bounds (waypoints the check left unmeasured)."""

from types import SimpleNamespace

import numpy as np

import refine
from refine.collision import check_path_clearance
from refine.frames import make_transform
from refine.report.panels import clearance_lines
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot
from refine.settings import Shape

TCP = make_transform(p=[0.0, 0.0, 0.35])


def by_name(lines):
    return {line["name"]: line for line in lines}


def test_every_waypoint_measured_draws_one_line_and_says_nothing_of_bounds():
    s = np.array([0.0, 0.1, 0.2])
    check = SimpleNamespace(
        waypoint_distance_m=np.array([0.05, 0.04, 0.06]),
        segment_distance_m=np.array([0.04, 0.03]),
        segment_samples=np.array([1, 4]),
        waypoint_measured=None,
    )
    lines = by_name(clearance_lines(s, check, 0.01))
    assert set(lines) == {"at waypoints", "least between waypoints", "margin"}
    assert lines["at waypoints"]["y"] == [50.0, 40.0, 60.0]
    assert not any("lower bound" in name for name in lines)


def test_unmeasured_waypoints_and_the_one_step_segments_ending_at_them_are_drawn_as_lower_bounds():
    """Four waypoints, the second unmeasured; segment 0 (one sub-step, ends 0 and 1) takes waypoint
    1's bound, segment 1 was sampled inside (3 sub-steps: its ends were measured then, so it is
    exact), segment 2 ends at two measured waypoints."""
    s = np.array([0.0, 0.1, 0.2, 0.3])
    check = SimpleNamespace(
        waypoint_distance_m=np.array([0.050, 0.020, 0.040, 0.060]),
        segment_distance_m=np.array([0.020, 0.015, 0.040]),
        segment_samples=np.array([1, 3, 1]),
        waypoint_measured=np.array([True, False, True, True]),
    )
    lines = by_name(clearance_lines(s, check, 0.01))
    every = lines["at waypoints (lower bound where not measured)"]
    assert every["y"] == [50.0, 20.0, 40.0, 60.0]
    assert every["text"] == ["measured", "lower bound (waypoint not measured)", "measured", "measured"]
    bound = lines["at waypoints: lower bound (not measured)"]
    assert (bound["x"], bound["y"], bound["mode"]) == ([0.1], [20.0], "markers")
    exact = lines["least between waypoints"]
    assert (exact["x"], exact["y"]) == ([0.15, 0.25], [15.0, 40.0])
    seg_bound = lines["least between waypoints: lower bound"]
    assert (seg_bound["x"], seg_bound["y"]) == ([0.05], [20.0])
    assert seg_bound["text"] == ["lower bound (an end not measured)"]
    assert lines["margin"]["y"] == [10.0, 10.0]


def test_on_a_real_check_the_points_not_called_bounds_are_fcls_figures_and_the_bounds_at_most_fcls():
    """A random walk of the IRB 4600 past a pillar and a ball, checked measuring only the waypoints
    that can hold the least figures and measuring every waypoint: the panel's points labelled
    measured are the full check's FCL figures, those labelled lower bounds are at most them, and
    some of them are strictly below (so the label tells something)."""
    robot = load_robot("abb_irb4600_60_205")
    pillar = Shape("pillar", "box", pose=make_transform(p=[1.5, -0.65, 1.0]), size_m=(0.2, 0.2, 2.0))
    ball = Shape("ball", "sphere", pose=make_transform(p=[1.45, -0.5, 0.5]), radius_m=0.08)
    nozzle = Shape("nozzle", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.15]), radius_m=0.03, length_m=0.3)
    rng = np.random.default_rng(4)
    q = np.radians([-35.0, 20.0, 15.0, 10.0, 50.0, 30.0]) + np.cumsum(rng.normal(0.0, np.radians(0.6), (60, 6)), axis=0)
    kin = TcpKinematics(robot, np.eye(4), TCP)

    def check(every):
        model = refine.collision.CollisionModel(
            robot, np.eye(4), TCP, (nozzle,), (pillar, ball), margin_m=0.01, self_margin_m=0.005
        )
        return check_path_clearance(model, q, kin, 0.005, every_waypoint=every)

    full, least_only = check(True), check(False)
    s = np.linspace(0.0, 0.59, len(q))
    lines = by_name(clearance_lines(s, least_only, 0.01))
    every = lines["at waypoints (lower bound where not measured)"]
    exact_wp = np.array([t == "measured" for t in every["text"]])
    truth = np.round(full.waypoint_distance_m * 1e3, 4)
    shown = np.array(every["y"])
    assert 0 < exact_wp.sum() < len(q)
    assert np.array_equal(shown[exact_wp], truth[exact_wp])
    assert np.all(shown[~exact_wp] <= truth[~exact_wp])
    assert np.any(shown[~exact_wp] < truth[~exact_wp] - 1e-3)
    assert lines["at waypoints: lower bound (not measured)"]["y"] == shown[~exact_wp].tolist()
    mid = np.round(0.5 * (s[1:] + s[:-1]), 4)
    seg_truth = dict(zip(mid.tolist(), np.round(full.segment_distance_m * 1e3, 4).tolist(), strict=True))
    exact_seg = lines["least between waypoints"]
    assert all(seg_truth[x] == y for x, y in zip(exact_seg["x"], exact_seg["y"], strict=True))
    bound_seg = lines["least between waypoints: lower bound"]
    assert bound_seg["x"] and all(seg_truth[x] >= y for x, y in zip(bound_seg["x"], bound_seg["y"], strict=True))
    assert len(exact_seg["x"]) + len(bound_seg["x"]) == len(q) - 1
