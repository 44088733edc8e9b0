"""KUKA Sunrise.OS application for an LBR iiwa: the refined path as a ``RoboticsAPIApplication`` Java class.

One file ``<ClassName>.java`` in package ``application`` (the class name is the problem name in
CamelCase):

* ``initialize()`` builds the tool in code: a ``Tool`` with its load (mass [kg], centre of mass
  [mm]) and a child frame ``TCP`` at ``tcp_in_flange`` (``XyzAbcTransformation.ofRad``: mm and rad)
  as its default motion frame, attached to the flange.
* Targets are ``Frame`` objects in the robot base frame (``robot.getRootFrame()``): X, Y, Z [mm],
  A, B, C [rad] (rotations about z, y', x'', as KUKA's A, B, C), with the redundancy information
  ``LBRE1Redundancy(E1, Status, Turn)``: E1 the angle of axis 3 [rad], Status and Turn by the LBR
  rules of :func:`refine.export.krl.kuka_status_turn`. Each pass's rows
  ``{x, y, z, a, b, c, e1, status, turn, v}`` (``v`` the Cartesian speed of the segment ending at
  the point [mm/s]) are returned by methods of at most :data:`ROWS_PER_METHOD` rows each, to keep
  every method far below the JVM's 64 KB code limit.
* ``run()``: ``ptp`` to the home joint position, then per pass ``ptp`` to the approach frame
  ``retract_m`` behind the first point along the tool z axis, ``lin`` onto the first point, the
  pass as one ``Spline`` of ``spl`` segments with their speeds, ``lin`` to the retract; ``ptp``
  home at the end. Near the wrist singularity the header says where.
* Process I/O goes through Sunrise I/O groups: a signal is named ``"<Group>.<Signal>"``, e.g.
  ``"MediaFlange.OutputX3Pin1"`` (the media flange's group; its outputs are ``OutputX3Pin1``,
  ``OutputX3Pin2``, ``OutputX3Pin11``, ``OutputX3Pin12``, its inputs ``InputX3Pin3``, ``...4``,
  ``...10``, ``...13``, ``...16``), which uses the generated class
  ``com.kuka.generated.ioAccess.<Group>IOGroup`` (injected) and its ``set<Signal>(boolean)`` /
  ``get<Signal>()``. A name without a group is an error.
* Glue and seal switch on the move: ``triggerWhen(new MotionPathCondition(ReferenceType.DEST,
  -lead_mm, 0), ...)`` (``lead_m``) or ``(ReferenceType.DEST, 0, -lead_ms)`` (``lead_s``) on the
  move onto the first point and on the spline segment that holds the switch-off point, the
  approach blended into the spline (``moveAsync`` with ``setBlendingCart``). A weld stands at both
  ends for its sequence (gas pre-flow, arc on, wait for the arc input with a timeout that switches
  everything off and throws, crater fill, arc off, post-flow).
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from refine.errors import InputError
from refine.export.krl import kuka_status_turn
from refine.export.motion import segment_speeds
from refine.export.program import (
    Switch,
    Wait,
    arc_abort,
    as_passes,
    header_notes,
    home_joints,
    lead_point,
    process_summary,
    weld_end,
    weld_start,
)
from refine.export.sink import put_text
from refine.frames import invert_transform, kuka_abc_from_matrix, matrix_from_kuka_abc
from refine.names import comment_text
from refine.paths import Trajectory
from refine.problem import Problem
from refine.types import Array
from refine.version import __version__

log = logging.getLogger(__name__)

ROWS_PER_METHOD = 200
"""Target rows per generated Java method."""
_SIGNAL = re.compile(r"([A-Za-z][A-Za-z0-9]*)\.([A-Za-z][A-Za-z0-9_]*)")


def class_name(problem_name: str) -> str:
    """The Java class name of a problem: its words in CamelCase, a letter first (``tig_weld`` -> ``TigWeld``)."""
    words = [w for w in re.split(r"[^A-Za-z0-9]+", problem_name) if w]
    name = "".join(w[:1].upper() + w[1:] for w in words)
    return name if name[:1].isalpha() else f"Path{name}"


def sunrise_signal(name: str, key: str = "process.output") -> tuple[str, str]:
    """``"<Group>.<Signal>"`` -> (group, signal) of a Sunrise I/O group.

    Raises:
        InputError: the name is not ``Group.Signal`` (both Java identifiers).
    """
    m = _SIGNAL.fullmatch(name.strip())
    if m is None:
        raise InputError(
            f"{key} {name!r}: a Sunrise signal is '<I/O group>.<signal>', e.g. 'MediaFlange.OutputX3Pin1'"
        )
    return m.group(1), m.group(2)


def _num(value: float, decimals: int) -> str:
    text = f"{value:.{decimals}f}".rstrip("0").rstrip(".")
    text = "0.0" if float(text) == 0.0 else text
    return text if "." in text else f"{text}.0"


def _row(T: Array, e1: float, status: int, turn: int, v_mm_s: float) -> str:
    xyz = [_num(c * 1000.0, 4) for c in T[:3, 3]]
    abc = [_num(math.radians(c), 9) for c in kuka_abc_from_matrix(T[:3, :3])]
    return "{" + ", ".join([*xyz, *abc, _num(e1, 9), f"{status}.0", f"{turn}.0", _num(v_mm_s, 4)]) + "}"


def _field(group: str) -> str:
    return group[:1].lower() + group[1:]


def _io_calls(problem: Problem) -> dict[str, tuple[str, str]]:
    """Role -> (group, signal) of the process I/O the program uses."""
    pr = problem.process
    roles = {"out": sunrise_signal(pr.output)}
    if pr.kind == "weld":
        roles["gas"] = sunrise_signal(pr.gas_output, "process.gas_output")
        roles["ok"] = sunrise_signal(pr.arc_ok_input, "process.arc_ok_input")
    return roles


def _weld_io(io: dict[str, tuple[str, str]]) -> tuple[Wait, Switch]:
    def wait(seconds: float, comment: str) -> str:
        return f"ThreadUtil.milliSleep({int(round(seconds * 1000.0))});" + (
            f" // {comment}" if comment else ""
        )

    def switch(role: str, on: bool, comment: str) -> str:
        group, signal = io[role]
        return f"{_field(group)}.set{signal}({'true' if on else 'false'});" + (
            f" // {comment}" if comment else ""
        )

    return wait, switch


def _weld_start(io: dict[str, tuple[str, str]], problem: Problem) -> list[str]:
    pr = problem.process
    wait, switch = _weld_io(io)
    ok_group, ok_signal = io["ok"]
    timeout_ms = int(round(pr.arc_timeout_s * 1000.0))
    return weld_start(
        problem,
        wait,
        switch,
        [
            "long arcWait = System.currentTimeMillis();",
            f"while (!{_field(ok_group)}.get{ok_signal}()) {{",
            f"    if (System.currentTimeMillis() - arcWait > {timeout_ms}) {{",
            *arc_abort(switch, "        "),
            f'        throw new IllegalStateException("Arc start failed: no {ok_signal} within {_num(pr.arc_timeout_s, 3)} s");',
            "    }",
            "    ThreadUtil.milliSleep(10);",
            "}",
        ],
    )


def _weld_end(io: dict[str, tuple[str, str]], problem: Problem) -> list[str]:
    return weld_end(problem, *_weld_io(io))


def _condition(problem: Problem, lead: float) -> str:
    if problem.process.lead_m is None:
        return f"new MotionPathCondition(ReferenceType.DEST, 0, -{int(round(lead * 1000.0))})"
    return f"new MotionPathCondition(ReferenceType.DEST, -{_num(lead * 1000.0, 3)}, 0)"


def write_sunrise(
    path: str | Path,
    trajectory: Trajectory,
    problem: Problem,
    robot: Any,
    *,
    passes: list[Any] | None = None,
    repairs: tuple[Any, ...] = (),
    approach_speed_m_s: float = 0.25,
    retract_m: float = 0.1,
    joint_velocity_rel: float = 0.2,
    speed_resolution_m_s: float = 1e-4,
) -> Path:
    """Write the trajectory as a Sunrise ``RoboticsAPIApplication`` (``<ClassName>.java``).

    Args:
        path: output file; its folder is used, the file is named after the class.
        trajectory: the refined, timed path (poses in {F}, joints for E1, Status and Turn).
        problem: tool, robot base, home, process I/O (``"<Group>.<Signal>"``) and switching.
        robot: the :class:`refine.robot.model.Robot` the joints belong to (a seven-axis KUKA LBR).
        passes: several passes as :class:`refine.export.program.ProgramPass` or
            ``(name, trajectory)``, in order; when given, ``trajectory`` is not written.
        repairs: the repaired segments of ``trajectory`` (when ``passes`` is not given).
        approach_speed_m_s: Cartesian speed of the moves onto the first point and to the retract [m/s].
        retract_m: approach and retract distance along the tool z axis [m].
        joint_velocity_rel: relative joint speed of the ``ptp`` moves (0..1].
        speed_resolution_m_s: segment speeds are rounded to this step [m/s].

    Returns:
        The path written.
    """
    if getattr(robot.spec, "controller", "") != "kuka" or robot.nq != 7:
        raise InputError(
            f"Sunrise applications are for the seven-axis KUKA LBR; {robot.spec.name!r} has "
            f"{robot.nq} axes and controller {robot.spec.controller!r}"
        )
    if not (0.0 < joint_velocity_rel <= 1.0 and approach_speed_m_s > 0.0 and speed_resolution_m_s > 0.0):
        raise InputError("Sunrise export: joint_velocity_rel must be in (0, 1] and speeds > 0")
    runs = as_passes(problem.name, trajectory, passes, repairs)
    for p in runs:
        if len(p.trajectory) < 2 or p.trajectory.q.shape[1] != 7:
            raise InputError(f"Sunrise pass {p.name!r}: needs >= 2 waypoints of 7 joints")
    name = class_name(problem.name)
    path = Path(path).with_name(f"{name}.java")
    pr, weld = problem.process, problem.process.kind == "weld"
    io = _io_calls(problem)
    groups = sorted({g for g, _ in io.values()})
    T_base_world = invert_transform(problem.robot.base_in_world)
    tool = problem.tool
    tcp_xyz = [_num(c * 1000.0, 4) for c in tool.tcp_in_flange[:3, 3]]
    tcp_abc = [_num(math.radians(c), 9) for c in kuka_abc_from_matrix(tool.tcp_in_flange[:3, :3])]
    cog = [_num(c * 1000.0, 4) for c in tool.cog_in_flange_m]
    home = home_joints(problem, robot, runs[0].trajectory.q[0])
    air = _num(approach_speed_m_s * 1000.0, 3)
    io_note = ", ".join(f"{role} {g}.{s}" for role, (g, s) in io.items())
    names = {role: f"{g}.{s}" for role, (g, s) in io.items()}
    process = process_summary(
        problem, "path triggers", names["out"], names.get("gas", ""), names.get("ok", "")
    )
    head = [
        f"// Written by refine {__version__} for problem '{comment_text(problem.name)}', robot "
        f"{problem.robot.model}, {len(runs)} pass(es).",
        "// Frames: TCP in the robot base frame, X Y Z [mm], A B C [rad], redundancy E1 [rad], Status, Turn.",
        f"// process I/O: {comment_text(io_note)}",
        f"// {process}",
        *(f"// {comment_text(line)}" for p in runs for line in header_notes(p, robot)),
    ]
    imports = [
        "import static com.kuka.roboticsAPI.motionModel.BasicMotions.lin;",
        "import static com.kuka.roboticsAPI.motionModel.BasicMotions.ptp;",
        "import static com.kuka.roboticsAPI.motionModel.BasicMotions.spl;",
        "",
        "import javax.inject.Inject;",
        "",
        "import com.kuka.common.ThreadUtil;",
        *(f"import com.kuka.generated.ioAccess.{g}IOGroup;" for g in groups),
        "import com.kuka.roboticsAPI.applicationModel.RoboticsAPIApplication;",
        "import com.kuka.roboticsAPI.conditionModel.ICallbackAction;",
        "import com.kuka.roboticsAPI.conditionModel.MotionPathCondition;",
        "import com.kuka.roboticsAPI.conditionModel.ReferenceType;",
        "import com.kuka.roboticsAPI.deviceModel.JointPosition;",
        "import com.kuka.roboticsAPI.deviceModel.LBR;",
        "import com.kuka.roboticsAPI.deviceModel.LBRE1Redundancy;",
        "import com.kuka.roboticsAPI.executionModel.IFiredTriggerInfo;",
        "import com.kuka.roboticsAPI.geometricModel.Frame;",
        "import com.kuka.roboticsAPI.geometricModel.ObjectFrame;",
        "import com.kuka.roboticsAPI.geometricModel.Tool;",
        "import com.kuka.roboticsAPI.geometricModel.math.Transformation;",
        "import com.kuka.roboticsAPI.geometricModel.math.XyzAbcTransformation;",
        "import com.kuka.roboticsAPI.motionModel.Spline;",
        "import com.kuka.roboticsAPI.motionModel.SplineMotionCP;",
    ]
    og, os_ = io["out"]
    body = [
        f"public class {name} extends RoboticsAPIApplication {{",
        "    @Inject",
        "    private LBR robot;",
        *(line for g in groups for line in ("    @Inject", f"    private {g}IOGroup {_field(g)};")),
        "    private Tool tool;",
        "    private ObjectFrame tcp;",
        "",
        "    private final ICallbackAction processOn = new ICallbackAction() {",
        "        @Override",
        "        public void onTriggerFired(IFiredTriggerInfo info) {",
        f"            {_field(og)}.set{os_}(true);",
        "        }",
        "    };",
        "    private final ICallbackAction processOff = new ICallbackAction() {",
        "        @Override",
        "        public void onTriggerFired(IFiredTriggerInfo info) {",
        f"            {_field(og)}.set{os_}(false);",
        "        }",
        "    };",
        "",
        "    @Override",
        "    public void initialize() {",
        f'        tool = new Tool("{comment_text(tool.name).replace(chr(34), "")}");',
        f"        tool.getLoadData().setMass({_num(tool.mass_kg, 4)});",
        f"        tool.getLoadData().setCenterOfMass({', '.join(cog)});",
        f'        tcp = tool.addChildFrame("TCP", XyzAbcTransformation.ofRad({", ".join(tcp_xyz + tcp_abc)}));',
        "        tool.setDefaultMotionFrame(tcp);",
        "        tool.attachTo(robot.getFlange());",
        "    }",
        "",
        "    @Override",
        "    public void run() {",
        f"        robot.move(ptp(home()).setJointVelocityRel({_num(joint_velocity_rel, 3)}));",
    ]
    methods: list[str] = []
    for i, p in enumerate(runs, start=1):
        tr = p.trajectory
        n = len(tr)
        poses = T_base_world @ tr.poses
        status, turn = kuka_status_turn(robot, tr.q)
        step = speed_resolution_m_s
        speeds = [approach_speed_m_s] + [max(round(v / step), 1) * step for v in segment_speeds(tr)]
        rows = [
            _row(poses[k], float(tr.q[k, 2]), int(status[k]), int(turn[k]), speeds[k] * 1000.0)
            for k in range(n)
        ]
        chunks = [rows[a : a + ROWS_PER_METHOD] for a in range(0, n, ROWS_PER_METHOD)]
        parts = [f"pass{i}Part{c + 1}" for c in range(len(chunks))]
        by_time = pr.lead_m is None
        lead = pr.lead_s if by_time else float(pr.lead_m)
        along = (
            tr.t
            if by_time
            else np.concatenate(
                [[0.0], np.cumsum(np.linalg.norm(np.diff(tr.poses[:, :3, 3], axis=0), axis=1))]
            )
        )
        off_k, off_lead = (n - 1, 0.0) if weld else lead_point(along, lead)
        label = comment_text(str(p.name))
        body += [f"        // pass {i} of {len(runs)}: {label}, {n} points, {float(tr.t[-1]):.3f} s planned"]
        off_value = off_lead * 1000.0  # ms for lead_s, mm for lead_m
        air_in = getattr(p, "air_in", None)
        if air_in is not None:  # the run's planned air move: via points, then the approach joints
            body += [
                f"        robot.move(ptp(new JointPosition({', '.join(_num(v, 9) for v in q)}))"
                f".setJointVelocityRel({_num(joint_velocity_rel, 3)}));" + (
                    f"  // via point of the planned move to pass {i}" if k < len(air_in) - 1 else
                    f"  // the approach point of pass {i}"
                )
                for k, q in enumerate(air_in)
            ]
        body += [
            f"        runPass(join({', '.join(f'{m}()' for m in parts)}), {off_k}, {_num(off_value, 3)}, "
            f"{'true' if weld else 'false'}, {'false' if air_in is not None else 'true'});"
        ]
        for m, chunk in zip(parts, chunks, strict=True):
            methods += [f"    private static double[][] {m}() {{", "        return new double[][] {"]
            methods += [f"            {r}," for r in chunk]
            methods += ["        };", "    }", ""]
    air_out = getattr(runs[-1], "air_out", None)
    if air_out is not None:  # the run's planned return: via points, then home
        body += [
            f"        robot.move(ptp(new JointPosition({', '.join(_num(v, 9) for v in q)}))"
            f".setJointVelocityRel({_num(joint_velocity_rel, 3)}));  // via point of the planned return"
            for q in air_out[:-1]
        ]
    body += [
        f"        robot.move(ptp(home()).setJointVelocityRel({_num(joint_velocity_rel, 3)}));",
        "    }",
        "",
    ]
    home_args = ", ".join(_num(v, 9) for v in home)
    body += [
        "    private JointPosition home() {",
        f"        return new JointPosition({home_args});",
        "    }",
        "",
        "    private Frame frame(double[] r) {",
        "        Frame f = new Frame(robot.getRootFrame(), r[0], r[1], r[2], r[3], r[4], r[5]);",
        "        f.setRedundancyInformation(robot, new LBRE1Redundancy(r[6], (int) r[7], (int) r[8]));",
        "        return f;",
        "    }",
        "",
        "    private static double[][] join(double[][]... parts) {",
        "        int n = 0;",
        "        for (double[][] part : parts) {",
        "            n = n + part.length;",
        "        }",
        "        double[][] rows = new double[n][];",
        "        int k = 0;",
        "        for (double[][] part : parts) {",
        "            for (double[] row : part) {",
        "                rows[k] = row;",
        "                k = k + 1;",
        "            }",
        "        }",
        "        return rows;",
        "    }",
        "",
        "    private void runPass(double[][] points, int offIndex, double offLead, boolean weld, boolean toApproach) {",
        "        Frame first = frame(points[0]);",
        "        if (toApproach) {",
        "            Frame approach = first.copyWithRedundancy();",
        f"            approach.transform(Transformation.ofTranslation(0.0, 0.0, -{_num(retract_m * 1000.0, 3)}));",
        f"            tcp.move(ptp(approach).setJointVelocityRel({_num(joint_velocity_rel, 3)}));",
        "        }",
        "        SplineMotionCP<?>[] segments = new SplineMotionCP<?>[points.length - 1];",
        "        for (int k = 1; k < points.length; k++) {",
        "            segments[k - 1] = spl(frame(points[k])).setCartVelocity(points[k][9]);",
        "        }",
        "        if (weld) {",
        f"            tcp.move(lin(first).setCartVelocity({air}));",
        *(f"            {ln}" for ln in (_weld_start(io, problem) if weld else ["// no weld sequence"])),
        "            tcp.move(new Spline(segments));",
        *(f"            {ln}" for ln in (_weld_end(io, problem) if weld else ["// no weld sequence"])),
        "        } else {",
    ]
    if weld:
        body += ['            throw new IllegalStateException("this program only welds");']
    else:
        lead = pr.lead_s if pr.lead_m is None else float(pr.lead_m)
        on_cond = _condition(problem, lead)
        off_cond = (
            "new MotionPathCondition(ReferenceType.DEST, 0, (long) -offLead)"
            if pr.lead_m is None
            else "new MotionPathCondition(ReferenceType.DEST, -offLead, 0)"
        )
        body += [
            f"            tcp.moveAsync(lin(first).setCartVelocity({air}).setBlendingCart(1.0)",
            f"                .triggerWhen({on_cond}, processOn));",
            f"            segments[offIndex - 1].triggerWhen({off_cond}, processOff);",
            "            tcp.move(new Spline(segments));",
        ]
    body += [
        "        }",
        "        Frame retract = frame(points[points.length - 1]).copyWithRedundancy();",
        f"        retract.transform(Transformation.ofTranslation(0.0, 0.0, -{_num(retract_m * 1000.0, 3)}));",
        f"        tcp.move(lin(retract).setCartVelocity({air}));",
        "    }",
        "",
    ]
    lines = ["package application;", "", *imports, "", *head, *body, *methods, "}"]
    put_text(path, "\n".join(lines) + "\n")
    log.info("wrote Sunrise application %s: %d pass(es)", path, len(runs))
    return path


@dataclass(frozen=True)
class SunrisePass:
    """One pass read back from a Sunrise application.

    Attributes:
        positions: TCP positions in the robot base frame [m], shape (N, 3).
        rotations: TCP orientations in the robot base frame, shape (N, 3, 3).
        e1_rad: redundancy angle E1 [rad], shape (N,).
        status, turn: Status and Turn, shape (N,) each.
        speeds: Cartesian speed of the move ending at each point [m/s], shape (N,).
    """

    positions: Array
    rotations: Array
    e1_rad: Array
    status: Array
    turn: Array
    speeds: Array


def parse_sunrise(path: str | Path) -> list[SunrisePass]:
    """Read back the passes of an application written by :func:`write_sunrise`.

    Raises:
        InputError: no pass or a malformed row.
    """
    text = Path(path).read_text(encoding="utf-8")
    rows: dict[tuple[int, int], list[list[float]]] = {}
    for m in re.finditer(
        r"double\[\]\[\] pass(\d+)Part(\d+)\(\) \{\s*return new double\[\]\[\] \{(.*?)\};", text, re.S
    ):
        body = re.findall(r"\{([^{}]*)\}", m.group(3))
        try:
            values = [[float(v) for v in b.split(",")] for b in body]
        except ValueError as e:
            raise InputError(f"Sunrise {path}: malformed row in pass {m.group(1)}") from e
        if any(len(v) != 10 for v in values):
            raise InputError(f"Sunrise {path}: a row of pass {m.group(1)} does not have 10 values")
        rows[(int(m.group(1)), int(m.group(2)))] = values
    passes = sorted({k[0] for k in rows})
    if not passes:
        raise InputError(f"Sunrise {path}: no pass found")
    out = []
    for i in passes:
        v = np.array([r for part in sorted(k[1] for k in rows if k[0] == i) for r in rows[(i, part)]])
        R = matrix_from_kuka_abc(np.degrees(v[:, 3:6]))
        out.append(SunrisePass(v[:, :3] / 1000.0, R, v[:, 6], v[:, 7], v[:, 8], v[:, 9] / 1000.0))
    return out
