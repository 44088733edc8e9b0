"""Every field a controller reads, checked by interpreting the program text as the controller would.

Each language gets a small interpreter written here, independent of the writers and their parsers:
it reads the declarations (tool, work object or base, payload, targets, speeds) and walks the
motion instructions in order, keeping the state a controller keeps (current speed, tool, base,
process output). What comes out is, per motion, the TCP pose the robot is sent to in its base
frame, the speed, the zone or blend and whether the process is on. The checks then hold the
program to the plan, with expectations derived from the plan alone:

* the flange pose each path target implies (target and tool data composed the way the controller
  does) equals the robot's forward kinematics at the planned joints;
* each path motion's speed equals the spacing of its two targets divided by the planned time
  between them (to half the documented rounding step);
* the process output switches on the move: on while the robot moves onto the first path target and
  off on the last path motion, each the documented lead before those targets;
* zones/blends: approximate motion all along a glue path, also at its ends (no standstill with the
  gun open);
* approach and retract lie on the tool axis, the documented distance behind the first/last target.

Rotations are rebuilt with scipy from each language's documented convention (RAPID quaternions
scalar first, KUKA A-B-C intrinsic Z-Y'-X'', UR rotation vectors).
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
from lxml import etree
from scipy.spatial.transform import Rotation

from refine.errors import InputError
from refine.export.krl import write_krl
from refine.export.pathml import write_pathml
from refine.export.rapid import write_rapid
from refine.export.urscript import write_urscript
from refine.export.writers import write_outputs
from refine.frames import transform_from_xyz_rpy
from refine.paths import Trajectory
from refine.problem import CadSettings, DemoSettings, Problem, ProcessSettings, RobotSettings, ToolSettings
from refine.robot.registry import load_robot
from refine.run.result import PassResult, RunResult

RESOLUTION_M_S = 1e-4  # the writers' documented default speed rounding step
RETRACT_M = 0.1  # the writers' documented default approach / retract distance


@dataclass(frozen=True)
class Motion:
    """One motion instruction as a controller executes it."""

    kind: str  # "lin" or "joint"
    T_base_tcp: np.ndarray | None  # where the TCP goes, in the robot base frame (None: a joint target)
    speed_m_s: float | None
    exact: bool  # True: exact stop (fine, no C_DIS, r=0)
    blend_m: float | None
    output_on: bool
    T_flange_tcp: np.ndarray | None  # the tool active for the motion
    zone: str | None = None  # RAPID zonedata name
    fields: dict | None = None  # KRL: the E6POS fields of the target (S, T, E1, ...)
    switch: tuple | None = None  # (output value, lead before the motion's end, "m" or "s") fired on it


def _T(R, p) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def _inv(T) -> np.ndarray:
    return np.linalg.inv(T)


# ---- RAPID ------------------------------------------------------------------------------------


def _rapid_value(text: str):
    """A RAPID aggregate ``[[1,2],TRUE,"x"]`` as nested Python lists."""
    return ast.literal_eval(re.sub(r"\bTRUE\b", "True", re.sub(r"\bFALSE\b", "False", text)))


def _rapid_pose(value) -> np.ndarray:
    """``[[x,y,z] mm, [q1,q2,q3,q4] scalar first]`` as a transform [m]."""
    (x, y, z), (q1, q2, q3, q4) = value
    return _T(Rotation.from_quat([q2, q3, q4, q1]).as_matrix(), np.array([x, y, z]) / 1000.0)


def _rapid_executed(text: str) -> list[str]:
    """The statements of ``PROC main()`` in execution order, with calls of the module's routines inlined."""
    procs: dict[str, list[str]] = {}
    current = None
    for raw in text.splitlines():
        line = raw.split("!")[0].strip()
        if m := re.match(r"PROC\s+(\w+)\s*\(\s*\)", line):
            current = procs.setdefault(m.group(1), [])
        elif line == "ENDPROC":
            current = None
        elif current is not None and line:
            current.append(line)

    def run(name: str) -> list[str]:
        out = []
        for line in procs[name]:
            call = re.fullmatch(r"(\w+)\s*;", line)
            out += run(call.group(1)) if call and call.group(1) in procs else [line]
        return out

    return run("main")


def interpret_rapid(text: str) -> tuple[list[Motion], dict]:
    decls = {
        m.group(3): (m.group(2), _rapid_value(m.group(4)))
        for m in re.finditer(r"\b(CONST|PERS|VAR)\s+(\w+)\s+(\w+)\s*:=\s*(.*?);", text, re.DOTALL)
    }
    motions, output, info = [], False, {"tools": {}, "outputs": set()}
    triggers: dict[str, tuple] = {}
    for line in _rapid_executed(text):
        if m := re.match(r"SetDO\s+(\w+)\s*,\s*(\d)\s*;", line):
            info["outputs"].add(m.group(1))
            output = m.group(2) == "1"
            continue
        if m := re.match(
            r"TriggIO\s+(\w+)\s*,\s*([-\d.eE+]+)\s*(\\Time)?\s*\\DOp:=(\w+)\s*,\s*(\d)\s*;", line
        ):
            lead = float(m.group(2)) if m.group(3) else float(m.group(2)) / 1000.0  # s, or mm -> m
            triggers[m.group(1)] = (m.group(5) == "1", lead, "s" if m.group(3) else "m")
            info["outputs"].add(m.group(4))
            continue
        if re.match(r"MoveAbsJ\s", line):
            motions.append(Motion("joint", None, None, True, None, output, None))
            continue
        fired = None
        if m := re.match(r"TriggL\s+(\w+)\s*,\s*(\w+)\s*,\s*(\w+)\s*,(.*)", line):
            fired = triggers[m.group(3)]
            line = f"MoveL {m.group(1)}, {m.group(2)},{m.group(4)}"
        m = re.match(
            r"Move([LJ])\s+(RelTool\((\w+)\s*,([^)]*)\)|\w+)\s*,\s*(\w+)\s*,\s*(\w+)\s*,\s*(\w+)(.*);", line
        )
        if not m:
            continue
        lj, _, rel_name, rel_args, speed, zone, tool, rest = m.groups()
        wobj_name = re.search(r"\\WObj:=(\w+)", rest).group(1)
        kind_w, wobj = decls[wobj_name]
        assert kind_w == "wobjdata" and wobj[0] is False  # the robot holds the tool, not the object
        T_wobj = _rapid_pose(wobj[3]) @ _rapid_pose(wobj[4])  # uframe · oframe
        kind_t, tooldata = decls[tool]
        assert kind_t == "tooldata" and tooldata[0] is True
        info["tools"][tool] = tooldata
        target = decls[rel_name or m.group(2)][1]
        T_target = _rapid_pose(target[:2])
        if rel_name:  # RelTool: displacement along the tool's own axes [mm]
            dx, dy, dz = (float(v) for v in rel_args.split(","))
            T_target = T_target @ _T(np.eye(3), np.array([dx, dy, dz]) / 1000.0)
        motions.append(
            Motion(
                "lin" if lj == "L" else "joint",
                T_wobj @ T_target,
                decls[speed][1][0] / 1000.0,
                zone == "fine",
                None,
                output,
                _rapid_pose(tooldata[1]),
                zone,
                switch=fired,
            )
        )
        if fired is not None:
            output = fired[0]
    return motions, info


