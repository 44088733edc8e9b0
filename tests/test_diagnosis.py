"""Diagnosis of repaired and infeasible segments, the messages' margins and the exit statuses."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.optimize

from refine.cli import exit_status, main
from refine.collision import CollisionModel
from refine.frames import make_transform
from refine.optimise.clearance import ClearanceSource
from refine.optimise.diagnosis import Diagnoser, closest_pair_text, reach_gap, reach_tilts
from refine.optimise.reach import reach_model
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot
from refine.settings import Shape

ROOT = Path(__file__).resolve().parents[1]
UNREACHABLE = ROOT / "problems" / "unreachable"


def test_exit_status_is_zero_for_executable_answers_and_one_for_infeasible():
    # README: 0 when every pass is ok or repaired, 1 when a pass is infeasible
    assert [exit_status(s) for s in ("ok", "repaired", "infeasible")] == [0, 0, 1]


@pytest.mark.slow
def test_run_exits_0_for_a_repair_and_1_for_an_infeasible_problem(tmp_path, capsys):
    assert main(["run", str(UNREACHABLE / "joint_limit"), "--out", str(tmp_path / "a"), "--no-report"]) == 0
    assert "status       repaired" in capsys.readouterr().out
    assert main(["run", str(UNREACHABLE / "out_of_reach"), "--out", str(tmp_path / "b"), "--no-report"]) == 1
    assert "status       infeasible" in capsys.readouterr().out


@pytest.fixture(scope="module")
def tool_in_forearm():
    """The IRB 4600 with a 80 mm ball 0.45 m behind the flange: inside the forearm (a self pair),
    and a box far away in the cell."""
    robot = load_robot("abb_irb4600_60_205")
    tcp = make_transform(p=[0.0, 0.0, 0.35])
    ball = Shape("ball", "sphere", pose=make_transform(p=[0.0, 0.0, -0.45]), radius_m=0.08)
    far = Shape("cabinet", "box", pose=make_transform(p=[3.0, 0.0, 0.0]), size_m=(0.5, 0.5, 0.5))
    model = CollisionModel(robot, np.eye(4), tcp, (ball,), (far,), margin_m=0.01, self_margin_m=0.005)
    return ClearanceSource(model, TcpKinematics(robot, np.eye(4), tcp), 0.001)


def test_a_self_collision_is_reported_with_the_self_margin(tool_in_forearm):
    q = np.zeros((3, 6))
    path = SimpleNamespace(fused=SimpleNamespace(s=np.array([0.0, 0.001, 0.002])))
    (v,) = tool_in_forearm.violations(path, q)
    assert v.reason.startswith("self-collision") and "tool:ball" in v.reason
    assert v.limit == pytest.approx(0.005)  # the self margin set above, not the cell margin 0.01
    assert "limit 0.005 m" in v.describe()


def test_the_clearance_line_says_when_the_closest_pair_is_a_self_pair(tool_in_forearm):
    q = np.zeros((3, 6))
    text = closest_pair_text(tool_in_forearm.clearance(q), {"cabinet"}, 0.01, 0.005)
    assert "self pair, self margin 5 mm" in text and "tool:ball" in text
    # the same check with the ball named as a cell object reads as a cell pair with the cell margin
    body, other = tool_in_forearm.clearance(q).segment_pair[0]
    text = closest_pair_text(tool_in_forearm.clearance(q), {"cabinet", other}, 0.01, 0.005)
    assert "cell pair, margin 10 mm" in text


def test_the_reach_model_matches_the_data_sheet_arm_lengths():
    """Wrist-centre range from the shoulder: iiwa 14 0.42 + 0.40 m links (axis 4 within 120 - 2 deg),
    IRB 4600-60/2.05 upper arm 0.90 m and forearm 0.96 m with the 0.175 m elbow offset."""
    iiwa = reach_model(load_robot("kuka_iiwa14_r820"), math.radians(2.0))
    assert iiwa.spherical
    assert iiwa.r_max_m == pytest.approx(0.82, abs=1e-4)
    bent = math.radians(180.0 - 118.0)  # the angle between the links at the elbow
    assert iiwa.r_min_m == pytest.approx(
        math.sqrt(0.42**2 + 0.40**2 - 2 * 0.42 * 0.40 * math.cos(bent)), abs=1e-3
    )
    irb = reach_model(load_robot("abb_irb4600_60_205"), math.radians(2.0))
    assert irb.spherical and irb.r_max_m == pytest.approx(0.90 + math.hypot(0.175, 0.96), abs=1e-4)
    assert not reach_model(load_robot("ur10e"), math.radians(2.0)).spherical  # offset wrist


def test_the_distance_from_the_shoulder_is_to_the_shoulder_turned_towards_or_away_from_the_point():
    """IRB 4600 (shoulder 0.175 m off axis 1): the shoulder turned with axis 1 by the point's azimuth
    less the wrist centre's (SciPy's rotation about the axis), or by half a turn more, whichever
    distance is nearer the range; points around the arm, on axis 1 and next to it."""
    from scipy.spatial.transform import Rotation

    reach = reach_model(load_robot("abb_irb4600_60_205"), math.radians(2.0))
    w, p = reach.axis1
    e1 = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(w, e1)
    points = np.random.default_rng(5).normal(size=(300, 3)) * 1.2
    points[:3] = p + np.outer([0.3, 1.0, -0.5], w)  # on axis 1
    points[3] = p + 2.0 * w + 1e-9 * e1
    expected = []
    for x in points:
        turn = math.atan2((x - p) @ e2, (x - p) @ e1) - math.atan2(
            (reach.wrist_ref - p) @ e2, (reach.wrist_ref - p) @ e1
        )
        d = [
            np.linalg.norm(x - (p + Rotation.from_rotvec(a * w).apply(reach.shoulder_ref - p)))
            for a in (turn, turn + math.pi)
        ]
        off = [max(reach.r_min_m - v, 0.0, v - reach.r_max_m) for v in d]
        expected.append(d[0] if off[0] <= off[1] else d[1])
    assert np.abs(reach.distance(points) - np.array(expected)).max() <= 1e-12


def test_the_reach_gap_claims_no_more_than_the_shoulder_turned_anywhere_on_its_circle_allows():
    """IRB 4600 (shoulder 0.175 m off axis 1), the TCP on the flange: a TCP is out of reach by at least the
    gap only if, with the shoulder turned to any of 7,200 angles about axis 1 (SciPy's rotation),
    the sphere of wrist centres around it stays beyond r_max or inside r_min of that shoulder; the
    gap is that least excess. Points around the arm, close to the shoulder, and reached by forward
    kinematics (gap 0)."""
    from scipy.spatial.transform import Rotation

    robot = load_robot("abb_irb4600_60_205")
    tool = np.eye(4)
    kin = TcpKinematics(robot, np.eye(4), tool)
    reach = reach_model(robot, math.radians(2.0))
    L = float(np.linalg.norm((np.linalg.inv(tool) @ np.append(reach.point_in_flange, 1.0))[:3]))
    w, c = reach.axis1
    rng = np.random.default_rng(11)
    shoulder = reach.shoulder_ref
    # around axis 1 at the shoulder's height: inside r_min of the shoulder turned towards them
    rho, phi, dz = (
        rng.uniform(0.0, 0.3, 200),
        rng.uniform(-math.pi, math.pi, 200),
        rng.uniform(-0.2, 0.2, 200),
    )
    near = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), shoulder[2] + dz])
    q = rng.uniform(robot.spec.lower + 0.05, robot.spec.upper - 0.05, (200, robot.nq))
    reached = kin.poses(q)[:, :3, 3]
    points = np.vstack([rng.normal(size=(300, 3)) * 1.5, near, reached])
    turns = Rotation.from_rotvec(np.outer(np.linspace(0.0, 2 * math.pi, 7200, endpoint=False), w))
    shoulders = c + turns.apply(shoulder - c)  # (7200, 3)
    d = np.linalg.norm(points[:, None, :] - shoulders[None], axis=2)  # (P, 7200)
    excess = np.maximum(np.maximum(d - L - reach.r_max_m, reach.r_min_m - d - L), 0.0).min(axis=1)
    gap = reach_gap(kin, points, 2.0)
    assert np.all(gap <= excess + 1e-9)
    assert np.abs(gap - excess).max() <= 1e-4  # the sampled circle's spacing (0.05 deg at <= 2 m)
    assert np.count_nonzero(excess[300:500] > 0.01) > 0  # some points near the shoulder are out of reach
    assert np.all(gap[500:] <= 1e-9)


def test_the_tilt_that_brings_the_wrist_centre_into_reach_matches_the_geometry():
    """iiwa 14, 0.20 m tool pointing down and leaning 30 deg back: the wrist centre sits 0.326 m up
    the tool axis from the TCP (0.126 m flange + 0.20 m tool); the needed tilt is found here with
    brentq on the plane geometry, independently of the diagnosis code."""
    robot = load_robot("kuka_iiwa14_r820")
    tcp = make_transform(p=[0.0, 0.0, 0.20])
    kin = TcpKinematics(robot, np.eye(4), tcp)
    shoulder = np.array([0.0, 0.0, 0.36])
    lean, x, z, arm = math.radians(30.0), 0.70, 0.10, 0.326

    def wrist(a):  # tool axis (pointing from flange to tip) leaning a back towards the robot
        return np.array([x + arm * math.sin(a), 0.0, z + arm * math.cos(a)])

    a_in = scipy.optimize.brentq(lambda a: np.linalg.norm(wrist(a) - shoulder) - 0.82, 0.0, lean)
    axis = np.array([-math.sin(lean), 0.0, -math.cos(lean)])
    x_axis = np.array([math.cos(lean), 0.0, -math.sin(lean)])
    R = np.column_stack([x_axis, np.cross(axis, x_axis), axis])
    path = SimpleNamespace(s=np.zeros(1), positions=np.array([[x, 0.0, z]]), rotations=R[None])
    tol = SimpleNamespace(orientation_deg=3.0, joint_margin_deg=2.0, singularity_margin=0.02)
    d0, tilt, d_cone, _, _ = Diagnoser(kin, path, tol, True).reach_at(make_transform(R, [x, 0.0, z]))
    assert d0 == pytest.approx(np.linalg.norm(wrist(lean) - shoulder), abs=1e-6)
    assert d0 > 0.82
    assert tilt == pytest.approx(math.degrees(lean - a_in), abs=0.15)  # searched in 0.1 deg steps
    assert d_cone == pytest.approx(np.linalg.norm(wrist(lean - math.radians(3.0)) - shoulder), abs=1e-3)


def test_reach_tilts_along_a_path_tilts_only_the_poses_out_of_reach():
    """The geometry of the test above along a line of TCP points, x from 0.50 to 0.80 m: a pose
    whose wrist centre is within 0.82 m of the shoulder needs no tilt and keeps its orientation;
    the others need the tilt brentq finds on the plane geometry."""
    robot = load_robot("kuka_iiwa14_r820")
    kin = TcpKinematics(robot, np.eye(4), make_transform(p=[0.0, 0.0, 0.20]))
    shoulder = np.array([0.0, 0.0, 0.36])
    lean, z, arm = math.radians(30.0), 0.10, 0.326
    axis = np.array([-math.sin(lean), 0.0, -math.cos(lean)])
    x_axis = np.array([math.cos(lean), 0.0, -math.sin(lean)])
    R = np.column_stack([x_axis, np.cross(axis, x_axis), axis])
    xs = np.linspace(0.50, 0.80, 31)
    path = SimpleNamespace(
        s=xs - xs[0], positions=np.column_stack([xs, 0 * xs, 0 * xs + z]), rotations=np.repeat(R[None], 31, 0)
    )
    tol = SimpleNamespace(orientation_deg=3.0, joint_margin_deg=2.0, singularity_margin=0.02)
    tilts, rotations = reach_tilts(kin, path, tol, True)
    for k, x in enumerate(xs):

        def gap(a, x=x):  # wrist-centre distance beyond 0.82 m with the tool leaning a back
            return np.linalg.norm([x + arm * math.sin(a), 0.0, z + arm * math.cos(a) - shoulder[2]]) - 0.82

        if gap(lean) <= 0.0:
            assert tilts[k] == 0.0 and np.array_equal(rotations[k], R)
        else:
            a_in = scipy.optimize.brentq(gap, 0.0, lean) if gap(0.0) < 0 else None
            if a_in is None:  # even upright it is out of reach: more tilt than the lean
                assert tilts[k] > math.degrees(lean)
            else:
                assert tilts[k] == pytest.approx(math.degrees(lean - a_in), abs=0.15)
                angle = math.degrees(math.acos(np.clip(rotations[k][:, 2] @ R[:, 2], -1, 1)))
                assert angle == pytest.approx(tilts[k], abs=1e-6)
    assert (tilts == 0).sum() >= 3 and (tilts > 0).sum() >= 3  # both kinds on this line


@pytest.mark.slow
def test_a_run_out_of_time_says_so_and_is_not_a_verdict():
    """wrist_flip needs well over 0.1 s of IPOPT; with that budget the pass stops, saying why."""
    import dataclasses

    from refine.export.result_json import result_dict
    from refine.problem import load_problem
    from refine.run.solve import solve_problem

    problem = load_problem(UNREACHABLE / "wrist_flip")
    problem = dataclasses.replace(problem, repair=dataclasses.replace(problem.repair, time_limit_s=0.1))
    result = solve_problem(problem)
    refinement = result.refinement
    assert refinement.time_limit_reached and refinement.status == "timeout"
    assert "time limit of 0.1 s" in refinement.reason and refinement.solver_status == "time limit reached"
    assert result_dict(result)["solver"]["time_limit_reached"] is True
    assert exit_status(result.status) == 1
