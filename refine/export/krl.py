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
T bit i = 1 when axis i+1 < 0.

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
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from refine import __version__
from refine.errors import InputError
from refine.export.rapid import segment_speeds
from refine.frames import invert_transform, kuka_abc_from_matrix, make_transform, matrix_from_kuka_abc
from refine.names import comment_text, identifier
from refine.paths import Array, Trajectory
from refine.problem import Problem

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


def kuka_status_turn(robot: Any, q: Array) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """KUKA Status and Turn of joint vectors (rules and sources in the module docstring).

    Args:
        robot: a :class:`refine.robot.Robot` with 6 joints (KUKA serial arm) or 7 (LBR iiwa).
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
    turn = ((qs < 0.0) * (1 << np.arange(n))).sum(axis=1).astype(np.int64)
    return (status[0], turn[0]) if q.ndim == 1 else (status, turn)


def _declarations(names: list[str], tr: Trajectory, robot: Any, back: Array) -> list[str]:
    """``DECL E6POS`` of the approach point, every waypoint and the retract point of one pass."""
    n = len(tr)
    status, turn = kuka_status_turn(robot, tr.q)
    if len(set(status)) > 1:  # a CP motion keeps its start Status: a change means a singular pose
        log.warning("KRL: Status changes along a LIN pass (%s): a singularity", sorted(set(status.tolist())))
    e1 = np.degrees(tr.q[:, 2]) if robot.nq == 7 else np.zeros(n)
    poses, rows = [tr.poses[0] @ back, *tr.poses, tr.poses[-1] @ back], [0, *range(n), n - 1]
    tail = ",".join(f"E{i} 0.0" for i in range(2, 7))
    return [
        f"DECL E6POS {name}={{{_xyzabc(T)},S {status[r]},T {turn[r]},E1 {_real(e1[r], 6)},{tail}}}"
        for name, T, r in zip(names, poses, rows, strict=True)
    ]


def _moves(names: list[str], tr: Trajectory, output: tuple[int, str], air: str, step: float) -> list[str]:
    """The motion of one pass: approach, output on, the seam, output off, retract."""
    (number, signal), path, current = output, names[1:-1], None
    lines = [f"$VEL.CP = {air}", f"PTP {names[0]}", f"LIN {path[0]}", f"$OUT[{number}]=TRUE ; on ({signal})"]
    for k, v in enumerate(segment_speeds(tr), start=1):
        text = _real(max(round(v / step), 1) * step, 6)
        lines += [f"$VEL.CP = {text}"] if text != current else []
        current = text
        lines.append(f"LIN {path[k]}" + (" C_DIS" if k < len(path) - 1 else ""))
    return lines + [f"$OUT[{number}]=FALSE ; off ({signal})", f"$VEL.CP = {air}", f"LIN {names[-1]}"]


def write_krl(
    path_src: str | Path,
    trajectory: Trajectory,
    problem: Problem,
    robot: Any,
    *,
    passes: list[tuple[str, Trajectory]] | None = None,
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
        problem: tool, robot base, process output.
        robot: the :class:`refine.robot.Robot` the joints belong to (controller ``"kuka"``).
        passes: several passes of a multi-pass weld as ``(name, trajectory)`` in order, the root pass
            included; when given, ``trajectory`` is not written. One fold per pass.
        approximation_m: ``$APO.CDIS`` approximation distance between path points [m].
        approach_speed_m_s: ``$VEL.CP`` of the moves onto the first point and to the retract [m/s].
        retract_m: approach and retract distance along the tool z axis [m].
        ptp_percent: axis speed of the ``PTP`` approach [% of the maximum].
        speed_resolution_m_s: ``$VEL.CP`` is rounded to this step [m/s].

    Returns:
        The ``.src`` and ``.dat`` paths written.
    """
    if getattr(robot.spec, "controller", "") != "kuka":
        raise InputError(f"KRL is for KUKA robots; {robot.spec.name!r} is for {robot.spec.controller}")
    runs = [(problem.name, trajectory)] if passes is None else list(passes)
    if not runs or any(len(tr) < 2 or tr.q.shape[1] != robot.nq for _, tr in runs):
        raise InputError(f"KRL export: needs passes of >= 2 waypoints of {robot.nq} joints, got {len(runs)}")
    if not (speed_resolution_m_s > 0.0 and approach_speed_m_s > 0.0 and approximation_m >= 0.0):
        raise InputError("KRL export: speeds must be > 0 and approximation_m >= 0")
    prog = _name(Path(path_src).stem, "prog")
    src, dat = (Path(path_src).with_name(prog + ext) for ext in (".src", ".dat"))
    tool, load = _name(f"TOOL_{problem.tool.name}", "TOOL"), _name(f"LOAD_{problem.tool.name}", "LOAD")
    number = krl_output_number(signal := problem.process.output) or DEFAULT_OUTPUT
    mapped = "" if krl_output_number(signal) else "mapped to "
    note = f"process output {signal!r} is {mapped}$OUT[{number}]" + (" (refine default)" if mapped else "")
    cog = [_real(v * 1000.0, 4) for v in problem.tool.cog_in_flange_m]
    header = f"; Written by refine {__version__} for problem '{comment_text(problem.name)}', robot {problem.robot.model}."
    dat_lines = [
        *("&ACCESS RVP", "&REL 1", f"DEFDAT {prog}", header),
        "; E6POS: TCP in {F} ($BASE = BASE_WORLD), X Y Z [mm], A B C [deg], S T (E1 = A3 [deg] on an LBR)",
        f"DECL FRAME {tool}={{{_xyzabc(problem.tool.tcp_in_flange)}}}",
        f"DECL FRAME BASE_WORLD={{{_xyzabc(invert_transform(problem.robot.base_in_world))}}}",
        f"DECL LOAD {load}={{M {_real(problem.tool.mass_kg, 4)},CM {{X {cog[0]},Y {cog[1]},Z {cog[2]},"
        "A 0.0,B 0.0,C 0.0},J {X 0.0,Y 0.0,Z 0.0}}",
    ]
    src_lines = [*("&ACCESS RVP", "&REL 1", f"DEF {prog}( )"), *_INI, header, f"; {note}"]
    src_lines += ["$BASE = BASE_WORLD", f"$TOOL = {tool}", f"$LOAD = {load}"]
    src_lines += [f"$APO.CDIS = {_real(approximation_m * 1000.0, 4)}", f"BAS (#VEL_PTP,{int(ptp_percent)} )"]
    air, back = _real(approach_speed_m_s, 6), make_transform(p=[0.0, 0.0, -retract_m])
    for i, (pass_name, tr) in enumerate(runs, start=1):
        points = [f"XP{k}" if len(runs) == 1 else f"XP{i}_{k}" for k in range(1, len(tr) + 1)]
        names = [f"XAPP{i}", *points, f"XRET{i}"]
        dat_lines += _declarations(names, tr, robot, back)
        head = f"pass {i} of {len(runs)}: " + comment_text(str(pass_name)).replace(";", ",")
        src_lines += [f";FOLD {head}", f"  ; {head}, {len(tr)} points, {float(tr.t[-1]):.3f} s planned"]
        src_lines += [f"  {line}" for line in _moves(names, tr, (number, signal), air, speed_resolution_m_s)]
        src_lines.append(";ENDFOLD")
    src.parent.mkdir(parents=True, exist_ok=True)
    src.write_text("\n".join([*src_lines, "END"]) + "\n", encoding="utf-8")
    dat.write_text("\n".join([*dat_lines, "ENDDAT"]) + "\n", encoding="utf-8")
    log.info("wrote KRL program %s (+ .dat): %d pass(es), $OUT[%d]", src, len(runs), number)
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

    Raises:
        InputError: no pass found, a point used but not declared, or a malformed declaration.
    """
    decls = _DECL_RE.finditer(Path(path_dat).read_text(encoding="utf-8"))
    points = {m.group(1).upper(): _fields(m.group(2), m.group(1)) for m in decls}
    passes: list[dict[str, Any]] = []
    label, speed = "", float("nan")
    for raw in Path(path_src).read_text(encoding="utf-8").splitlines():
        if fold := _FOLD_RE.match(raw.strip()):
            label = fold.group(1).strip()
        code = raw.split(";", 1)[0].strip()
        if m := re.fullmatch(r"\$VEL\.CP\s*=\s*(\S+)", code, re.IGNORECASE):
            speed = float(m.group(1))
        elif re.match(r"PTP\s", code, re.IGNORECASE):
            passes.append({"name": label, "moves": [], "on": None, "off": None, "out": 0})
        elif re.match(r"LIN\s", code, re.IGNORECASE) and passes:
            if not (m := re.fullmatch(r"LIN\s+(\w+)(\s+C_DIS)?", code, re.IGNORECASE)):
                raise InputError(f"KRL {path_src}: cannot read {code!r}")
            if m.group(1).upper() not in points:
                raise InputError(f"KRL {path_src}: point {m.group(1)} is not declared in {path_dat}")
            passes[-1]["moves"].append((m.group(1).upper(), speed))
        elif (m := re.fullmatch(r"\$OUT\[(\d+)\]\s*=\s*(TRUE|FALSE)", code, re.IGNORECASE)) and passes:
            key = "on" if m.group(2).upper() == "TRUE" else "off"
            passes[-1][key], passes[-1]["out"] = len(passes[-1]["moves"]), int(m.group(1))
    result = []
    for p in passes:
        if not p["on"] or p["off"] is None:
            raise InputError(f"KRL {path_src}: pass {p['name']!r} does not switch its output on and off")
        moves = p["moves"][p["on"] - 1 : p["off"]]
        v = np.array([[points[name][k] for k in "X Y Z A B C S T E1".split()] for name, _ in moves])
        names, speeds = tuple(name for name, _ in moves), np.array([s for _, s in moves])
        S, T, R = v[:, 6].astype(np.int64), v[:, 7].astype(np.int64), matrix_from_kuka_abc(v[:, 3:6])
        result.append(KrlPass(p["name"], names, v[:, :3] / 1000.0, R, S, T, v[:, 8], speeds, p["out"]))
    if not result:
        raise InputError(f"KRL {path_src}: no pass (PTP approach followed by LIN moves) found")
    return result