# ---- KRL --------------------------------------------------------------------------------------


def _krl_fields(body: str) -> dict[str, float]:
    return {k.upper(): float(v) for k, v in re.findall(r"([A-Za-z]\w*)\s+(-?[\d.]+(?:[eE][-+]?\d+)?)", body)}


def _krl_frame(f: dict[str, float]) -> np.ndarray:
    R = Rotation.from_euler("ZYX", [f["A"], f["B"], f["C"]], degrees=True).as_matrix()  # intrinsic Z, Y', X''
    return _T(R, np.array([f["X"], f["Y"], f["Z"]]) / 1000.0)


def interpret_krl(src: str, dat: str) -> list[Motion]:
    decls = {
        m.group(2).upper(): _krl_fields(m.group(3))
        for m in re.finditer(
            r"DECL\s+(E6POS|FRAME|POS|E6AXIS)\s+(\w+)\s*=\s*\{([^{}]*)\}", dat, re.IGNORECASE
        )
    }
    # TOOL_DATA[n] / BASE_DATA[n] live in the controller; the .dat states what they must hold
    for m in re.finditer(r";\s*((?:TOOL|BASE)_DATA\[\d+\]).*?must be \{([^{}]*)\}", dat):
        decls[m.group(1).upper()] = _krl_fields(m.group(2))
    axes = {m.group(1).upper() for m in re.finditer(r"DECL\s+E6AXIS\s+(\w+)", dat, re.IGNORECASE)}
    motions, state = [], {"vel": None, "base": None, "tool": None, "out": False, "trigger": None}
    for raw in src.splitlines():
        line = raw.split(";")[0].strip()
        if m := re.match(r"\$VEL\.CP\s*=\s*([-\d.eE+]+)", line):
            state["vel"] = float(m.group(1))
        elif m := re.match(r"\$BASE\s*=\s*(\w+(?:\[\d+\])?)", line):
            state["base"] = _krl_frame(decls[m.group(1).upper()])
        elif m := re.match(r"\$TOOL\s*=\s*(\w+(?:\[\d+\])?)", line):
            state["tool"] = _krl_frame(decls[m.group(1).upper()])
        elif m := re.match(r"\$OUT\[(\d+)\]\s*=\s*(TRUE|FALSE)", line, re.IGNORECASE):
            state["out"] = m.group(2).upper() == "TRUE"
        elif m := re.match(
            r"TRIGGER\s+WHEN\s+(DISTANCE|PATH)\s*=\s*([-\d.]+)\s+DELAY\s*=\s*([-\d.]+)\s+DO\s+\$OUT\[\d+\]\s*=\s*(TRUE|FALSE)",
            line,
            re.IGNORECASE,
        ):
            if m.group(1).upper() == "PATH":  # PATH=-d: d mm before the end point of the next motion
                state["trigger"] = (m.group(4).upper() == "TRUE", -float(m.group(2)) / 1000.0, "m")
            else:  # DISTANCE=1 is the end point; a negative DELAY [ms] moves the switch earlier
                assert float(m.group(2)) == 1.0
                state["trigger"] = (m.group(4).upper() == "TRUE", -float(m.group(3)) / 1000.0, "s")
        elif m := re.match(r"(PTP|LIN)\s+(\w+)(\s+C_DIS)?", line, re.IGNORECASE):
            if m.group(2).upper() in axes:  # a joint target (home)
                motions.append(Motion("joint", None, None, True, None, state["out"], state["tool"]))
                continue
            target = state["base"] @ _krl_frame(decls[m.group(2).upper()])
            motions.append(
                Motion(
                    "lin" if m.group(1).upper() == "LIN" else "joint",
                    target,
                    state["vel"] if m.group(1).upper() == "LIN" else None,
                    m.group(3) is None,
                    None,
                    state["out"],
                    state["tool"],
                    None,
                    fields=decls[m.group(2).upper()],
                    switch=state["trigger"],
                )
            )
            if state["trigger"] is not None:
                state["out"], state["trigger"] = state["trigger"][0], None
    return motions


# ---- URScript ---------------------------------------------------------------------------------


def _ur_pose(text: str) -> np.ndarray:
    x, y, z, rx, ry, rz = (float(v) for v in text.split(","))
    return _T(Rotation.from_rotvec([rx, ry, rz]).as_matrix(), [x, y, z])


