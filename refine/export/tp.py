"""FANUC TP program: the refined path as ``L`` moves through Cartesian positions (ASCII ``.ls``).

The format (the ASCII form of a teach-pendant program that FANUC's ASCII upload option or
ROBOGUIDE translates to a ``.tp``), as FANUC's HandlingTool operator manual describes it and as
programs published with ROS-Industrial and onerobotics' ``tp_plus`` (its test suite and docs are
the reference for the ``TB``/``DB`` and ``$WAITTMOUT`` syntax) show it:

* ``/PROG <NAME>``, ``/ATTR`` (owner, comment, protection, ``TCD:`` task data, ``DEFAULT_GROUP =
  1,*,*,*,*``), ``/MN`` with one numbered line per instruction ``   n:  <instruction> ;`` (motion
  lines ``   n:J ...`` / ``   n:L ...``), ``/POS`` with one ``P[i]{ GP1: ... };`` per position,
  ``/END``.
* Comments ``! text ;`` of at most :data:`COMMENT_CHARS` characters. The header comments give, per
  value, the tool frame ``UTOOL[t]`` (the TCP in the faceplate) and the user frame ``UFRAME[u]``
  (the world {F} in the controller's world frame) in mm and deg, to be entered on the controller
  (MENU > SETUP > Frames); the program selects them with ``UFRAME_NUM=u`` and ``UTOOL_NUM=t``
  (``[frames] base_number`` and ``[tool] number``).
* Motion: ``J P[i] 20% FINE`` to the home position (joint representation ``J1= .. deg``, the
  controller's joints), ``J`` to an approach point ``retract_m`` behind the first path point along the
  tool z axis (with a run's planned air move, :class:`refine.export.program.ProgramPass` ``air_in``:
  ``J ... FINE`` to each of its via points and to its end, the approach joints, as joint positions;
  the planned return's via points likewise before home), ``L P[i] <v>mm/sec CNT<n>`` through the path, ``L`` to the retract point, ``J`` home.
  Zones and speeds follow :func:`refine.export.motion.program_motion` (``result.json`` states the
  same figures): each target's ``CNT<n>`` is the largest ``n <= cnt`` whose modelled corner keeps
  ``[process] path_tolerance_m``, else ``FINE`` (:func:`refine.export.motion.tp_zones`); each
  segment runs at the fastest of a few levels not above its planned speed and within ``[output]
  speed_share`` of it, in whole mm/sec where such levels do, else in whole cm/min (1/6 mm/s), else
  in tenths of an inch/min (about 0.042 mm/s, the finest TP unit, as in ``16.0inch/min``).
* Process output switched on the move: ``TB <s>sec,DO[n]=ON`` (time before) or ``DB <d>mm,DO[n]=ON``
  (distance before) on the move onto the first path point and ``...=OFF`` on the move that holds
  the switching point before the last (``process.lead_s`` / ``lead_m``). A weld stops on the first
  point and runs the arc start (gas ``DO``, ``WAIT``, arc ``DO``, ``$WAITTMOUT`` in 1/100 s and
  ``WAIT (DI[k]=ON) TIMEOUT,LBL[90]``, the label after ``END`` switching off and aborting), the
  crater fill and post-flow at the last point.
* Runs near the wrist singularity move with the ``Wjnt`` option (wrist joint motion).
* Positions: ``UF : u, UT : t, CONFIG : 'F|N U|D T|B, t1, t4, t6'`` and ``X Y Z`` [mm, 4
  decimals], ``W P R`` [deg, 4 decimals] with ``R_uf_tcp = Rz(R)·Ry(P)·Rx(W)`` (fixed-axis X-Y-Z,
  :func:`refine.frames.fixed_xyz_from_matrix`).

Configuration (:func:`fanuc_config`, from the controller's joints and the arm's geometry): ``F``
(flip) when J5 < 0, else ``N``; ``U`` when the elbow is above the line from the shoulder to the
wrist centre, else ``D``; ``T`` when the wrist centre is in front of axis 1, ``B`` behind it; the
turn numbers of J1, J4, J6 are ``floor((J + 180 deg) / 360 deg)`` (0 for -180 <= J < 180 deg).

Joints: every joint value the program holds is the controller's (:meth:`RobotSpec.to_controller`,
with the J2/J3 coupling of ``joint_coupling = "fanuc_j2_j3"``). Positions are measured in the
controller's world frame, the URDF frame ``controller_frame`` (ROS-Industrial's ``base``).
"""

