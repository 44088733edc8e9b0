"""``refine calibrate KIND ...``: measure a problem's frames from measurement files.

Each kind prints a summary with the residuals (or, with ``--json``, one JSON object) and a
problem-file snippet; ``--write PROBLEM`` puts the result into that problem file instead.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from refine.calibrate.result import Calibration
from refine.errors import InputError


def _log_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", type=Path, help="tracker log")
    p.add_argument(
        "--format",
        default="liberty_ascii",
        choices=("liberty_ascii", "liberty_binary", "csv"),
        help="log format",
    )
    p.add_argument(
        "--units",
        default=None,
        help="position unit of the log: in or cm (Liberty; default: the file's '# units:' line, else in), "
        "m, mm, cm or in (CSV; default m)",
    )
    p.add_argument("--station", type=int, default=1, help="tracker station (sensor) number (default 1)")
    p.add_argument("--rate-hz", type=float, default=240.0, help="sample rate of logs without times [Hz]")


def _output_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary")
    p.add_argument(
        "--write", type=Path, default=None, metavar="PROBLEM", help="update this problem file in place"
    )
    p.add_argument(
        "--no-z-model", action="store_true", help="do not estimate the tracker's distance-dependent z error"
    )


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``calibrate`` and its kinds to the subcommands of ``refine``."""
    cal = sub.add_parser("calibrate", help="measure a frame of a problem from measurement files")
    kinds = cal.add_subparsers(dest="kind", required=True)

    pivot = kinds.add_parser("pivot", help="hand tool tip in the sensor frame, from a pivoting swing")
    _log_options(pivot)
    _output_options(pivot)
    pivot.add_argument(
        "--min-swing-deg", type=float, default=None, help="least RMS swing about two axes [deg]"
    )
    pivot.add_argument(
        "--problem", type=Path, default=None, help="take the tool's sensor orientation from this problem"
    )

    rec = kinds.add_parser("receiver", help="source_in_world from the tool tip resting on known points")
    _log_options(rec)
    rec.add_argument(
        "points", type=Path, help="CSV of the touched points, x,y,z [m] in the world frame, in order"
    )
    _output_options(rec)
    rec.add_argument("--tip-in-sensor", type=float, nargs=3, metavar=("X", "Y", "Z"), help="tip offset [m]")
    rec.add_argument(
        "--problem", type=Path, default=None, help="take the tip offset from this problem's tool"
    )
    rec.add_argument(
        "--min-dwell-s", type=float, default=0.5, help="least rest on each point [s] (default 0.5)"
    )
    rec.add_argument("--threshold-m", type=float, default=None, help="largest residual of a good point [m]")

    trace = kinds.add_parser(
        "receiver-path", help="source_in_world from a demonstration traced along the problem's CAD path (ICP)"
    )
    _log_options(trace)
    _output_options(trace)
    trace.add_argument(
        "--problem",
        type=Path,
        required=True,
        help="the problem: its CAD path, its tool's tip and its source_in_world as the first guess",
    )
    trace.add_argument(
        "--max-guess-offset-m",
        type=float,
        default=0.2,
        help="farthest the registration may lie from the problem's source_in_world [m] (default 0.2)",
    )
    trace.add_argument(
        "--max-guess-turn-deg",
        type=float,
        default=30.0,
        help="largest turn between the registration and the problem's source_in_world [deg] (default 30)",
    )

    tcp = kinds.add_parser("tcp", help="tcp_in_flange by the four-point (or six-point) method")
    tcp.add_argument(
        "readings", type=Path, help="CSV of robot readings: j1..jn [deg] or flange poses x,y,z,qw,qx,qy,qz"
    )
    _robot_options(tcp)
    tcp.add_argument(
        "--six-point", action="store_true", help="the last two readings are the +z and +x axis readings"
    )

    work = kinds.add_parser("workpiece", help="cad_in_world from the robot's TCP touched onto CAD points")
    work.add_argument(
        "readings",
        type=Path,
        help="CSV of robot readings: j1..jn [deg] or TCP poses x,y,z,qw,qx,qy,qz (base frame)",
    )
    work.add_argument(
        "points", type=Path, help="CSV of the touched points, x,y,z [m] in the CAD frame, in order"
    )
    _robot_options(work)
    work.add_argument(
        "--tcp-in-flange",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="TCP offset [m] (else the problem's)",
    )

    cost = kinds.add_parser(
        "cost", help="propagate the [calibration] standard deviations of a problem's frames to its TCP path"
    )
    cost.add_argument(
        "problem", type=Path, help="problem folder or its problem.toml, with a [calibration] table"
    )
    cost.add_argument(
        "--trajectory",
        type=Path,
        default=None,
        help="trajectory.csv of a run: its TCP poses are the path (default: the fused CAD path and demonstration)",
    )
    cost.add_argument(
        "--truth",
        type=Path,
        default=None,
        help="a problem holding the true frames (a simulation's): also report the error the actual "
        "calibration error causes",
    )
    cost.add_argument("--json", action="store_true", help="print one JSON object instead of the table")


