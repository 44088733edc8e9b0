"""Yaskawa Motoman INFORM job: the refined path as ``MOVL`` moves through Cartesian positions (``.JBI``).

The format is the job data format of Yaskawa's "Interface with an easy offline teaching system"
(NX100 manual HW0481924 and DX100 manual HW0482494, section 4.1 "Job Data Format"; the header
sample of Motoman's knowledge base "INFORM job header"):

* ``/JOB``, ``//NAME <NAME>`` (letters, digits, ``_``, at most :data:`NAME_CHARS`), ``//POS`` with
  ``///NPOS <C>,0,0,0,0,0`` (the number of robot teaching positions), ``///TOOL <t>`` (``[tool]
  number``; a comment gives the values its tool file must hold), ``///POSTYPE ROBOT`` (Cartesian
  data in the robot coordinate system), ``///RECTAN``,
  ``///RCONF l,m,n,o,p,q,0,...`` (24 values, the last 18 unused) before the positions it applies to,
  and ``Cnnnnn=X,Y,Z,Rx,Ry,Rz``: X Y Z [mm, 3 decimals], Rx Ry Rz [deg, 4 decimals] with
  ``R_robot_tcp = Rz(Rz)·Ry(Ry)·Rx(Rx)`` (rotations about the fixed X, Y, Z axes in that order).
* ``//INST``, ``///DATE``, ``///COMM`` (at most 32 characters), ``///ATTR SC,RW``, ``///GROUP1
  RB1``, then the instructions: ``NOP``, comments ``'text`` (at most :data:`COMMENT_CHARS`),
  ``MOVJ C00000 VJ=<%>`` to home, ``MOVJ`` to an approach point ``retract_m`` behind the first path
  point along the tool z axis (with a run's planned air move, ``ProgramPass.air_in``: ``MOVJ ...
  PL=0`` to each of its via points and to its end, the approach joints, each written as the TCP
  there with the joints' figure; the planned return's via points likewise before home), ``MOVL Cnnnnn V=<mm/s> PL=<0..8>`` through the path, ``MOVL`` to the
  retract point, ``MOVJ`` home, ``END``. Zones and speeds follow
  :func:`refine.export.motion.program_motion` (``result.json`` states the same figures): ``PL=<pl>``
  where its corner keeps ``[process] path_tolerance_m``, else ``PL=0`` (and ``PL=0`` where the robot
  stops); ``V`` at 0.1 mm/s, the fastest of a few levels not above the segment's planned speed and
  within ``[output] speed_share`` of it.
* Process output: ``DOUT OT#(n) ON`` once the robot stands on the first path point (``PL=0``) and
  ``DOUT OT#(n) OFF`` on the last: INFORM switches an output after the move before it has ended,
  so a job has no switching ahead of a point and ``process.lead_s``/``lead_m`` is not applied (the
  header says so). A weld: gas ``DOUT``, ``TIMER T=<s>``, arc ``DOUT``, ``WAIT IN#(k)=ON T=<s>``
  and ``JUMP *ARCFAIL IF IN#(k)=OFF``; crater fill and post-flow at the last point.
* The home position is written as a Cartesian position with the figure of the home joints, which
  a comment lists (the controller's joints, deg).

Figure, ``///RCONF`` (:func:`yaskawa_rconf`, manuals' "Manipulator Type"): ``l`` 0 flip / 1 no-flip,
flip when the R axis (axis 4) is in -90 < R <= 90 deg (or 270..360, -360..-270); ``m`` 0 upper arm
(the elbow above the line from the L axis to the wrist centre) / 1 lower arm; ``n`` 0 front / 1 rear
(the wrist centre behind the S axis); ``o``, ``p``, ``q`` 1 when R, T, S (axes 4, 6, 1) >= 180 deg.
Positions are measured in the robot coordinate system, the URDF frame ``controller_frame``
(ROS-Industrial's ``base``).
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
    process_summary,
    singular_runs,
)
from refine.export.sink import put_text
from refine.export.sink import stamp as sink_stamp
from refine.frames import fixed_xyz_from_matrix, invert_transform, make_transform
from refine.names import comment_text, identifier
from refine.paths import Trajectory
from refine.problem import Problem
from refine.types import Array
from refine.version import __version__

log = logging.getLogger(__name__)

NAME_CHARS = 32
"""Longest job name (DX100, YRC1000: 32 characters; the NX100 takes 8)."""
COMMENT_CHARS = 32
"""Longest comment line [characters]."""
RCONF_VALUES = 24
"""Values of a ``///RCONF`` line: six figures and 18 unused (DX100 format)."""
MAX_TOOL = 63
MAX_OUTPUT = 4096
DEFAULT_OUTPUT = 1
"""``OT#`` number used when ``process.output`` names no number."""
MAX_SPEED_MM_S = 1500.0


