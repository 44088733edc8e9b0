"""FANUC TP and Yaskawa INFORM programs: parsed whole by their grammars, every field read back by an
interpreter written here, and held to the plan.

The interpreters follow the manuals' definitions, independently of the writers:

* TP: ``P[i]`` in the user frame ``UFRAME[u]`` (its values from the program's comments, which the
  programmer enters on the controller), with the tool ``UTOOL[t]``; ``R = Rz(R)·Ry(P)·Rx(W)``; the
  user frame is measured in the controller's world frame (the URDF frame ``controller_frame``).
  The flange pose the controller reaches is ``T_root_controller · UFRAME · P · inv(UTOOL)``.
* INFORM: ``Cnnnnn`` in the ROBOT frame (the controller frame), with the tool file; ``Rx Ry Rz``
  about the fixed axes, ``R = Rz·Ry·Rx``.
* CONFIG and RCONF from the joints with the manuals' rules; the joints written are the controller's,
  with FANUC's J3 measured from the horizontal (``J3_urdf = J3_controller + J2_controller``).

Expected values come from Pinocchio's forward kinematics at the planned URDF joints.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import re
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("lark")

from lark import Lark, Token  # noqa: E402

from refine.errors import InputError  # noqa: E402
from refine.export.inform import write_inform  # noqa: E402
from refine.export.motion import program_motion  # noqa: E402
from refine.export.tp import write_tp  # noqa: E402
from refine.problem import ProcessSettings  # noqa: E402
from refine.robot.model import Robot  # noqa: E402

GRAMMARS = Path(__file__).resolve().parent / "grammars"
_spec = importlib.util.spec_from_file_location(
    "program_grammar", Path(__file__).with_name("program_grammar.py")
)
pg = importlib.util.module_from_spec(_spec)
sys.modules["program_grammar"] = pg
_spec.loader.exec_module(pg)
POSITION_MM, ORIENTATION_DEG = 0.01, 0.001  # what a program pose may differ from the plan
CONTROLLER_FRAME_IN_ROOT = np.array([0.0, 0.0, 0.4])  # a "base" frame like ROS-Industrial's


def _parser(name: str) -> Lark:
    return Lark((GRAMMARS / f"{name}.lark").read_text(encoding="utf-8"), parser="lalr")


def _with_base_frame(model: pin.Model) -> pin.Model:
    model = model.copy()
    placement = pin.SE3(np.eye(3), CONTROLLER_FRAME_IN_ROOT)
    model.addFrame(pin.Frame("base", 0, 0, placement, pin.FrameType.OP_FRAME))
    return model


@pytest.fixture(scope="module")
def fanuc(irb4600):
    """The IRB 4600's kinematics on a FANUC controller that counts J3 from the horizontal."""
    spec = dataclasses.replace(
        irb4600.spec, controller="fanuc", joint_coupling="fanuc_j2_j3", controller_frame="base"
    )
    return Robot(spec, _with_base_frame(irb4600.model))


@pytest.fixture(scope="module")
def yaskawa(irb4600):
    spec = dataclasses.replace(irb4600.spec, controller="yaskawa", controller_frame="base")
    return Robot(spec, _with_base_frame(irb4600.model))


def _T(R, p_mm) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.asarray(p_mm, dtype=float) / 1000.0
    return T


def _fixed_xyz(angles_deg) -> np.ndarray:
    return Rotation.from_euler("xyz", angles_deg, degrees=True).as_matrix()  # extrinsic: Rz·Ry·Rx


def _flange(robot: Robot, q: np.ndarray) -> np.ndarray:
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    return data.oMf[robot.model.getFrameId("tool0")].homogeneous


def _errors(A: list[np.ndarray], B: list[np.ndarray]) -> tuple[float, float]:
    assert len(A) == len(B)
    dp = max(float(np.linalg.norm(a[:3, 3] - b[:3, 3])) * 1000.0 for a, b in zip(A, B, strict=True))
    dr = max(
        float(np.degrees(np.linalg.norm(Rotation.from_matrix(a[:3, :3].T @ b[:3, :3]).as_rotvec())))
        for a, b in zip(A, B, strict=True)
    )
    return dp, dr


# ---- the manuals' rules, written here ----------------------------------------------------------


