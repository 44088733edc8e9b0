"""Every program is parsed whole by a grammar of its language and its targets match trajectory.csv."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("lark")

from lark.exceptions import LarkError  # noqa: E402

from refine.export.krl import write_krl  # noqa: E402
from refine.export.rapid import write_rapid  # noqa: E402
from refine.export.urscript import write_urscript  # noqa: E402
from refine.paths import Trajectory  # noqa: E402
from refine.problem import ProcessSettings, load_problem  # noqa: E402
from refine.robot.model import Robot
from refine.robot.registry import load_robot
from refine.run.write import run

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location(
    "program_grammar", Path(__file__).with_name("program_grammar.py")
)
pg = importlib.util.module_from_spec(_spec)
sys.modules["program_grammar"] = pg
_spec.loader.exec_module(pg)

POSITION_MM, ORIENTATION_DEG = 1e-4, 2e-6  # the programs' rounding: 4 decimals of mm, 9 of a quaternion
CHAINED_MM = 2e-4  # a target and a rounded work object (4 decimals of mm each) chained


def test_rapid_glue_module_parses_and_its_targets_are_the_trajectory(tmp_path, trajectory, problem, irb4600):
    module = write_rapid(tmp_path / "g.mod", trajectory, problem, irb4600)
    prog = pg.read_rapid(module, problem.robot.base_in_world)
    (p,) = prog.passes
    dp, dr = pg.pose_errors(p.poses, trajectory.poses)
    assert dp <= CHAINED_MM and dr <= ORIENTATION_DEG
    st = prog.statements
    assert st[:3] == ["ConfJ", "ConfL", "MoveAbsJ"] and st[-1] == "MoveAbsJ", "home at start and end"
    assert st.count("TriggIO") == 2 and st.count("TriggL") == 2 and "SetDO" not in st
    # + the approach speed; more levels only as the speed share needs: levels a factor (1 - share)
    # apart cover the planned speeds' range with ceil(log(v_max / v_min) / -log(1 - share)) + 1
    v = 0.5 * (trajectory.speed[1:] + trajectory.speed[:-1])
    share = problem.output.speed_share
    geometric = math.ceil(math.log(v.max() / v.min()) / -math.log(1.0 - share)) + 1
    assert len(prog.facts["speeddata"]) <= max(problem.output.speed_levels, geometric) + 1


def test_rapid_weld_module_has_the_start_and_end_sequence(tmp_path, trajectory, problem, irb4600):
    weld = dataclasses.replace(
        problem,
        process=ProcessSettings(kind="weld", output="doArc", gas_output="doGas", arc_ok_input="diArc"),
    )
    prog = pg.read_rapid(write_rapid(tmp_path / "w.mod", trajectory, weld, irb4600), weld.robot.base_in_world)
    st = prog.statements
    seq = ["SetDO", "WaitTime", "SetDO", "WaitDI", "IF"]
    first = st.index("SetDO")
    assert st[first : first + 5] == seq
    assert st[-6:] == ["WaitTime", "SetDO", "WaitTime", "SetDO", "MoveL", "MoveAbsJ"]  # crater, post-flow
    dp, dr = pg.pose_errors(prog.passes[0].poses, trajectory.poses)
    assert dp <= CHAINED_MM and dr <= ORIENTATION_DEG


def test_long_paths_are_split_into_routines(tmp_path, trajectory_factory, problem, irb4600):
    tr = trajectory_factory(130)
    small = dataclasses.replace(problem, output=dataclasses.replace(problem.output, moves_per_routine=50))
    prog = pg.read_rapid(write_rapid(tmp_path / "r.mod", tr, small, irb4600), problem.robot.base_in_world)
    assert prog.facts["routines"] == ["main", "path_1", "path_2", "path_3"]  # 129 path moves
    dp, _ = pg.pose_errors(prog.passes[0].poses, tr.poses)
    assert dp <= CHAINED_MM


def test_krl_program_parses_and_its_points_are_the_trajectory(tmp_path, trajectory, problem, irb4600):
    kuka6 = Robot(dataclasses.replace(irb4600.spec, controller="kuka"), irb4600.model)
    glue = dataclasses.replace(problem, process=dataclasses.replace(problem.process, lead_m=0.003))
    src, dat = write_krl(tmp_path / "k.src", trajectory, glue, kuka6)
    prog = pg.read_krl(src, dat)
    (p,) = prog.passes
    dp, dr = pg.pose_errors(p.poses, trajectory.poses)
    # E6POS are in BASE_DATA[n] = the world seen from the base: poses in {F} as written
    assert dp <= POSITION_MM and dr <= ORIENTATION_DEG
    assert prog.statements.count("trigger:PATH") == 2
    assert prog.facts["axis_decls"] == ["XHOMEPOS"]


def test_urscript_in_both_modes_parses_and_its_poses_are_the_trajectory(tmp_path):
    ur = load_robot("ur10e")
    problem = load_problem(ROOT / "problems" / "ur10e_sealing")
    q0 = np.radians([0.0, -100.0, 130.0, -120.0, -90.0, 0.0])
    q = q0 + np.linspace(0.0, 1.0, 40)[:, None] * np.radians([20.0, 5.0, -5.0, 10.0, 10.0, 30.0])
    poses = np.array([problem.robot.base_in_world @ ur.fk(qk) @ problem.tool.tcp_in_flange for qk in q])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))])
    t = s / 0.05
    tr = Trajectory(t, s, q, poses[:, :3, 3].copy(), poses, poses[:, :3, :3].copy(), np.full(len(q), 0.05))
    for mode in ("program", "script_node"):
        script = write_urscript(tmp_path / f"{mode}.script", tr, problem, ur, mode=mode)
        prog = pg.read_urscript(script, problem.robot.base_in_world)
        dp, dr = pg.pose_errors(prog.passes[0].poses, poses)
        assert dp <= 1e-5 and dr <= ORIENTATION_DEG
        lines = script.read_text().strip().splitlines()
        assert (lines[-1] == "ur10e_sealing()") == (mode == "program")


@pytest.mark.parametrize(
    ("grammar", "text"),
    [
        ("rapid", "MODULE m\n PROC main()\n MoveL p1, v100 fine, tool0;\n ENDPROC\nENDMODULE\n"),
        ("rapid", "MODULE m\n PROC main()\n MoveL p1, v100, fine, tool0\n ENDPROC\nENDMODULE\n"),
        ("krl_src", "DEF p( )\nLIN XP1 C_DISS\nEND\n"),
        ("krl_src", "DEF p( )\nTRIGGER WHEN DISTANCE=1 DO $OUT[1]=TRUE\nEND\n"),
        ("urscript", "def p():\n  movel(p[0,0,0,0,0,0], a=1.2\nend\n"),
        ("urscript", "def p():\n  while True:\n    sync()\nend\n"),
    ],
)
def test_the_grammars_reject_broken_programs(grammar, text):
    with pytest.raises(LarkError):
        pg.parser(grammar).parse(text)


# ---- every bundled problem ----------------------------------------------------------------------

BUNDLED = ["glass_adhesive", "tig_weld", "ur10e_sealing", "kr8_arc_weld"]


@pytest.fixture(scope="module", params=BUNDLED)
def bundled(request, tmp_path_factory):
    out = tmp_path_factory.mktemp(request.param)
    run(load_problem(ROOT / "problems" / request.param), out)
    return request.param, out


@pytest.mark.slow
def test_every_program_of_every_bundled_problem_parses_and_matches_trajectory_csv(bundled):
    name, out = bundled
    results = pg.read_programs(out)
    assert results, f"{name}: no program written"
    for prog, errors in results:
        for dp, dr in errors:
            assert dp <= POSITION_MM, f"{name} {prog.files}: {dp:.2e} mm"
            assert dr <= ORIENTATION_DEG, f"{name} {prog.files}: {dr:.2e} deg"
        weld = load_problem(ROOT / "problems" / name).process.kind == "weld"
        st = prog.statements
        if prog.language == "rapid":
            assert st[2] == "MoveAbsJ" and st[-1] == "MoveAbsJ"
            assert ("WaitDI" in st) == weld and ("TriggL" in st) != weld
        elif prog.language == "krl":
            assert st.count("wait_for") == (len(prog.passes) if weld else 0)
        elif prog.language == "urscript":
            assert ("run:process_on" in st) != weld