def _robot_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", default=None, help="robot model of the registry (else the problem's)")
    p.add_argument(
        "--problem", type=Path, default=None, help="take the robot, its base and its tool from this problem"
    )
    p.add_argument(
        "--units", default="m", choices=("m", "mm"), help="position unit of pose readings (default m)"
    )
    p.add_argument("--threshold-m", type=float, default=None, help="largest residual of a good reading [m]")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary")
    p.add_argument(
        "--write", type=Path, default=None, metavar="PROBLEM", help="update this problem file in place"
    )


def run(args: argparse.Namespace) -> int:
    """Run ``refine calibrate``; returns the exit status (errors raise RefineError)."""
    if args.kind == "cost":
        return _cost(args)
    handler = {
        "pivot": _pivot,
        "receiver": _receiver,
        "receiver-path": _receiver_path,
        "tcp": _tcp,
        "workpiece": _workpiece,
    }[args.kind]
    cal, table, key, T, comment = handler(args)
    if args.write is not None:
        from refine.calibrate.files import update_problem

        written = update_problem(args.write, table, key, T)
    if args.json:
        print(json.dumps(cal.as_dict(), indent=2))
    else:
        print("\n".join(summary_lines(cal)))
        if args.write is not None:
            print(f"written      [{table}] {key} into {written}")
        else:
            from refine.calibrate.files import snippet

            print("\n" + snippet(table, key, T, comment), end="")
    return 0


def summary_lines(cal: Calibration) -> list[str]:
    """Human-readable lines: the values, the residual figures and the rejected measurements."""
    from refine.calibrate.files import pose_line

    lines = [f"calibration  {cal.kind}"]
    for name, v in cal.values.items():
        v = np.asarray(v)
        if v.shape == (4, 4):
            lines.append(f"{name:12s} {pose_line('', v)[3:]}")
        else:
            lines.append(f"{name:12s} [{', '.join(f'{x * 1000:.2f}' for x in v)}] mm")
    lines.append(f"rms residual {cal.rms_residual_m * 1000:.3f} mm, max {cal.max_residual_m * 1000:.3f} mm")
    if cal.labels:
        for k, (label, r) in enumerate(zip(cal.labels, cal.residuals_m, strict=True)):
            flag = "  REJECTED" if k in cal.outliers else ""
            lines.append(f"  {label:10s} residual {r * 1000:8.3f} mm{flag}")
    else:
        lines.append(f"rejected     {len(cal.outliers)} of {len(cal.residuals_m)} measurements")
    for name, value in cal.figures.items():
        lines.append(f"  {name} = {value:.6g}")
    return lines


def _read_log(args: argparse.Namespace):  # noqa: ANN202 - TrackerLog
    from refine.calibrate.files import read_log

    return read_log(args.log, args.format, args.units, args.station, args.rate_hz)


def _pivot(args: argparse.Namespace) -> tuple[Calibration, str, str, np.ndarray, str]:
    from refine.calibrate.pivot import MIN_SWING_DEG, solve_pivot
    from refine.calibrate.receiver import check_tracker_range
    from refine.frames import invert_transform, make_transform

    log = _read_log(args)
    check_tracker_range(log)
    cal = solve_pivot(
        log.positions,
        log.rotations,
        fit_z=not args.no_z_model,
        min_swing_deg=MIN_SWING_DEG if args.min_swing_deg is None else args.min_swing_deg,
    )
    R_E_TCP = np.eye(3)
    comment = (
        "tip from a pivot calibration; the TCP orientation in the sensor frame is not measured (identity)"
    )
    source = args.problem or args.write
    if source is not None:
        from refine.problem import load_problem

        R_E_TCP = load_problem(source).tool.sensor_in_tcp[:3, :3].T
        comment = "tip from a pivot calibration; TCP orientation kept from the problem"
    T_E_TCP = make_transform(R_E_TCP, cal.values["tip_in_sensor_m"])
    return cal, "tool", "sensor_in_tcp", invert_transform(T_E_TCP), comment


def _tip(args: argparse.Namespace) -> np.ndarray:
    from refine.frames import invert_transform

    if args.tip_in_sensor is not None:
        tip = np.asarray(args.tip_in_sensor, dtype=float)
        if np.linalg.norm(tip) > 1.0:
            raise InputError(
                f"--tip-in-sensor {tip.tolist()} is {np.linalg.norm(tip):.1f} m long: give metres"
            )
        return tip
    if args.problem is None:
        raise InputError("give the tool's tip offset: --tip-in-sensor X Y Z [m] or --problem DIR")
    from refine.problem import load_problem

    return invert_transform(load_problem(args.problem).tool.sensor_in_tcp)[:3, 3]


def _receiver(args: argparse.Namespace) -> tuple[Calibration, str, str, np.ndarray, str]:
    from refine.calibrate.files import read_points_csv
    from refine.calibrate.receiver import RECEIVER_THRESHOLD_M, register_receiver_from_log

    tip = _tip(args)
    points, names = read_points_csv(args.points)
    log = _read_log(args)
    cal = register_receiver_from_log(
        log,
        tip,
        points,
        min_dwell_s=args.min_dwell_s,
        fit_z=not args.no_z_model,
        threshold_m=RECEIVER_THRESHOLD_M if args.threshold_m is None else args.threshold_m,
        labels=names,
    )
    T = cal.values["source_in_world"]
    return cal, "frames", "source_in_world", T, f"receiver registered on {len(points)} touched points"


def _receiver_path(args: argparse.Namespace) -> tuple[Calibration, str, str, np.ndarray, str]:
    from refine.cad import read_cad_path
    from refine.calibrate.receiver_path import register_receiver_to_path
    from refine.frames import invert_transform
    from refine.problem import load_problem

    problem = load_problem(args.problem)
    cad = read_cad_path(problem.cad, problem.frames.cad_in_world)
    tip = invert_transform(problem.tool.sensor_in_tcp)[:3, 3]
    cal = register_receiver_to_path(
        _read_log(args),
        tip,
        cad.positions,
        problem.frames.source_in_world,
        fit_z=not args.no_z_model,
        max_guess_offset_m=args.max_guess_offset_m,
        max_guess_turn_deg=args.max_guess_turn_deg,
    )
    T = cal.values["source_in_world"]
    return cal, "frames", "source_in_world", T, "receiver registered on a trace along the CAD path"


def _robot_and_problem(args: argparse.Namespace):  # noqa: ANN202 - (Robot | None, Problem | None)
    from refine.robot.registry import load_robot

    problem = None
    if args.problem is not None:
        from refine.problem import load_problem

        problem = load_problem(args.problem)
    model = args.robot or (problem.robot.model if problem is not None else None)
    return (load_robot(model) if model else None), problem


def _flange_or_tcp_poses(args: argparse.Namespace) -> tuple[str, np.ndarray, object]:
    """("joints" | "poses", poses (N, 4, 4) [m], problem); joints go through the robot's FK."""
    from refine.calibrate.files import read_robot_readings

    kind, data = read_robot_readings(args.readings, args.units)
    robot, problem = _robot_and_problem(args)
    if kind == "poses":
        return kind, data, problem
    if robot is None:
        raise InputError(
            f"{args.readings}: joint readings need the robot model: --robot MODEL or --problem DIR"
        )
    if data.shape[1] != robot.nq:
        raise InputError(
            f"{args.readings}: {data.shape[1]} joint columns but robot {robot.spec.name!r} has {robot.nq} joints"
        )
    return kind, robot.fk_many(data), problem


def _tcp(args: argparse.Namespace) -> tuple[Calibration, str, str, np.ndarray, str]:
    from refine.calibrate.robot_touch import ROBOT_THRESHOLD_M, calibrate_tcp

    _, flange, problem = _flange_or_tcp_poses(args)
    threshold = ROBOT_THRESHOLD_M if args.threshold_m is None else args.threshold_m
    cal = calibrate_tcp(flange, six_point=args.six_point, threshold_m=threshold)
    T = cal.values["tcp_in_flange"].copy()
    comment = "tcp_in_flange by the six-point method"
    if not args.six_point:
        source = problem
        if source is None and args.write is not None:
            from refine.problem import load_problem

            source = load_problem(args.write)
        if source is not None:
            T[:3, :3] = source.tool.tcp_in_flange[:3, :3]
            comment = "TCP position by the four-point method; orientation kept from the problem"
        else:
            comment = "TCP position by the four-point method; orientation not measured (identity)"
    return cal, "tool", "tcp_in_flange", T, comment


def _workpiece(args: argparse.Namespace) -> tuple[Calibration, str, str, np.ndarray, str]:
    from refine.calibrate.files import read_points_csv
    from refine.calibrate.robot_touch import ROBOT_THRESHOLD_M, register_workpiece, tcp_positions_world
    from refine.frames import make_transform

    kind, poses, problem = _flange_or_tcp_poses(args)
    points, names = read_points_csv(args.points)
    base = problem.robot.base_in_world if problem is not None else np.eye(4)
    if kind == "poses":
        tcp = np.eye(4)  # the controller reports the TCP itself
    elif args.tcp_in_flange is not None:
        tcp = make_transform(None, np.asarray(args.tcp_in_flange, dtype=float))
    elif problem is not None:
        tcp = problem.tool.tcp_in_flange
    else:
        raise InputError("joint readings need the TCP: --tcp-in-flange X Y Z [m] or --problem DIR")
    threshold = ROBOT_THRESHOLD_M if args.threshold_m is None else args.threshold_m
    cal = register_workpiece(tcp_positions_world(poses, base, tcp), points, threshold, labels=names)
    T = cal.values["cad_in_world"]
    return cal, "frames", "cad_in_world", T, f"workpiece registered on {len(points)} robot touches"


def _cost(args: argparse.Namespace) -> int:
    from refine.calibrate.cost import calibration_cost, nominal_frames, tcp_poses_from_trajectory
    from refine.frames import make_transform
    from refine.problem import load_problem

    problem = load_problem(args.problem)
    if problem.calibration is None:
        raise InputError(
            f"{problem.source or args.problem}: no [calibration] table; give each frame's standard deviations, "
            f"e.g. cad_in_world = {{ xyz_m = 0.0005, rpy_deg = 0.05 }}"
        )
    if args.trajectory is not None:
        poses = tcp_poses_from_trajectory(args.trajectory)
    else:
        from refine.run.stages import fused_path

        fused = fused_path(problem)
        poses = make_transform(fused.rotations, fused.positions)
    costs = calibration_cost(poses, nominal_frames(problem), problem.calibration)
    if args.truth is not None:
        from refine.calibrate.cost import PathCost, deltas_between, path_errors
        from refine.settings import FRAMES

        deltas = deltas_between(nominal_frames(problem), nominal_frames(load_problem(args.truth)))
        for name in FRAMES:
            costs.append(
                PathCost.from_errors(
                    f"actual {name}", *path_errors(poses, nominal_frames(problem), {name: deltas[name]})
                )
            )
        costs.append(PathCost.from_errors("actual all", *path_errors(poses, nominal_frames(problem), deltas)))
    if args.json:
        print(json.dumps({"waypoints": len(poses), "frames": [c.__dict__ for c in costs]}, indent=2))
        return 0
    from refine.calibrate.cost import cost_lines

    print("\n".join(cost_lines(costs, len(poses), problem.calibration.samples)))
    if args.truth is not None:
        print("actual: the error the frames' difference from the truth causes (worst = the largest)")
    return 0