def _name(text: str) -> str:
    return identifier(text, "J", NAME_CHARS).upper()


def yaskawa_io_number(name: str, kind: str, default: int) -> tuple[int, str]:
    """The number of an ``OT#(n)``/``IN#(n)`` named ``"OT#(n)"``, ``"OTn"`` or ``"n"``, else ``default``.

    Returns:
        the number and a note for the job's comments.
    """
    m = re.fullmatch(rf"\s*(?:{kind}#?\s*\(\s*(\d+)\s*\)|{kind}\s*(\d+)|(\d+))\s*", name, re.IGNORECASE)
    if m is None:
        return default, f"{comment_text(repr(name))} mapped to {kind}#({default})"
    number = int(m.group(1) or m.group(2) or m.group(3))
    if not 1 <= number <= MAX_OUTPUT:
        raise InputError(f"process I/O {name!r}: INFORM {kind}#(n) needs n in 1..{MAX_OUTPUT}")
    return number, f"{comment_text(repr(name))} is {kind}#({number})"


def yaskawa_rconf(robot: Any, q: Array) -> list[tuple[int, ...]]:
    """The figure ``///RCONF`` (24 values) of URDF joint vectors (module docstring).

    Args:
        robot: a six-axis :class:`refine.robot.model.Robot` (controller ``"yaskawa"``).
        q: URDF joints [rad], shape (N, 6) or (6,).
    """
    qs = np.atleast_2d(np.asarray(q, dtype=float))
    behind, elbow_up = arm_configuration(robot, qs)
    deg = np.degrees(robot.spec.to_controller(qs))
    out = []
    for k in range(len(qs)):
        s, r, t = deg[k, 0], deg[k, 3], deg[k, 5]
        r_wrapped = (r + 180.0) % 360.0 - 180.0  # (-180, 180]: flip iff in (-90, 90]
        flip = -90.0 < r_wrapped <= 90.0
        figure = (int(not flip), int(not elbow_up[k]), int(behind[k]), int(r >= 180.0), int(t >= 180.0))
        out.append((*figure, int(s >= 180.0), *([0] * (RCONF_VALUES - 6))))
    return out


@dataclass(frozen=True)
class _Io:
    out: int
    gas: int
    arc_ok: int


class _Job:
    """The positions and instructions being written."""

    def __init__(self) -> None:
        self.positions: list[tuple[Array, tuple[int, ...]]] = []
        self.inst: list[str] = []

    def position(self, T_robot_tcp: Array, rconf: tuple[int, ...]) -> str:
        self.positions.append((T_robot_tcp, rconf))
        return f"C{len(self.positions) - 1:05d}"

    def comment(self, text: str) -> None:
        clean = comment_text(text, 1000).replace("'", "`")
        self.inst += [f"'{part}" for part in textwrap.wrap(clean, COMMENT_CHARS)]

    def pos_lines(self) -> list[str]:
        lines, current = [], None
        for k, (T, rconf) in enumerate(self.positions):
            if rconf != current:
                lines.append("///RCONF " + ",".join(str(v) for v in rconf))
                current = rconf
            xyz = [fixed_decimals(v * 1000.0, 3) for v in T[:3, 3]]
            rxyz = [fixed_decimals(v, 4) for v in fixed_xyz_from_matrix(T[:3, :3])]
            lines.append(f"C{k:05d}=" + ",".join(xyz + rxyz))
        return lines


def _weld_start(job: _Job, problem: Problem, io: _Io) -> None:
    pr = problem.process
    job.comment("gas pre-flow")
    job.inst += [f"DOUT OT#({io.gas}) ON", f"TIMER T={fixed_decimals(pr.preflow_s, 2)}"]
    job.comment("arc on, wait for arc ok")
    job.inst += [
        f"DOUT OT#({io.out}) ON",
        f"WAIT IN#({io.arc_ok})=ON T={fixed_decimals(pr.arc_timeout_s, 2)}",
        f"JUMP *ARCFAIL IF IN#({io.arc_ok})=OFF",
    ]


def _weld_end(job: _Job, problem: Problem, io: _Io) -> None:
    pr = problem.process
    job.comment("crater fill")
    job.inst += [f"TIMER T={fixed_decimals(pr.crater_fill_s, 2)}", f"DOUT OT#({io.out}) OFF"]
    job.comment("gas post-flow")
    job.inst += [f"TIMER T={fixed_decimals(pr.postflow_s, 2)}", f"DOUT OT#({io.gas}) OFF"]


def _joint_position(job: _Job, robot: Any, problem: Problem, q: Array) -> str:
    """A position of the job at URDF joints ``q`` [rad]: the TCP in the ROBOT frame with their figure."""
    T = invert_transform(controller_base(robot)) @ robot.fk(q) @ problem.tool.tcp_in_flange
    return job.position(T, yaskawa_rconf(robot, q)[0])