def interpret_urscript(text: str) -> list[Motion]:
    motions, tool, out, env, pending, depth = [], None, False, {}, None, 0
    for line in text.splitlines():
        line = line.split("#")[0].strip()
        if depth:  # inside a thread: it runs beside the program, when started
            depth += line.startswith(("while ", "if ", "thread ")) - (line == "end")
            continue
        if line.startswith("thread "):
            depth = 1
            continue
        if m := re.match(r"(on|off)_(target|lead)\s*=\s*(p\[[^\]]*\]|[-\d.eE+]+)$", line):
            env[f"{m.group(1)}_{m.group(2)}"] = m.group(3)
        elif m := re.match(r"run process_(on|off)\(\)", line):
            # the thread switches when the TCP comes within <lead> of <target>: the next movel must end there
            pending = (m.group(1) == "on", float(env[f"{m.group(1)}_lead"]), "m", env[f"{m.group(1)}_target"])
        elif m := re.match(r"set_tcp\(p\[([^\]]*)\]\)", line):
            tool = _ur_pose(m.group(1))
        elif m := re.match(r"set_digital_out\((\d+),\s*(True|False)\)", line):
            out = m.group(2) == "True"
        elif m := re.match(r"movel\(p\[([^\]]*)\],\s*a=([^,]+),\s*v=([^,]+),\s*r=([^)]+)\)", line):
            r = float(m.group(4))
            fired = None
            if pending is not None and pending[3] == f"p[{m.group(1)}]":  # the thread's target: it fires here
                fired, pending = pending[:3], None
            motions.append(
                Motion("lin", _ur_pose(m.group(1)), float(m.group(3)), r == 0.0, r, out, tool, switch=fired)
            )
            if fired is not None:
                out = fired[0]
        elif line.startswith("movej("):
            motions.append(Motion("joint", None, None, True, None, out, tool))
    return motions


# ---- the plans --------------------------------------------------------------------------------


def planned(robot, problem: Problem, q0_deg, q1_deg, n: int) -> Trajectory:
    """A joint path from q0 to q1 whose planned speed alternates 40 / 110 mm/s waypoint by waypoint.

    The times follow from the speeds: each segment takes its chord over the mean of its end speeds,
    so "the speed of a segment" has one right value, chord / time, and either end's speed is wrong
    by 35 mm/s.
    """
    u = np.linspace(0.0, 1.0, n)[:, None]
    q = np.radians(q0_deg) + np.radians(np.subtract(q1_deg, q0_deg)) * u
    poses = np.array([problem.robot.base_in_world @ robot.fk(qk) @ problem.tool.tcp_in_flange for qk in q])
    chords = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    speed = np.where(np.arange(n) % 2 == 0, 0.04, 0.11)
    t = np.concatenate([[0.0], np.cumsum(chords / (0.5 * (speed[1:] + speed[:-1])))])
    s = np.concatenate([[0.0], np.cumsum(chords)])
    return Trajectory(t, s, q, poses[:, :3, 3].copy(), poses, poses[:, :3, :3].copy(), speed)


def _problem(name, model, base, tcp, output) -> Problem:
    return Problem(
        name=name,
        root=Path("."),
        robot=RobotSettings(model=model, base_in_world=transform_from_xyz_rpy(*base)),
        tool=ToolSettings(
            name="gun",
            tcp_in_flange=transform_from_xyz_rpy(*tcp),
            mass_kg=3.0,
            cog_in_flange_m=(0.01, -0.02, 0.1),
        ),
        cad=CadSettings(file=Path("part.csv")),
        demonstration=DemoSettings(file=Path("demo.txt")),
        # a path tolerance above every zone asked for, so the zones stand as asked (their
        # narrowing to a tighter tolerance: tests/export/test_zones.py)
        process=ProcessSettings(kind="glue", output=output, lead_m=LEAD_M, path_tolerance_m=0.05),
    )


LEAD_M = 0.004  # the gun opens and closes 4 mm ahead of the first and the last path target

CASES = {
    "rapid": (
        "abb_irb4600_60_205",
        ([0.4, -0.3, 0.25], [5.0, -3.0, 30.0]),
        ([0.02, -0.01, 0.25], [10.0, 20.0, 35.0]),
        "doGlue",
        ([-20.0, 10.0, -15.0, 40.0, 50.0, -60.0], [35.0, 30.0, 5.0, -70.0, -35.0, 120.0]),
    ),
    "krl": (
        "kuka_iiwa14_r820",
        ([0.3, -0.2, 0.75], [0.0, 4.0, -40.0]),
        ([0.0, 0.015, 0.21], [-8.0, 25.0, 60.0]),
        "doArc",
        ([-30.0, 35.0, -40.0, -75.0, 20.0, 60.0, -10.0], [25.0, 55.0, 30.0, -40.0, -35.0, -20.0, 80.0]),
    ),
    "urscript": (
        "ur10e",
        ([-0.5, 0.4, 0.9], [0.0, -6.0, 135.0]),
        ([0.005, 0.01, 0.18], [0.0, 15.0, -25.0]),
        "DO3",
        ([20.0, -100.0, 110.0, -100.0, -90.0, -150.0], [50.0, -80.0, 90.0, -120.0, -70.0, 150.0]),
    ),
}