def _geometry(robot: Robot, q: np.ndarray) -> tuple[bool, bool]:
    """(wrist centre behind axis 1, elbow above the shoulder-wrist line) from Pinocchio's joint frames."""
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, q)
    j1 = data.oMi[1]
    shoulder, elbow, wrist = data.oMi[2].translation, data.oMi[3].translation, data.oMi[5].translation
    behind = (j1.rotation.T @ (wrist - j1.translation))[0] < 0.0
    u = (wrist - shoulder) / np.linalg.norm(wrist - shoulder)
    up = j1.rotation[:, 2] - np.dot(j1.rotation[:, 2], u) * u
    return bool(behind), bool(np.dot(elbow - shoulder, up) > 0.0)


def _fanuc_joints_deg(q_urdf: np.ndarray) -> np.ndarray:
    deg = np.degrees(q_urdf).copy()
    deg[2] = deg[2] - deg[1]  # J3 from the horizontal
    return deg


def _expected_config(robot: Robot, q: np.ndarray) -> str:
    behind, up = _geometry(robot, q)
    j = _fanuc_joints_deg(q)
    turns = [math.floor((j[i] + 180.0) / 360.0) for i in (0, 3, 5)]
    return (
        f"'{'F' if j[4] < 0 else 'N'} {'U' if up else 'D'} {'B' if behind else 'T'}, "
        + ", ".join(str(t) for t in turns)
        + "'"
    )


def _expected_rconf(robot: Robot, q: np.ndarray) -> list[int]:
    behind, up = _geometry(robot, q)
    s, r, t = np.degrees(q[[0, 3, 5]])
    r180 = math.remainder(r, 360.0)  # in [-180, 180]
    flip = -90.0 < r180 <= 90.0
    return [
        0 if flip else 1,
        0 if up else 1,
        1 if behind else 0,
        int(r >= 180),
        int(t >= 180),
        int(s >= 180),
    ] + [0] * 18


# ---- TP -----------------------------------------------------------------------------------------


def interpret_tp(text: str) -> dict:
    """The parse tree of a TP program walked: motions in order, positions, frames from the comments."""
    tree = _parser("tp").parse(text)
    positions, motions, comments, frames_used = {}, [], [], {}
    for p in tree.find_data("pdef"):
        index, uf, ut = (int(c) for c in p.children[:3])
        body = p.children[3]
        if body.data == "cartesian":
            config = str(body.children[0])
            xyz = [float(v) for v in body.children[1].children]
            wpr = [float(v) for v in body.children[2].children]
            positions[index] = ("cartesian", uf, ut, config, _T(_fixed_xyz(wpr), xyz))
        else:
            j = [float(jv.children[1]) for jv in body.children]
            positions[index] = ("joints", uf, ut, None, np.array(j))
    for line in tree.find_data("line"):
        st = line.children[1]
        if isinstance(st, Token):
            continue
        if st.data == "motion":
            kind = str(st.children[0])
            pos = int(st.children[1].children[0])
            speed = st.children[2]
            options = st.children[4:]
            switches = [
                (o.data, float(o.children[0]), str(o.children[1].children[2]))
                for o in options
                if o.data in ("time_before", "distance_before")
            ]
            motions.append(
                {
                    "kind": kind,
                    "pos": pos,
                    "speed": float(speed.children[0]),
                    "unit": {
                        "joint_speed": "%",
                        "linear_speed": "mm/sec",
                        "linear_speed_cm": "cm/min",
                        "linear_speed_inch": "inch/min",
                    }[speed.data],
                    "fine": st.children[3].data == "fine",
                    "cnt": int(st.children[3].children[0]) if st.children[3].data == "cnt" else None,
                    "wjnt": any(o.data == "wjnt" for o in options),
                    "switches": switches,
                }
            )
        elif st.data == "comment" and st.children:
            comments.append(str(st.children[0]).strip())
        elif st.data == "frame_select":
            frames_used[str(st.children[0])] = int(st.children[1])
        elif st.data == "io_set":
            motions.append({"kind": "io", "value": str(st.children[2])})
    frames: dict[str, dict[str, float]] = {}
    for c in comments:
        if m := re.fullmatch(r"(UFRAME|UTOOL)\[(\d+)\] ([XYZWPR])=(-?[\d.]+) (mm|deg)\s*", c):
            frames.setdefault(f"{m.group(1)}[{m.group(2)}]", {})[m.group(3)] = float(m.group(4))
    return {"positions": positions, "motions": motions, "frames": frames, "selected": frames_used}


