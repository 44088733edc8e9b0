"""Circular moves in the programs: RAPID ``MoveC``, KRL ``CIRC``, URScript ``movec`` on a CAD arc.

A path of a straight lead-in, a 20 mm quarter arc and a straight lead-out is placed in reach of
each robot (joints by IK), its arc written as circular moves, and the program read back by a small
interpreter here (independent of the writers' parsers): the start of each circular move is the
target the move before it ended at, the via and the end its two targets. The circle through
those three points is solved here from its own equations (equal distance to the three, in their
plane) and sampled from start through via to end; every sample must lie on the CAD arc the test
drew, and the three targets must be waypoints of the plan. The grammars of
``tests/export/grammars`` must parse the programs.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.export.krl import write_krl
from refine.export.rapid import write_rapid
from refine.export.urscript import write_urscript
from refine.frames import transform_from_xyz_rpy
from refine.optimise.controller_arc import arc_pieces
from refine.paths import Trajectory
from refine.problem import CadSettings, DemoSettings, Problem, ProcessSettings, RobotSettings, ToolSettings
from refine.robot.kinematics import TcpKinematics, solve_ik_batch
from refine.robot.registry import load_robot

from .program_grammar import parser

RADIUS = 0.02
CASES = {
    "rapid": ("abb_irb4600_60_205", [0.0, 20.0, 10.0, 0.0, 60.0, 0.0]),
    "krl": ("kuka_kr8_r1440_2_arc_hw", [0.0, -80.0, 100.0, 0.0, 60.0, 0.0]),
    "urscript": ("ur10e", [20.0, -100.0, 110.0, -100.0, -90.0, 0.0]),
}


def _problem(model: str) -> Problem:
    return Problem(
        name="arc",
        root=Path("."),
        robot=RobotSettings(model=model),
        tool=ToolSettings(
            name="torch", tcp_in_flange=transform_from_xyz_rpy([0.0, 0.0, 0.2], [0.0, 0.0, 0.0])
        ),
        cad=CadSettings(file=Path("part.dxf")),
        demonstration=DemoSettings(file=Path("demo.txt")),
        process=ProcessSettings(kind="glue", output="doGlue", lead_m=0.002, path_tolerance_m=0.05),
    )


def _path(T_mid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Waypoints (lead-in, quarter arc, lead-out) in the plane z = const of T_mid, the tool turning
    with the tangent; the arc's centre and a dense copy of it."""
    centre = T_mid[:3, 3] - np.array([RADIUS, 0.0, 0.0])
    ang = np.linspace(0.0, math.pi / 2, 17)
    arc = centre + RADIUS * np.column_stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)])
    lead_in = arc[0] - np.outer(np.arange(4, 0, -1) * 0.002, [0.0, 1.0, 0.0])
    lead_out = arc[-1] + np.outer(np.arange(1, 5) * 0.002, [-1.0, 0.0, 0.0])
    turn = np.concatenate([np.zeros(4), ang, np.full(4, math.pi / 2)])
    R = Rotation.from_rotvec(np.outer(turn, [0.0, 0.0, 1.0])) * Rotation.from_matrix(T_mid[:3, :3])
    T = np.tile(np.eye(4), (len(turn), 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R.as_matrix(), np.vstack([lead_in, arc, lead_out])
    dense = np.linspace(0.0, math.pi / 2, 4001)
    return T, centre, centre + RADIUS * np.column_stack([np.cos(dense), np.sin(dense), np.zeros_like(dense)])


def _trajectory(robot, problem: Problem, q_mid_deg) -> tuple[Trajectory, np.ndarray]:
    kin = TcpKinematics(robot, problem.robot.base_in_world, problem.tool.tcp_in_flange)
    T, centre, _ = _path(kin.poses(np.radians(q_mid_deg)[None])[0])
    seed = np.radians(q_mid_deg)
    q = []
    for Tk in T:
        qk, err = solve_ik_batch(kin, Tk[None], seed[None], robot.spec.lower, robot.spec.upper, tol=1e-12)
        assert err[0] < 1e-9
        q.append(qk[0])
        seed = qk[0]
    q = np.array(q)
    poses = kin.poses(q)
    speed = np.full(len(q), 0.01)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))])
    tr = Trajectory(s / 0.01, s, q, poses[:, :3, 3].copy(), poses, poses[:, :3, :3].copy(), speed)
    return replace(tr, arcs=tuple(arc_pieces(tr.positions_ref, 0.5 * (speed[1:] + speed[:-1]), 0.02))), centre