@pytest.fixture(scope="module", params=sorted(CASES))
def program(request, tmp_path_factory):
    """(language, robot, problem, trajectory, motions, extra) for each program language."""
    lang = request.param
    model, base, tcp, output, (q0, q1) = CASES[lang]
    robot = load_robot(model)
    problem = _problem(f"bead {lang}", model, base, tcp, output)
    tr = planned(robot, problem, q0, q1, 25)
    out = tmp_path_factory.mktemp(lang)
    extra: dict = {}
    if lang == "rapid":
        path = write_rapid(out / "bead.mod", tr, problem, robot, zone="z5")
        motions, extra = interpret_rapid(path.read_text())
    elif lang == "krl":
        src, dat = write_krl(out / "bead.src", tr, problem, robot)
        motions = interpret_krl(src.read_text(), dat.read_text())
    else:
        path = write_urscript(out / "bead.script", tr, problem, robot, blend_m=0.004)
        motions = interpret_urscript(path.read_text())
    return lang, robot, problem, tr, motions, extra


def _path_motions(motions: list[Motion], n: int) -> list[Motion]:
    """The n motions through the path targets: the one onto the first target and the n - 1 after it."""
    lin = [m for m in motions if m.kind == "lin" and m.T_base_tcp is not None]
    assert len(lin) == n + 1, f"expected approach-onto-first + {n - 1} path + retract moves, got {len(lin)}"
    return lin[:n]


def test_every_target_with_the_program_tool_puts_the_flange_where_the_planned_joints_do(program):
    lang, robot, problem, tr, motions, _ = program
    path = _path_motions(motions, len(tr))
    for k, m in enumerate(path):
        flange = m.T_base_tcp @ _inv(m.T_flange_tcp)
        fk = robot.fk(tr.q[k])
        np.testing.assert_allclose(flange[:3, 3], fk[:3, 3], atol=2e-6, err_msg=f"{lang} target {k}")
        angle = Rotation.from_matrix(flange[:3, :3].T @ fk[:3, :3]).magnitude()
        assert np.degrees(angle) < 1e-5, (lang, k)


def test_the_program_tool_is_the_problem_tool(program):
    lang, _, problem, _, motions, extra = program
    tools = {m.T_flange_tcp.tobytes() for m in motions if m.T_flange_tcp is not None}
    assert len(tools) == 1, f"{lang}: one tool for the whole program"
    T = next(m.T_flange_tcp for m in motions if m.T_flange_tcp is not None)
    np.testing.assert_allclose(T[:3, 3], problem.tool.tcp_in_flange[:3, 3], atol=1e-7)
    angle = Rotation.from_matrix(T[:3, :3].T @ problem.tool.tcp_in_flange[:3, :3]).magnitude()
    assert np.degrees(angle) < 1e-6, lang
    if lang == "rapid":  # the payload: [mass kg, cog mm, ...]
        (load,) = (t[2] for t in extra["tools"].values())
        assert load[0] == pytest.approx(problem.tool.mass_kg)
        np.testing.assert_allclose(load[1], np.array(problem.tool.cog_in_flange_m) * 1000.0, atol=1e-3)


def test_each_path_motion_runs_at_its_target_spacing_over_the_planned_time(program):
    """KRL and URScript: the planned speed; RAPID: a few speed levels, none above the planned speed."""
    lang, _, problem, tr, motions, _ = program
    path = _path_motions(motions, len(tr))
    for k in range(1, len(tr)):
        spacing = np.linalg.norm(path[k].T_base_tcp[:3, 3] - path[k - 1].T_base_tcp[:3, 3])
        expected = spacing / (tr.t[k] - tr.t[k - 1])
        if lang == "rapid":
            assert path[k].speed_m_s <= expected + 0.5 * RESOLUTION_M_S + 1e-7, (lang, k)
        else:
            assert path[k].speed_m_s == pytest.approx(expected, abs=0.5 * RESOLUTION_M_S + 1e-7), (lang, k)
    if lang == "rapid":  # every segment's planned speed is 75 mm/s (40 and 110 at its ends)
        assert len({m.speed_m_s for m in path[1:]}) <= problem.output.speed_levels


def test_the_process_switches_on_the_move_the_lead_before_the_first_and_the_last_target(program):
    lang, _, _, tr, motions, _ = program
    lin = [m for m in motions if m.kind == "lin"]
    # onto the first target with the process off until it switches, every path motion with it on
    assert [m.output_on for m in lin] == [False] + [True] * (len(tr) - 1) + [False], lang
    assert not any(m.output_on for m in motions if m.kind == "joint")
    fired = [(k, m.switch) for k, m in enumerate(lin) if m.switch is not None]
    assert [f[1][0] for f in fired] == [True, False], lang
    (k_on, (_, lead_on, unit_on)), (k_off, (_, lead_off, unit_off)) = fired
    assert k_on == 0 and unit_on == "m" and lead_on == pytest.approx(LEAD_M), lang  # onto the first target
    # the off switch: LEAD_M before the last target, measured along the path from the motion's end
    to_last = tr.s[-1] - tr.s[k_off] if lang != "urscript" else 0.0  # the UR thread aims at the last target
    assert unit_off == "m" and lead_off + to_last == pytest.approx(LEAD_M, abs=1e-6), lang
    assert 1 <= k_off <= len(tr) - 1


def test_a_glue_path_is_approximated_all_along_also_at_its_ends(program):
    lang, _, _, tr, motions, _ = program
    path = _path_motions(motions, len(tr))
    assert not any(m.exact for m in path), lang
    if lang == "rapid":  # the zone asked for, z5, at every path target
        assert {m.zone for m in path} == {"z5"}
    if lang == "urscript":  # blends: at most the asked 4 mm, never overlapping the next one
        r = np.array([m.blend_m for m in path])
        gaps = np.linalg.norm(np.diff([m.T_base_tcp[:3, 3] for m in path], axis=0), axis=1)
        assert np.all(r[1:-1] <= 0.004 + 1e-12) and np.all(r[1:-2] + r[2:-1] <= gaps[1:-1] + 1e-9)


