"""Calibration in the app: measurement files from the problem folder fitted, shown, offered as a change.

The page names each file by its path relative to the problem folder; :func:`inside_folder` refuses
any path that leaves it (``..``, an absolute path, a symbolic link out of it). Each kind is the fit
``refine calibrate KIND`` runs (:mod:`refine.calibrate`), on the problem as edited in the app (its
tool, robot, base and frames, changes not yet saved included):

========== ============================================================ ==========================
kind       files                                                        frame it gives
========== ============================================================ ==========================
pivot      a tracker log of the tip swung about a divot                 ``tool.sensor_in_tcp``
receiver   a tracker log of the tip resting on points, and their        ``frames.source_in_world``
           world coordinates (CSV ``name,x,y,z`` [m])
trace      a tracker log of the tip traced along the CAD path           ``frames.source_in_world``
tcp        robot readings with the tip on one point (CSV of joints      ``tool.tcp_in_flange``
           [deg] or flange poses); ``six_point`` for the orientation
workpiece  robot readings with the TCP on points of the part, and the   ``frames.cad_in_world``
           points in the CAD frame (CSV ``name,x,y,z`` [m])
========== ============================================================ ==========================

The answer holds the fit's lines (:func:`refine.calibrate.cli.summary_lines`), every residual
with the rejected ones marked (and the point names where there are points), and the change the
page sends when the user accepts it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from refine.calibrate.cli import summary_lines
from refine.calibrate.files import LOG_FORMATS, read_log, read_points_csv, read_robot_readings
from refine.calibrate.result import Calibration
from refine.errors import InputError
from refine.frames import invert_transform, make_transform
from refine.paths import TrackerLog
from refine.problem import Problem
from refine.serve.edits import pose_table

MIN_DWELL_S = 0.5
"""Least rest of the tip on each touched point of a receiver log [s] (``refine calibrate receiver``'s default)."""


def inside_folder(folder: Path, name: Any, what: str = "a calibration file") -> Path:
    """The file ``name`` (relative to ``folder``), refused unless it is a file inside the folder."""
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"{what} must be named by its path in the problem folder, got {name!r}")
    relative = Path(name)
    root = folder.resolve()
    if relative.is_absolute() or ".." in relative.parts:
        raise InputError(f"{what} {name!r}: not a path inside the problem folder {root}")
    path = (root / relative).resolve()
    if root not in path.parents:
        raise InputError(f"{what} {name!r}: leads out of the problem folder {root} (a symbolic link)")
    if not path.is_file():
        raise InputError(f"{what} {name!r}: no such file in the problem folder {root}")
    return path


def _number(request: dict[str, Any], key: str, default: float, low: float, high: float, unit: str) -> float:
    value = request.get(key, default)
    if value is None or value == "":
        return default
    if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
        raise InputError(f"{key} must be a number in [{low:g}, {high:g}] {unit}, got {value!r}")
    return float(value)


def _log(problem: Problem, request: dict[str, Any]) -> TrackerLog:
    fmt = request.get("format", "liberty_ascii")
    if fmt not in LOG_FORMATS:
        raise InputError(f"calibration format {fmt!r}: one of {', '.join(LOG_FORMATS)}")
    units = request.get("units") or None
    if units is not None and not isinstance(units, str):
        raise InputError(f"units must be a unit name (in, cm, m, mm), got {units!r}")
    rate = _number(request, "rate_hz", 240.0, 1.0, 10_000.0, "Hz")
    station = int(_number(request, "station", 1, 1, 16, "(sensor number)"))
    path = inside_folder(problem.root, request.get("file"), "the tracker log")
    return read_log(path, fmt, units, station, rate)


def _points(problem: Problem, request: dict[str, Any]) -> tuple[np.ndarray, tuple[str, ...]]:
    return read_points_csv(inside_folder(problem.root, request.get("points"), "the points file"))


def _tip(problem: Problem) -> np.ndarray:
    """The tool's tip in the sensor frame [m], from the problem's ``sensor_in_tcp``."""
    return invert_transform(problem.tool.sensor_in_tcp)[:3, 3]


def _flange_poses(problem: Problem, request: dict[str, Any]) -> tuple[str, np.ndarray]:
    """("joints" | "poses", the poses (N, 4, 4) [m]) of the readings file; joints through the FK."""
    from refine.robot.registry import robot_for

    units = request.get("units") or "m"
    if units not in ("m", "mm"):
        raise InputError(f"units of pose readings must be m or mm, got {units!r}")
    path = inside_folder(problem.root, request.get("readings"), "the robot readings")
    kind, data = read_robot_readings(path, units)
    if kind == "poses":
        return kind, data
    robot = robot_for(problem.robot)
    if data.shape[1] != robot.nq:
        raise InputError(
            f"{path.name}: {data.shape[1]} joint columns but robot {robot.spec.name!r} has {robot.nq} joints"
        )
    return kind, robot.fk_many(np.asarray(data, dtype=float))