from __future__ import annotations

import logging
import re
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from refine.errors import InputError
from refine.export.motion import program_motion
from refine.export.program import (
    arm_configuration,
    as_passes,
    controller_base,
    fixed_decimals,
    header_notes,
    home_joints,
    lead_point,
    process_summary,
    singular_runs,
)
from refine.export.sink import put_text
from refine.frames import fixed_xyz_from_matrix, invert_transform, make_transform
from refine.names import comment_text, identifier
from refine.paths import Trajectory
from refine.problem import Problem
from refine.types import Array
from refine.version import __version__

log = logging.getLogger(__name__)

COMMENT_CHARS = 32
"""Longest comment the teach pendant holds [characters]; longer text is split over several lines."""
MAX_UFRAME, MAX_UTOOL = 9, 10
"""User frames 1..9 and tool frames 1..10 of an R-30iB controller."""
MAX_DO = 512
DEFAULT_OUTPUT = 1
"""``DO`` number used when ``process.output`` names no number."""
ABORT_LABEL = 90
"""``LBL`` of the failed arc start."""
MAX_SPEED_MM_S = 2000
CM_MIN = 1.0 / 6000.0
"""One cm/min [m/s]: the step of the path speeds (TP speeds are whole numbers of their unit)."""


def _name(text: str) -> str:
    """A TP program name: letters, digits, ``_``, a letter first, upper case, at most 36 characters."""
    return identifier(text, "P", 36).upper()


def fanuc_io_number(name: str, kind: str, default: int) -> tuple[int, str]:
    """The number of a ``DO[n]``/``DI[n]`` named ``"DO[n]"``, ``"DOn"`` or ``"n"``, else ``default``.

    Returns:
        the number and a note for the program's comments.
    """
    m = re.fullmatch(rf"\s*(?:{kind}\s*\[\s*(\d+)\s*\]|{kind}\s*(\d+)|(\d+))\s*", name, re.IGNORECASE)
    if m is None:
        return default, f"{comment_text(repr(name))} mapped to {kind}[{default}]"
    number = int(m.group(1) or m.group(2) or m.group(3))
    if not 1 <= number <= MAX_DO:
        raise InputError(f"process I/O {name!r}: FANUC {kind}[n] needs n in 1..{MAX_DO}")
    return number, f"{comment_text(repr(name))} is {kind}[{number}]"


def fanuc_config(robot: Any, q: Array) -> list[str]:
    """FANUC configuration strings ``'N U T, 0, 0, 0'`` of URDF joint vectors (module docstring).

    Args:
        robot: a six-axis :class:`refine.robot.model.Robot` (controller ``"fanuc"``).
        q: URDF joints [rad], shape (N, 6) or (6,).
    """
    qs = np.atleast_2d(np.asarray(q, dtype=float))
    behind, elbow_up = arm_configuration(robot, qs)
    deg = np.degrees(robot.spec.to_controller(qs))
    turns = np.floor((deg[:, [0, 3, 5]] + 180.0) / 360.0).astype(int)
    out = []
    for k in range(len(qs)):
        flags = ("F" if deg[k, 4] < 0.0 else "N") + " " + ("U" if elbow_up[k] else "D")
        flags += " " + ("B" if behind[k] else "T")
        out.append(f"{flags}, {turns[k, 0]}, {turns[k, 1]}, {turns[k, 2]}")
    return out


def _xyzwpr(T: Array) -> tuple[list[str], list[str]]:
    xyz = [fixed_decimals(v * 1000.0, 4) for v in T[:3, 3]]
    wpr = [fixed_decimals(v, 4) for v in fixed_xyz_from_matrix(T[:3, :3])]
    return xyz, wpr