def test_approach_and_retract_are_on_the_tool_axis_behind_the_first_and_last_targets(program):
    lang, _, _, tr, motions, _ = program
    lin = [m for m in motions if m.kind == "lin" and m.T_base_tcp is not None]
    first, last, retract = lin[0].T_base_tcp, lin[len(tr) - 1].T_base_tcp, lin[-1].T_base_tcp
    np.testing.assert_allclose(retract[:3, 3], last[:3, 3] - RETRACT_M * last[:3, 2], atol=1e-6, err_msg=lang)
    approach = [m for m in motions if m.T_base_tcp is not None and m is not lin[0]][0]
    if lang == "rapid":  # the MoveJ to the approach point is a pose target there
        np.testing.assert_allclose(
            approach.T_base_tcp[:3, 3], first[:3, 3] - RETRACT_M * first[:3, 2], atol=1e-6
        )


def test_targets_are_the_planned_poses_in_the_robot_base_frame(program):
    """The work object / base frame carries {F} into the robot base frame: inv(base_in_world)."""
    lang, _, problem, tr, motions, _ = program
    path = _path_motions(motions, len(tr))
    expected = np.linalg.inv(problem.robot.base_in_world) @ tr.poses
    np.testing.assert_allclose(np.array([m.T_base_tcp for m in path]), expected, atol=2e-6, err_msg=lang)


def test_a_plan_at_a_different_speed_changes_every_path_speed(program, tmp_path):
    """Speeds come from the plan: the same path planned twice as fast is written twice as fast."""
    lang, robot, problem, tr, _, _ = program
    fast = replace(tr, t=tr.t / 2.0, speed=tr.speed * 2.0)
    tmp = tmp_path
    if lang == "rapid":
        motions, _ = interpret_rapid(write_rapid(tmp / "b.mod", fast, problem, robot).read_text())
    elif lang == "krl":
        src, dat = write_krl(tmp / "b.src", fast, problem, robot)
        motions = interpret_krl(src.read_text(), dat.read_text())
    else:
        motions = interpret_urscript(write_urscript(tmp / "b.script", fast, problem, robot).read_text())
    path = _path_motions(motions, len(tr))
    slow = _path_motions(program[4], len(tr))
    for k in range(1, len(tr)):
        spacing = np.linalg.norm(path[k].T_base_tcp[:3, 3] - path[k - 1].T_base_tcp[:3, 3])
        if lang == "rapid":  # the speed levels scale with the plan
            assert path[k].speed_m_s == pytest.approx(2.0 * slow[k].speed_m_s, abs=2 * RESOLUTION_M_S), (
                lang,
                k,
            )
        else:
            assert path[k].speed_m_s == pytest.approx(spacing / (fast.t[k] - fast.t[k - 1]), abs=1e-4), (
                lang,
                k,
            )


# ---- PathML -----------------------------------------------------------------------------------

FIXED_AXIS = {"rx": 0, "ry": 1, "rz": 2}
"""Frame angle label -> the fixed (extrinsic) axis x, y, z it turns about (AutomationML Frame)."""


def test_pathml_frames_are_the_planned_poses_in_fixed_axis_angles(tmp_path):
    """Each point's Frame, read with lxml and turned back with scipy's extrinsic x-y-z, is the pose."""
    model, base, tcp, output, (q0, q1) = CASES["rapid"]
    robot = load_robot(model)
    problem = _problem("bead pathml", model, base, tcp, output)
    tr = planned(robot, problem, q0, q1, 25)
    doc = etree.parse(str(write_pathml(tmp_path / "bead.aml", tr, problem)))
    frames = [
        el
        for el in doc.iter()
        if etree.QName(el).localname == "Attribute"
        and el.get("Name") == "Frame"
        and etree.QName(el.getparent()).localname == "InternalElement"  # a point, not a library's type
    ]
    assert len(frames) == len(tr)
    for k, frame in enumerate(frames):
        values = {
            sub.get("Name"): (
                float(next(v for v in sub if etree.QName(v).localname == "Value").text),
                sub.get("Unit"),
            )
            for sub in frame
            if etree.QName(sub).localname == "Attribute"
        }
        assert {values[a][1] for a in "xyz"} == {"m"} and {values[a][1] for a in FIXED_AXIS} == {"deg"}
        np.testing.assert_allclose([values[a][0] for a in "xyz"], tr.poses[k, :3, 3], atol=1e-12)
        angles = np.zeros(3)
        for label, axis in FIXED_AXIS.items():
            angles[axis] = values[label][0]
        R = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()  # lower case: fixed axes
        angle = Rotation.from_matrix(R.T @ tr.poses[k, :3, :3]).magnitude()
        assert np.degrees(angle) < 1e-9, k


# ---- what gets written for a run ----------------------------------------------------------------

SUFFIXES = {
    "rapid": {"rapid": ".mod"},
    "krl": {"krl_src": ".src", "krl_dat": ".dat"},
    "urscript": {"urscript": ".script"},
}


@pytest.mark.parametrize("lang", sorted(CASES))
def test_a_run_writes_the_program_asked_for_and_its_interpretation_is_the_plan(lang, tmp_path):
    model, base, tcp, output, (q0, q1) = CASES[lang]
    robot = load_robot(model)
    problem = _problem(f"bead {lang}", model, base, tcp, output)
    tr = planned(robot, problem, q0, q1, 12)
    result = RunResult(problem, robot, (PassResult("pass 1", 1, 1, None, None, None, tr),), None)
    outputs = write_outputs(result, tmp_path, (lang,))
    assert {k: v.suffix for k, v in outputs.items() if k in SUFFIXES[lang]} == SUFFIXES[lang]
    assert {"trajectory", "pathml"} <= set(outputs)
    assert not set(outputs) - {"trajectory", "pathml"} - set(SUFFIXES[lang])  # only the program asked for
    if lang == "rapid":
        motions, _ = interpret_rapid(outputs["rapid"].read_text())
    elif lang == "krl":
        motions = interpret_krl(outputs["krl_src"].read_text(), outputs["krl_dat"].read_text())
    else:
        motions = interpret_urscript(outputs["urscript"].read_text())
    path = _path_motions(motions, len(tr))
    expected = np.linalg.inv(problem.robot.base_in_world) @ tr.poses
    np.testing.assert_allclose(np.array([m.T_base_tcp for m in path]), expected, atol=2e-6)