def write_inform(
    path: str | Path,
    trajectory: Trajectory,
    problem: Problem,
    robot: Any,
    *,
    passes: list[Any] | None = None,
    repairs: tuple[Any, ...] = (),
    approach_speed_m_s: float = 0.25,
    retract_m: float = 0.1,
    joint_percent: float = 20.0,
    pl: int = 1,
    speed_resolution_m_s: float = 1e-4,
) -> Path:
    """Write the trajectory as a Yaskawa INFORM job (``<NAME>.JBI``).

    Args:
        path: output file; its stem, made a job name (upper case), names the job and the file.
        trajectory: the refined, timed path (poses in {F}, URDF joints for the figure).
        problem: tool number, robot base, home, process output, speed levels.
        robot: the :class:`refine.robot.model.Robot` the joints belong to (controller ``"yaskawa"``).
        passes: several passes (:class:`refine.export.program.ProgramPass` or ``(name,
            trajectory)``); when given, ``trajectory`` is not written.
        repairs: the repaired segments of ``trajectory`` (when ``passes`` is not given).
        approach_speed_m_s: ``V`` of the moves onto the first point and to the retract [m/s].
        retract_m: approach and retract distance along the tool z axis [m].
        joint_percent: ``VJ`` of the ``MOVJ`` moves [% of the joints' maximum].
        pl: position level of the path moves (0..8; 0 stops on every point); ``PL=0`` where the
            corner would leave ``[process] path_tolerance_m`` (:func:`refine.export.motion.program_motion`).
        speed_resolution_m_s: speed levels are multiples of this [m/s] (INFORM ``V`` has 0.1 mm/s).

    Returns:
        The path written.
    """
    if getattr(robot.spec, "controller", "") != "yaskawa":
        raise InputError(
            f"INFORM is for Yaskawa Motoman robots; {robot.spec.name!r} has controller {robot.spec.controller!r}"
        )
    if robot.nq != 6:
        raise InputError(f"INFORM export: needs a six-axis arm, {robot.spec.name!r} has {robot.nq} joints")
    runs = as_passes(problem.name, trajectory, passes, repairs)
    if any(len(p.trajectory) < 2 for p in runs):
        raise InputError("INFORM export: every pass needs at least 2 waypoints")
    if not (0 <= pl <= 8 and 0.01 <= joint_percent <= 100.0):
        raise InputError(
            f"INFORM export: pl must be 0..8 and joint_percent 0.01..100 [%], got {pl}, {joint_percent}"
        )
    if not (speed_resolution_m_s >= 1e-4 and approach_speed_m_s > 0.0 and retract_m > 0.0):
        raise InputError(
            "INFORM export: speed_resolution_m_s must be >= 0.0001 m/s (V has 0.1 mm/s), approach speed and "
            "retract [m] > 0"
        )
    tool = problem.tool.number
    if not 0 <= tool <= MAX_TOOL:
        raise InputError(f"INFORM export: [tool] number = {tool} must be a tool file 0..{MAX_TOOL}")
    name = _name(Path(path).stem)
    out_path = Path(path).with_name(name + ".JBI")
    pr = problem.process
    out, out_note = yaskawa_io_number(pr.output, "OT", DEFAULT_OUTPUT)
    gas, gas_note = yaskawa_io_number(pr.gas_output, "OT", DEFAULT_OUTPUT + 1)
    arc_ok, ok_note = yaskawa_io_number(pr.arc_ok_input, "IN", 1)
    io, weld = _Io(out, gas, arc_ok), pr.kind == "weld"
    T_robot_world = invert_transform(controller_base(robot)) @ invert_transform(problem.robot.base_in_world)
    back = make_transform(p=[0.0, 0.0, -retract_m])

    job = _Job()
    home_q = home_joints(problem, robot, runs[0].trajectory.q[0])
    home = _joint_position(job, robot, problem, home_q)
    job.inst.append("NOP")
    job.comment(f"refine {__version__}: {problem.name}, {problem.robot.model}")
    job.comment(f"output {out_note}")
    if weld:
        job.comment(process_summary(problem, "DOUT", f"OT#({out})", gas_note, ok_note))
    else:
        lead = f"{pr.lead_s:g} s" if pr.lead_m is None else f"{pr.lead_m * 1000.0:g} mm"
        job.comment(
            f"{pr.kind}: OT#({out}) on at the first point and off at the last, standing (PL=0); "
            f"the process lead of {lead} is not applied: INFORM switches after the move"
        )
    for p in runs:
        for note in header_notes(p, robot):
            job.comment(note)
    job.comment(f"positions: TCP of tool {tool} ({problem.tool.name}) in the ROBOT frame, mm and deg")
    T_tool = problem.tool.tcp_in_flange
    values = [fixed_decimals(v * 1000.0, 3) for v in T_tool[:3, 3]] + [
        fixed_decimals(v, 4) for v in fixed_xyz_from_matrix(T_tool[:3, :3])
    ]
    job.comment(
        f"tool file {tool} must hold "
        + ", ".join(f"{k}={v}" for k, v in zip(("X", "Y", "Z", "Rx", "Ry", "Rz"), values, strict=True))
    )
    home_deg = np.degrees(robot.spec.to_controller(home_q))
    job.comment("home joints [deg]: " + ", ".join(fixed_decimals(v, 3) for v in home_deg))
    vj = fixed_decimals(joint_percent, 2)
    air = fixed_decimals(min(approach_speed_m_s * 1000.0, MAX_SPEED_MM_S), 1)
    job.inst.append(f"MOVJ {home} VJ={vj}")
    for i, p in enumerate(runs, start=1):
        tr = p.trajectory
        job.comment(f"pass {i} of {len(runs)}: {p.name}, {len(tr)} points")
        rconf = yaskawa_rconf(robot, tr.q)
        T = T_robot_world @ tr.poses
        vias = [] if p.air_in is None else [_joint_position(job, robot, problem, qk) for qk in p.air_in]
        app = job.position(T[0] @ back, rconf[0]) if p.air_in is None else vias[-1]
        points = [job.position(Tk, rk) for Tk, rk in zip(T, rconf, strict=True)]
        ret = job.position(T[-1] @ back, rconf[-1])
        motion = program_motion(
            "inform", tr, problem, retract_m=retract_m, pl=pl, speed_resolution_m_s=speed_resolution_m_s
        )
        zones = motion.zones
        for a, b in singular_runs(robot, tr.q):
            job.comment(f"points {a}-{b} near the wrist singularity")
        if zones.narrowed:
            job.comment(
                f"{len(zones.narrowed)} point(s) at PL=0 to keep the path tolerance {zones.tolerance_m * 1e3:g} mm"
            )
        job.inst += [f"MOVJ {v} VJ={vj} PL=0" for v in vias[:-1]]  # the planned air move's via points
        job.inst += [
            f"MOVJ {app} VJ={vj} PL={pl if p.air_in is None else 0}",
            f"MOVL {points[0]} V={air} PL=0",
        ]
        if weld:
            _weld_start(job, problem, io)
        else:
            job.inst.append(f"DOUT OT#({out}) ON")
        for k in range(1, len(tr)):
            v = fixed_decimals(min(motion.programmed_m_s[k - 1] * 1000.0, MAX_SPEED_MM_S), 1)
            job.inst.append(f"MOVL {points[k]} V={v} {'PL=0' if k == len(tr) - 1 else zones.label[k]}")
        if weld:
            _weld_end(job, problem, io)
        else:
            job.inst.append(f"DOUT OT#({out}) OFF")
        job.inst.append(f"MOVL {ret} V={air} PL={pl}")
    back_vias = runs[-1].air_out
    if back_vias is not None and len(back_vias) > 1:  # the planned return's via points
        job.inst += [f"MOVJ {_joint_position(job, robot, problem, q)} VJ={vj} PL=0" for q in back_vias[:-1]]
    job.inst.append(f"MOVJ {home} VJ={vj}")
    if weld:
        job.inst += ["JUMP *DONE", "*ARCFAIL", f"DOUT OT#({io.out}) OFF", f"DOUT OT#({io.gas}) OFF"]
        job.comment(f"no arc within {fixed_decimals(pr.arc_timeout_s, 2)} s")
        job.inst += ["PAUSE", "*DONE"]
    job.inst.append("END")
    stamp = sink_stamp().strftime("%Y/%m/%d %H:%M")
    lines = [
        "/JOB",
        f"//NAME {name}",
        "//POS",
        f"///NPOS {len(job.positions)},0,0,0,0,0",
        f"///TOOL {tool}",
        "///POSTYPE ROBOT",
        "///RECTAN",
        *job.pos_lines(),
        "//INST",
        f"///DATE {stamp}",
        f"///COMM {comment_text(problem.name, COMMENT_CHARS)}",
        "///ATTR SC,RW",
        "///GROUP1 RB1",
        *job.inst,
    ]
    put_text(out_path, "\r\n".join(lines) + "\r\n", encoding="ascii")
    log.info(
        "wrote INFORM job %s: %d pass(es), %d positions, OT#(%d)",
        out_path,
        len(runs),
        len(job.positions),
        out,
    )
    return out_path


def inform_file_name(stem: str) -> str:
    """The file name :func:`write_inform` writes for an output stem."""
    return _name(stem) + ".JBI"