def _frame(values: dict[str, float]) -> np.ndarray:
    return _T(_fixed_xyz([values["W"], values["P"], values["R"]]), [values["X"], values["Y"], values["Z"]])


def _tp_path(prog: dict) -> list[dict]:
    """The path moves: from the move onto the first path point to the one before the retract."""
    moves = [m for m in prog["motions"] if m["kind"] in ("J", "L")]
    first = next(i for i, m in enumerate(moves) if m["kind"] == "L")  # after the home and approach J
    last = max(i for i, m in enumerate(moves) if m["kind"] == "L")  # the retract
    return moves[first:last]


def _turns_and_legs_mm(trajectory) -> tuple[np.ndarray, np.ndarray]:
    """The direction change at every inner target [rad] (N-2,) and every move's length [mm] (N-1,)."""
    d = np.diff(trajectory.poses[:, :3, 3], axis=0) * 1000.0
    legs = np.linalg.norm(d, axis=1)
    turn = [
        math.acos(max(-1.0, min(1.0, float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b)))))
        for a, b in zip(d[:-1], d[1:], strict=True)
    ]
    return np.array(turn), legs


def _glue_problem(problem, **process):
    return dataclasses.replace(problem, process=dataclasses.replace(problem.process, **process))


def test_tp_glue_program_parses_and_every_pose_is_the_forward_kinematics(
    tmp_path, trajectory, problem, fanuc
):
    glue = _glue_problem(problem, lead_s=0.2, output="DO[7]")
    prog = interpret_tp(write_tp(tmp_path / "bead.ls", trajectory, glue, fanuc).read_text(encoding="ascii"))
    uf, ut = glue.frames.base_number, glue.tool.number
    assert prog["selected"] == {"UFRAME_NUM": uf, "UTOOL_NUM": ut}
    T_root_uf = _T(np.eye(3), CONTROLLER_FRAME_IN_ROOT * 1000.0) @ _frame(prog["frames"][f"UFRAME[{uf}]"])
    T_flange_tcp = _frame(prog["frames"][f"UTOOL[{ut}]"])
    path = _tp_path(prog)
    assert len(path) == len(trajectory)
    reached, planned = [], []
    for move, q in zip(path, trajectory.q, strict=True):
        kind, p_uf, p_ut, config, T_uf_tcp = prog["positions"][move["pos"]]
        assert (kind, p_uf, p_ut) == ("cartesian", uf, ut)
        assert config == _expected_config(fanuc, q)
        reached.append(T_root_uf @ T_uf_tcp @ np.linalg.inv(T_flange_tcp))
        planned.append(_flange(fanuc, q))
    dp, dr = _errors(reached, planned)
    assert dp <= POSITION_MM and dr <= ORIENTATION_DEG, (dp, dr)
    # the glue switches on the move: 0.2 s before the first path point, 0.2 s before the last
    assert path[0]["switches"] == [("time_before", 0.2, "ON")]
    offs = [m for m in path if m["switches"] and m["switches"][0][2] == "OFF"]
    assert len(offs) == 1 and offs[0]["switches"][0][1] <= 0.2 + 1e-9
    t_end = float(trajectory.t[-1])
    k_off = path.index(offs[0])
    assert trajectory.t[k_off - 1] <= t_end - 0.2 <= trajectory.t[k_off] + 1e-9  # the move that holds it
    # speeds: whole mm/sec or cm/min, or tenths of inch/min, not above the planned speed nor 2 % below it
    planned_mm_s = 500.0 * (trajectory.speed[:-1] + trajectory.speed[1:])
    written = np.array([m["speed"] for m in path[1:]])
    assert all(
        v == round(v, 0 if m["unit"] != "inch/min" else 1) for v, m in zip(written, path[1:], strict=True)
    )
    per_mm_s = {"mm/sec": 1.0, "cm/min": 1.0 / 6.0, "inch/min": 25.4 / 60.0}
    mm_s = np.array([v * per_mm_s[m["unit"]] for v, m in zip(written, path[1:], strict=True)])
    assert np.all(mm_s <= planned_mm_s + 1e-9) and np.all(mm_s >= 0.98 * planned_mm_s - 1e-9)
    # CNT between the ends, from the model worked here: the corner starts n/100 x v x 0.25 s before
    # the target (v the faster move [mm/s]), at most half of either move, and cuts it by that x sin(turn/2)
    turn, legs = _turns_and_legs_mm(trajectory)
    for k in range(1, len(path) - 1):
        full, half, sine = (
            max(mm_s[k - 1], mm_s[k]) * 0.25,
            0.5 * min(legs[k - 1], legs[k]),
            math.sin(turn[k - 1] / 2),
        )
        expected = next(
            (n for n in range(100, 0, -1) if min(full * n / 100.0, half) * sine <= 0.5 + 1e-9), None
        )
        assert (None if path[k]["fine"] else path[k]["cnt"]) == expected, k
    # and what the program writes is what result.json reports (refine.export.motion)
    reported = program_motion("tp", trajectory, glue).zones.label
    assert [("FINE" if m["fine"] else f"CNT{m['cnt']}") for m in path] == list(reported)


