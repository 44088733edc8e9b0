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


def run(args: argparse.Namespace) -> int:
    """Run ``refine calibrate``; returns the exit status (errors raise RefineError)."""
    handler = {"pivot": _pivot, "receiver": _receiver}[args.kind]
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