def _frame_comments(label: str, T: Array) -> list[str]:
    """One comment per value of a frame, ``UFRAME[1] X=12.3456 mm``."""
    xyz, wpr = _xyzwpr(T)
    return [f"{label} {k}={v} mm" for k, v in zip("XYZ", xyz, strict=True)] + [
        f"{label} {k}={v} deg" for k, v in zip("WPR", wpr, strict=True)
    ]


@dataclass(frozen=True)
class _Io:
    out: int
    gas: int
    arc_ok: int


class _Program:
    """The ``/MN`` lines and ``/POS`` entries being written."""

    def __init__(self, uf: int, ut: int) -> None:
        self.mn: list[str] = []
        self.pos: list[str] = []
        self.uf, self.ut = uf, ut

    def line(self, text: str) -> None:
        self.mn.append(f"  {text} ;")

    def comment(self, text: str) -> None:
        clean = comment_text(text, 1000).replace(";", ",")
        for part in textwrap.wrap(clean, COMMENT_CHARS) or [""]:
            self.line(f"! {part}")

    def motion(self, text: str) -> None:
        self.mn.append(f"{text} ;")

    def cartesian(self, T: Array, config: str) -> int:
        index = len(self.pos) + 1
        xyz, wpr = _xyzwpr(T)
        self.pos.append(
            f"P[{index}]{{\n   GP1:\n\tUF : {self.uf}, UT : {self.ut},\t\tCONFIG : '{config}',\n"
            f"\tX = {xyz[0]}  mm,\tY = {xyz[1]}  mm,\tZ = {xyz[2]}  mm,\n"
            f"\tW = {wpr[0]} deg,\tP = {wpr[1]} deg,\tR = {wpr[2]} deg\n}};"
        )
        return index

    def joints(self, q_controller_deg: Array) -> int:
        index = len(self.pos) + 1
        j = [f"J{i + 1}= {fixed_decimals(v, 4)} deg" for i, v in enumerate(q_controller_deg)]
        sep = ",\t"
        self.pos.append(
            f"P[{index}]{{\n   GP1:\n\tUF : {self.uf}, UT : {self.ut},\n"
            f"\t{sep.join(j[:3])},\n\t{sep.join(j[3:])}\n}};"
        )
        return index


def _weld_start(prog: _Program, problem: Problem, io: _Io) -> None:
    pr = problem.process
    prog.line(f"DO[{io.gas}]=ON")
    prog.comment("gas pre-flow")
    prog.line(f"WAIT {fixed_decimals(pr.preflow_s, 2)}(sec)")
    prog.line(f"DO[{io.out}]=ON")
    prog.comment("arc on, wait for arc ok")
    prog.line(f"$WAITTMOUT=({int(round(pr.arc_timeout_s * 100.0))})")
    prog.line(f"WAIT (DI[{io.arc_ok}]=ON) TIMEOUT,LBL[{ABORT_LABEL}]")


def _weld_end(prog: _Program, problem: Problem, io: _Io) -> None:
    pr = problem.process
    prog.comment("crater fill")
    prog.line(f"WAIT {fixed_decimals(pr.crater_fill_s, 2)}(sec)")
    prog.line(f"DO[{io.out}]=OFF")
    prog.comment("gas post-flow")
    prog.line(f"WAIT {fixed_decimals(pr.postflow_s, 2)}(sec)")
    prog.line(f"DO[{io.gas}]=OFF")


def _switch(problem: Problem, io: _Io, value: str, lead: float) -> str:
    """``TB <s>sec,DO[n]=..`` or ``DB <d>mm,DO[n]=..``: ``lead`` [s or m] before the move's end."""
    if problem.process.lead_m is None:
        return f" TB {fixed_decimals(lead, 2)}sec,DO[{io.out}]={value}"
    return f" DB {fixed_decimals(lead * 1000.0, 1)}mm,DO[{io.out}]={value}"