def test_tp_home_holds_the_controllers_joints(tmp_path, trajectory, problem, fanuc):
    home_controller = (10.0, 20.0, -5.0, 0.0, 45.0, 30.0)
    homed = dataclasses.replace(problem, robot=dataclasses.replace(problem.robot, home_deg=home_controller))
    prog = interpret_tp(write_tp(tmp_path / "h.ls", trajectory, homed, fanuc).read_text(encoding="ascii"))
    moves = [m for m in prog["motions"] if m["kind"] in ("J", "L")]
    assert moves[0]["kind"] == "J" and moves[-1]["pos"] == moves[0]["pos"], "home at start and end"
    kind, *_, joints = prog["positions"][moves[0]["pos"]]
    assert kind == "joints"
    np.testing.assert_allclose(joints, home_controller, atol=1e-4)
    # without home_deg: the first waypoint, as the pendant shows it (J3 = J3_urdf - J2_urdf)
    prog = interpret_tp(write_tp(tmp_path / "f.ls", trajectory, problem, fanuc).read_text(encoding="ascii"))
    joints = prog["positions"][[m for m in prog["motions"] if m["kind"] == "J"][0]["pos"]][4]
    q0 = np.degrees(trajectory.q[0])
    np.testing.assert_allclose(joints, [q0[0], q0[1], q0[2] - q0[1], q0[3], q0[4], q0[5]], atol=1e-4)


def test_tp_weld_program_stops_on_the_seam_ends_and_aborts_without_arc(tmp_path, trajectory, problem, fanuc):
    weld = dataclasses.replace(
        problem,
        process=ProcessSettings(kind="weld", output="DO[3]", gas_output="DO[4]", arc_ok_input="DI[5]"),
    )
    text = write_tp(tmp_path / "w.ls", trajectory, weld, fanuc).read_text(encoding="ascii")
    prog = interpret_tp(text)
    path = _tp_path(prog)
    assert path[0]["fine"] and path[-1]["fine"] and not any(m["switches"] for m in path)
    assert "WAIT (DI[5]=ON) TIMEOUT,LBL[90]" in text and "$WAITTMOUT=(200)" in text  # 2 s in 1/100 s
    statements = [
        ln.split(":", 1)[1].strip() for ln in text.split("/MN")[1].split("/POS")[0].splitlines()[1:]
    ]
    end = statements.index("END ;")
    assert statements[end + 1 :] == [
        "LBL[90] ;",
        "DO[3]=OFF ;",
        "DO[4]=OFF ;",
        "! no arc within 2.00 s ;",
        "ABORT ;",
    ]


# ---- INFORM -------------------------------------------------------------------------------------


def interpret_inform(text: str) -> dict:
    tree = _parser("inform").parse(text)
    positions, rconf = {}, None
    for item in next(tree.find_data("pos")).children:
        if isinstance(item, Token) or item.data not in ("rconf", "cvar"):
            continue
        if item.data == "rconf":
            rconf = [int(v) for v in item.children]
        else:
            v = [float(x) for x in item.children[1:]]
            positions[str(item.children[0])] = (_T(_fixed_xyz(v[3:]), v[:3]), rconf)
    tool = int(next(tree.find_data("tool")).children[0])
    npos = [int(v) for v in next(tree.find_data("npos")).children]
    body = next(tree.find_data("body"))
    inst = []
    for st in body.children:
        if isinstance(st, Token):
            continue
        if st.data in ("movj", "movl"):
            pl = next(
                (int(c.children[0]) for c in st.children if hasattr(c, "data") and c.data == "pl"), None
            )
            inst.append((st.data, str(st.children[0]), float(st.children[1]), pl))
        elif st.data == "dout":
            inst.append(("dout", int(st.children[0]), str(st.children[1]), None))
    return {"positions": positions, "inst": inst, "tool": tool, "npos": npos}


