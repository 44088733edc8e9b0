"""Command line: ``refine run PROBLEM --out DIR``, ``refine check PROBLEM``, ``refine serve PROBLEM``, ``refine robots``."""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import os
import sys
import time
from pathlib import Path

from refine.interrupt import forget_completion, stoppable
from refine.run.check import add_safety_options, check_command


def _seconds_since_process_start() -> float | None:
    """Wall time since this process started [s] (Linux /proc), or None elsewhere."""
    try:
        fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        start_ticks = int(fields[19])
        uptime = float(Path("/proc/uptime").read_text().split()[0])
        return uptime - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


LAZY_COMMANDS = {
    "calibrate": ("refine.calibrate.cli", "measure a frame of a problem from measurement files"),
    "bench": ("refine.bench.cli", "benchmark refine against other methods on named suites"),
}
"""Subcommands whose modules take long to import (NumPy, SciPy), by name: the module whose
``add_parser`` adds them and their one-line help. Only the command being run imports its module;
for any other the parser holds a stand-in with the same help (``refine --help`` lists it)."""


def _command(argv: list[str] | None) -> str | None:
    """The subcommand named in ``argv`` (the first word not an option), or None."""
    words = sys.argv[1:] if argv is None else argv
    return next((w for w in words if not w.startswith("-")), None)


def _add_lazy(sub: argparse._SubParsersAction, name: str, chosen: str | None) -> None:
    module, help_text = LAZY_COMMANDS[name]
    if chosen == name:
        importlib.import_module(module).add_parser(sub)
    else:
        sub.add_parser(name, help=help_text, add_help=False).add_argument("rest", nargs=argparse.REMAINDER)


