"""ABB RAPID module: the refined path as ``MoveL`` instructions through ``robtarget`` constants.

What the module holds, in order:

* ``PERS tooldata``: the TCP in the flange (mm, quaternion ``[q1, q2, q3, q4]`` scalar first),
  the tool mass [kg] and centre of gravity [mm].
* ``PERS wobjdata``: its user frame is the world frame {F} in the robot base frame,
  ``inv(base_in_world)``, so every ``robtarget`` is a TCP pose in {F}. This assumes the controller's
  world frame is the robot base (no base frame configured in the controller).
* ``CONST speeddata``: one per distinct segment speed; a segment's ``v_tcp`` is the mean of the
  planned speeds at its two ends [mm/s], rounded to a resolution (0.1 mm/s by default) so that
  equal speeds share one ``speeddata``. ``v_ori``, ``v_leax``, ``v_reax`` take ABB's values for the
  predefined ``v100``..``v1000`` (500 deg/s, 5000 mm/s, 1000 deg/s).
* ``CONST robtarget``: one per waypoint, in path order, from ``trajectory.poses``; ``robconf``
  from ``trajectory.q`` (:func:`abb_confdata`); external axes unused (``9E+09``).
* ``PROC main``: ``MoveJ`` to a point ``retract`` behind the first target along the tool z axis,
  ``MoveL`` onto it (``fine``), the process output on, ``MoveL`` through every target (small zone,
  ``fine`` at the last), the output off, and a ``MoveL`` retract along the tool z axis.

Configuration data (RAPID Technical Reference Manual, data type ``confdata``): ``cf1``, ``cf4``,
``cf6`` are the quadrants of axes 1, 4, 6: quadrant 0 is [0, 90) deg, 1 is [90, 180), -1 is
[-90, 0), -2 is [-180, -90), i.e. ``floor(q / 90 deg)``. ``cfx`` numbers the eight arm
configurations of a serial six-axis robot: ``4·b1 + 2·b2 + b3`` where ``b1`` = 1 when the wrist
centre is behind axis 1, ``b2`` = 1 when it is behind the lower arm, ``b3`` = 1 when axis 5 is
negative (manual's table: 0 = front/front/positive ... 7 = behind/behind/negative).
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from refine.errors import InputError
from refine.export.motion import program_motion, segment_speeds
from refine.export.program import (
    ProgramPass,
    Switch,
    Wait,
    arc_abort,
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
from refine.frames import continuous_quaternions, invert_transform, quaternion_from_matrix
from refine.names import comment_text, identifier
from refine.paths import Trajectory
from refine.problem import Problem
from refine.types import Array
from refine.version import __version__

log = logging.getLogger(__name__)

_EXTAX = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"
RAPID_MAX_TIME_LEAD_S = 0.5
"""``TriggIO \\Time`` is meant for short times before the end point (RAPID reference: below 0.5 s)."""
_SPEED_TAIL = "500,5000,1000"  # v_ori [deg/s], v_leax [mm/s], v_reax [deg/s]


def _identifier(text: str, fallback: str) -> str:
    return identifier(text, fallback, 32)


def _num(value: float, decimals: int) -> str:
    text = f"{value:.{decimals}f}"
    return "0" if float(text) == 0.0 else text.rstrip("0").rstrip(".")


def _pose(T: Array) -> str:
    """``[[x,y,z],[q1,q2,q3,q4]]`` with x, y, z in mm."""
    trans = ",".join(_num(v * 1000.0, 4) for v in T[:3, 3])
    quat = ",".join(_num(v, 9) for v in quaternion_from_matrix(T[:3, :3]))
    return f"[[{trans}],[{quat}]]"


def _jointtarget(name: str, q: Array) -> str:
    """``CONST jointtarget`` of joints ``q`` [rad] (``robax`` in deg, external axes unused)."""
    return f"    CONST jointtarget {name}:=[[{','.join(_num(v, 4) for v in np.degrees(q))}],{_EXTAX}];"


def abb_confdata(robot: Any, q: Array) -> NDArray[np.int64]:
    """ABB configuration data ``[cf1, cf4, cf6, cfx]`` of joint vectors (see the module docstring).

    The geometry comes from the robot model: the wrist centre is the origin of joint 5 (axes 4, 5,
    6 intersect there); "in front of axis 1" means a positive x in the frame of joint 1 (the arm
    points along x at zero); "in front of the lower arm" means on the side of the plane through
    axes 2 and 3 that ``axis2 × (joint 3 - joint 2)`` points to, which is forward for ABB's
    positive-forward axis 2.

    Args:
        robot: a :class:`refine.robot.model.Robot` with six joints (an ABB serial arm).
        q: joint positions [rad], shape (N, 6) or (6,).

    Returns:
        Integer configuration data, shape (N, 4) (or (4,) for a single q).
    """
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    qs = np.atleast_2d(q)
    if qs.shape[1] != 6 or robot.nq != 6:
        raise InputError(
            f"ABB confdata needs a six-axis robot and q of shape (N, 6), got "
            f"{robot.spec.name!r} with q {q.shape}"
        )
    conf = np.zeros((len(qs), 4), dtype=np.int64)
    conf[:, :3] = np.floor(np.degrees(qs[:, [0, 3, 5]]) / 90.0)
    model, data = robot.model, robot.data
    to_wrist = np.empty((len(qs), 3))  # wrist centre - joint 2
    arm = np.empty((len(qs), 3))  # joint 3 - joint 2
    axis2 = np.empty((len(qs), 3))
    behind_axis1 = np.empty(len(qs), dtype=bool)
    for k, qk in enumerate(qs):
        pin.computeJointJacobians(model, data, qk)
        p2, p3 = data.oMi[2].translation, data.oMi[3].translation
        wrist = data.oMi[5].translation
        axis2[k] = pin.getJointJacobian(model, data, 2, pin.LOCAL_WORLD_ALIGNED)[3:, 1]
        behind_axis1[k] = (data.oMi[1].rotation.T @ (wrist - data.oMi[1].translation))[0] < 0.0
        to_wrist[k], arm[k] = wrist - p2, p3 - p2
    normal = np.cross(axis2, arm)  # all at once: one call instead of one per waypoint
    behind_lower_arm = np.array([float(np.dot(w, n)) < 0.0 for w, n in zip(to_wrist, normal, strict=True)])
    conf[:, 3] = 4 * behind_axis1 + 2 * behind_lower_arm + (qs[:, 4] < 0.0)
    return conf[0] if single else conf


__all__ = ["abb_confdata", "parse_rapid_targets", "segment_speeds", "write_rapid"]


def _trigg_io(name: str, lead: float, by_time: bool, output: str, value: int) -> str:
    unit = " \\Time" if by_time else ""
    amount = _num(lead, 4) if by_time else _num(lead * 1000.0, 3)
    return f"TriggIO {name}, {amount}{unit} \\DOp:={output}, {value};"


def _weld_io(problem: Problem, output: str) -> tuple[Wait, Switch]:
    signals = {"out": output, "gas": problem.process.gas_output}

    def wait(seconds: float, comment: str) -> str:
        return f"WaitTime {_num(seconds, 3)};" + (f"  ! {comment}" if comment else "")

    def switch(role: str, on: bool, comment: str) -> str:
        return f"SetDO {signals[role]}, {int(on)};" + (f"  ! {comment}" if comment else "")

    return wait, switch


def _weld_start(problem: Problem, output: str) -> list[str]:
    pr = problem.process
    wait, switch = _weld_io(problem, output)
    timeout = _num(pr.arc_timeout_s, 3)
    return weld_start(
        problem,
        wait,
        switch,
        [
            f"WaitDI {pr.arc_ok_input}, 1 \\MaxTime:={timeout} \\TimeFlag:=arcTimeout;",
            "IF arcTimeout THEN",
            *arc_abort(switch, "    "),
            f'    ErrWrite "Arc start failed", "no {pr.arc_ok_input} within {timeout} s";',
            "    EXIT;",
            "ENDIF",
        ],
    )


def _weld_end(problem: Problem, output: str) -> list[str]:
    return weld_end(problem, *_weld_io(problem, output))


def _tool_and_wobj(problem: Problem, tool: str, wobj: str, cog: str) -> list[str]:
    """The ``tooldata`` and ``wobjdata`` declarations.

    A tool on the flange: ``robhold`` TRUE, its TCP in the flange; the work object is the world {F}
    in the robot base. A stationary tool: ``robhold`` FALSE, its TCP in the base (the controller's
    world); the work object is the held part, ``robhold`` TRUE, its user frame in the flange (wrist)
    frame, so each target is the stationary TCP seen from the part.
    """
    t = problem.tool
    load = f"[{_num(t.mass_kg, 3)},[{cog}],[1,0,0,0],0,0,0]"
    if not t.stationary:
        return [
            f"    PERS tooldata {tool}:=[TRUE,{_pose(t.tcp_in_flange)},{load}];",
            f'    PERS wobjdata {wobj}:=[FALSE,TRUE,"",'
            f"{_pose(invert_transform(problem.robot.base_in_world))},[[0,0,0],[1,0,0,0]]];",
        ]
    tcp_in_base = invert_transform(problem.robot.base_in_world) @ t.tcp_in_world
    return [
        f"    PERS tooldata {tool}:=[FALSE,{_pose(tcp_in_base)},{load}];",
        f'    PERS wobjdata {wobj}:=[TRUE,TRUE,"",{_pose(t.tcp_in_flange)},[[0,0,0],[1,0,0,0]]];',
    ]


def write_rapid(
    path: str | Path,
    trajectory: Trajectory,
    problem: Problem,
    robot: Any,
    *,
    repairs: tuple[Any, ...] = (),
    pass_name: str = "pass 1",
    zone: str = "z1",
    approach_speed_m_s: float = 0.25,
    retract_m: float = 0.1,
    speed_resolution_m_s: float = 1e-4,
    air_in: Array | None = None,
    air_out: Array | None = None,
    air_in_s: tuple[float, ...] | None = None,
    air_out_s: tuple[float, ...] | None = None,
    start_home: bool = True,
    end_home: bool = True,
) -> Path:
    """Write the trajectory as an ABB RAPID module (``.mod``).

    Args:
        path: output file; the module is named after the problem.
        trajectory: the refined, timed path (poses in {F}, joints for the configuration data).
        problem: tool data, robot base, home, process output and switching, ``[output]``
            ``speed_levels`` and ``moves_per_routine``.
        robot: the :class:`refine.robot.model.Robot` the joints belong to (six-axis ABB).
        repairs: the repaired segments of this path (listed in the header).
        pass_name: the pass's name in the header.
        zone: zone between path targets (``"z0"``, ``"z1"``, ...).
        approach_speed_m_s: TCP speed of the approach and retract moves [m/s].
        retract_m: approach and retract distance along the tool z axis [m].
        speed_resolution_m_s: speed levels are multiples of this step [m/s] (0.1 mm/s by default).
        air_in: the run's planned move from home to the approach point, as joints [rad] (K, n): via
            points, then the approach joints; written as ``MoveAbsJ ... fine`` through each (the
            approach point then a joint target, and the ``MoveL`` onto the first target its straight
            line). None: ``MoveJ`` to the approach point as a pose.
        air_out: the run's planned return, joints [rad] (K, n) after the retract point (via points,
            then home), each a ``MoveAbsJ ... fine``; None: straight home.
        air_in_s: the planned time of each joint move of ``air_in`` [s] (one per row): each
            ``MoveAbsJ`` then runs in it (its time argument ``T``, rounded up to the millisecond), as
            planned at ``[output] air_speed_share``; None: at ``vAir``.
        air_out_s: the same for ``air_out``.
        start_home: the module starts with a move to home; False for a pass of a multi-pass weld
            that runs after the previous pass's module (``air_in`` is then the planned link from
            its retract point).
        end_home: the module ends with the move home; False for a pass the next module follows.

    Returns:
        The path written.
    """
    path = Path(path)
    n = len(trajectory)
    if n < 2:
        raise InputError(f"RAPID export needs at least 2 waypoints, got {n}")
    if getattr(robot.spec, "controller", "abb") != "abb":
        raise InputError(
            f"RAPID is for ABB robots; {robot.spec.name!r} has controller {robot.spec.controller!r}"
        )
    if not re.fullmatch(r"z\d+", zone):
        raise InputError(f"RAPID zone must be z0, z1, z5, ..., got {zone!r}")
    if not speed_resolution_m_s > 0.0:
        raise InputError(f"speed_resolution_m_s must be > 0, got {speed_resolution_m_s}")
    module = _identifier(problem.name, "m")
    tool = _identifier(problem.tool.name, "t")
    stationary = problem.tool.stationary
    wobj = "wobjPart" if stationary else "wobjWorld"
    pr, weld = problem.process, problem.process.kind == "weld"
    signals = [pr.output] + ([pr.gas_output, pr.arc_ok_input] if weld else [])
    for signal in signals:
        if not re.fullmatch(r"[A-Za-z]\w{0,31}", signal):
            raise InputError(
                f"process signal {signal!r} is not a RAPID signal name (letter, then letters, digits, _)"
            )
    output = pr.output
    tool_t = problem.tool
    cog = ",".join(_num(v * 1000.0, 4) for v in tool_t.cog_in_flange_m)

    conf = abb_confdata(robot, trajectory.q)
    quats = continuous_quaternions(quaternion_from_matrix(trajectory.poses[:, :3, :3]))
    width = max(4, len(str(n - 1)))
    names = [f"p{k:0{width}d}" for k in range(n)]

    # ---- speeds: a few levels, none above the planned speed, each segment within the speed share;
    # ---- zones: the largest of z1, z0 whose deviation keeps the path tolerance, else fine
    motion = program_motion(
        "rapid",
        trajectory,
        problem,
        zone=zone,
        retract_m=retract_m,
        speed_resolution_m_s=speed_resolution_m_s,
    )
    lengths = motion.lengths_m
    levels = motion.levels
    level_of = np.searchsorted(levels, motion.programmed_m_s)
    extra_s = motion.extra_time_s
    zones = motion.zones
    speed_name = [f"vPath{i + 1}" for i in range(len(levels))]
    retract_mm = _num(retract_m * 1000.0, 3)

    # ---- process switching on the move (not weld: the arc starts and ends standing still)
    by_time = pr.lead_m is None
    lead = pr.lead_s if by_time else float(pr.lead_m)
    approach = retract_m / approach_speed_m_s if by_time else retract_m
    if by_time and lead > RAPID_MAX_TIME_LEAD_S:
        raise InputError(
            f"process.lead_s = {lead:g} s: RAPID TriggIO \\Time allows at most {RAPID_MAX_TIME_LEAD_S} s; "
            "give lead_m instead"
        )
    if not weld and lead > approach:
        unit = "s" if by_time else "m"
        raise InputError(
            f"process lead {lead:g} {unit} is longer than the approach move ({approach:g} {unit})"
        )
    off_k, off_lead = lead_point(
        trajectory.t if by_time else np.concatenate([[0.0], np.cumsum(lengths)]), lead
    )

    move_tail = f"{tool} \\WObj:={wobj};"
    notes = header_notes(ProgramPass(pass_name, trajectory, tuple(repairs)), robot)
    process_note = process_summary(problem, "TriggIO", output, pr.gas_output, pr.arc_ok_input)
    lines = [
        f"MODULE {module}",
        f"    ! Written by refine {__version__} for problem '{comment_text(problem.name)}', robot "
        f"{problem.robot.model}, {n} targets, {float(trajectory.t[-1]):.3f} s planned.",
        (
            f"    ! Targets: the stationary TCP ({tool}, robhold FALSE) in the frame of the part the robot holds "
            f"({wobj}, robhold TRUE, on the flange); trans [mm], "
            if stationary
            else f"    ! Targets: TCP poses in the world frame {{F}} ({wobj}); trans [mm], "
        )
        + "rot [q1,q2,q3,q4], robconf [cf1,cf4,cf6,cfx] of the refined joints.",
        f"    ! Process: {process_note}.",
        f"    ! Speeds: {len(levels)} speeddata levels, each segment at the fastest level not above its "
        f"planned speed and within {problem.output.speed_share:.1%} of it: {extra_s:+.3f} s on the planned path.",
        f"    ! Zones: {zone} between targets, smaller or fine at {len(zones.narrowed)} target(s) to keep "
        f"the path tolerance {zones.tolerance_m * 1e3:g} mm; largest corner deviation "
        f"{zones.largest_deviation_m * 1e3:.3f} mm.",
        *(f"    ! {line}" for line in notes),
        *_tool_and_wobj(problem, tool, wobj, cog),
        f"    CONST jointtarget jHome:=[[{','.join(_num(v, 4) for v in np.degrees(home_joints(problem, robot, trajectory.q[0])))}],{_EXTAX}];",
        f"    CONST speeddata vAir:=[{_num(approach_speed_m_s * 1000.0, 3)},{_SPEED_TAIL}];",
    ]
    lines += [
        f"    CONST speeddata {name}:=[{_num(v * 1000.0, 6)},{_SPEED_TAIL}];"
        for name, v in zip(speed_name, levels, strict=True)
    ]
    speed_at = len(lines)  # each circular move's own speeddata goes here
    lines += ["    VAR bool arcTimeout;"] if weld else ["    VAR triggdata trOn;", "    VAR triggdata trOff;"]
    for k in range(n):
        trans = ",".join(_num(v * 1000.0, 4) for v in trajectory.poses[k, :3, 3])
        rot = ",".join(_num(v, 9) for v in quats[k])
        cf = ",".join(str(int(c)) for c in conf[k])
        lines.append(f"    CONST robtarget {names[k]}:=[[{trans}],[{rot}],[{cf}],{_EXTAX}];")

    # ---- path moves, with the wrist singularity handling around the runs near it
    sing_on, sing_off = {}, {}
    for a, b in singular_runs(robot, trajectory.q):
        sing_on[max(a, 1)] = f"SingArea \\Wrist;  ! near the wrist singularity at targets {a}-{b}"
        sing_off[min(b + 1, n - 1)] = "SingArea \\Off;"
    moves = []
    arcs = {a.start + 1: a for a in circular_pieces(trajectory, sing_on, sing_off, off_k if not weld else None)}
    skip_to, arc_speeds = 0, []
    for k in range(1, n):
        if k <= skip_to:
            continue
        if k in sing_on:
            moves.append(sing_on[k])
        z = zones.label[k]
        v = speed_name[level_of[k - 1]]
        if (arc := arcs.get(k)) is not None:  # the CAD's arc: one circular move at its own speed
            v = f"vArc{len(arc_speeds) + 1}"
            arc_speeds.append(f"    CONST speeddata {v}:=[{_num(arc.speed_m_s * 1000.0, 6)},{_SPEED_TAIL}];")
            moves.append(f"MoveC {names[arc.via]}, {names[arc.end]}, {v}, {zones.label[arc.end]}, {move_tail}")
            skip_to = arc.end
            continue
        if k == off_k and not weld:
            moves.append(f"TriggL {names[k]}, {v}, trOff, {z}, {move_tail}")
        else:
            moves.append(f"MoveL {names[k]}, {v}, {z}, {move_tail}")
        if k in sing_off:
            moves.append(sing_off[k])
    notes_arc = [f"    ! {n}" for n in circular_note(len(arc_speeds), "path frame (CirPathMode \\PathFrame)")]
    lines[speed_at:speed_at] = notes_arc + arc_speeds
    size = problem.output.moves_per_routine
    chunks = [moves[i : i + size] for i in range(0, len(moves), size)]
    routines = [f"path_{i + 1}" for i in range(len(chunks))]

    main = ["ConfJ \\On;", "ConfL \\On;"]
    abs_tail = f"{tool} \\WObj:={wobj};" if stationary else f"{tool};"  # a stationary tool needs its wobj
    if arcs:  # MoveC's orientation: in the circle's path frame, from the start's to the end's
        main.append("CirPathMode \\PathFrame;")
    home_move = f"MoveAbsJ jHome\\NoEOffs, vAir, fine, {abs_tail}"
    main.append(home_move if start_home else "! runs after the previous pass's module, from its retract point")
    air_zone = "z10" if air_in is None else "fine"  # planned motions: exact stops, as verified
    air_decls: list[str] = []
    if air_in is None:
        main.append(f"MoveJ RelTool({names[0]}, 0, 0, -{retract_mm}), vAir, z10, {move_tail}")
    else:
        air_names = [f"jIn{k + 1}" for k in range(len(air_in))]
        air_decls += [_jointtarget(a, q) for a, q in zip(air_names, air_in, strict=True)]
        main += [
            f"MoveAbsJ {a}\\NoEOffs, {_air_speed(air_in_s, k)}, fine, {abs_tail}" for k, a in enumerate(air_names)
        ]
        main[-1] += "  ! the approach point"
    if weld:
        main += [f"MoveL {names[0]}, vAir, fine, {move_tail}", *_weld_start(problem, output)]
    else:
        main += [
            _trigg_io("trOn", lead, by_time, output, 1),
            _trigg_io("trOff", off_lead, by_time, output, 0),
            f"TriggL {names[0]}, vAir, trOn, {zones.label[0]}, {move_tail}",
        ]
    main += [f"{r};" for r in routines]
    main += _weld_end(problem, output) if weld else []
    main.append(f"MoveL RelTool({names[-1]}, 0, 0, -{retract_mm}), vAir, {air_zone}, {move_tail}")
    if air_out is not None and len(air_out) > 1:
        out_names = [f"jOut{k + 1}" for k in range(len(air_out) - 1)]  # the last row is home
        air_decls += [_jointtarget(a, q) for a, q in zip(out_names, air_out[:-1], strict=True)]
        main += [
            f"MoveAbsJ {a}\\NoEOffs, {_air_speed(air_out_s, k)}, fine, {abs_tail}" for k, a in enumerate(out_names)
        ]
    if air_out is not None and air_out_s is not None:
        home_move = f"MoveAbsJ jHome\\NoEOffs, {_air_speed(air_out_s, len(air_out) - 1)}, fine, {abs_tail}"
    main.append(home_move if end_home else "! the next pass's module follows")
    home_at = next(k for k, ln in enumerate(lines) if ln.startswith("    CONST jointtarget jHome"))
    lines[home_at + 1 : home_at + 1] = air_decls
    lines += ["", "    PROC main()", *(f"        {ln}" for ln in main), "    ENDPROC"]
    for r, chunk in zip(routines, chunks, strict=True):
        lines += ["", f"    PROC {r}()", *(f"        {ln}" for ln in chunk), "    ENDPROC"]
    lines.append("ENDMODULE")
    put_text(path, "\n".join(lines) + "\n")
    log.info(
        "wrote RAPID module %s: %d targets, %d speeddata, %d routines", path, n, len(levels), len(routines)
    )
    return path


_NUMS = r"\[([^\[\]]*)\]"
_TARGET_RE = re.compile(
    rf"CONST\s+robtarget\s+(\w+)\s*:=\s*\[\s*{_NUMS}\s*,\s*{_NUMS}\s*,\s*"
    rf"{_NUMS}\s*,\s*{_NUMS}\s*\]\s*;"
)
_SPEED_RE = re.compile(rf"CONST\s+speeddata\s+(\w+)\s*:=\s*{_NUMS}\s*;")
_MOVE_RE = re.compile(r"\b(?:Move[LJ]|TriggL)\s+(\w+)\s*,\s*(\w+)\s*,")
_MOVEC_RE = re.compile(r"\bMoveC\s+(\w+)\s*,\s*(\w+)\s*,\s*(\w+)\s*,")


def _floats(text: str, count: int, where: str) -> list[float]:
    values = [float(v) for v in text.split(",")]
    if len(values) != count:
        raise InputError(f"RAPID {where}: expected {count} numbers, got {len(values)}")
    return values


def _air_speed(times: tuple[float, ...] | None, k: int) -> str:
    """``vAir`` with the planned time of joint move ``k`` (its time argument ``T``, rounded up to 1 ms), or ``vAir`` alone."""
    if times is None or k >= len(times):
        return "vAir"
    return f"vAir\\T:={math.ceil(times[k] * 1000.0 - 1e-9) / 1000.0:.3f}"


def parse_rapid_targets(path: str | Path) -> tuple[Array, Array, NDArray[np.int64], Array]:
    """Read back the targets of a module written by :func:`write_rapid`.

    Returns:
        positions [m], shape (N, 3); quaternions (q1..q4, scalar first), shape (N, 4);
        configuration data, shape (N, 4); speeds [m/s], shape (N,): ``v_tcp`` of the first move
        instruction that ends at each target (NaN if none does).

    Raises:
        InputError: no robtarget in the file or a malformed one.
    """
    text = Path(path).read_text(encoding="utf-8")
    speeds = {m.group(1): _floats(m.group(2), 4, m.group(1))[0] / 1000.0 for m in _SPEED_RE.finditer(text)}
    targets = list(_TARGET_RE.finditer(text))
    if not targets:
        raise InputError(f"RAPID {path}: no CONST robtarget found")
    index = {m.group(1): k for k, m in enumerate(targets)}
    positions = np.array([_floats(m.group(2), 3, m.group(1)) for m in targets]) / 1000.0
    quats = np.array([_floats(m.group(3), 4, m.group(1)) for m in targets])
    confs = np.array([[int(v) for v in _floats(m.group(4), 4, m.group(1))] for m in targets])
    target_speed = np.full(len(targets), math.nan)
    for m in _MOVE_RE.finditer(text):
        k = index.get(m.group(1))
        if k is not None and math.isnan(target_speed[k]):
            target_speed[k] = speeds.get(m.group(2), math.nan)
    for m in _MOVEC_RE.finditer(text):  # the via and the end point run at the circular move's speed
        for name in m.group(1, 2):
            k = index.get(name)
            if k is not None and math.isnan(target_speed[k]):
                target_speed[k] = speeds.get(m.group(3), math.nan)
    return positions, quats, confs.astype(np.int64), target_speed