def test_inform_glue_job_parses_and_every_pose_is_the_forward_kinematics(
    tmp_path, trajectory, problem, yaskawa
):
    glue = _glue_problem(problem, output="OT#(12)")
    job = interpret_inform(
        write_inform(tmp_path / "bead.JBI", trajectory, glue, yaskawa).read_text(encoding="ascii")
    )
    assert job["tool"] == glue.tool.number and job["npos"][0] == len(job["positions"]) == len(trajectory) + 3
    moves = [i for i in job["inst"] if i[0] in ("movj", "movl")]
    on = job["inst"].index(("dout", 12, "ON", None))
    off = job["inst"].index(("dout", 12, "OFF", None))
    path = [i for i in job["inst"][on - 1 : off] if i[0] == "movl"]
    assert len(path) == len(trajectory) and path[0][3] == 0 and path[-1][3] == 0, "stands where it switches"
    T_root_robot = _T(np.eye(3), CONTROLLER_FRAME_IN_ROOT * 1000.0)
    T_flange_tcp = glue.tool.tcp_in_flange
    reached, planned = [], []
    for (_, c, _, _), q in zip(path, trajectory.q, strict=True):
        T_robot_tcp, rconf = job["positions"][c]
        assert rconf == _expected_rconf(yaskawa, q)
        reached.append(T_root_robot @ T_robot_tcp @ np.linalg.inv(T_flange_tcp))
        planned.append(_flange(yaskawa, q))
    dp, dr = _errors(reached, planned)
    assert dp <= POSITION_MM and dr <= ORIENTATION_DEG, (dp, dr)
    planned_mm_s = 500.0 * (trajectory.speed[:-1] + trajectory.speed[1:])
    written = np.array([v for _, _, v, _ in path[1:]])
    assert np.all(written <= planned_mm_s + 1e-9) and np.all(written >= 0.98 * planned_mm_s - 1e-9)
    # PL=1 between the ends where half the shorter move times sin(turn/2) keeps 0.5 mm, else PL=0
    turn, legs = _turns_and_legs_mm(trajectory)
    for k in range(1, len(path) - 1):
        cut = 0.5 * min(legs[k - 1], legs[k]) * math.sin(turn[k - 1] / 2)
        assert path[k][3] == (1 if cut <= 0.5 + 1e-9 else 0), k
    reported = program_motion("inform", trajectory, glue).zones.label
    assert [f"PL={pl}" for *_, pl in path[1:-1]] == list(reported[1:-1])
    assert moves[0][0] == "movj" and moves[-1][:2] == moves[0][:2], "home at start and end"


def test_inform_weld_job_waits_for_the_arc(tmp_path, trajectory, problem, yaskawa):
    weld = dataclasses.replace(
        problem,
        process=ProcessSettings(kind="weld", output="OT#(3)", gas_output="OT#(4)", arc_ok_input="IN#(5)"),
    )
    text = write_inform(tmp_path / "w.JBI", trajectory, weld, yaskawa).read_text(encoding="ascii")
    interpret_inform(text)  # parses
    lines = text.splitlines()
    seq = [ln for ln in lines if re.match(r"(DOUT|TIMER|WAIT|JUMP)", ln)]
    assert seq[:5] == [
        "DOUT OT#(4) ON",
        "TIMER T=0.50",
        "DOUT OT#(3) ON",
        "WAIT IN#(5)=ON T=2.00",
        "JUMP *ARCFAIL IF IN#(5)=OFF",
    ]
    assert lines[-1] == "END"


# ---- the rules themselves, by hand ----------------------------------------------------------------