def _parser(argv: list[str] | None = None, *, every: bool = False) -> argparse.ArgumentParser:
    """The command line's parser; only the command in ``argv`` imports its module (all with ``every``)."""
    chosen = _command(argv)
    p = argparse.ArgumentParser(
        prog="refine", description="Refine a demonstrated robot path onto a CAD path."
    )
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-v info, -vv debug)")
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser(
        "run", help="solve a problem and write result.json, trajectory.csv, PathML and programs"
    )
    run.add_argument("problem", type=Path, help="problem folder or its problem.toml")
    run.add_argument("--out", type=Path, default=None, help="output folder (default: out/<problem name>)")
    run.add_argument(
        "--programs",
        default=None,
        help="comma-separated program formats overriding [output] programs (available: rapid)",
    )
    run.add_argument(
        "--urscript-mode",
        choices=("program", "script_node"),
        default=None,
        help="URScript as a program calling its function (default) or as a PolyScope Script node body",
    )
    run.add_argument("--json", action="store_true", help="print result.json instead of the summary")
    run.add_argument("--no-report", action="store_true", help="do not write report.html")
    check = sub.add_parser(
        "check", help="read every input and run every check of `run` without solving (exit 2 when run would)"
    )
    check.add_argument("problem", type=Path)
    check.add_argument("--out", type=Path, default=None, help="also check this output folder")
    check.add_argument("--programs", default=None, help="program formats to check, as for run")
    for parser in (run, check):
        add_safety_options(parser)
    robots = sub.add_parser("robots", help="list the robots of the registry, or import one")
    _add_import(robots.add_subparsers(dest="robots_command"))
    _add_lazy(sub, "calibrate", "calibrate" if every else chosen)
    from refine.run.batch import add_parser as add_batch

    add_batch(sub)
    _add_lazy(sub, "bench", "bench" if every else chosen)
    from refine.serve.cli import add_parser as add_serve

    add_serve(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``refine`` command; returns the exit status.

    Ctrl-C (SIGINT, or SIGTERM) before a run's new output set is in place exits with status 130
    and leaves the previous set; once the new set is in place the run ends as it would have, with
    its own status (0 ``ok``/``repaired``, 1 ``infeasible``): see :mod:`refine.interrupt`. As the
    ``refine`` program, signals are held back from the moment the command is done until the
    process ends, so a late Ctrl-C never turns into a traceback or a death by signal.
    """
    program = _is_program()
    forget_completion()
    try:
        try:
            status = _main(argv)
        finally:
            if program:
                from refine.interrupt import hold_signals

                hold_signals()
    except KeyboardInterrupt:
        status = _interrupted()
    except SystemError as e:
        from refine.control import ctrl_c_inside

        if not ctrl_c_inside(e):
            raise
        status = _interrupted()
    return _exit_now(status) if program else status


def _interrupted() -> int:
    """Say what an interrupt left in the output folder; the exit status (module ``main``)."""
    from refine.interrupt import completed_status

    done = completed_status()
    if done is not None:
        print(
            "refine: interrupted after the new outputs were complete; result.json describes them",
            file=sys.stderr,
        )
        return exit_status(done)
    print("refine: interrupted; the output folder keeps its previous complete set", file=sys.stderr)
    return 130


def _add_import(sub: argparse._SubParsersAction) -> None:
    """``refine robots import``: a registry folder from a ROS-Industrial support package."""
    p = sub.add_parser(
        "import",
        help="write a registry folder (URDF, convex link shapes, self-collision matrix, robot.toml, "
        "README) from a ROS-Industrial support package",
    )
    p.add_argument("package", type=Path, help="the support package's folder (holding its package.xml)")
    p.add_argument("--name", required=True, help="the registry name (lower-case letters, digits, _)")
    p.add_argument(
        "--xacro", default=None, help="the description, relative to the package (default: its only one)"
    )
    p.add_argument("--controller", required=True, help="controller family: abb, kuka, ur, fanuc, yaskawa")
    p.add_argument("--program", default=None, help="program format (default: the controller family's)")
    p.add_argument("--maker", default=None, help="manufacturer (default: the controller family's)")
    p.add_argument("--model", default=None, help="the maker's designation (default: the <robot name>)")
    p.add_argument("--flange-frame", default="tool0", help="the frame the tool is mounted on")
    p.add_argument(
        "--reach-m", type=float, default=None, help="the reach [m] (default: the wrist centre's from axis 1)"
    )
    p.add_argument(
        "--package",
        dest="packages",
        action="append",
        default=[],
        metavar="NAME=FOLDER",
        help="a ROS package's folder, when it is not beside the description (repeatable)",
    )
    p.add_argument(
        "--licence", type=Path, default=None, help="licence file to copy (default: the package's LICENSE)"
    )
    p.add_argument(
        "--samples", type=int, default=20000, help="random configurations for the self-collision matrix"
    )
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--registry", type=Path, default=None, help="the registry folder (default: robots/)")
    p.add_argument("--replace", action="store_true", help="write over an existing folder")
    p.add_argument(
        "--joint-coupling",
        default="auto",
        help="how the controller counts the joints: auto (a FANUC package's J23_factor), none, fanuc_j2_j3",
    )
    p.set_defaults(handler=_import_robot)


def _import_robot(args: argparse.Namespace) -> int:
    from refine.errors import InputError
    from refine.robot.importer import import_support_package
    from refine.robot.registry import robots_dir

    packages = {}
    for item in args.packages:
        name, sep, folder = item.partition("=")
        if not sep or not name or not folder:
            raise InputError(f"--package {item!r}: expected NAME=FOLDER")
        packages[name] = Path(folder)
    import_support_package(
        args.package,
        args.name,
        args.registry or robots_dir(),
        controller=args.controller,
        xacro=args.xacro,
        program=args.program,
        maker=args.maker,
        model=args.model,
        flange_frame=args.flange_frame,
        reach_m=args.reach_m,
        packages=packages,
        licence=args.licence,
        samples=args.samples,
        seed=args.seed,
        replace=args.replace,
        joint_coupling=args.joint_coupling,
    )
    return 0


def _main(argv: list[str] | None) -> int:
    args = _parser(argv).parse_args(argv)
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")

    from refine.errors import RefineError

    try:
        if getattr(args, "handler", None) is not None:  # subcommands that bring their own handler
            return args.handler(args)
        if args.command == "calibrate":
            from refine.calibrate.cli import run as run_calibrate

            return run_calibrate(args)
        if args.command == "bench":
            from refine.bench.cli import run as run_bench

            return run_bench(args)
        if args.command == "robots":
            from refine.robot.registry import available_robots, load_robot

            for name in available_robots():
                spec = load_robot(name).spec
                axes = len(spec.joint_names)
                print(f"{name:24s} {spec.maker}, {axes} axes, reach {spec.reach_m:.2f} m, urdf {spec.urdf}")
            return 0
        with stoppable():
            from refine.problem import load_problem

            problem = load_problem(args.problem, allow_outside=args.allow_outside)
            if args.command == "check":
                return check_command(args, problem)
            return _run(args, problem)
    except KeyboardInterrupt:
        return _interrupted()
    except RefineError as e:
        from refine.names import message_text

        print(f"refine: error: {message_text(e)}", file=sys.stderr)
        return 2


def _is_program() -> bool:
    """Whether this process is the ``refine`` program (not ``main`` called from Python)."""
    top = sys.modules.get("__main__")
    spec = getattr(top, "__spec__", None)
    return (spec is not None and spec.name == "refine.cli") or Path(
        getattr(top, "__file__", "") or ""
    ).name == "refine"


def _exit_now(status: int) -> int:
    """As the ``refine`` program, exit at once (tearing down CasADi and Pinocchio takes seconds).

    Nothing is left to finish: the output folder holds a complete set and no staging folder.
    When ``main`` is called from Python (tests, scripts), the status is returned instead.
    """
    if _is_program():
        sys.stdout.flush()
        sys.stderr.flush()
        logging.shutdown()
        os._exit(status)
    return status


def _run(args: argparse.Namespace, problem) -> int:  # noqa: ANN001 - Problem, imported lazily
    from refine.export.result_json import result_dict, write_timings
    from refine.run.result import summary_lines
    from refine.run.write import run

    out = args.out or Path("out") / problem.file_stem
    if args.urscript_mode:
        import dataclasses

        output = dataclasses.replace(problem.output, urscript_mode=args.urscript_mode)
        problem = dataclasses.replace(problem, output=output)
    from refine.run.preflight import parse_programs

    programs = parse_programs(args.programs, problem)
    t0 = time.perf_counter()
    result = run(
        problem, out, programs, report=not args.no_report, accept_frame_error=args.accept_frame_error
    )
    since_start = _seconds_since_process_start()
    result.timings_s["run"] = time.perf_counter() - t0
    result.timings_s["total"] = since_start if since_start is not None else result.timings_s["run"]
    write_timings(result.outputs["result"], result)  # again, now with the total time
    if args.json:
        print(json.dumps(result_dict(result), indent=2))
    else:
        print("\n".join(summary_lines(result)))
        print(f"outputs      {out}/: " + ", ".join(p.name for p in result.outputs.values()))
        if problem.calibration is not None:
            from refine.calibrate.cost import run_cost_lines

            print("\n".join(run_cost_lines(result)))
    return exit_status(result.status)


def exit_status(status: str) -> int:
    """The exit status of a run: 0 ``ok``/``repaired`` (executable), 1 ``infeasible``/``timeout``."""
    return 0 if status in ("ok", "repaired") else 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
