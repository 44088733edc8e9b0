"""Problem text written into programs stays inside comments and identifiers (no injected statements)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from refine.export.krl import write_krl
from refine.export.pathml import write_pathml
from refine.export.rapid import write_rapid
from refine.export.urscript import write_urscript
from refine.frames import transform_from_xyz_rpy
from refine.paths import Trajectory
from refine.problem import CadSettings, DemoSettings, Problem, ProcessSettings, RobotSettings, ToolSettings
from refine.robot.registry import load_robot

# every line break a parser might honour, then statements each dialect would run
EVIL = (
    "x\nPROC evil()\r\n$OUT[1]=TRUE\x0bset_digital_out(5, True)\x0c\x85ENDMODULE\u2028"
    "DEF boom()\u2029popup(1)\x00\x1b[2J;\"'"
)
CASES = {  # robot, writer, suffix, comment marker, joint path [deg]
    "rapid": (
        "abb_irb4600_60_205",
        write_rapid,
        ".mod",
        "!",
        ([-20, 10, -15, 40, 50, -60], [35, 30, 5, -70, -35, 120]),
    ),
    "krl": (
        "kuka_iiwa14_r820",
        write_krl,
        ".src",
        ";",
        ([-30, 35, -40, -75, 20, 60, -10], [25, 55, 30, -40, -35, -20, 80]),
    ),
    "urscript": (
        "ur10e",
        write_urscript,
        ".script",
        "#",
        ([20, -100, 110, -100, -90, -150], [50, -80, 90, -120, -70, 150]),
    ),
}


def _problem(model: str, name: str, output: str) -> Problem:
    return Problem(
        name=name,
        root=Path("."),
        robot=RobotSettings(model=model),
        tool=ToolSettings(name="gun", tcp_in_flange=transform_from_xyz_rpy([0.0, 0.0, 0.2], [0.0, 0.0, 0.0])),
        cad=CadSettings(file=Path("p.csv")),
        demonstration=DemoSettings(file=Path("d.txt")),
        process=ProcessSettings(kind="glue", output=output),
    )


def _trajectory(robot, problem: Problem, q0_deg, q1_deg, n: int = 12) -> Trajectory:
    u = np.linspace(0.0, 1.0, n)[:, None]
    q = np.radians(q0_deg) + np.radians(np.subtract(q1_deg, q0_deg)) * u
    poses = np.array([robot.fk(qk) @ problem.tool.tcp_in_flange for qk in q])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))])
    v = np.full(n, 0.05)
    t = s / 0.05
    return Trajectory(t, s, q, poses[:, :3, 3].copy(), poses, poses[:, :3, :3].copy(), v)


@pytest.mark.parametrize("kind", sorted(CASES))
def test_a_hostile_problem_name_cannot_add_statements_to_a_program(tmp_path, kind):
    model, writer, suffix, marker, (q0, q1) = CASES[kind]
    robot = load_robot(model)
    problem = _problem(model, EVIL, {"rapid": "doGlue", "krl": "$OUT[7]", "urscript": "DO2"}[kind])
    clean = dataclasses.replace(problem, name="plain")
    tr = _trajectory(robot, problem, q0, q1)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    written = writer(tmp_path / "a" / f"prog{suffix}", tr, problem, robot)
    reference = writer(tmp_path / "b" / f"prog{suffix}", tr, clean, robot)
    path = written[0] if isinstance(written, tuple) else written
    ref = reference[0] if isinstance(reference, tuple) else reference
    text, ref_text = Path(path).read_text(), Path(ref).read_text()
    assert text.isascii() and "\x00" not in text and "\x1b" not in text
    # the same number of lines as with a plain name: nothing was split off the header comment
    assert len(text.splitlines()) == len(ref_text.splitlines())
    # outside comments the two programs differ only in identifiers made from the name
    ident_evil, ident_plain = re.compile(r"\w*x_PROC_evil\w*"), re.compile(r"\bplain\w*")
    for line, ref_line in zip(text.splitlines(), ref_text.splitlines(), strict=True):
        if line.strip().startswith(marker):
            continue
        assert ident_evil.sub("NAME", line) == ident_plain.sub("NAME", ref_line), line
    assert Path(path).parent == tmp_path / "a"


def test_pathml_gets_a_printable_name(tmp_path):
    robot = load_robot("abb_irb4600_60_205")
    problem = _problem("abb_irb4600_60_205", EVIL, "doGlue")
    from refine.names import comment_text

    problem = dataclasses.replace(problem, name=comment_text(EVIL))  # what load_problem stores
    tr = _trajectory(robot, problem, *CASES["rapid"][4])
    path = write_pathml(tmp_path / "p.aml", tr, problem)
    from lxml import etree

    etree.parse(str(path))  # well-formed