def _pivot(problem: Problem, request: dict[str, Any]) -> tuple[Calibration, str, np.ndarray]:
    from refine.calibrate.pivot import solve_pivot
    from refine.calibrate.receiver import check_tracker_range

    log = _log(problem, request)
    check_tracker_range(log)
    cal = solve_pivot(log.positions, log.rotations)
    R_E_TCP = problem.tool.sensor_in_tcp[:3, :3].T  # the TCP's orientation is not measured: kept
    return cal, "tool.sensor_in_tcp", invert_transform(make_transform(R_E_TCP, cal.values["tip_in_sensor_m"]))


def _receiver(problem: Problem, request: dict[str, Any]) -> tuple[Calibration, str, np.ndarray]:
    from refine.calibrate.receiver import register_receiver_from_log

    points, names = _points(problem, request)
    cal = register_receiver_from_log(
        _log(problem, request),
        _tip(problem),
        points,
        min_dwell_s=_number(request, "min_dwell_s", MIN_DWELL_S, 0.05, 60.0, "s"),
        labels=names,
    )
    return cal, "frames.source_in_world", cal.values["source_in_world"]


def _trace(problem: Problem, request: dict[str, Any]) -> tuple[Calibration, str, np.ndarray]:
    from refine.cad import read_cad_path
    from refine.calibrate.receiver_path import register_receiver_to_path

    if problem.cad is None:
        raise InputError("a trace along the CAD path needs the problem's [cad] path")
    cad = read_cad_path(problem.cad, problem.frames.cad_in_world)
    cal = register_receiver_to_path(
        _log(problem, request), _tip(problem), cad.positions, problem.frames.source_in_world
    )
    return cal, "frames.source_in_world", cal.values["source_in_world"]


def _tcp(problem: Problem, request: dict[str, Any]) -> tuple[Calibration, str, np.ndarray]:
    from refine.calibrate.robot_touch import calibrate_tcp

    six = request.get("six_point", False)
    if not isinstance(six, bool):
        raise InputError(f"six_point must be true or false, got {six!r}")
    _, flange = _flange_poses(problem, request)
    cal = calibrate_tcp(flange, six_point=six)
    T = np.array(cal.values["tcp_in_flange"], dtype=float)
    if not six:  # four points measure the position only: the orientation is kept from the problem
        T[:3, :3] = problem.tool.tcp_in_flange[:3, :3]
    return cal, "tool.tcp_in_flange", T


def _workpiece(problem: Problem, request: dict[str, Any]) -> tuple[Calibration, str, np.ndarray]:
    from refine.calibrate.robot_touch import register_workpiece, tcp_positions_world

    kind, poses = _flange_poses(problem, request)
    points, names = _points(problem, request)
    tcp = np.eye(4) if kind == "poses" else problem.tool.tcp_in_flange  # a controller's poses are the TCP's
    touched = tcp_positions_world(poses, problem.robot.base_in_world, tcp)
    cal = register_workpiece(touched, points, labels=names)
    return cal, "frames.cad_in_world", cal.values["cad_in_world"]


KINDS: dict[str, Callable[[Problem, dict[str, Any]], tuple[Calibration, str, np.ndarray]]] = {
    "pivot": _pivot,
    "receiver": _receiver,
    "trace": _trace,
    "tcp": _tcp,
    "workpiece": _workpiece,
}
"""The calibrations the app fits (module docstring), each giving (fit, the key it changes, its pose)."""


def fit(problem: Problem, request: dict[str, Any]) -> dict[str, Any]:
    """Fit the calibration ``request`` asks for (``kind`` and its files, module docstring).

    Raises:
        InputError: an unknown kind or format, a file outside the problem folder, a bad number, or
            what the readers and the fit refuse (their messages, with units).
    """
    kind = request.get("kind", "pivot")
    if kind not in KINDS:
        raise InputError(f"calibration kind {kind!r}: the app fits {', '.join(KINDS)}")
    cal, key, T = KINDS[kind](problem, request)
    residuals = np.asarray(cal.residuals_m) * 1e3
    return {
        "kind": kind,
        "key": key,
        "lines": summary_lines(cal),
        "values": {name: np.asarray(v).round(9).tolist() for name, v in cal.values.items()},
        "rms_residual_mm": round(cal.rms_residual_m * 1e3, 4),
        "max_residual_mm": round(cal.max_residual_m * 1e3, 4),
        "residuals_mm": residuals.round(4).tolist(),
        "labels": list(cal.labels),
        "rejected": list(cal.outliers),
        "change": {key: pose_table(T)},
    }
