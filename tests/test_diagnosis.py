"""Diagnosis of repaired and infeasible segments, the messages' margins and the exit statuses."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from refine.cli import exit_status, main
from refine.collision import CollisionModel
from refine.diagnosis import closest_pair_text
from refine.frames import make_transform
from refine.optimise.clearance import ClearanceSource
from refine.optimise.seed import TcpKinematics
from refine.robot import load_robot
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
