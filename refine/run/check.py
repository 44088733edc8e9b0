"""``refine check``: every reader and every check of ``refine run``, without solving or writing.

It fails (exit 2) exactly when ``run`` would fail on its input: it loads the problem, runs the
:mod:`refine.run.preflight` checks (programs, I/O names, joint lists, output folder), reads the CAD path
and the demonstration, runs the demonstration quality gate and the alignment, reads the cell's and
the tool's collision shapes and generates the passes of a multi-pass weld, and stops there.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from refine.problem import Problem


def add_safety_options(parser: argparse.ArgumentParser) -> None:
    """The options ``run`` and ``check`` share about what input to accept."""
    parser.add_argument(
        "--allow-outside",
        action="store_true",
        help="accept data files outside the problem folder (refused by default)",
    )
    parser.add_argument(
        "--accept-frame-error",
        action="store_true",
        help="go on when the tracker frame looks rotated or shifted against the CAD path (a warning "
        "in result.json instead of a stop)",
    )


def check_command(args: argparse.Namespace, problem: Problem) -> int:
    """Run every check on ``problem`` and print what was read; returns 0 (errors raise)."""
    from refine.robot.registry import robot_for
    from refine.run.preflight import parse_programs, preflight
    from refine.run.stages import constraint_sources, fused_path

    programs = parse_programs(args.programs, problem)
    robot = robot_for(problem.robot)  # the registry's robot or the URDF's, as ``run`` resolves it
    pre = preflight(problem, args.out, programs, robot=robot)
    fused = fused_path(problem, accept_frame_error=args.accept_frame_error)
    constraint_sources(problem, robot)  # reads the cell's and tool's meshes
    if problem.multipass is not None and problem.multipass.layers > 1:
        from refine.fuse.passes import generate_passes

        generate_passes(fused, problem.multipass)
    demo = "" if problem.demonstration is None else f", demonstration {problem.demonstration.file.name}"
    print(
        f"{problem.name}: problem file OK, inputs read and checked (robot {robot.spec.name}, CAD {problem.cad.file.name}{demo}, "
        f"{len(fused)} waypoints over {fused.s[-1]:.3f} m; programs {', '.join(pre.programs) or 'none'})"
    )
    return 0