def test_a_run_with_an_infeasible_pass_writes_nothing(tmp_path):
    model, base, tcp, output, (q0, q1) = CASES["rapid"]
    robot = load_robot(model)
    problem = _problem("bead", model, base, tcp, output)
    tr = planned(robot, problem, q0, q1, 12)
    passes = (
        PassResult("layer 1 pass 1", 1, 1, None, None, None, tr),
        PassResult("layer 2 pass 1", 2, 1, None, None, None, None),
    )
    assert write_outputs(RunResult(problem, robot, passes, None), tmp_path, ("rapid",)) == {}
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_program_format_is_refused_naming_the_known_ones(tmp_path):
    model, base, tcp, output, (q0, q1) = CASES["rapid"]
    robot = load_robot(model)
    problem = _problem("bead", model, base, tcp, output)
    result = RunResult(
        problem,
        robot,
        (PassResult("pass 1", 1, 1, None, None, None, planned(robot, problem, q0, q1, 5)),),
        None,
    )
    with pytest.raises(InputError, match="'karel' is not one of .*rapid"):
        write_outputs(result, tmp_path, ("karel",))


def test_krl_turn_has_a_bit_set_for_each_negative_axis(tmp_path):
    """KUKA Turn: bit i is set when axis i + 1 is negative (KSS manual, E6POS), from the planned joints."""
    model, base, tcp, output, (q0, q1) = CASES["krl"]
    robot = load_robot(model)
    problem = _problem("bead", model, base, tcp, output)
    tr = planned(robot, problem, q0, q1, 25)
    src, dat = write_krl(tmp_path / "b.src", tr, problem, robot)
    path = _path_motions(interpret_krl(src.read_text(), dat.read_text()), len(tr))
    expected = [sum(1 << i for i, qi in enumerate(qk) if qi < 0.0) for qk in tr.q]
    assert [int(m.fields["T"]) for m in path] == expected
    assert len(set(expected)) > 1  # the path crosses zero on some axis


def test_the_rapid_module_is_named_after_the_problem(tmp_path):
    model, base, tcp, output, (q0, q1) = CASES["rapid"]
    robot = load_robot(model)
    problem = _problem("bead 7-a", model, base, tcp, output)
    text = write_rapid(tmp_path / "b.mod", planned(robot, problem, q0, q1, 2), problem, robot).read_text()
    assert re.search(r"^MODULE bead_7_a$", text, re.MULTILINE)
    motions, _ = interpret_rapid(text)
    assert len(_path_motions(motions, 2)) == 2  # two waypoints are enough for a program


def test_reading_back_a_script_without_a_pass_says_so(tmp_path):
    from refine.export.urscript import parse_urscript

    path = tmp_path / "empty.script"
    path.write_text("def empty():\n  set_tcp(p[0,0,0.1,0,0,0])\nend\n")
    with pytest.raises(InputError, match="no pass"):
        parse_urscript(path)


def _case(lang, n=6, **settings):
    model, base, tcp, output, (q0, q1) = CASES[lang]
    robot = load_robot(model)
    problem = _problem("bead", model, base, tcp, settings.get("output", output))
    return robot, problem, planned(robot, problem, q0, q1, n)


def test_the_krl_load_is_the_tool_mass_and_centre_of_mass_in_millimetres(tmp_path):
    robot, problem, tr = _case("krl")
    _, dat = write_krl(tmp_path / "b.src", tr, problem, robot)
    # the controller's LOAD_DATA entry the program selects, as the .dat states it must be set
    m = re.search(r"LOAD_DATA\[\d+\] must be \{M\s+([-\d.]+)\s*,\s*CM\s*\{([^{}]*)\}", dat.read_text())
    assert float(m.group(1)) == pytest.approx(problem.tool.mass_kg)
    cm = _krl_fields(m.group(2))
    np.testing.assert_allclose([cm["X"], cm["Y"], cm["Z"]], np.array(problem.tool.cog_in_flange_m) * 1000.0)


@pytest.mark.parametrize(
    ("output", "ok"), [("$OUT[4096]", True), ("$OUT[4097]", False), ("0", False), ("1", True)]
)
def test_krl_process_outputs_are_out_1_to_4096(tmp_path, output, ok):
    robot, problem, tr = _case("krl", output=output)
    if ok:
        src, _ = write_krl(tmp_path / "b.src", tr, problem, robot)
        number = int(re.sub(r"\D", "", output))
        assert f"$OUT[{number}]=TRUE" in src.read_text()
    else:
        with pytest.raises(InputError, match=r"\$OUT\[1\]..\$OUT\[4096\]"):
            write_krl(tmp_path / "b.src", tr, problem, robot)


@pytest.mark.parametrize(
    "options", [{"approach_speed_m_s": 0.0}, {"speed_resolution_m_s": -1e-4}, {"approximation_m": -0.001}]
)
def test_krl_refuses_speeds_and_approximation_out_of_range(tmp_path, options):
    robot, problem, tr = _case("krl")
    with pytest.raises(InputError, match="speeds must be > 0 and approximation_m >= 0"):
        write_krl(tmp_path / "b.src", tr, problem, robot, **options)