def _speed(v_m_s: float) -> str:
    """A TP path speed in the coarsest unit that holds it: whole mm/sec, whole cm/min, or 0.1 inch/min.

    The levels come from :func:`refine.export.motion.program_motion` as multiples of one of them.
    """
    mm_s, cm_min = v_m_s * 1000.0, v_m_s / CM_MIN
    if abs(mm_s - round(mm_s)) < 1e-6:
        return f"{min(max(int(round(mm_s)), 1), MAX_SPEED_MM_S)}mm/sec"
    if abs(cm_min - round(cm_min)) < 1e-6:
        return f"{min(max(int(round(cm_min)), 1), 6 * MAX_SPEED_MM_S)}cm/min"
    inch_min = v_m_s * 60.0 / 0.0254
    return f"{fixed_decimals(min(max(inch_min, 0.1), MAX_SPEED_MM_S * 60.0 / 25.4), 1)}inch/min"


def _planned_joints(prog: _Program, robot: Any, q: Array, ptp_percent: int) -> None:
    """A planned air move's via points and end as ``J`` moves to joint positions, stopping on each (as verified)."""
    for qk in np.atleast_2d(q):
        index = prog.joints(np.degrees(robot.spec.to_controller(qk)))
        prog.motion(f"J P[{index}] {int(ptp_percent)}% FINE")


def _pass_moves(
    prog: _Program,
    tr: Trajectory,
    robot: Any,
    problem: Problem,
    io: _Io,
    *,
    approach_speed_m_s: float,
    retract_m: float,
    ptp_percent: int,
    cnt: int,
    air_in: Array | None = None,
) -> None:
    weld = problem.process.kind == "weld"
    conf = fanuc_config(robot, tr.q)
    back = make_transform(p=[0.0, 0.0, -retract_m])
    app = prog.cartesian(tr.poses[0] @ back, conf[0]) if air_in is None else 0
    points = [prog.cartesian(T, c) for T, c in zip(tr.poses, conf, strict=True)]
    ret = prog.cartesian(tr.poses[-1] @ back, conf[-1])
    by_time = problem.process.lead_m is None
    lead = problem.process.lead_s if by_time else float(problem.process.lead_m)
    motion = program_motion("tp", tr, problem, retract_m=retract_m, cnt=cnt, approach_m_s=approach_speed_m_s)
    along = tr.t if by_time else np.concatenate([[0.0], np.cumsum(motion.lengths_m)])
    off_k, off_lead = lead_point(along, lead)
    zones = motion.zones
    approach_mm_s = min(max(int(round(approach_speed_m_s * 1000.0)), 1), MAX_SPEED_MM_S)
    wjnt = np.zeros(len(tr), dtype=bool)
    for a, b in singular_runs(robot, tr.q):
        wjnt[max(a, 1) : b + 2] = True
        prog.comment(f"waypoints {a}-{b} near the wrist singularity: Wjnt")
    if zones.narrowed:
        prog.comment(
            f"{len(zones.narrowed)} corner(s) below CNT{cnt} or FINE to keep the path tolerance "
            f"{zones.tolerance_m * 1e3:g} mm"
        )
    if air_in is None:
        prog.motion(f"J P[{app}] {int(ptp_percent)}% CNT100")
    else:
        _planned_joints(prog, robot, air_in, ptp_percent)
    if weld:
        prog.motion(f"L P[{points[0]}] {approach_mm_s}mm/sec {zones.label[0]}")
        _weld_start(prog, problem, io)
    else:
        on = _switch(problem, io, "ON", lead)
        prog.motion(f"L P[{points[0]}] {approach_mm_s}mm/sec {zones.label[0]}{on}")
    for k in range(1, len(tr)):
        option = " Wjnt" if wjnt[k] else ""
        off = _switch(problem, io, "OFF", off_lead) if k == off_k and not weld else ""
        speed = _speed(float(motion.programmed_m_s[k - 1]))
        prog.motion(f"L P[{points[k]}] {speed} {zones.label[k]}{option}{off}")
    if weld:
        _weld_end(prog, problem, io)
    prog.motion(f"L P[{ret}] {approach_mm_s}mm/sec CNT{cnt}")


