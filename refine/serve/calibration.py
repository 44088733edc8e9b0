"""Calibration in the app: a pivot log from the problem folder fitted, shown, and offered as a change.

The page names a log by its path relative to the problem folder; :func:`inside_folder` refuses any
path that leaves it (``..``, an absolute path, a symbolic link out of it). The fit is
:func:`refine.calibrate.pivot.solve_pivot` as ``refine calibrate pivot --problem`` runs it: the tip
in the sensor frame is measured, the TCP's orientation in the sensor frame is kept from the problem.
The answer holds the fit's lines (:func:`refine.calibrate.cli.summary_lines`), every sample's
residual with the rejected ones marked, and the change ``tool.sensor_in_tcp`` the page sends when
the user accepts it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from refine.calibrate.cli import summary_lines
from refine.calibrate.files import LOG_FORMATS, read_log
from refine.calibrate.pivot import solve_pivot
from refine.calibrate.receiver import check_tracker_range
from refine.errors import InputError
from refine.frames import invert_transform, make_transform
from refine.problem import Problem
from refine.serve.edits import pose_table

KINDS = ("pivot",)
"""The calibrations the app fits."""


def inside_folder(folder: Path, name: Any) -> Path:
    """The file ``name`` (relative to ``folder``), refused unless it is a file inside the folder."""
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"a calibration file must be named by its path in the problem folder, got {name!r}")
    relative = Path(name)
    root = folder.resolve()
    if relative.is_absolute() or ".." in relative.parts:
        raise InputError(f"{name!r}: not a path inside the problem folder {root}")
    path = (root / relative).resolve()
    if root not in path.parents:
        raise InputError(f"{name!r}: leads out of the problem folder {root} (a symbolic link)")
    if not path.is_file():
        raise InputError(f"{name!r}: no such file in the problem folder {root}")
    return path


def fit(problem: Problem, request: dict[str, Any]) -> dict[str, Any]:
    """Fit the calibration ``request`` asks for (``kind``, ``file``, ``format``, ``units``, ``rate_hz``).

    Raises:
        InputError: an unknown kind or format, a file outside the problem folder, a bad rate, or
            what the reader and the fit refuse (their messages, with units).
    """
    kind = request.get("kind", "pivot")
    if kind not in KINDS:
        raise InputError(f"calibration kind {kind!r}: the app fits {', '.join(KINDS)}")
    fmt = request.get("format", "liberty_ascii")
    if fmt not in LOG_FORMATS:
        raise InputError(f"calibration format {fmt!r}: one of {', '.join(LOG_FORMATS)}")
    rate = request.get("rate_hz", 240.0)
    if isinstance(rate, bool) or not isinstance(rate, int | float) or not 1.0 <= rate <= 10_000.0:
        raise InputError(f"rate_hz must be a number in [1, 10000] Hz, got {rate!r}")
    units = request.get("units") or None
    if units is not None and not isinstance(units, str):
        raise InputError(f"units must be a unit name (in, cm, m, mm), got {units!r}")
    path = inside_folder(problem.root, request.get("file"))
    log = read_log(path, fmt, units, 1, float(rate))
    check_tracker_range(log)
    cal = solve_pivot(log.positions, log.rotations)
    R_E_TCP = problem.tool.sensor_in_tcp[:3, :3].T  # the TCP's orientation is not measured: kept
    sensor_in_tcp = invert_transform(make_transform(R_E_TCP, cal.values["tip_in_sensor_m"]))
    return {
        "kind": kind,
        "file": str(path.relative_to(problem.root.resolve())),
        "lines": summary_lines(cal),
        "tip_in_sensor_mm": (np.asarray(cal.values["tip_in_sensor_m"]) * 1e3).round(3).tolist(),
        "rms_residual_mm": round(cal.rms_residual_m * 1e3, 4),
        "max_residual_mm": round(cal.max_residual_m * 1e3, 4),
        "residuals_mm": (cal.residuals_m * 1e3).round(4).tolist(),
        "rejected": list(cal.outliers),
        "change": {"tool.sensor_in_tcp": pose_table(sensor_in_tcp)},
    }