def test_pathml_needs_at_least_one_layer(tmp_path):
    _, problem, tr = _case("rapid")
    with pytest.raises(InputError, match="at least one layer"):
        write_pathml(tmp_path / "b.aml", tr, problem, layers=[])


@pytest.mark.parametrize("output", ["1doGlue", "do-glue", "x" * 33, "$OUT[3]"])
def test_a_rapid_output_that_is_not_a_signal_name_is_refused(tmp_path, output):
    robot, problem, tr = _case("rapid", output=output)
    with pytest.raises(InputError, match="is not a RAPID signal name"):
        write_rapid(tmp_path / "b.mod", tr, problem, robot)


@pytest.mark.parametrize(("output", "number"), [("DO0", 0), ("DO7", 7), ("DO8", None)])
def test_ur_standard_outputs_are_0_to_7(tmp_path, output, number):
    robot, problem, tr = _case("urscript", output=output)
    if number is None:
        with pytest.raises(InputError, match="UR standard digital outputs are 0..7"):
            write_urscript(tmp_path / "b.script", tr, problem, robot)
    else:
        text = write_urscript(tmp_path / "b.script", tr, problem, robot).read_text()
        assert f"set_digital_out({number}, True)" in text


def test_a_run_asking_for_sunrise_writes_a_java_application_with_one_frame_per_target(tmp_path):
    """The iiwa's Sunrise program is written by the run: one row (X Y Z A B C E1 Status Turn speed) a target."""
    model, base, tcp, _, (q0, q1) = CASES["krl"]
    robot = load_robot(model)
    problem = _problem("bead", model, base, tcp, "MediaFlange.OutputX3Pin1")
    tr = planned(robot, problem, q0, q1, 12)
    result = RunResult(problem, robot, (PassResult("pass 1", 1, 1, None, None, None, tr),), None)
    outputs = write_outputs(result, tmp_path, ("sunrise",))
    assert outputs["sunrise"].suffix == ".java" and outputs["sunrise"].is_file()
    text = outputs["sunrise"].read_text()
    assert "extends RoboticsAPIApplication" in text
    number = r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"
    rows = re.findall(r"\{\s*" + number + r"(?:\s*,\s*" + number + r"){9}\s*\}", text)  # X Y Z A B C E1 S T v
    assert len(rows) >= len(tr)


def test_rapid_refuses_a_path_of_one_waypoint(tmp_path):
    model, base, tcp, output, (q0, q1) = CASES["rapid"]
    robot = load_robot(model)
    problem = _problem("bead", model, base, tcp, output)
    tr = planned(robot, problem, q0, q1, 12)
    one = Trajectory(**{f: getattr(tr, f)[:1] for f in Trajectory.__dataclass_fields__})
    with pytest.raises(InputError, match="at least 2 waypoints, got 1"):
        write_rapid(tmp_path / "one.mod", one, problem, robot)
    assert not (tmp_path / "one.mod").exists()


def test_rapid_refuses_a_robot_that_is_not_an_abb(tmp_path):
    """A RAPID module for a UR arm would be loaded by nobody: the writer refuses it, naming the controller."""
    robot, problem, tr = _case("urscript")
    with pytest.raises(InputError, match="RAPID is for ABB robots.*controller 'ur'"):
        write_rapid(tmp_path / "b.mod", tr, problem, robot)
    assert not (tmp_path / "b.mod").exists()


def test_urscript_refuses_an_approach_pose_out_of_reach(tmp_path):
    """A retract of 3 m puts the approach pose beyond the UR10e's 1.3 m reach: no joints reach it."""
    from refine.errors import SolverError

    robot, problem, tr = _case("urscript")
    with pytest.raises(SolverError, match="reach the approach pose"):
        write_urscript(tmp_path / "b.script", tr, problem, robot, retract_m=3.0)


@pytest.mark.parametrize(
    ("options", "ok"),
    [
        ({"approach_speed_m_s": 0.0}, False),
        ({"approach_speed_m_s": 1e-3}, True),
        ({"joint_velocity_rel": 0.0}, False),
        ({"joint_velocity_rel": 1.0}, True),
        ({"joint_velocity_rel": 1.01}, False),
        ({"speed_resolution_m_s": 0.0}, False),
    ],
)
def test_sunrise_speeds_must_be_positive_and_the_joint_velocity_at_most_one(tmp_path, options, ok):
    from refine.export.sunrise import write_sunrise

    robot, problem, tr = _case("krl", output="MediaFlange.OutputX3Pin1")
    if ok:
        assert write_sunrise(tmp_path / "b.java", tr, problem, robot, **options).is_file()
    else:
        with pytest.raises(InputError, match=r"joint_velocity_rel must be in \(0, 1\] and speeds > 0"):
            write_sunrise(tmp_path / "b.java", tr, problem, robot, **options)