def test_configuration_rules_on_poses_worked_by_hand(fanuc, yaskawa):
    from refine.export.inform import yaskawa_rconf
    from refine.export.tp import fanuc_config

    # zero pose with J5 = +30: arm forward, elbow above the shoulder-wrist line -> N U T
    q = np.radians([0.0, 0.0, 0.0, 0.0, 30.0, 0.0])
    assert fanuc_config(fanuc, q) == ["N U T, 0, 0, 0"]
    # J5 negative: flip; J6 at 200 deg: turn 1; J4 at -190: turn -1
    q = np.radians([0.0, 0.0, 0.0, -190.0, -30.0, 200.0])
    assert fanuc_config(fanuc, q) == ["F U T, 0, -1, 1"]
    # upper arm tilted far back (J2 = -100 deg) with the forearm along it: wrist centre behind axis 1
    q = np.radians([0.0, -100.0, -90.0, 0.0, 30.0, 0.0])
    assert fanuc_config(fanuc, q)[0].split(",")[0].endswith("B")
    # Yaskawa: R = 0 is flip, R = 120 deg no-flip; T = 200 deg sets p
    assert yaskawa_rconf(yaskawa, np.radians([0.0, 0.0, 0.0, 0.0, 30.0, 0.0]))[0][:6] == (0, 0, 0, 0, 0, 0)
    assert yaskawa_rconf(yaskawa, np.radians([0.0, 0.0, 0.0, 120.0, 30.0, 200.0]))[0][:6] == (
        1,
        0,
        0,
        0,
        1,
        0,
    )


def test_writers_refuse_other_controllers_and_frame_numbers(tmp_path, trajectory, problem, irb4600, fanuc):
    with pytest.raises(InputError, match="FANUC"):
        write_tp(tmp_path / "a.ls", trajectory, problem, irb4600)
    with pytest.raises(InputError, match="Yaskawa"):
        write_inform(tmp_path / "a.JBI", trajectory, problem, fanuc)
    far = dataclasses.replace(problem, frames=dataclasses.replace(problem.frames, base_number=12))
    with pytest.raises(InputError, match="user frame 1..9"):
        write_tp(tmp_path / "b.ls", trajectory, far, fanuc)


def test_the_grammar_readers_find_each_pass_as_the_plan(tmp_path, trajectory, problem, fanuc, yaskawa):
    tp = pg.read_tp(write_tp(tmp_path / "r.ls", trajectory, problem, fanuc))
    (p,) = tp.passes
    assert pg.pose_errors(p.poses, trajectory.poses)[0] <= POSITION_MM
    T_root_robot = _T(np.eye(3), CONTROLLER_FRAME_IN_ROOT * 1000.0)
    job = pg.read_inform(
        write_inform(tmp_path / "r.JBI", trajectory, problem, yaskawa),
        problem.robot.base_in_world,
        T_root_robot,
    )
    (p,) = job.passes
    dp, dr = pg.pose_errors(p.poses, trajectory.poses)
    assert dp <= POSITION_MM and dr <= ORIENTATION_DEG


def test_preflight_runs_tp_and_inform_only_on_their_controllers(problem, irb4600, fanuc, yaskawa):
    from refine.run.preflight import check_programs

    check_programs(problem, fanuc.spec, ("tp",))
    check_programs(problem, yaskawa.spec, ("inform",))
    with pytest.raises(InputError, match="abb controller runs rapid only"):
        check_programs(problem, irb4600.spec, ("tp",))
    with pytest.raises(InputError, match="fanuc controller runs tp only"):
        check_programs(problem, fanuc.spec, ("inform",))
    bad = _glue_problem(problem, output="DO[600]")
    with pytest.raises(InputError, match=r"DO\[n\] needs n in 1..512"):
        check_programs(bad, fanuc.spec, ("tp",))