def _moves(lang: str, files: list[Path]) -> list[tuple[str, list[np.ndarray]]]:
    """(kind, target positions in {F} [m]) of every Cartesian move, in program order."""
    text = files[0].read_text()
    if lang == "rapid":
        targets = {
            m.group(1): np.array([float(v) for v in m.group(2).split(",")]) / 1000.0
            for m in re.finditer(r"CONST robtarget (\w+):=\[\[([^\]]*)\]", text)
        }
        pattern = r"^\s*(MoveL|TriggL|MoveC)\s+(\w+)\s*,\s*(\w+)"
        return [
            (m.group(1), [targets[m.group(2)]] + ([targets[m.group(3)]] if m.group(1) == "MoveC" else []))
            for m in re.finditer(pattern, text, re.MULTILINE)
            if m.group(2) in targets
        ]
    if lang == "krl":
        dat = files[1].read_text()
        targets = {
            m.group(1).upper(): np.array([float(v) for v in m.group(2, 3, 4)]) / 1000.0
            for m in re.finditer(r"DECL E6POS (\w+)=\{X ([-\d.]+),Y ([-\d.]+),Z ([-\d.]+)", dat)
        }
        out = []
        for m in re.finditer(r"^\s*(LIN|CIRC)\s+(\w+)(?:\s*,\s*(\w+))?", text, re.MULTILINE):
            out.append((m.group(1), [targets[n.upper()] for n in m.group(2, 3) if n is not None]))
        return out
    out = []
    for m in re.finditer(r"^\s*(movel|movec)\((p\[[^\]]*\])(?:,\s*(p\[[^\]]*\]))?", text, re.MULTILINE):
        out.append(
            (m.group(1), [np.array([float(v) for v in p[2:-1].split(",")][:3]) for p in m.group(2, 3) if p])
        )
    return out


def circle_samples(p0: np.ndarray, pv: np.ndarray, p1: np.ndarray, count: int = 200) -> np.ndarray:
    """Points of the circle from p0 through pv to p1, from the circle's own equations."""
    n = np.cross(pv - p0, p1 - p0)
    A = np.array([2.0 * (pv - p0), 2.0 * (p1 - p0), n])
    b = np.array([pv @ pv - p0 @ p0, p1 @ p1 - p0 @ p0, n @ p0])
    c = np.linalg.solve(A, b)
    u = (p0 - c) / np.linalg.norm(p0 - c)
    w = np.cross(n / np.linalg.norm(n), u)
    r = np.linalg.norm(p0 - c)

    def angle(p):
        return math.atan2((p - c) @ w, (p - c) @ u) % (2.0 * math.pi)

    assert angle(pv) < angle(p1)  # turning about n, the via comes before the end
    a = np.linspace(0.0, angle(p1), count)
    return c + r * (np.outer(np.cos(a), u) + np.outer(np.sin(a), w))