def test_each_pathml_track_of_a_multipass_weld_states_its_lateral_offset_and_layer_height(tmp_path):
    """Layer L sits (L - 1) layer heights above the root; each track carries its pass's lateral offset."""
    from refine.paths import FusedPath
    from refine.settings import MultipassSettings

    model, base, tcp, output, (q0, q1) = CASES["krl"]
    robot = load_robot(model)
    offsets = ((0.0,), (-0.0015, 0.0015))
    problem = replace(
        _problem("bead", model, base, tcp, output),
        multipass=MultipassSettings(layers=2, layer_height_m=0.002, lateral_offsets_m=offsets),
    )
    passes = []
    for layer, index, n in ((1, 1, 5), (2, 1, 6), (2, 2, 7)):
        tr = planned(robot, problem, q0, q1, n)
        fused = FusedPath(tr.s, tr.positions_ref, tr.rotations_demo, tr.speed, tr.t, np.zeros(n))
        passes.append(PassResult(f"layer {layer} pass {index}", layer, index, fused, None, None, tr))
    outputs = write_outputs(RunResult(problem, robot, tuple(passes), None), tmp_path, ())
    root = etree.parse(str(outputs["pathml"])).getroot()
    ns = {"c": root.nsmap[None]}
    found = {}
    for layer in root.iterfind(".//c:InternalElement", ns):
        for track in layer.iterfind("c:InternalElement", ns):
            if track.find("c:RoleRequirements", ns).get("RefBaseRoleClassPath").endswith("/Track"):
                attrs = {a.get("Name"): a for a in track.iterfind("c:Attribute", ns)}
                found[(layer.get("Name"), track.get("Name"))] = {
                    k: (float(attrs[k].findtext("c:Value", namespaces=ns)), attrs[k].get("Unit"))
                    for k in ("lateral_offset", "layer_height")
                }
                assert len(track.findall("c:InternalElement", ns)) == len(passes[len(found) - 1].fused)
    assert found == {
        ("Layer1", "Track1"): {"lateral_offset": (0.0, "m"), "layer_height": (0.0, "m")},
        ("Layer2", "Track1"): {"lateral_offset": (-0.0015, "m"), "layer_height": (0.002, "m")},
        ("Layer2", "Track2"): {"lateral_offset": (0.0015, "m"), "layer_height": (0.002, "m")},
    }


@pytest.mark.parametrize(
    ("kind", "output", "message"),
    [
        ("krl", "$OUT[4096]", None),
        ("krl", "1", None),
        ("krl", "doGlue", None),  # a name: the program's default output, stated in its comments
        ("krl", "$OUT[4097]", r"KRL outputs are \$OUT\[1\]..\$OUT\[4096\]"),
        ("krl", "0", r"KRL outputs are \$OUT\[1\]..\$OUT\[4096\]"),
        ("urscript", "DO7", None),
        ("urscript", "DO8", "UR standard digital outputs are 0..7"),
    ],
)
def test_a_run_checks_the_process_output_against_the_controller_s_range_before_solving(kind, output, message):
    from refine.run.preflight import check_output_signal

    if message is None:
        check_output_signal(kind, output)
    else:
        with pytest.raises(InputError, match=message):
            check_output_signal(kind, output)


@pytest.mark.parametrize(
    ("options", "ok"), [({"speed_resolution_m_s": 0.0}, False), ({"approximation_m": 0.0}, True)]
)
def test_krl_speed_rounding_must_be_positive_and_an_exact_path_is_allowed(tmp_path, options, ok):
    """A 0 m/s rounding step cannot round anything; approximation 0 m is exact stops (C_DIS off)."""
    robot, problem, tr = _case("krl")
    if ok:
        src, _ = write_krl(tmp_path / "b.src", tr, problem, robot, **options)
        assert src.is_file()
    else:
        with pytest.raises(InputError, match="speeds must be > 0 and approximation_m >= 0"):
            write_krl(tmp_path / "b.src", tr, problem, robot, **options)


def test_reading_back_a_krl_point_that_is_not_numbers_says_which(tmp_path):
    from refine.export.krl import parse_krl

    robot, problem, tr = _case("krl")
    src, dat = write_krl(tmp_path / "b.src", tr, problem, robot)
    text = dat.read_text()
    m = re.search(r"DECL E6POS (\w+)=\{X ([-\d.]+)", text)
    dat.write_text(text.replace(f"{m.group(1)}={{X {m.group(2)}", f"{m.group(1)}={{X abc", 1))
    with pytest.raises(InputError, match=rf"KRL {m.group(1)}: malformed E6POS"):
        parse_krl(src, dat)


@pytest.mark.parametrize(("lead_m", "ok"), [(RETRACT_M, True), (RETRACT_M + 1e-4, False)])
def test_a_rapid_process_lead_may_be_as_long_as_the_approach_move(tmp_path, lead_m, ok):
    """The gun may open at the very start of the 0.1 m approach move, not before it."""
    robot, problem, tr = _case("rapid")
    problem = replace(problem, process=replace(problem.process, lead_m=lead_m))
    if ok:
        assert write_rapid(tmp_path / "b.mod", tr, problem, robot).is_file()
    else:
        with pytest.raises(InputError, match="longer than the approach move"):
            write_rapid(tmp_path / "b.mod", tr, problem, robot)


def test_a_weld_script_read_back_gives_the_pass_between_the_arc_on_and_off(tmp_path):
    from refine.export.urscript import parse_urscript

    robot, problem, tr = _case("urscript", n=8)
    weld = replace(problem, process=replace(problem.process, kind="weld", lead_m=None))
    script = write_urscript(tmp_path / "w.script", tr, weld, robot)
    (back,) = parse_urscript(script)
    T_base_world = np.linalg.inv(weld.robot.base_in_world)
    np.testing.assert_allclose(back.poses[:, :3, 3], (T_base_world @ tr.poses)[:, :3, 3], atol=1e-6)


def test_a_pathml_point_without_a_speed_is_read_with_its_frame_and_no_speed(tmp_path):
    """Speed, time and arc length are optional point values (another tool may give only the Frame)."""
    from refine.cad.pathml_read import read_pathml

    _, problem, tr = _case("rapid")
    path = write_pathml(tmp_path / "b.aml", tr, problem)
    root = etree.parse(str(path))
    ns = {"c": root.getroot().nsmap[None]}
    point = root.find(".//c:InternalElement[@Name='P0002']", ns)
    point.remove(next(a for a in point.iterfind("c:Attribute", ns) if a.get("Name") == "speed"))
    root.write(str(path))
    (track,) = read_pathml(path).layers[0].tracks
    assert np.isnan(track.speed[2]) and np.isfinite(np.delete(track.speed, 2)).all()
    np.testing.assert_allclose(track.positions[2], tr.poses[2, :3, 3], atol=1e-12)
