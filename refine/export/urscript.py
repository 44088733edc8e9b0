"""URScript program: the refined path as ``movel`` moves for a Universal Robots controller.

One ``def <name>():`` ... ``end`` program:

* ``set_tcp(p[x, y, z, rx, ry, rz])``: the TCP in the flange [m, rotation vector rad] and
  ``set_payload(m, [cx, cy, cz])``: the tool mass [kg] and centre of gravity [m].
* Per pass, a block opened by the comment ``# pass i of n: <name>``: ``movej`` to the joints of an
  approach pose ``retract_m`` behind the first waypoint along the tool z axis (solved by damped
  least squares from the first waypoint's refined joints, so the approach stays on their branch),
  ``movel`` onto the first waypoint, ``set_digital_out(n, True)``, ``movel`` through every waypoint
  with ``v`` the segment speed [m/s] (mean of the planned speeds at its ends, rounded to
  ``speed_resolution_m_s``) and blend radius ``r``, ``set_digital_out(n, False)``, and a ``movel``
  retract along the tool z axis. ``r`` is ``blend_m`` capped at 40 % of the shorter neighbouring
  segment so blends never overlap, and 0 on the first and last waypoint (exact stops).
* Poses are in the controller's base frame: ``inv(base_in_world) · T_F_TCP`` (``robots/ur10e``'s base
  link is UR's base frame), positions with 8 decimals [m], rotation vectors with 9 [rad].

Rotation vectors (:func:`continuous_rotvecs`): :func:`refine.frames.rotvec_from_matrix` gives angles in
[0, π], so the vector flips to the opposite side as a path turns through π. Every ``u·(θ + 2πk)``
(u the axis, k an integer) is the same rotation; each pose takes the one closest to the previous
pose's vector, so consecutive rotation vectors stay continuous along the whole program.

Digital output: ``process.output`` ``"3"`` or ``"DO3"`` (any case) selects standard digital output 3
(0..7); any other name maps to output :data:`DEFAULT_OUTPUT`, named in a comment in the program.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from refine.errors import InputError, SolverError
from refine.export.motion import program_motion, segment_speeds
from refine.export.program import (
    Switch,
    Wait,
    arc_abort,
    as_passes,
    circular_note,
    circular_pieces,
    header_notes,
    home_joints,
    process_summary,
    weld_end,
    weld_start,
)
from refine.export.sink import put_text
from refine.frames import invert_transform, make_transform, matrix_from_rotvec, rotvec_from_matrix
from refine.names import comment_text, identifier
from refine.paths import Trajectory
from refine.problem import Problem
from refine.robot.kinematics import TcpKinematics, solve_ik
from refine.types import Array
from refine.version import __version__

log = logging.getLogger(__name__)

DEFAULT_OUTPUT = 0  # standard digital output used when process.output names no number


def _num(value: float, decimals: int) -> str:
    text = f"{value:.{decimals}f}"
    return "0" if float(text) == 0.0 else text.rstrip("0").rstrip(".")


def _pose(T: Array, rotvec: Array | None = None) -> str:
    rv = rotvec_from_matrix(T[:3, :3]) if rotvec is None else rotvec
    return "p[" + ",".join([_num(v, 8) for v in T[:3, 3]] + [_num(v, 9) for v in rv]) + "]"


def ur_output_number(output: str) -> int | None:
    """The standard digital output named by ``process.output`` (``"3"``, ``"DO3"``), else None."""
    m = re.fullmatch(r"\s*(?:DO\s*)?(\d+)\s*", output, re.IGNORECASE)
    if m is None:
        return None
    if not 0 <= int(m.group(1)) <= 7:
        raise InputError(f"process.output {output!r}: UR standard digital outputs are 0..7")
    return int(m.group(1))


def continuous_rotvecs(R: Array, previous: Array | None = None) -> Array:
    """Rotation vectors [rad], shape (N, 3), of rotations R, shape (N, 3, 3), kept continuous.

    Each is the equivalent ``u·(θ + 2πk)`` closest to the vector before it (to ``previous`` [rad],
    shape (3,), for the first one when given).
    """
    out = rotvec_from_matrix(R)
    prev = previous
    for k in range(len(out)):
        if prev is not None:
            theta, prev_norm = float(np.linalg.norm(out[k])), float(np.linalg.norm(prev))
            axis = out[k] / theta if theta > 1e-12 else (prev / prev_norm if prev_norm > 1e-12 else None)
            if axis is not None:
                turns = round((float(np.dot(axis, prev)) - theta) / (2.0 * math.pi))
                cands = [axis * (theta + 2.0 * math.pi * m) for m in (turns - 1, turns, turns + 1)]
                out[k] = min(cands, key=lambda c: float(np.linalg.norm(c - prev)))
        prev = out[k]
    return out


def _approach_joints(robot: Any, q0: Array, T_base_flange: Array, label: str) -> Array:
    """Joints [rad] within the limits reaching ``T_base_flange``, by damped least squares from ``q0``."""
    kin = TcpKinematics(robot, np.eye(4), np.eye(4))
    q, residual = solve_ik(
        kin, T_base_flange, q0, robot.spec.lower, robot.spec.upper, damping=1e-5, tol=1e-10
    )
    if residual > 1e-9:
        raise SolverError(
            f"URScript pass {label!r}: no joints within the limits reach the approach pose "
            f"(residual {residual:.1e}, position [m] and angle [rad] stacked)"
        )
    return q


def _io_number(name: str, kind: str, default: int) -> tuple[int, str]:
    """A UR standard digital output or input (``"3"``, ``"DO3"`` / ``"DI3"``), else ``default``."""
    word = "input" if kind == "DI" else "output"
    m = re.fullmatch(rf"\s*(?:{kind}\s*)?(\d+)\s*", name, re.IGNORECASE)
    if m is None:
        return default, f"{comment_text(repr(name))} mapped to digital {word} {default} (refine default)"
    if not 0 <= int(m.group(1)) <= 7:
        raise InputError(f"process I/O {name!r}: UR standard digital {word}s are 0..7")
    return int(m.group(1)), f"{name!r} is digital {word} {int(m.group(1))}"


def _timed(jmove: str, times: tuple[float, ...] | None, k: int) -> str:
    """``movej``'s arguments: with ``t`` the planned time of air move ``k`` (rounded up to 1 ms) when known.

    A ``movej`` given ``t`` takes that time (the controller then ignores ``a`` and ``v``), the time
    the run planned at ``[output] air_speed_share``.
    """
    if times is None or not 0 <= k < len(times):
        return jmove
    return f"{jmove}, t={math.ceil(times[k] * 1000.0 - 1e-9) / 1000.0:.3f}"


def _lead_m(problem: Problem, tr: Trajectory, approach_speed_m_s: float) -> tuple[float, float]:
    """The process lead as distances [m] before the first point (on) and the last point (off).

    ``lead_m`` is used as it is; ``lead_s`` becomes a distance with the approach speed before the
    first point and with the planned timing along the path before the last one.
    """
    pr = problem.process
    if pr.lead_m is not None:
        return float(pr.lead_m), float(pr.lead_m)
    t_at = max(float(tr.t[-1]) - pr.lead_s, 0.0)
    return pr.lead_s * approach_speed_m_s, float(tr.s[-1] - np.interp(t_at, tr.t, tr.s))


def _switch_threads(out: int) -> list[str]:
    """Two threads that switch the process output when the TCP comes within a distance of a pose."""
    lines = ["global on_target = p[0,0,0,0,0,0]", "global on_lead = 0.0"]
    lines += ["global off_target = p[0,0,0,0,0,0]", "global off_lead = 0.0"]
    for name, value in (("on", "True"), ("off", "False")):
        lines += [
            f"thread process_{name}():",
            f"  while point_dist(get_actual_tcp_pose(), {name}_target) > {name}_lead:",
            "    sync()",
            "  end",
            f"  set_digital_out({out}, {value})",
            "end",
        ]
    return lines


def _weld_io(out: int, gas: int) -> tuple[Wait, Switch]:
    signals = {"out": out, "gas": gas}

    def wait(seconds: float, comment: str) -> str:
        return f"sleep({_num(seconds, 3)})" + (f"  # {comment}" if comment else "")

    def switch(role: str, on: bool, comment: str) -> str:
        return f"set_digital_out({signals[role]}, {on})" + (f"  # {comment}" if comment else "")

    return wait, switch


def _weld_start(out: int, gas: int, ok: int, problem: Problem) -> list[str]:
    pr = problem.process
    wait, switch = _weld_io(out, gas)
    timeout = _num(pr.arc_timeout_s, 3)
    return weld_start(
        problem,
        wait,
        switch,
        [
            "arc_wait = 0.0",
            f"while not get_standard_digital_in({ok}) and arc_wait < {timeout}:",
            "  sync()",
            "  arc_wait = arc_wait + get_steptime()",
            "end",
            f"if not get_standard_digital_in({ok}):",
            *arc_abort(switch, "  "),
            f'  popup("no arc signal within {timeout} s", "Arc start failed", error=True)',
            "  halt",
            "end",
        ],
    )


def _weld_end(out: int, gas: int, problem: Problem) -> list[str]:
    return weld_end(problem, *_weld_io(out, gas))


def write_urscript(
    path: str | Path,
    trajectory: Trajectory,
    problem: Problem,
    robot: Any,
    *,
    passes: list[Any] | None = None,
    repairs: tuple[Any, ...] = (),
    mode: str | None = None,
    acceleration_m_s2: float = 1.2,
    approach_speed_m_s: float = 0.25,
    retract_m: float = 0.1,
    blend_m: float = 0.001,
    joint_speed_rad_s: float = 0.5,
    joint_acceleration_rad_s2: float = 1.0,
    speed_resolution_m_s: float = 1e-4,
) -> Path:
    """Write the trajectory as a URScript program (``.script``).

    Args:
        path: output file; the program is named after the problem.
        trajectory: the refined, timed path (poses in {F}, joints for the approach).
        problem: tool, robot base, home, process output and switching.
        robot: the :class:`refine.robot.model.Robot` the joints belong to (controller ``"ur"``).
        passes: several passes of a multi-pass weld as :class:`refine.export.program.ProgramPass`
            or ``(name, trajectory)`` in order, the root pass included; when given, ``trajectory``
            is not written. One block per pass.
        repairs: the repaired segments of ``trajectory`` (when ``passes`` is not given).
        mode: ``"program"`` (a function called at the end of the file) or ``"script_node"`` (the
            body alone, for a PolyScope Script node); ``[output] urscript_mode`` when None.
        acceleration_m_s2: tool acceleration ``a`` of every ``movel`` [m/s^2].
        approach_speed_m_s: tool speed of the moves onto the first waypoint and the retract [m/s].
        retract_m: approach and retract distance along the tool z axis [m].
        blend_m: blend radius between waypoints [m] (capped; 0 at a weld's ends).
        joint_speed_rad_s: joint speed of the ``movej`` moves [rad/s].
        joint_acceleration_rad_s2: joint acceleration of the ``movej`` moves [rad/s^2].
        speed_resolution_m_s: segment speeds are rounded to this step [m/s].

    Returns:
        The path written.
    """
    if getattr(robot.spec, "controller", "") != "ur":
        raise InputError(
            f"URScript is for UR robots; {robot.spec.name!r} has controller {robot.spec.controller!r}"
        )
    mode = problem.output.urscript_mode if mode is None else mode
    if mode not in ("program", "script_node"):
        raise InputError(f"URScript mode must be 'program' or 'script_node', got {mode!r}")
    runs = as_passes(problem.name, trajectory, passes, repairs)
    for p in runs:
        if len(p.trajectory) < 2 or p.trajectory.q.shape[1] != robot.nq:
            raise InputError(
                f"URScript pass {p.name!r}: needs >= 2 waypoints of {robot.nq} joints, got q {p.trajectory.q.shape}"
            )
    if not (speed_resolution_m_s > 0.0 and approach_speed_m_s > 0.0 and blend_m >= 0.0):
        raise InputError("URScript export: speeds must be > 0 and blend_m >= 0")
    path = Path(path)
    prog = identifier(problem.name, "p", 63)
    pr, weld = problem.process, problem.process.kind == "weld"
    out, note = _io_number(pr.output, "DO", DEFAULT_OUTPUT)
    gas, gas_note = _io_number(pr.gas_output, "DO", DEFAULT_OUTPUT + 1)
    ok, ok_note = _io_number(pr.arc_ok_input, "DI", 0)
    tool = problem.tool
    T_base_world = invert_transform(problem.robot.base_in_world)
    back = make_transform(p=[0.0, 0.0, -retract_m])
    a, air, step = _num(acceleration_m_s2, 6), _num(approach_speed_m_s, 6), speed_resolution_m_s
    jmove = f"a={_num(joint_acceleration_rad_s2, 6)}, v={_num(joint_speed_rad_s, 6)}"
    home = home_joints(problem, robot, runs[0].trajectory.q[0])
    process = process_summary(problem, "a thread watching the TCP", note, gas_note, ok_note)
    body = [
        f"# Written by refine {__version__} for problem '{comment_text(problem.name)}', robot {problem.robot.model}, "
        f"{len(runs)} pass(es).",
        "# Poses: TCP in the robot base frame, p[x, y, z [m], rx, ry, rz (rotation vector) [rad]].",
        f"# process output {comment_text(repr(pr.output))} -> digital output {out}",
        f"# {process}",
        *(f"# {line}" for p in runs for line in header_notes(p, robot)),
        f"set_tcp({_pose(tool.tcp_in_flange)})",
        f"set_payload({_num(tool.mass_kg, 4)}, [{', '.join(_num(v, 6) for v in tool.cog_in_flange_m)}])",
        *([] if weld else _switch_threads(out)),
        f"movej([{','.join(_num(v, 9) for v in home)}], {jmove})  # home",
    ]
    previous = None
    for i, p in enumerate(runs, start=1):
        tr = p.trajectory
        n, label = len(tr), comment_text(str(p.name))
        poses = np.concatenate([T_base_world @ tr.poses, [T_base_world @ tr.poses[-1] @ back]])
        air_in = getattr(p, "air_in", None)
        if air_in is None:
            q_app = _approach_joints(
                robot, tr.q[0], poses[0] @ back @ invert_transform(tool.tcp_in_flange), label
            )
        else:  # the run's planned air move: via points (no blend), then the approach joints
            q_app = air_in[-1]
            times = getattr(p, "air_in_s", None)
            body += [
                f"movej([{','.join(_num(v, 9) for v in q)}], {_timed(jmove, times, k)})"
                f"  # via point of the planned move to pass {i}"
                for k, q in enumerate(air_in[:-1])
            ]
        rv = continuous_rotvecs(poses[:, :3, :3], previous)
        previous = rv[-1]
        gaps = np.linalg.norm(np.diff(poses[:n, :3, 3], axis=0), axis=1)
        zones = program_motion(
            "urscript", tr, problem, blend_m=blend_m, retract_m=retract_m, speed_resolution_m_s=step
        ).zones
        blends = zones.radius_m  # capped at 40 % of the neighbouring moves, smaller where the tolerance needs
        on_lead, off_lead = _lead_m(problem, tr, approach_speed_m_s)
        if on_lead > retract_m:
            raise InputError(f"process lead {on_lead:g} m is longer than the approach move ({retract_m:g} m)")
        s_end = np.concatenate([[0.0], np.cumsum(gaps)])
        off_k = max(int(np.flatnonzero(s_end[-1] - s_end <= off_lead + 1e-12)[0]), 1)
        body += [
            f"# pass {i} of {len(runs)}: {label}, {n} waypoints, {float(tr.t[-1]):.3f} s planned",
            f"# blends: r <= {_num(blend_m, 6)} m, smaller at {len(zones.narrowed)} waypoint(s) to keep the "
            f"path tolerance {zones.tolerance_m * 1e3:g} mm; largest corner deviation "
            f"{zones.largest_deviation_m * 1e3:.3f} mm",
            f"movej([{','.join(_num(v, 9) for v in q_app)}], "
            f"{_timed(jmove, getattr(p, 'air_in_s', None), len(air_in) - 1 if air_in is not None else -1)})",
        ]
        if weld:
            body += [
                f"movel({_pose(poses[0], rv[0])}, a={a}, v={air}, r=0)",
                *_weld_start(out, gas, ok, problem),
            ]
        else:
            body += [
                f"on_target = {_pose(poses[0], rv[0])}",
                f"on_lead = {_num(on_lead, 6)}",
                "run process_on()",
                f"movel({_pose(poses[0], rv[0])}, a={a}, v={air}, r={_num(blends[0], 6)})",
            ]
        arcs = {c.start + 1: c for c in circular_pieces(tr, off_k if not weld else None)}
        skip_to = written_arcs = 0
        for k, v in enumerate(segment_speeds(tr), start=1):
            if k <= skip_to:
                continue
            if k == off_k and not weld:
                body += [f"off_target = {_pose(poses[n - 1], rv[n - 1])}", f"off_lead = {_num(off_lead, 6)}"]
                body.append("run process_off()")
            if (c := arcs.get(k)) is not None:  # the CAD's arc: one circular move, orientation start -> end
                speed = _num(max(math.floor(c.speed_m_s / step + 1e-9), 1) * step, 6)  # not above its slowest
                body.append(
                    f"movec({_pose(poses[c.via], rv[c.via])}, {_pose(poses[c.end], rv[c.end])}, a={a}, "
                    f"v={speed}, r={_num(blends[c.end], 6)}, mode=0)"
                )
                skip_to, written_arcs = c.end, written_arcs + 1
                continue
            speed = _num(max(round(v / step), 1) * step, 6)
            body.append(f"movel({_pose(poses[k], rv[k])}, a={a}, v={speed}, r={_num(blends[k], 6)})")
        body += [f"# {n}" for n in circular_note(written_arcs, "slerp (mode=0)")]
        body += _weld_end(out, gas, problem) if weld else []
        body.append(f"movel({_pose(poses[n], rv[n])}, a={a}, v={air}, r=0)")
    air_out = getattr(runs[-1], "air_out", None)
    back_s = getattr(runs[-1], "air_out_s", None)
    if air_out is not None:  # the run's planned return: via points, then home
        body += [
            f"movej([{','.join(_num(v, 9) for v in q)}], {_timed(jmove, back_s, k)})  # via point of the planned return"
            for k, q in enumerate(air_out[:-1])
        ]
    last = len(air_out) - 1 if air_out is not None else -1
    body.append(f"movej([{','.join(_num(v, 9) for v in home)}], {_timed(jmove, back_s, last)})  # home")
    if mode == "program":
        lines = [f"def {prog}():", *(f"  {ln}" for ln in body), "end", f"{prog}()"]
    else:
        lines = [f"# PolyScope Script node: {prog}", *body]
    put_text(path, "\n".join(lines) + "\n")
    log.info("wrote URScript %s (%s): %d pass(es), digital output %d", path, mode, len(runs), out)
    return path


@dataclass(frozen=True)
class UrPass:
    """One pass read back from a URScript program: its waypoints, in path order.

    Attributes:
        name: the pass name from its comment.
        poses: TCP poses in the robot base frame, T_base_TCP, shape (N, 4, 4) [m].
        rotvecs: the rotation vectors as written [rad], shape (N, 3).
        speeds: ``v`` of the ``movel`` ending at each waypoint [m/s], shape (N,).
        blend_radii: ``r`` of each waypoint's ``movel`` [m], shape (N,).
        q_approach: joints of the approach ``movej`` [rad], shape (n,).
        output: the digital output switched around the pass.
        tcp_in_flange: the program's ``set_tcp``, (4, 4).
    """

    name: str
    poses: Array
    rotvecs: Array
    speeds: Array
    blend_radii: Array
    q_approach: Array
    output: int
    tcp_in_flange: Array


_NUMS = r"\[([^\[\]]*)\]"
_MOVEL_RE = re.compile(rf"movel\(p{_NUMS}\s*,\s*a=([^,]+),\s*v=([^,]+),\s*r=([^)]+)\)")
_MOVEC_RE = re.compile(
    rf"movec\(p{_NUMS}\s*,\s*p{_NUMS}\s*,\s*a=([^,]+),\s*v=([^,]+),\s*r=([^,]+),\s*mode=0\)"
)


def _vector(text: str, count: int | None, where: str) -> Array:
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError as e:
        raise InputError(f"URScript {where}: not a list of numbers: [{text}]") from e
    if count is not None and values.shape != (count,):
        raise InputError(f"URScript {where}: expected {count} numbers, got {values.size}")
    return values


def _transform(text: str, where: str) -> Array:
    v = _vector(text, 6, where)
    return make_transform(matrix_from_rotvec(v[3:]), v[:3])


def parse_urscript(path: str | Path) -> list[UrPass]:
    """Read back the passes of a program written by :func:`write_urscript` (either mode).

    A pass starts at its ``# pass i of n`` comment; its first ``movej`` is the approach. Its
    waypoints are the ``movel`` moves from the one the process output switches on at (a started
    ``process_on`` thread belongs to the move after it, ``set_digital_out`` to the move before it)
    to the one before the retract.

    Raises:
        InputError: no pass found, a pass that does not switch its output, or a malformed pose.
    """
    text = Path(path).read_text(encoding="utf-8")
    head = re.search(r"#\s*process output .* -> digital output (\d+)", text)
    out = int(head.group(1)) if head else DEFAULT_OUTPUT
    tcp = np.eye(4)
    passes: list[dict[str, Any]] = []
    for raw in text.splitlines():
        line = raw.strip()
        if m := re.match(r"#\s*pass\s+\d+\s+of\s+\d+:\s*(.*?)(?:, \d+ waypoints,.*)?$", line):
            passes.append({"name": m.group(1), "q": None, "moves": [], "on": None, "off": None})
        elif m := re.fullmatch(rf"set_tcp\(p{_NUMS}\)", line):
            tcp = _transform(m.group(1), "set_tcp")
        elif (m := re.match(rf"movej\({_NUMS}", line)) and passes and passes[-1]["q"] is None:
            passes[-1]["q"] = _vector(m.group(1), None, "movej")
        elif line.startswith("movec(") and passes:  # the via point and the end point
            if not (m := _MOVEC_RE.fullmatch(line)):
                raise InputError(f"URScript {path}: cannot read {line!r}")
            passes[-1]["moves"] += [(m.group(1), float(m.group(4)), 0.0), (m.group(2), float(m.group(4)), float(m.group(5)))]
        elif line.startswith("movel(") and passes:
            if not (m := _MOVEL_RE.fullmatch(line)):
                raise InputError(f"URScript {path}: cannot read {line!r}")
            passes[-1]["moves"].append((m.group(1), float(m.group(3)), float(m.group(4))))
        elif (m := re.fullmatch(r"run process_(on|off)\(\)", line)) and passes:
            passes[-1][m.group(1)] = len(passes[-1]["moves"])
        elif (m := re.match(rf"set_digital_out\({out},\s*(True|False)\)", line)) and passes:
            passes[-1]["on" if m.group(1) == "True" else "off"] = len(passes[-1]["moves"]) - 1
    result = []
    for p in passes:
        if p["on"] is None or p["off"] is None or p["on"] < 0 or p["q"] is None:
            raise InputError(f"URScript {path}: pass {p['name']!r} does not switch its output on and off")
        moves = p["moves"][p["on"] : -1]
        poses = np.array([_transform(text, "movel") for text, _, _ in moves])
        rotvecs = np.array([_vector(text, 6, "movel")[3:] for text, _, _ in moves])
        speeds, radii = np.array([v for _, v, _ in moves]), np.array([r for _, _, r in moves])
        result.append(UrPass(p["name"], poses, rotvecs, speeds, radii, p["q"], out, tcp))
    if not result:
        raise InputError(f"URScript {path}: no pass (movej approach followed by movel moves) found")
    return result
