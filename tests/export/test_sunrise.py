"""The Sunrise application: Java a grammar parses, frames that are the plan, the LBR's redundancy, I/O."""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from refine.errors import InputError
from refine.export.krl import kuka_status_turn
from refine.export.rapid import segment_speeds
from refine.export.sunrise import class_name, parse_sunrise, sunrise_signal, write_sunrise
from refine.frames import invert_transform
from refine.paths import Trajectory
from refine.problem import load_problem
from refine.robot.registry import load_robot

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location(
    "program_grammar", Path(__file__).with_name("program_grammar.py")
)
pg = importlib.util.module_from_spec(_spec)
sys.modules["program_grammar"] = pg
_spec.loader.exec_module(pg)


@pytest.fixture(scope="module")
def iiwa():
    return load_robot("kuka_iiwa14_r820")


@pytest.fixture(scope="module")
def weld_problem():
    return load_problem(ROOT / "problems" / "tig_weld")


def _trajectory(robot, problem, n: int, turn_deg: float = 0.0) -> Trajectory:
    q0 = np.radians([-20.0, 57.0, -11.0, -72.0, 24.0, 60.0, 50.0])
    q1 = q0 + np.radians([25.0, 8.0, 12.0, 10.0, -40.0, 15.0, 40.0 + turn_deg])
    q = q0 + (q1 - q0) * np.linspace(0.0, 1.0, n)[:, None]
    poses = np.array([problem.robot.base_in_world @ robot.fk(qk) @ problem.tool.tcp_in_flange for qk in q])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))])
    v = 0.004 + 0.002 * np.sin(np.linspace(0.0, np.pi, n))
    t = np.concatenate([[0.0], np.cumsum(np.diff(s) / (0.5 * (v[1:] + v[:-1])))])
    return Trajectory(t, s, q, poses[:, :3, 3].copy(), poses, poses[:, :3, :3].copy(), v)


@pytest.fixture(scope="module")
def written(tmp_path_factory, iiwa, weld_problem):
    passes = [
        ("root", _trajectory(iiwa, weld_problem, 260)),
        ("cap", _trajectory(iiwa, weld_problem, 40, 10.0)),
    ]
    path = write_sunrise(
        tmp_path_factory.mktemp("sr") / "x.java", passes[0][1], weld_problem, iiwa, passes=passes
    )
    return path, passes


def test_the_class_is_named_after_the_problem_and_the_file_after_the_class(written):
    path, _ = written
    assert (
        path.name == "TigWeld.java"
        and class_name("tig_weld") == "TigWeld"
        and class_name("3 beads") == "Path3Beads"
    )
    assert "public class TigWeld extends RoboticsAPIApplication {" in path.read_text()


def test_a_java_grammar_parses_it_and_its_frames_are_the_planned_poses(written, weld_problem):
    path, passes = written
    prog = pg.read_sunrise(path, weld_problem.robot.base_in_world)
    assert len(prog.passes) == 2
    for parsed, (_, tr) in zip(prog.passes, passes, strict=True):
        dp, dr = pg.pose_errors(parsed.poses, tr.poses)
        assert dp <= 1e-4 and dr <= 2e-6
    assert prog.facts["rows"] == {
        "pass1Part1": 200,
        "pass1Part2": 60,
        "pass2Part1": 40,
    }  # 200 rows per method
    assert prog.statements[:2] == prog.statements[-2:] == ["ptp", "home"]  # ptp(home()) first and last


def test_redundancy_and_speeds_are_those_of_the_plan(written, iiwa, weld_problem):
    path, passes = written
    T_base_world = invert_transform(weld_problem.robot.base_in_world)
    for run, (_, tr) in zip(parse_sunrise(path), passes, strict=True):
        status, turn = kuka_status_turn(iiwa, tr.q)
        np.testing.assert_array_equal(run.status, status)
        np.testing.assert_array_equal(run.turn, turn)
        np.testing.assert_allclose(run.e1_rad, tr.q[:, 2], atol=1e-9)
        np.testing.assert_allclose(run.positions, (T_base_world @ tr.poses)[:, :3, 3], atol=1e-7)
        assert run.speeds[0] == pytest.approx(0.25)
        np.testing.assert_allclose(run.speeds[1:], segment_speeds(tr), atol=0.5e-4 + 1e-9)


def test_the_weld_sequence_uses_the_media_flange_signals(written):
    text = written[0].read_text()
    start = [
        "mediaFlange.setOutputX3Pin2(true); // gas pre-flow",
        "ThreadUtil.milliSleep(500);",
        "mediaFlange.setOutputX3Pin1(true); // arc on",
        "while (!mediaFlange.getInputX3Pin3()) {",
        "ThreadUtil.milliSleep(1000); // crater fill",
        "mediaFlange.setOutputX3Pin1(false); // arc off",
        "ThreadUtil.milliSleep(6000); // gas post-flow",
    ]
    at = [text.index(s) for s in start]
    assert at == sorted(at)
    assert 'throw new IllegalStateException("Arc start failed: no InputX3Pin3 within 2.0 s");' in text
    assert "@Inject\n    private MediaFlangeIOGroup mediaFlange;" in text


def test_glue_switches_on_the_move_by_path_triggers(tmp_path, iiwa, weld_problem):
    glue = dataclasses.replace(
        weld_problem, process=dataclasses.replace(weld_problem.process, kind="glue", lead_m=0.003)
    )
    text = write_sunrise(tmp_path / "g.java", _trajectory(iiwa, glue, 30), glue, iiwa).read_text()
    assert ".triggerWhen(new MotionPathCondition(ReferenceType.DEST, -3.0, 0), processOn));" in text
    assert "new MotionPathCondition(ReferenceType.DEST, -offLead, 0), processOff);" in text
    assert (
        "setBlendingCart(1.0)" in text
        and "milliSleep" not in text.split("private void runPass")[1].split("} else {")[1]
    )
    prog = pg.read_sunrise(tmp_path / "TigWeld.java", glue.robot.base_in_world)
    assert len(prog.passes[0].poses) == 30


@pytest.mark.parametrize("name", ["doArcOn", "MediaFlange", "Media Flange.Out", "$OUT[1]"])
def test_a_signal_without_an_io_group_is_refused(name):
    with pytest.raises(InputError, match="Group|group"):
        sunrise_signal(name)


def test_only_a_seven_axis_lbr_gets_a_sunrise_application(tmp_path, weld_problem):
    ur = load_robot("ur10e")
    tr = Trajectory(
        np.arange(3.0),
        np.arange(3.0),
        np.zeros((3, 6)),
        np.zeros((3, 3)),
        np.tile(np.eye(4), (3, 1, 1)),
        np.tile(np.eye(3), (3, 1, 1)),
        np.ones(3),
    )
    with pytest.raises(InputError, match="seven-axis"):
        write_sunrise(tmp_path / "x.java", tr, weld_problem, ur)


def test_a_run_refuses_sunrise_for_a_six_axis_kuka_before_solving(weld_problem):
    from refine.robot.model import Robot
    from refine.run.preflight import preflight

    abb = load_robot("abb_irb4600_60_205")
    kuka6 = Robot(dataclasses.replace(abb.spec, controller="kuka"), abb.model)  # a six-axis KUKA arm
    problem = dataclasses.replace(weld_problem, robot=dataclasses.replace(weld_problem.robot, home_deg=None))
    with pytest.raises(InputError, match="seven-axis KUKA LBR"):
        preflight(problem, None, ("sunrise",), robot=kuka6)
    preflight(problem, None, ("krl",), robot=kuka6)  # the same arm may run KRL
