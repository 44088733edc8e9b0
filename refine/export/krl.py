"""KUKA KRL program: the refined path as ``LIN`` moves through ``E6POS`` points (``.src`` + ``.dat``).

* ``.dat``: ``DECL FRAME TOOL_<tool>`` (TCP in the flange), ``DECL FRAME BASE_WORLD`` (the world {F} in
  the robot base, ``inv(base_in_world)``), ``DECL LOAD`` (tool mass, centre of gravity), one ``DECL
  E6POS`` per waypoint (``XP<k>``, ``XP<pass>_<k>`` for several passes), an approach and a retract point
  (``XAPP<pass>``, ``XRET<pass>``) ``retract_m`` behind the end waypoints along the tool z axis. X, Y, Z
  [mm, 4 decimals]; A, B, C [deg, 6 decimals] from :func:`refine.frames.kuka_abc_from_matrix`
  (``Rz(A)·Ry(B)·Rx(C)``, C = 0 at B = ±90 deg); the controller stores ``REAL`` in single precision.
* ``.src``: ``DEF``/``END``, KUKA's ``INI`` fold, ``$BASE``, ``$TOOL``, ``$LOAD`` from those (every
  ``E6POS`` is then a TCP pose in {F}, assuming the controller's ``$WORLD`` is the robot base),
  ``$APO.CDIS``, then a fold ``;FOLD pass i of n: <name>`` per pass: ``PTP`` to the approach point,
  ``LIN`` onto the first point, ``$OUT[n]=TRUE``, ``LIN ... C_DIS`` through the points (the last one
  exact), ``$OUT[n]=FALSE``, ``LIN`` to the retract point (writing ``$OUT`` stops the advance run, so
  the output switches with the robot on the end points). ``$VEL.CP`` [m/s]: the segment speed
  (:func:`refine.export.rapid.segment_speeds`) rounded to ``speed_resolution_m_s``, set when it changes.

Process output: ``process.output`` ``"$OUT[12]"`` or ``"12"`` names the output; any other name (such as
``doGlue``) maps to ``$OUT[1]`` (:data:`DEFAULT_OUTPUT`), with a comment naming the signal for re-mapping.

Status and Turn (:func:`kuka_status_turn`) of a six-axis KUKA, from the KUKA expert programming manual
as quoted in robot-forum.com thread 7173 ("x value of wrist root point") and from Beckhoff TF5200
"Status & Turn (IS, IT)", which documents KUKA's convention: S bit 0 = 1 when the wrist root point
has a negative x in the A1 coordinate system (the frame turning with axis 1): overhead area; bit 1 = 1
when the wrist root point lies in front of the line through axes 2 and 3 (it flips at the stretched
elbow; elbow-up poses have it set, hence KUKA's usual ``S 2`` / ``S 6``); bit 2 = 1 when A5 < 0.
T bit i = 1 when axis i+1 < 0; an axis within :data:`TURN_ZERO_RAD` of zero counts as at zero (bit
0), so the bits do not follow the solver's rounding of a joint held at zero.

LBR iiwa (7 axes) on a KRC: the Sunrise handbook's redundancy information as quoted in
``IFL-CAMP/iiwa_stack`` ``iiwa_msgs/msg/RedundancyInformation.msg``: S bit 0 = 1 when working overhead
(the same wrist-root test; the wrist root is where axes 5, 6, 7 meet), bit 1 = 1 when A4 < 0, bit 2 = 1
when A6 <= 0; E1 = the redundancy angle, the angle of axis 3 [deg]. That source says Turn is not used
on the iiwa (no axis passes ±180 deg, so T selects nothing); T is still written, bit i = A(i+1) < 0.
Geometry from the model (link frames parallel to the base at zero as in ``robots/``, the wrist root at
the second-to-last joint); joint signs must be KUKA's.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from refine.errors import InputError
from refine.export.motion import Zones, program_motion, segment_speeds
from refine.export.program import (
    Switch,
    Wait,
    arc_abort,
    as_passes,
    circular_note,
    circular_pieces,
    header_notes,
    home_joints,
    lead_point,
    process_summary,
    singular_runs,
    weld_end,
    weld_start,
)
from refine.export.sink import put_text
from refine.frames import invert_transform, kuka_abc_from_matrix, make_transform, matrix_from_kuka_abc
from refine.names import comment_text, identifier
from refine.paths import Trajectory
from refine.problem import Problem
from refine.types import Array
from refine.version import __version__

log = logging.getLogger(__name__)

DEFAULT_OUTPUT = 1  # $OUT number used when process.output names no number
_INI = (  # the INI fold of KUKA's standard program template
    ";FOLD INI|  ;FOLD BASISTECH INI|    GLOBAL INTERRUPT DECL 3 WHEN $STOPMESS==TRUE DO IR_STOPM ( )|"
    "    INTERRUPT ON 3|    BAS (#INITMOV,0 )|  ;ENDFOLD (BASISTECH INI)|;ENDFOLD (INI)"
).split("|")


def _name(text: str, fallback: str) -> str:
    """A KRL name: letters, digits, ``_``, starting with a letter, at most 24 characters."""
    return identifier(text, fallback, 24)


def _real(value: float, decimals: int) -> str:
    text = f"{value:.{decimals}f}".rstrip("0").rstrip(".")
    return "0.0" if float(text) == 0.0 else (text if "." in text else f"{text}.0")


def _xyzabc(T: Array) -> str:
    """``X ..,Y ..,Z ..,A ..,B ..,C ..`` of a transform: mm and degrees."""
    xyz = [_real(v * 1000.0, 4) for v in T[:3, 3]]
    abc = [_real(v, 6) for v in kuka_abc_from_matrix(T[:3, :3])]
    return ",".join(f"{k} {v}" for k, v in zip("XYZABC", xyz + abc, strict=True))


def krl_output_number(output: str) -> int | None:
    """The ``$OUT`` number named by ``process.output`` (``"$OUT[12]"`` or ``"12"``), else None."""
    m = re.fullmatch(r"\s*(?:\$OUT\[\s*(\d+)\s*\]|(\d+))\s*", output, re.IGNORECASE)
    if m is None:
        return None
    number = int(m.group(1) or m.group(2))
    if not 1 <= number <= 4096:
        raise InputError(f"process.output {output!r}: KRL outputs are $OUT[1]..$OUT[4096]")
    return number


TURN_ZERO_RAD = 1e-9
"""An axis closer to zero than this [rad] has Turn bit 0 (the rule's A >= 0): a joint the optimiser
holds at zero (a redundant arm's seventh, drawn to the middle of its range) ends at +-1e-22 rad
or so, whose sign is rounding, and a program must not change with it. 1e-9 rad is far below what
any program prints (1e-4 deg)."""


def kuka_status_turn(robot: Any, q: Array) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """KUKA Status and Turn of joint vectors (rules and sources in the module docstring).

    Args:
        robot: a :class:`refine.robot.model.Robot` with 6 joints (KUKA serial arm) or 7 (LBR iiwa).
        q: joint positions [rad], shape (N, n) or (n,).

    Returns:
        Status and Turn, each of shape (N,) (integers for a single q).
    """
    q = np.asarray(q, dtype=float)
    qs, n = np.atleast_2d(q), robot.nq
    if n not in (6, 7) or qs.shape[1] != n:
        raise InputError(f"KUKA Status/Turn needs 6 or 7 axes; got {robot.spec.name!r} with q {q.shape}")
    status = np.zeros(len(qs), dtype=np.int64)
    model, data = robot.model, robot.data
    for k, qk in enumerate(qs):
        pin.forwardKinematics(model, data, qk)
        a1, wrist = data.oMi[1], data.oMi[n - 1].translation
        overhead = float((a1.rotation.T @ (wrist - a1.translation))[0]) < 0.0
        if n == 6:
            p2, p3 = data.oMi[2].translation, data.oMi[3].translation
            front = float(np.dot(np.cross(a1.rotation[:, 1], p3 - p2), wrist - p2)) > 0.0
            status[k] = int(overhead) + 2 * int(front) + 4 * int(qk[4] < 0.0)
        else:
            status[k] = int(overhead) + 2 * int(qk[3] < 0.0) + 4 * int(qk[5] <= 0.0)
    turn = ((qs < -TURN_ZERO_RAD) * (1 << np.arange(n))).sum(axis=1).astype(np.int64)
    return (status[0], turn[0]) if q.ndim == 1 else (status, turn)


def krl_io_number(name: str, kind: str, default: int) -> tuple[int, str]:
    """The number of a KRL ``$OUT``/``$IN`` named ``"$OUT[n]"``/``"$IN[n]"`` or ``"n"``, else ``default``.

    Returns:
        the number and a note for the program's comments.
    """
    m = re.fullmatch(rf"\s*(?:\${kind}\[\s*(\d+)\s*\]|(\d+))\s*", name, re.IGNORECASE)
    if m is None:
        return default, f"{comment_text(repr(name))} mapped to ${kind}[{default}] (refine default)"
    number = int(m.group(1) or m.group(2))
    if not 1 <= number <= 4096:
        raise InputError(f"process I/O {name!r}: KRL has ${kind}[1]..${kind}[4096]")
    return number, f"{name!r} is ${kind}[{number}]"


def _declarations(
    names: list[str],
    tr: Trajectory,
    robot: Any,
    back: Array,
    q_approach: Array | None = None,
    stationary: bool = False,
) -> list[str]:
    """``DECL E6POS`` of the approach point, every waypoint and the retract point of one pass.

    ``q_approach``: the planned joints at the approach point [rad], whose Status and Turn the
    approach point gets (else the first waypoint's). ``stationary``: an external TCP, each point the
    held part ($TOOL) in the standing tool's frame ($BASE), the inverse of the tool seen from the part.
    """
    n = len(tr)
    status, turn = kuka_status_turn(robot, tr.q)
    if q_approach is not None:
        s_app, t_app = kuka_status_turn(robot, np.asarray(q_approach, dtype=float)[None])
        status, turn = status.copy(), turn.copy()
    if len(set(status)) > 1:  # a CP motion keeps its start Status: a change means a singular pose
        log.warning("KRL: Status changes along a LIN pass (%s): a singularity", sorted(set(status.tolist())))
    e1 = np.degrees(tr.q[:, 2]) if robot.nq == 7 else np.zeros(n)
    poses, rows = [tr.poses[0] @ back, *tr.poses, tr.poses[-1] @ back], [0, *range(n), n - 1]
    if stationary:
        poses = [invert_transform(T) for T in poses]
    tail = ",".join(f"E{i} 0.0" for i in range(2, 7))
    out = [
        f"DECL E6POS {name}={{{_xyzabc(T)},S {status[r]},T {turn[r]},E1 {_real(e1[r], 6)},{tail}}}"
        for name, T, r in zip(names, poses, rows, strict=True)
    ]
    if q_approach is not None:
        e1_app = math.degrees(q_approach[2]) if robot.nq == 7 else 0.0
        out[0] = (
            f"DECL E6POS {names[0]}={{{_xyzabc(poses[0])},S {int(s_app[0])},T {int(t_app[0])},"
            f"E1 {_real(e1_app, 6)},{tail}}}"
        )
    return out


def _frames_stationary(problem: Problem, tool_n: int, base_n: int) -> tuple[str, ...]:
    """The frames of an external TCP: BASE_DATA the standing tool, TOOL_DATA the held part."""
    tool_in_base = invert_transform(problem.robot.base_in_world) @ problem.tool.tcp_in_world
    return (
        f"; E6POS: the held part ($TOOL = TOOL_DATA[{tool_n}]) in the standing tool's frame ($BASE = "
        f"BASE_DATA[{base_n}]), $IPO_MODE = #TCP, X Y Z [mm], A B C [deg], S T (E1 = A3 [deg] on an LBR)",
        f"; TOOL_DATA[{tool_n}] (the held part's frame on the flange) must be {{{_xyzabc(problem.tool.tcp_in_flange)}}}",
        f"; BASE_DATA[{base_n}] ({comment_text(problem.tool.name)}, the standing tool) must be {{{_xyzabc(tool_in_base)}}}",
    )


def _e6axis(q: Array) -> str:
    """``A1 .. A6`` [deg] and ``E1`` (the seventh axis of an LBR, else 0) of a joint vector."""
    deg = [_real(v, 4) for v in np.degrees(q)]
    axes = [f"A{i + 1} {v}" for i, v in enumerate(deg[:6])]
    ext = [f"E1 {deg[6] if len(deg) > 6 else '0.0'}"] + [f"E{i} 0.0" for i in range(2, 7)]
    return ",".join(axes + ext)


@dataclass(frozen=True)
class _Io:
    """The I/O numbers of a program: process output, and for a weld gas output and arc-ok input."""

    out: int
    gas: int
    arc_ok: int


def _weld_io(io: _Io) -> tuple[Wait, Switch]:
    signals = {"out": io.out, "gas": io.gas}

    def wait(seconds: float, comment: str) -> str:
        return f"WAIT SEC {_real(seconds, 3)}" + (f" ; {comment}" if comment else "")

    def switch(role: str, on: bool, comment: str) -> str:
        return f"$OUT[{signals[role]}]={'TRUE' if on else 'FALSE'}" + (f" ; {comment}" if comment else "")

    return wait, switch


def _weld_start(io: _Io, problem: Problem) -> list[str]:
    pr = problem.process
    wait, switch = _weld_io(io)
    timeout_ms = int(round(pr.arc_timeout_s * 1000.0))
    return weld_start(
        problem,
        wait,
        switch,
        [
            f"$TIMER[1]=-{timeout_ms} ; arc start timeout [ms]",
            "$TIMER_STOP[1]=FALSE",
            f"WAIT FOR $IN[{io.arc_ok}] OR $TIMER_FLAG[1]",
            "$TIMER_STOP[1]=TRUE",
            f"IF NOT $IN[{io.arc_ok}] THEN",
            *arc_abort(switch, "  "),
            f"  HALT ; no arc signal within {_real(pr.arc_timeout_s, 3)} s",
            "ENDIF",
        ],
    )


def _weld_end(io: _Io, problem: Problem) -> list[str]:
    return weld_end(problem, *_weld_io(io))


def _trigger(problem: Problem, io: _Io, value: str, lead: float) -> str:
    """``TRIGGER WHEN`` for the move that follows: ``lead`` [s or m] before its end point."""
    if problem.process.lead_m is None:
        return f"TRIGGER WHEN DISTANCE=1 DELAY=-{int(round(lead * 1000.0))} DO $OUT[{io.out}]={value}"
    return f"TRIGGER WHEN PATH=-{_real(lead * 1000.0, 3)} DELAY=0 DO $OUT[{io.out}]={value}"


def _moves(
    names: list[str],
    tr: Trajectory,
    robot: Any,
    problem: Problem,
    io: _Io,
    air: str,
    step: float,
    zones: Zones,
) -> list[str]:
    """The motion of one pass: approach, process on, the seam, process off, retract.

    Each path point is approximated (``C_DIS``) or an exact stop as ``zones`` says.
    """
    path, current, weld = names[1:-1], None, problem.process.kind == "weld"
    by_time = problem.process.lead_m is None
    lead = problem.process.lead_s if by_time else float(problem.process.lead_m)
    along = tr.t if by_time else np.concatenate([[0.0], np.cumsum(_lengths(tr))])
    off_k, off_lead = lead_point(along, lead)
    lines = [f"$VEL.CP = {air}", f"PTP {names[0]}"]
    if weld:
        lines += [f"LIN {path[0]}", *_weld_start(io, problem)]
    else:
        lines += [_trigger(problem, io, "TRUE", lead), f"LIN {path[0]}" + _zone(zones, 0)]
    sing_on, sing_off = {}, {}
    for a, b in singular_runs(robot, tr.q):
        sing_on[max(a, 1)] = f"$ORI_TYPE = #JOINT ; near the wrist singularity at points {a + 1}-{b + 1}"
        sing_off[min(b + 1, len(tr) - 1)] = "$ORI_TYPE = #VAR"
    arcs = {a.start + 1: a for a in circular_pieces(tr, sing_on, sing_off, off_k if not weld else None)}
    skip_to = 0
    if arcs:  # CIRC's orientation: from the start's to the end's at a constant rate, in the base
        lines.insert(2, "$CIRC_TYPE = #BASE")
    for k, v in enumerate(segment_speeds(tr), start=1):
        if k <= skip_to:
            continue
        arc = arcs.get(k)
        steps = max(round(v / step), 1)
        if arc is not None:  # one speed for the circular move, not above its slowest segment's
            steps = max(math.floor(arc.speed_m_s / step + 1e-9), 1)
        text = _real(steps * step, 6)
        lines += [f"$VEL.CP = {text}"] if text != current else []
        current = text
        lines += [sing_on[k]] if k in sing_on else []
        lines += [_trigger(problem, io, "FALSE", off_lead)] if k == off_k and not weld else []
        if arc is not None:  # the CAD's arc: one circular move through the via point (see the header)
            lines.append(f"CIRC {path[arc.via]}, {path[arc.end]}" + _zone(zones, arc.end))
            skip_to = arc.end
            continue
        lines.append(f"LIN {path[k]}" + _zone(zones, k))
        lines += [sing_off[k]] if k in sing_off else []
    lines += _weld_end(io, problem) if weld else []
    return lines + [f"$VEL.CP = {air}", f"LIN {names[-1]}"]


def _zone(zones: Zones, k: int) -> str:
    """`` C_DIS`` where point ``k`` is approximated, nothing at an exact stop."""
    return " C_DIS" if zones.label[k] == "C_DIS" else ""


def _lengths(tr: Trajectory) -> Array:
    return np.linalg.norm(np.diff(tr.poses[:, :3, 3], axis=0), axis=1)


def write_krl(
    path_src: str | Path,
    trajectory: Trajectory,
    problem: Problem,
    robot: Any,
    *,
    passes: list[Any] | None = None,
    repairs: tuple[Any, ...] = (),
    approximation_m: float = 0.001,
    approach_speed_m_s: float = 0.25,
    retract_m: float = 0.1,
    ptp_percent: int = 20,
    speed_resolution_m_s: float = 1e-4,
) -> tuple[Path, Path]:
    """Write the trajectory as a KUKA KRL program, ``<name>.src`` and ``<name>.dat``.

    Args:
        path_src: output ``.src`` file; its stem, made a KRL name, names the program and both files.
        trajectory: the refined, timed path (poses in {F}, joints for Status, Turn and E1).
        problem: tool and base numbers, home, process output and switching.
        robot: the :class:`refine.robot.model.Robot` the joints belong to (controller ``"kuka"``).
        passes: several passes of a multi-pass weld as :class:`refine.export.program.ProgramPass`
            or ``(name, trajectory)`` in order, the root pass included; when given, ``trajectory``
            is not written. One fold per pass.
        repairs: the repaired segments of ``trajectory`` (when ``passes`` is not given).
        approximation_m: ``$APO.CDIS`` approximation distance between path points [m].
        approach_speed_m_s: ``$VEL.CP`` of the moves onto the first point and to the retract [m/s].
        retract_m: approach and retract distance along the tool z axis [m].
        ptp_percent: axis speed of the ``PTP`` moves [% of the maximum].
        speed_resolution_m_s: ``$VEL.CP`` is rounded to this step [m/s].

    Returns:
        The ``.src`` and ``.dat`` paths written.
    """
    if getattr(robot.spec, "controller", "") != "kuka":
        raise InputError(f"KRL is for KUKA robots; {robot.spec.name!r} is for {robot.spec.controller}")
    runs = as_passes(problem.name, trajectory, passes, repairs)
    if any(len(p.trajectory) < 2 or p.trajectory.q.shape[1] != robot.nq for p in runs):
        raise InputError(f"KRL export: needs passes of >= 2 waypoints of {robot.nq} joints, got {len(runs)}")
    if not (speed_resolution_m_s > 0.0 and approach_speed_m_s > 0.0 and approximation_m >= 0.0):
        raise InputError("KRL export: speeds must be > 0 and approximation_m >= 0")
    prog = _name(Path(path_src).stem, "prog")
    src, dat = (Path(path_src).with_name(prog + ext) for ext in (".src", ".dat"))
    pr = problem.process
    out, out_note = krl_io_number(pr.output, "OUT", DEFAULT_OUTPUT)
    gas, gas_note = krl_io_number(pr.gas_output, "OUT", DEFAULT_OUTPUT + 1)
    arc_ok, ok_note = krl_io_number(pr.arc_ok_input, "IN", 1)
    io = _Io(out, gas, arc_ok)
    tool_n, base_n = problem.tool.number, problem.frames.base_number
    cog = [_real(v * 1000.0, 4) for v in problem.tool.cog_in_flange_m]
    header = f"; Written by refine {__version__} for problem '{comment_text(problem.name)}', robot {problem.robot.model}."
    stationary = problem.tool.stationary
    dat_lines = [
        *("&ACCESS RVP", "&REL 1", f"DEFDAT {prog}", header),
        *(_frames_stationary(problem, tool_n, base_n) if stationary else (
            f"; E6POS: TCP in {{F}} ($BASE = BASE_DATA[{base_n}]), X Y Z [mm], A B C [deg], S T "
            "(E1 = A3 [deg] on an LBR)",
            f"; TOOL_DATA[{tool_n}] ({comment_text(problem.tool.name)}) must be {{{_xyzabc(problem.tool.tcp_in_flange)}}}",
            f"; BASE_DATA[{base_n}] (world {{F}}) must be "
            f"{{{_xyzabc(invert_transform(problem.robot.base_in_world))}}}",
        )),
        f"; LOAD_DATA[{tool_n}] must be {{M {_real(problem.tool.mass_kg, 4)},CM {{X {cog[0]},Y {cog[1]},"
        f"Z {cog[2]},A 0.0,B 0.0,C 0.0}},J {{X 0.0,Y 0.0,Z 0.0}}}}",
        f"DECL E6AXIS XHOMEPOS={{{_e6axis(home_joints(problem, robot, runs[0].trajectory.q[0]))}}}",
    ]
    process_lines = [f"; {process_summary(problem, 'TRIGGER', out_note, gas_note, ok_note)}"]
    notes = [line for p in runs for line in header_notes(p, robot)]
    src_lines = [*("&ACCESS RVP", "&REL 1", f"DEF {prog}( )"), *_INI, header]
    src_lines += [
        f"; process output {comment_text(repr(pr.output))} -> $OUT[{out}]",
        *process_lines,
        *(f"; {n}" for n in notes),
    ]
    src_lines += [
        f"$BASE = BASE_DATA[{base_n}]",
        f"$TOOL = TOOL_DATA[{tool_n}]",
        f"$LOAD = LOAD_DATA[{tool_n}]",
        *(["$IPO_MODE = #TCP ; external TCP: the tool stands, the robot moves the part"] if stationary else []),
    ]
    src_lines += [f"$APO.CDIS = {_real(approximation_m * 1000.0, 4)}", f"BAS (#VEL_PTP,{int(ptp_percent)} )"]
    src_lines.append("PTP XHOMEPOS")
    air, back = _real(approach_speed_m_s, 6), make_transform(p=[0.0, 0.0, -retract_m])
    for i, p in enumerate(runs, start=1):
        tr = p.trajectory
        points = [f"XP{k}" if len(runs) == 1 else f"XP{i}_{k}" for k in range(1, len(tr) + 1)]
        names = [f"XAPP{i}", *points, f"XRET{i}"]
        air_in = getattr(p, "air_in", None)
        dat_lines += _declarations(names, tr, robot, back, None if air_in is None else air_in[-1], stationary)
        head = f"pass {i} of {len(runs)}: " + comment_text(str(p.name)).replace(";", ",")
        zones = program_motion(
            "krl",
            tr,
            problem,
            approximation_m=approximation_m,
            retract_m=retract_m,
            speed_resolution_m_s=speed_resolution_m_s,
        ).zones
        src_lines += [
            f";FOLD {head}",
            f"  ; {head}, {len(tr)} points, {float(tr.t[-1]):.3f} s planned",
            f"  ; zones: C_DIS, exact at {len(zones.narrowed)} point(s) to keep the path tolerance "
            f"{zones.tolerance_m * 1e3:g} mm; largest corner deviation {zones.largest_deviation_m * 1e3:.3f} mm",
        ]
        if air_in is not None:  # the run's planned air move: via points (exact stops), then the approach
            vias = [f"XIN{i}_{k}" for k in range(1, len(air_in))]
            dat_lines += [f"DECL E6AXIS {v}={{{_e6axis(q)}}}" for v, q in zip(vias, air_in, strict=False)]
            src_lines += [f"  PTP {v} ; via point of the planned move to pass {i}" for v in vias]
        moves = _moves(names, tr, robot, problem, io, air, speed_resolution_m_s, zones)
        circular = sum(ln.startswith("CIRC ") for ln in moves)
        src_lines += [f"  ; {n}" for n in circular_note(circular, "slerp ($CIRC_TYPE = #BASE)")]
        src_lines += [f"  {line}" for line in moves]
        src_lines.append(";ENDFOLD")
    air_out = getattr(runs[-1], "air_out", None)
    if air_out is not None:  # the run's planned return: via points, then home
        vias = [f"XOUT{k}" for k in range(1, len(air_out))]
        dat_lines += [f"DECL E6AXIS {v}={{{_e6axis(q)}}}" for v, q in zip(vias, air_out, strict=False)]
        src_lines += [f"PTP {v} ; via point of the planned return" for v in vias]
    src_lines.append("PTP XHOMEPOS")
    put_text(src, "\n".join([*src_lines, "END"]) + "\n")
    put_text(dat, "\n".join([*dat_lines, "ENDDAT"]) + "\n")
    log.info("wrote KRL program %s (+ .dat): %d pass(es), $OUT[%d]", src, len(runs), out)
    return src, dat


@dataclass(frozen=True)
class KrlPass:
    """One pass read back from a KRL program: its path points, in path order.

    Attributes:
        name: the pass name from its fold.
        points: the E6POS names.
        positions: TCP positions in {F} [m], shape (N, 3).
        rotations: TCP orientations R_F_TCP, shape (N, 3, 3).
        status, turn: Status S and Turn T, shape (N,) each.
        e1_deg: E1 of each point [deg] (the LBR's redundancy angle), shape (N,).
        speeds: ``$VEL.CP`` of the move ending at each point [m/s], shape (N,).
        output: the ``$OUT`` number switched around the pass.
    """

    name: str
    points: tuple[str, ...]
    positions: Array
    rotations: Array
    status: NDArray[np.int64]
    turn: NDArray[np.int64]
    e1_deg: Array
    speeds: Array
    output: int


_DECL_RE = re.compile(r"^\s*DECL\s+E6POS\s+(\w+)\s*=\s*\{([^{}]*)\}", re.IGNORECASE | re.MULTILINE)
_FOLD_RE = re.compile(r";\s*FOLD\s+pass\s+\d+\s+of\s+\d+:\s*(.*)$", re.IGNORECASE)


def _fields(body: str, where: str) -> dict[str, float]:
    try:  # "X 1.0,Y 2.0,..." -> {"X": 1.0, ...}
        return {k.upper(): float(v) for k, v in (item.split() for item in body.split(","))}
    except ValueError as e:
        raise InputError(f"KRL {where}: malformed E6POS {{{body}}}") from e


def parse_krl(path_src: str | Path, path_dat: str | Path) -> list[KrlPass]:
    """Read back the passes of a program written by :func:`write_krl`.

    A pass runs from a ``PTP`` to an approach point to the last ``LIN`` before the next pass; its
    path points are the moves from the one the process output switches on at (a ``TRIGGER`` belongs
    to the move after it, an assignment to the move before it) to the one before the retract.

    Raises:
        InputError: no pass found, a point used but not declared, or a malformed declaration.
    """
    decls = _DECL_RE.finditer(Path(path_dat).read_text(encoding="utf-8"))
    points = {m.group(1).upper(): _fields(m.group(2), m.group(1)) for m in decls}
    text = Path(path_src).read_text(encoding="utf-8")
    head = re.search(r"^;\s*process output .* -> \$OUT\[(\d+)\]", text, re.IGNORECASE | re.MULTILINE)
    out = int(head.group(1)) if head else DEFAULT_OUTPUT
    passes: list[dict[str, Any]] = []
    label, speed = "", float("nan")
    for raw in text.splitlines():
        if fold := _FOLD_RE.match(raw.strip()):
            label = fold.group(1).strip()
        code = raw.split(";", 1)[0].strip()
        switch = re.search(rf"\$OUT\[{out}\]\s*=\s*(TRUE|FALSE)", code, re.IGNORECASE)
        if m := re.fullmatch(r"\$VEL\.CP\s*=\s*(\S+)", code, re.IGNORECASE):
            speed = float(m.group(1))
        elif m := re.fullmatch(r"PTP\s+(\w+)", code, re.IGNORECASE):
            if m.group(1).upper() in points:
                passes.append({"name": label, "moves": [], "on": None, "off": None})
        elif re.match(r"LIN\s", code, re.IGNORECASE) and passes:
            if not (m := re.fullmatch(r"LIN\s+(\w+)(\s+C_DIS)?", code, re.IGNORECASE)):
                raise InputError(f"KRL {path_src}: cannot read {code!r}")
            if m.group(1).upper() not in points:
                raise InputError(f"KRL {path_src}: point {m.group(1)} is not declared in {path_dat}")
            passes[-1]["moves"].append((m.group(1).upper(), speed))
        elif re.match(r"CIRC\s", code, re.IGNORECASE) and passes:  # the via point and the end point
            if not (m := re.fullmatch(r"CIRC\s+(\w+)\s*,\s*(\w+)(\s+C_DIS)?", code, re.IGNORECASE)):
                raise InputError(f"KRL {path_src}: cannot read {code!r}")
            for name in (m.group(1).upper(), m.group(2).upper()):
                if name not in points:
                    raise InputError(f"KRL {path_src}: point {name} is not declared in {path_dat}")
                passes[-1]["moves"].append((name, speed))
        elif switch and passes:
            key = "on" if switch.group(1).upper() == "TRUE" else "off"
            after = 0 if code.upper().startswith("TRIGGER") else -1  # a TRIGGER acts on the next move
            passes[-1][key] = len(passes[-1]["moves"]) + after
    result = []
    for p in passes:
        if p["on"] is None or p["off"] is None or p["on"] < 0:
            raise InputError(f"KRL {path_src}: pass {p['name']!r} does not switch $OUT[{out}] on and off")
        moves = p["moves"][p["on"] : -1]
        v = np.array([[points[name][k] for k in "X Y Z A B C S T E1".split()] for name, _ in moves])
        names, speeds = tuple(name for name, _ in moves), np.array([s for _, s in moves])
        S, T, R = v[:, 6].astype(np.int64), v[:, 7].astype(np.int64), matrix_from_kuka_abc(v[:, 3:6])
        result.append(KrlPass(p["name"], names, v[:, :3] / 1000.0, R, S, T, v[:, 8], speeds, out))
    if not result:
        raise InputError(f"KRL {path_src}: no pass (PTP approach followed by LIN moves) found")
    return result