@pytest.mark.parametrize("lang", sorted(CASES))
def test_the_circular_moves_run_on_the_cad_arc_through_plan_waypoints(lang, tmp_path):
    model, q_mid = CASES[lang]
    robot = load_robot(model)
    problem = _problem(model)
    tr, centre = _trajectory(robot, problem, q_mid)
    assert len(tr.arcs) == 1 and (tr.arcs[0].start, tr.arcs[0].end) == (4, 20)
    if lang == "rapid":
        files = [write_rapid(tmp_path / "arc.mod", tr, problem, robot)]
        parser("rapid").parse(files[0].read_text())
    elif lang == "krl":
        files = list(write_krl(tmp_path / "arc.src", tr, problem, robot))
        parser("krl_src").parse(files[0].read_text())
    else:
        files = [write_urscript(tmp_path / "arc.script", tr, problem, robot)]
        parser("urscript").parse(files[0].read_text())
    moves = _moves(lang, files)
    circular = [k for k, (kind, _) in enumerate(moves) if kind.lower() in ("movec", "circ")]
    assert len(circular) == 1
    k = circular[0]
    start, (via, end) = moves[k - 1][1][-1], moves[k][1]
    points = circle_samples(start, via, end)
    # on the CAD arc: in its plane, at its radius, inside its quarter
    d = points - centre
    off = np.hypot(np.linalg.norm(d[:, :2], axis=1) - RADIUS, d[:, 2])
    assert off.max() < 2e-6  # the programs' position rounding (0.1 µm in mm, 1 µm in m)
    assert np.all(np.degrees(np.arctan2(d[:, 1], d[:, 0])) > -1e-3)
    assert np.all(np.degrees(np.arctan2(d[:, 1], d[:, 0])) < 90.0 + 1e-3)
    # the three targets are the plan's arc start, middle and end
    p = tr.poses[:, :3, 3]
    for target, index in ((start, 4), (via, 12), (end, 20)):
        assert np.linalg.norm(target - p[index]) < 2e-6
    # every waypoint outside the arc keeps its straight move
    assert len(moves) - sum(len(m[1]) for m in moves) == -1  # only the circular move has two targets


def test_without_arcs_the_programs_move_straight(tmp_path):
    model, q_mid = CASES["krl"]
    robot = load_robot(model)
    problem = _problem(model)
    tr, _ = _trajectory(robot, problem, q_mid)
    src, dat = write_krl(tmp_path / "arc.src", replace(tr, arcs=()), problem, robot)
    assert "CIRC" not in src.read_text()


@pytest.mark.slow
def test_a_run_writes_the_cad_arc_as_one_verified_movec_and_keeps_its_verdict(tmp_path):
    """With ``circular_moves`` (the default) and without."""
    import json

    from refine import solve
    from refine.synthetic import write_arc_problem

    file = write_arc_problem(tmp_path / "arc", "ur10e", "urscript", [0.6, -0.05, 0.3])
    text = file.read_text()
    file.write_text(text.replace('programs = ["urscript"]', 'programs = ["urscript"]\ncircular_moves = true'))
    on = solve(file)
    on.write(tmp_path / "on")
    file.write_text(text.replace('programs = ["urscript"]', 'programs = ["urscript"]\ncircular_moves = false'))
    off = solve(file)
    off.write(tmp_path / "off")
    doc = json.loads((tmp_path / "on" / "result.json").read_text())
    assert (
        doc["passes"][0]["status"]
        == json.loads((tmp_path / "off" / "result.json").read_text())["passes"][0]["status"]
        == "ok"
    )
    # the 40 mm lead-in in 20 steps of 2 mm, then the quarter arc (31.4 mm) in 16 steps: waypoints 20..36
    moves = doc["passes"][0]["circular_moves"]
    assert moves["written"] == [[20, 28, 36]]
    assert all(c["ok"] and c["max_cad_deviation_m"] < 2e-6 for c in moves["checks"])
    script = next((tmp_path / "on").glob("*.script")).read_text()
    assert (
        script.count("movec(") == 1 and "movec(" not in next((tmp_path / "off").glob("*.script")).read_text()
    )
    assert json.loads((tmp_path / "off" / "result.json").read_text())["passes"][0]["circular_moves"] is None


@pytest.mark.parametrize("lang", ["krl", "urscript"])
def test_the_writers_parsers_read_the_circular_move_s_via_and_end_as_path_points(lang, tmp_path):
    from refine.export.krl import parse_krl
    from refine.export.urscript import parse_urscript

    model, q_mid = CASES[lang]
    robot = load_robot(model)
    problem = _problem(model)
    tr, _ = _trajectory(robot, problem, q_mid)
    if lang == "krl":
        (read,) = parse_krl(*write_krl(tmp_path / "arc.src", tr, problem, robot))
    else:
        (read,) = parse_urscript(write_urscript(tmp_path / "arc.script", tr, problem, robot))
    keep = [k for k in range(len(tr)) if not (4 < k < 20 and k != 12)]  # the arc: start 4, via 12, end 20
    got = read.positions if lang == "krl" else read.poses[:, :3, 3]  # base = world here
    np.testing.assert_allclose(got, tr.poses[keep, :3, 3], atol=2e-6)