def write_tp(
    path: str | Path,
    trajectory: Trajectory,
    problem: Problem,
    robot: Any,
    *,
    passes: list[Any] | None = None,
    repairs: tuple[Any, ...] = (),
    approach_speed_m_s: float = 0.25,
    retract_m: float = 0.1,
    ptp_percent: int = 20,
    cnt: int = 100,
) -> Path:
    """Write the trajectory as a FANUC TP program in ASCII (``<NAME>.ls``).

    Args:
        path: output file; its stem, made a TP name (upper case), names the program and the file.
        trajectory: the refined, timed path (poses in {F}, URDF joints for CONFIG).
        problem: tool and user frame numbers, home, process output and switching, speed levels.
        robot: the :class:`refine.robot.model.Robot` the joints belong to (controller ``"fanuc"``).
        passes: several passes (:class:`refine.export.program.ProgramPass` or ``(name,
            trajectory)``); when given, ``trajectory`` is not written.
        repairs: the repaired segments of ``trajectory`` (when ``passes`` is not given).
        approach_speed_m_s: speed of the moves onto the first point and to the retract [m/s].
        retract_m: approach and retract distance along the tool z axis [m].
        ptp_percent: speed of the ``J`` moves [% of the joints' maximum].
        cnt: the largest ``CNT`` of the path moves (1..100; 100 blends the most); smaller, or
            ``FINE``, where the corner would leave ``[process] path_tolerance_m``
            (:func:`refine.export.motion.tp_zones`).

    Returns:
        The path written.
    """
    if getattr(robot.spec, "controller", "") != "fanuc":
        raise InputError(
            f"TP is for FANUC robots; {robot.spec.name!r} has controller {robot.spec.controller!r}"
        )
    if robot.nq != 6:
        raise InputError(f"TP export: needs a six-axis arm, {robot.spec.name!r} has {robot.nq} joints")
    runs = as_passes(problem.name, trajectory, passes, repairs)
    if any(len(p.trajectory) < 2 for p in runs):
        raise InputError("TP export: every pass needs at least 2 waypoints")
    if not (1 <= cnt <= 100 and 1 <= ptp_percent <= 100):
        raise InputError(
            f"TP export: cnt must be 1..100 and ptp_percent 1..100 [%], got {cnt}, {ptp_percent}"
        )
    if not (approach_speed_m_s > 0.0 and retract_m > 0.0):
        raise InputError("TP export: approach speed [m/s] and retract [m] must be > 0")
    uf, ut = problem.frames.base_number, problem.tool.number
    if not (1 <= uf <= MAX_UFRAME and 1 <= ut <= MAX_UTOOL):
        raise InputError(
            f"TP export: [frames] base_number = {uf} must be a user frame 1..{MAX_UFRAME} and [tool] number "
            f"= {ut} a tool frame 1..{MAX_UTOOL}"
        )
    name = _name(Path(path).stem)
    out_path = Path(path).with_name(name + ".ls")
    pr = problem.process
    out, out_note = fanuc_io_number(pr.output, "DO", DEFAULT_OUTPUT)
    gas, gas_note = fanuc_io_number(pr.gas_output, "DO", DEFAULT_OUTPUT + 1)
    arc_ok, ok_note = fanuc_io_number(pr.arc_ok_input, "DI", 1)
    io = _Io(out, gas, arc_ok)
    weld = pr.kind == "weld"
    by_time = pr.lead_m is None
    lead = pr.lead_s if by_time else float(pr.lead_m)
    approach = retract_m / approach_speed_m_s if by_time else retract_m
    if not weld and lead > approach:
        unit = "s" if by_time else "m"
        raise InputError(
            f"process lead {lead:g} {unit} is longer than the approach move ({approach:g} {unit})"
        )
    T_uf_world = invert_transform(controller_base(robot)) @ invert_transform(problem.robot.base_in_world)

    prog = _Program(uf, ut)
    prog.comment(f"refine {__version__}: {problem.name}, {problem.robot.model}")
    prog.comment(f"process output {out_note}")
    prog.comment(process_summary(problem, "TB/DB", f"DO[{out}]", gas_note, ok_note))
    for p in runs:
        for note in header_notes(p, robot):
            prog.comment(note)
    prog.comment(f"UFRAME[{uf}] = world {{F}} in the robot world frame, set it to:")
    for text in _frame_comments(f"UFRAME[{uf}]", T_uf_world):
        prog.comment(text)
    prog.comment(f"UTOOL[{ut}] = TCP of {problem.tool.name} in the faceplate, set it to:")
    for text in _frame_comments(f"UTOOL[{ut}]", problem.tool.tcp_in_flange):
        prog.comment(text)
    if robot.spec.joint_coupling:
        prog.comment("joints are the controller's: J3 from the horizontal")
    prog.line(f"UFRAME_NUM={uf}")
    prog.line(f"UTOOL_NUM={ut}")
    home_deg = np.degrees(robot.spec.to_controller(home_joints(problem, robot, runs[0].trajectory.q[0])))
    home = prog.joints(home_deg)
    prog.motion(f"J P[{home}] {int(ptp_percent)}% FINE")
    for i, p in enumerate(runs, start=1):
        prog.comment(f"pass {i} of {len(runs)}: {p.name}, {len(p.trajectory)} points")
        _pass_moves(
            prog,
            p.trajectory,
            robot,
            problem,
            io,
            approach_speed_m_s=approach_speed_m_s,
            retract_m=retract_m,
            ptp_percent=ptp_percent,
            cnt=cnt,
            air_in=p.air_in,
        )
    if runs[-1].air_out is not None and len(runs[-1].air_out) > 1:
        _planned_joints(prog, robot, runs[-1].air_out[:-1], ptp_percent)  # the planned return's via points
    prog.motion(f"J P[{home}] {int(ptp_percent)}% FINE")
    if weld:
        prog.line("END")
        prog.line(f"LBL[{ABORT_LABEL}]")
        prog.line(f"DO[{io.out}]=OFF")
        prog.line(f"DO[{io.gas}]=OFF")
        prog.comment(f"no arc within {fixed_decimals(pr.arc_timeout_s, 2)} s")
        prog.line("ABORT")
    mn = [f"{k:4d}:{line}" for k, line in enumerate(prog.mn, start=1)]
    attr = [
        "/ATTR",
        "OWNER\t\t= MNEDITOR;",
        f'COMMENT\t\t= "{comment_text(problem.name, 16).replace(chr(34), "")}";',
        "PROG_SIZE\t= 0;",
        f"FILE_NAME\t= {name};",
        "VERSION\t\t= 0;",
        f"LINE_COUNT\t= {len(mn)};",
        "MEMORY_SIZE\t= 0;",
        "PROTECT\t\t= READ_WRITE;",
        "TCD:  STACK_SIZE\t= 0,",
        "      TASK_PRIORITY\t= 50,",
        "      TIME_SLICE\t= 0,",
        "      BUSY_LAMP_OFF\t= 0,",
        "      ABORT_REQUEST\t= 0,",
        "      PAUSE_REQUEST\t= 0;",
        "DEFAULT_GROUP\t= 1,*,*,*,*;",
        "CONTROL_CODE\t= 00000000 00000000;",
    ]
    text = "\n".join([f"/PROG  {name}", *attr, "/MN", *mn, "/POS", *prog.pos, "/END"]) + "\n"
    put_text(out_path, text, encoding="ascii")
    log.info(
        "wrote TP program %s: %d pass(es), %d positions, DO[%d]", out_path, len(runs), len(prog.pos), out
    )
    return out_path


def tp_file_name(stem: str) -> str:
    """The file name :func:`write_tp` writes for an output stem."""
    return _name(stem) + ".ls"
