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

from refine import __version__
from refine.errors import InputError, SolverError
from refine.export.rapid import segment_speeds
from refine.frames import invert_transform, make_transform, matrix_from_rotvec, rotvec_from_matrix
from refine.names import comment_text, identifier
from refine.paths import Array, Trajectory
from refine.problem import Problem

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
    """Joints [rad] reaching ``T_base_flange``, by damped least squares from ``q0``."""
    q = np.array(q0, dtype=float)
    for _ in range(100):
        T = robot.fk(q)
        err = np.concatenate(
            [T_base_flange[:3, 3] - T[:3, 3], rotvec_from_matrix(T_base_flange[:3, :3] @ T[:3, :3].T)]
        )
        if np.linalg.norm(err) < 1e-11:
            break
        J = robot.jacobian(q)
        q = q + J.T @ np.linalg.solve(J @ J.T + 1e-10 * np.eye(6), err)
    else:
        raise SolverError(
            f"URScript pass {label!r}: no joints reach the approach pose (residual {np.linalg.norm(err):.1e})"
        )
    if np.any(q < robot.spec.lower) or np.any(q > robot.spec.upper):
        raise SolverError(f"URScript pass {label!r}: the approach pose needs joints outside their limits")
    return q


def write_urscript(
    path: str | Path,
    trajectory: Trajectory,
    problem: Problem,
    robot: Any,
    *,
    passes: list[tuple[str, Trajectory]] | None = None,
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
        problem: tool, robot base, process output.
        robot: the :class:`refine.robot.Robot` the joints belong to (controller ``"ur"``).
        passes: several passes of a multi-pass weld as ``(name, trajectory)`` in order, the root pass
            included; when given, ``trajectory`` is not written. One block per pass.
        acceleration_m_s2: tool acceleration ``a`` of every ``movel`` [m/s^2].
        approach_speed_m_s: tool speed of the moves onto the first waypoint and the retract [m/s].
        retract_m: approach and retract distance along the tool z axis [m].
        blend_m: blend radius between waypoints [m] (capped, 0 at the ends).
        joint_speed_rad_s: joint speed of the approach ``movej`` [rad/s].
        joint_acceleration_rad_s2: joint acceleration of the approach ``movej`` [rad/s^2].
        speed_resolution_m_s: segment speeds are rounded to this step [m/s].

    Returns:
        The path written.
    """
    if getattr(robot.spec, "controller", "") != "ur":
        raise InputError(
            f"URScript is for UR robots; {robot.spec.name!r} has controller {robot.spec.controller!r}"
        )
    runs = [(problem.name, trajectory)] if passes is None else list(passes)
    if not runs:
        raise InputError("URScript export: passes is empty; give at least one (name, trajectory)")
    for name, tr in runs:
        if len(tr) < 2 or tr.q.shape[1] != robot.nq:
            raise InputError(
                f"URScript pass {name!r}: needs >= 2 waypoints of {robot.nq} joints, got q {tr.q.shape}"
            )
    if not (speed_resolution_m_s > 0.0 and approach_speed_m_s > 0.0 and blend_m >= 0.0):
        raise InputError("URScript export: speeds must be > 0 and blend_m >= 0")
    path = Path(path)
    prog = identifier(problem.name, "p", 63)
    signal = problem.process.output
    number = ur_output_number(signal)
    note = f"process output {signal!r} is digital output {number}"
    if number is None:
        number = DEFAULT_OUTPUT
        note = f"process output {signal!r} mapped to digital output {number} (refine default)"
    tool = problem.tool
    T_base_world = invert_transform(problem.robot.base_in_world)
    back = make_transform(p=[0.0, 0.0, -retract_m])
    a, air, step = _num(acceleration_m_s2, 6), _num(approach_speed_m_s, 6), speed_resolution_m_s
    lines = [
        f"def {prog}():",
        f"  # Written by refine {__version__} for problem '{comment_text(problem.name)}', robot {problem.robot.model}, "
        f"{len(runs)} pass(es).",
        "  # Poses: TCP in the robot base frame, p[x, y, z [m], rx, ry, rz (rotation vector) [rad]].",
        f"  # {note}",
        f"  set_tcp({_pose(tool.tcp_in_flange)})",
        f"  set_payload({_num(tool.mass_kg, 4)}, [{', '.join(_num(v, 6) for v in tool.cog_in_flange_m)}])",
    ]
    previous = None
    for i, (pass_name, tr) in enumerate(runs, start=1):
        n, label = len(tr), comment_text(str(pass_name))
        poses = np.concatenate([T_base_world @ tr.poses, [T_base_world @ tr.poses[-1] @ back]])
        q_app = _approach_joints(
            robot, tr.q[0], poses[0] @ back @ invert_transform(tool.tcp_in_flange), label
        )
        rv = continuous_rotvecs(poses[:, :3, :3], previous)
        previous = rv[-1]
        gaps = np.linalg.norm(np.diff(poses[:n, :3, 3], axis=0), axis=1)
        blends = np.zeros(n)
        blends[1:-1] = np.minimum(blend_m, 0.4 * np.minimum(gaps[:-1], gaps[1:]))
        lines += [
            f"  # pass {i} of {len(runs)}: {label}, {n} waypoints, {float(tr.t[-1]):.3f} s planned",
            f"  movej([{','.join(_num(v, 9) for v in q_app)}], a={_num(joint_acceleration_rad_s2, 6)}, "
            f"v={_num(joint_speed_rad_s, 6)})",
            f"  movel({_pose(poses[0], rv[0])}, a={a}, v={air}, r=0)",
            f"  set_digital_out({number}, True)",
        ]
        for k, v in enumerate(segment_speeds(tr), start=1):
            speed = _num(max(round(v / step), 1) * step, 6)
            lines.append(f"  movel({_pose(poses[k], rv[k])}, a={a}, v={speed}, r={_num(blends[k], 6)})")
        lines += [
            f"  set_digital_out({number}, False)",
            f"  movel({_pose(poses[n], rv[n])}, a={a}, v={air}, r=0)",
        ]
    lines.append("end")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    log.info("wrote URScript %s: %d pass(es), digital output %d", path, len(runs), number)
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
    """Read back the passes of a program written by :func:`write_urscript`.

    Raises:
        InputError: no pass found, a pass that does not switch its output, or a malformed pose.
    """
    tcp, label = np.eye(4), ""
    passes: list[dict[str, Any]] = []
    for raw in Path(path).read_text(encoding="utf-8").splitlines():
        line = raw.strip()
        if m := re.match(r"#\s*pass\s+\d+\s+of\s+\d+:\s*(.*?)(?:, \d+ waypoints,.*)?$", line):
            label = m.group(1)
        elif m := re.fullmatch(rf"set_tcp\(p{_NUMS}\)", line):
            tcp = _transform(m.group(1), "set_tcp")
        elif m := re.match(rf"movej\({_NUMS}", line):
            q = _vector(m.group(1), None, "movej")
            passes.append({"name": label, "q": q, "moves": [], "on": None, "off": None, "out": -1})
        elif line.startswith("movel(") and passes:
            if not (m := _MOVEL_RE.fullmatch(line)):
                raise InputError(f"URScript {path}: cannot read {line!r}")
            passes[-1]["moves"].append((m.group(1), float(m.group(3)), float(m.group(4))))
        elif (m := re.fullmatch(r"set_digital_out\((\d+),\s*(True|False)\)", line)) and passes:
            key = "on" if m.group(2) == "True" else "off"
            passes[-1][key], passes[-1]["out"] = len(passes[-1]["moves"]), int(m.group(1))
    result = []
    for p in passes:
        if not p["on"] or p["off"] is None:
            raise InputError(f"URScript {path}: pass {p['name']!r} does not switch its output on and off")
        moves = p["moves"][p["on"] - 1 : p["off"]]
        poses = np.array([_transform(text, "movel") for text, _, _ in moves])
        rotvecs = np.array([_vector(text, 6, "movel")[3:] for text, _, _ in moves])
        speeds, radii = np.array([v for _, v, _ in moves]), np.array([r for _, _, r in moves])
        result.append(UrPass(p["name"], poses, rotvecs, speeds, radii, p["q"], p["out"], tcp))
    if not result:
        raise InputError(f"URScript {path}: no pass (movej approach followed by movel moves) found")
    return result