@pytest.mark.slow
def test_the_m20ia_weld_writes_a_tp_program_in_the_controllers_joints(tmp_path):
    """``refine run problems/m20ia_arc_weld``: every TP pose against FK at trajectory.csv's joints."""
    import csv
    import json

    from refine.problem import load_problem
    from refine.robot.registry import load_robot
    from refine.run.write import run

    root = Path(__file__).resolve().parents[2]
    problem = load_problem(root / "problems" / "m20ia_arc_weld")
    run(problem, tmp_path)
    doc = json.loads((tmp_path / "result.json").read_text())
    assert doc["status"] == "ok", doc["reason"]
    assert set(doc["outputs"]) >= {"tp"} and not {"rapid", "krl", "inform"} & set(doc["outputs"])
    robot = load_robot("fanuc_m20ia")
    with (tmp_path / "trajectory.csv").open(newline="") as f:
        q_controller = np.array(
            [[float(r[f"q{j}"]) for j in range(1, 7)] for r in csv.DictReader(f)]
        )  # [rad]
    q = q_controller.copy()
    q[:, 2] = q_controller[:, 2] + q_controller[:, 1]  # the pendant's J3 back to the URDF's
    prog = interpret_tp((tmp_path / doc["outputs"]["tp"]).read_text(encoding="ascii"))
    T_root_world = np.array(doc["robot"]["controller_in_base"])
    np.testing.assert_allclose(T_root_world[:3, 3], [0.0, 0.0, 0.525])  # the description's base frame
    uf, ut = prog["selected"]["UFRAME_NUM"], prog["selected"]["UTOOL_NUM"]
    T_root_uf = T_root_world @ _frame(prog["frames"][f"UFRAME[{uf}]"])
    T_flange_tcp = _frame(prog["frames"][f"UTOOL[{ut}]"])
    path = _tp_path(prog)
    reached = [T_root_uf @ prog["positions"][m["pos"]][4] @ np.linalg.inv(T_flange_tcp) for m in path]
    dp, dr = _errors(reached, [_flange(robot, qk) for qk in q])
    assert dp <= POSITION_MM and dr <= ORIENTATION_DEG, (dp, dr)
    assert all(
        prog["positions"][m["pos"]][3] == _expected_config(robot, qk) for m, qk in zip(path, q, strict=True)
    )
    home = prog["positions"][[m for m in prog["motions"] if m["kind"] == "J"][0]["pos"]][4]
    np.testing.assert_allclose(home, problem.robot.home_deg, atol=1e-4)  # the pendant's joints, as given
    j3 = np.degrees(q_controller[:, 2])
    assert np.all((j3 >= -185.0 + 2.0 - 1e-6) & (j3 <= 273.1 - 2.0 + 1e-6))  # the J3 range, with the margin


def test_planned_air_moves_are_written_through_their_via_points(
    tmp_path, trajectory, problem, fanuc, yaskawa
):
    """A run's planned move into the pass (via point, then the approach joints) and its return's via
    point: TP as joint positions in the controller's joints, INFORM as the TCP there with the figure."""
    from refine.export.program import ProgramPass

    q0 = trajectory.q[0]
    via_in, approach, via_out = q0 + np.radians([5, -4, 3, 0, 2, 0]), q0, q0 + np.radians([-6, 3, 0, 2, 0, 1])
    home = q0 + np.radians([0, -10, 5, 0, 0, 0])
    run = ProgramPass(
        "pass 1", trajectory, air_in=np.array([via_in, approach]), air_out=np.array([via_out, home])
    )
    prog = interpret_tp(
        write_tp(tmp_path / "air.ls", trajectory, problem, fanuc, passes=[run]).read_text("ascii")
    )
    moves = [m for m in prog["motions"] if m["kind"] in ("J", "L")]
    first_l = next(i for i, m in enumerate(moves) if m["kind"] == "L")
    into = moves[1:first_l]  # after home: the via point and the approach
    assert [m["kind"] for m in into] == ["J", "J"] and all(m["fine"] for m in into)
    for m, q in zip(into, (via_in, approach), strict=True):
        kind, *_, joints = prog["positions"][m["pos"]]
        assert kind == "joints"
        np.testing.assert_allclose(joints, _fanuc_joints_deg(q), atol=1e-4)
    back = moves[-2]  # the return's via point, then home
    np.testing.assert_allclose(prog["positions"][back["pos"]][4], _fanuc_joints_deg(via_out), atol=1e-4)
    assert moves[-1]["pos"] == moves[0]["pos"]

    job = interpret_inform(
        write_inform(tmp_path / "air.JBI", trajectory, problem, yaskawa, passes=[run]).read_text("ascii")
    )
    movj = [i for i in job["inst"] if i[0] == "movj"]
    T_root_robot = _T(np.eye(3), CONTROLLER_FRAME_IN_ROOT * 1000.0)
    T_flange_tcp = problem.tool.tcp_in_flange
    for (_, c, _, pl), q in zip(movj[1:3], (via_in, approach), strict=True):
        T_robot_tcp, rconf = job["positions"][c]
        dp, dr = _errors([T_root_robot @ T_robot_tcp @ np.linalg.inv(T_flange_tcp)], [_flange(yaskawa, q)])
        assert (
            dp <= POSITION_MM and dr <= ORIENTATION_DEG and rconf == _expected_rconf(yaskawa, q) and pl == 0
        )
    T_robot_tcp, rconf = job["positions"][movj[-2][1]]
    dp, _ = _errors([T_root_robot @ T_robot_tcp @ np.linalg.inv(T_flange_tcp)], [_flange(yaskawa, via_out)])
    assert dp <= POSITION_MM and movj[-1][1] == movj[0][1]
