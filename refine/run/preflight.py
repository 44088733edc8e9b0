"""Checks that run before anything is solved or written: what ``refine check`` and ``refine run`` share.

A problem that loads (``refine.problem`` checks every value and file) can still be wrong for the
robot or the output folder. :func:`preflight` finds those mistakes before the solve, so a run never
spends minutes and then refuses to write:

* the program formats exist and the robot's controller runs them (RAPID: ABB, KRL: the KUKA KR
  arms, Sunrise: the KUKA LBR iiwa, URScript: Universal Robots, TP: FANUC, INFORM: Yaskawa);
* ``process.output`` is a signal each of those programs can switch (a RAPID signal name, a KRL
  ``$OUT[n]`` with n in 1..4096, a UR standard output 0..7, a FANUC ``DO[n]`` with n in 1..512, a
  Yaskawa ``OT#(n)`` with n in 1..4096); TP needs a six-axis arm, a user frame 1..9 and a tool frame
  1..10, INFORM a six-axis arm and a tool file 0..63;
* ``robot.home_deg`` and ``robot.joint_acceleration_deg_s2`` have one value per joint;
* the home pose is inside the joint limits and keeps the collision margins: its robot and tool
  are no closer to a cell object than ``collision.margin_m`` and to each other than
  ``collision.self_margin_m`` (every motion of the program starts and ends there);
* the output folder is a folder (or can be made one), and no output would overwrite an input file.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from refine.errors import InputError, option
from refine.names import identifier
from refine.problem import Problem
from refine.settings import PROGRAM_FORMATS

if TYPE_CHECKING:
    from refine.robot.model import Robot
    from refine.robot.spec import RobotSpec

_RAPID_SIGNAL = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,31}")


@dataclass(frozen=True)
class Preflight:
    """What the checks established.

    Attributes:
        programs: the program formats to write.
        out_dir: the output folder, resolved (None when not checked).
        outputs: the file names a run may write into ``out_dir``.
    """

    programs: tuple[str, ...]
    out_dir: Path | None
    outputs: tuple[str, ...]


def parse_programs(text: str | None, problem: Problem) -> tuple[str, ...] | None:
    """The program formats of ``--programs`` (comma-separated), or None when it was not given."""
    if text is None:
        return None
    programs = tuple(p.strip() for p in text.split(",") if p.strip())
    for kind in programs:
        if kind not in PROGRAM_FORMATS:
            raise InputError(f"--programs: {kind!r} is not one of {', '.join(PROGRAM_FORMATS)}")
    return programs


def check_programs(problem: Problem, spec: RobotSpec, programs: tuple[str, ...]) -> None:
    """Every program format is known, runs on the robot's controller and can switch ``process.output``.

    The formats a robot runs are :attr:`refine.robot.spec.RobotSpec.programs`: its own ``program``
    when the registry names one (``sunrise`` for the LBR iiwa, ``krl`` for the KR 8), else every
    format of its controller family.
    """
    for kind in programs:
        if kind not in PROGRAM_FORMATS:
            raise InputError(f"program format {kind!r} is not one of {', '.join(PROGRAM_FORMATS)}")
        if kind not in spec.programs:
            runs = ", ".join(spec.programs)
            model = f" ({spec.model})" if spec.model else ""
            raise InputError(
                f"program format {kind!r} does not run on robot {spec.name!r}{model}: its {spec.controller} "
                f"controller runs {runs} only; use {runs} ([output] programs or "
                f"{option('--programs', 'programs=')})",
                key="programs",
                value=kind,
                expected=f"one of {runs}",
            )
        check_output_signal(kind, problem.process.output)


def check_output_signal(kind: str, output: str) -> None:
    """``output`` (``process.output``) is a signal the ``kind`` program can switch.

    Raises:
        InputError: a name RAPID cannot declare, or an output number outside the controller's range.
    """
    if kind == "rapid" and not _RAPID_SIGNAL.fullmatch(output):
        raise InputError(
            f"process.output {output!r} is not a RAPID signal name (a letter, then up to 31 letters, "
            "digits or _)"
        )
    if kind == "krl":
        from refine.export.krl import krl_output_number

        krl_output_number(output)  # raises outside $OUT[1..4096]; a name maps to the default
    if kind == "urscript":
        from refine.export.urscript import ur_output_number

        ur_output_number(output)  # raises outside 0..7; a name maps to the default
    if kind == "tp":
        from refine.export.tp import fanuc_io_number

        fanuc_io_number(output, "DO", 1)  # raises outside DO[1..512]; a name maps to the default
    if kind == "inform":
        from refine.export.inform import yaskawa_io_number

        yaskawa_io_number(output, "OT", 1)  # raises outside OT#(1..4096); a name maps to the default
    if kind == "sunrise":
        from refine.export.sunrise import sunrise_signal

        sunrise_signal(output)  # raises unless "<I/O group>.<signal>"


def check_arm_programs(problem: Problem, robot: Robot, programs: tuple[str, ...]) -> None:
    """TP and INFORM: a six-axis arm, and frame and tool numbers the controller has."""
    for kind in ("tp", "inform"):
        if kind in programs and robot.nq != 6:
            raise InputError(
                f"program format {kind!r} is for six-axis arms; robot {robot.spec.name!r} has {robot.nq}"
            )
    if "tp" in programs:
        from refine.export.tp import MAX_UFRAME, MAX_UTOOL

        if not 1 <= problem.frames.base_number <= MAX_UFRAME:
            raise InputError(
                f"frames.base_number = {problem.frames.base_number}: a FANUC user frame is 1..{MAX_UFRAME}"
            )
        if not 1 <= problem.tool.number <= MAX_UTOOL:
            raise InputError(f"tool.number = {problem.tool.number}: a FANUC tool frame is 1..{MAX_UTOOL}")


def check_joint_lists(problem: Problem, n_joints: int, robot_name: str) -> None:
    """``home_deg`` and ``joint_acceleration_deg_s2`` have one value per joint of the robot."""
    for key in ("home_deg", "joint_acceleration_deg_s2"):
        values = getattr(problem.robot, key)
        if values is not None and len(values) != n_joints:
            raise InputError(
                f"robot.{key} has {len(values)} values but robot {robot_name!r} has {n_joints} joints"
            )


def check_home(problem: Problem, robot: Robot) -> None:
    """``robot.home_deg`` lies inside the joint limits and keeps the collision margins.

    Raises:
        InputError: a joint outside its limits, or the closest pair below its margin, named with
            the distance in mm (negative: the bodies overlap by that much).
    """
    import math

    import numpy as np

    home = problem.robot.home_deg
    if home is None:
        return
    spec = robot.spec
    q = np.radians(spec.from_controller(np.asarray(home, dtype=float)))  # the controller's -> the URDF's
    coupled = " (as the URDF counts it)" if spec.joint_coupling else ""
    for j, (v, lo, hi) in enumerate(zip(q, spec.lower, spec.upper, strict=True)):
        if not lo <= v <= hi:
            raise InputError(
                f"robot.home_deg: joint {j + 1} at {math.degrees(v):g} deg{coupled} is outside its limits "
                f"[{math.degrees(lo):.1f}, {math.degrees(hi):.1f}] deg"
            )
    if not problem.collision.enabled or not (problem.cell or problem.tool.collision):
        return
    from refine.collision import CollisionModel

    model = CollisionModel.for_problem(problem, robot)
    below = sorted(
        (c for c in model.contacts(q, max(model.margin_m, model.self_margin_m)) if c.clearance_m < 0.0),
        key=lambda c: c.clearance_m,
    )
    if below:
        c = below[0]
        margin = c.distance_m - c.clearance_m
        where = "inside" if c.distance_m < 0.0 else "closer than the margin to"
        others = "; ".join(f"{b.body} vs {b.other} at {b.distance_m * 1e3:.1f} mm" for b in below[1:4])
        raise InputError(
            f"robot.home_deg = [{', '.join(f'{float(v):g}' for v in home)}] deg puts {c.body} {where} {c.other}: distance {c.distance_m * 1e3:.1f} mm "
            f"(margin {margin * 1e3:g} mm)"
            + (f"; also {others}" if others else "")
            + "; every motion of the program starts and ends at home: choose a home clear of the cell"
        )


def planned_outputs(problem: Problem, programs: tuple[str, ...], report: bool = True) -> tuple[str, ...]:
    """Every file name a run of ``problem`` may write (the writers' naming rules)."""
    stem = problem.file_stem
    mp = problem.multipass
    passes = [(1, 1)]
    if mp is not None and mp.layers > 1:
        passes = [(k, i) for k, row in enumerate(mp.lateral_offsets_m, 1) for i in range(1, len(row) + 1)]
    names = ["result.json", f"{stem}.aml", "motions.csv"]
    names += ["trajectory.csv"] if len(passes) == 1 else [f"trajectory_L{k}P{i}.csv" for k, i in passes]
    if report:
        names.append("report.html")
    for kind in programs:
        if kind == "rapid":
            names += [f"{stem}.mod"] if len(passes) == 1 else [f"{stem}_L{k}P{i}.mod" for k, i in passes]
        elif kind == "krl":
            prog = identifier(stem, "prog", 24)
            names += [f"{prog}.src", f"{prog}.dat"]
        elif kind == "urscript":
            names.append(f"{stem}.script")
        elif kind == "tp":
            from refine.export.tp import tp_file_name

            names.append(tp_file_name(stem))
        elif kind == "inform":
            from refine.export.inform import inform_file_name

            names.append(inform_file_name(stem))
        elif kind == "sunrise":
            from refine.export.sunrise import class_name

            names.append(f"{class_name(problem.name)}.java")
    return tuple(names)


def check_output_dir(problem: Problem, out_dir: Path, outputs: tuple[str, ...]) -> Path:
    """The output folder is usable and no output file would replace an input file.

    Returns:
        ``out_dir`` resolved.

    Raises:
        InputError: ``out_dir`` is a file, lies under a file, cannot be created or written, or an
            output name would land on one of the problem's input files.
    """
    out = Path(out_dir).resolve()
    probe = out
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(
            f"{option('--out', 'out_dir')} {str(out_dir)!r}: {probe} is a file, not a folder",
            key="out_dir",
            value=str(out_dir),
            expected="a folder refine may write in",
        )
    if not os.access(probe, os.W_OK | os.X_OK):
        raise InputError(
            f"{option('--out', 'out_dir')} {str(out_dir)!r}: no permission to write in {probe}",
            key="out_dir",
            value=str(out_dir),
            expected="a folder refine may write in",
        )
    inputs = {p.resolve() for p in (*problem.input_files, problem.root / "problem.toml")}
    for name in outputs:
        target = out / name
        if target.resolve() in inputs or (target.is_symlink() or (target.exists() and not target.is_file())):
            raise InputError(
                f"{option('--out', 'out_dir')} {str(out_dir)!r}: the output {name!r} would replace {target.resolve()}, which is "
                "an input of the problem or not a regular file; choose another output folder"
            )
    return out


def preflight(
    problem: Problem,
    out_dir: Path | None = None,
    programs: tuple[str, ...] | None = None,
    *,
    report: bool = True,
    robot: Robot | None = None,
) -> Preflight:
    """Run every check that needs the robot or the output folder (module docstring).

    Args:
        problem: the loaded problem.
        out_dir: the output folder, or None to skip the folder checks.
        programs: program formats overriding ``[output] programs``.
        report: whether ``report.html`` will be written.
        robot: the robot, when the caller holds it; None to load ``problem.robot`` from the registry.

    Raises:
        InputError: the first failed check, naming the key or the option.
    """
    from refine.robot.registry import robot_for

    where = f"{problem.source}: " if problem.source is not None else ""
    if robot is None:
        robot = robot_for(problem.robot)
    if programs is None:
        programs = problem.output.programs
        if programs is None:
            programs = (robot.spec.default_program,)
    else:
        where = f"{option('--programs', 'programs')}: "
    try:
        if problem.tool.stationary:
            from refine.settings.stationary import check_stationary_programs

            check_stationary_programs(programs)
        check_programs(problem, robot.spec, programs)
        if "sunrise" in programs and robot.nq != 7:
            raise InputError(
                f"program format 'sunrise' is for the seven-axis KUKA LBR, but robot {robot.spec.name!r} has "
                f"{robot.nq} axes; use krl"
            )
        check_arm_programs(problem, robot, programs)
    except InputError as e:
        raise InputError(f"{where}{e}", key=e.key, value=e.value, expected=e.expected, file=e.file) from e
    try:
        check_joint_lists(problem, robot.nq, robot.spec.name)
        check_home(problem, robot)
    except InputError as e:
        raise InputError(f"{problem.source}: {e}" if problem.source else str(e)) from e
    outputs = planned_outputs(problem, programs, report)
    out = None if out_dir is None else check_output_dir(problem, out_dir, outputs)
    return Preflight(programs, out, outputs)
