"""The ``[calibration]`` table: each frame's standard deviations.

The ``[calibration]`` table: each frame's standard deviations (translation per axis [m], rotation
per axis [deg]) that :mod:`refine.calibrate.cost` propagates to the path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from refine.errors import InputError

#: The frames whose uncertainty can be given, in the order they are reported.
FRAMES = ("base_in_world", "tcp_in_flange", "cad_in_world", "source_in_world", "sensor_in_tcp")


@dataclass(frozen=True)
class FrameUncertainty:
    """Standard deviations of one frame's error, per axis of the frame.

    Attributes:
        xyz_m: translation, 1 sigma per axis [m], shape (3,).
        rpy_deg: rotation (rotation-vector components), 1 sigma per axis [deg], shape (3,).
    """

    xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class CalibrationSettings:
    """``[calibration]``: the frames' uncertainty and the Monte Carlo settings.

    Attributes:
        frames: uncertainty by frame name (a subset of :data:`FRAMES`).
        samples: Monte Carlo samples per frame.
        seed: seed of the random errors.
    """

    frames: dict[str, FrameUncertainty]
    samples: int = 1000
    seed: int = 0

    def __post_init__(self) -> None:
        if not 10 <= self.samples <= 100_000:
            raise InputError(f"calibration.samples must be 10 to 100000, got {self.samples}")


def _sigmas(value: Any, key: str) -> tuple[float, float, float]:
    values = value if isinstance(value, list) else [value, value, value]
    if len(values) != 3 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        raise InputError(f"{key} must be a number or a list of 3 numbers, got {value!r}")
    if not all(math.isfinite(v) and v >= 0.0 for v in values):
        raise InputError(f"{key} must be finite and >= 0, got {value!r}")
    return (float(values[0]), float(values[1]), float(values[2]))


def calibration_settings(table: dict[str, Any]) -> CalibrationSettings:
    """Read a ``[calibration]`` table (keys: the frames of :data:`FRAMES`, ``samples``, ``seed``).

    Each frame is ``{ xyz_m = sigma or [sx, sy, sz], rpy_deg = sigma or [sx, sy, sz] }``.

    Raises:
        InputError: an unknown key (listing the allowed ones) or a bad value.
    """
    allowed = {*FRAMES, "samples", "seed"}
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise InputError(
            f"[calibration] unknown key(s) {', '.join(map(repr, unknown))}; allowed: {', '.join(sorted(allowed))}"
        )
    frames = {}
    for name in FRAMES:
        if name not in table:
            continue
        t = table[name]
        if not isinstance(t, dict) or not set(t) <= {f.name for f in fields(FrameUncertainty)}:
            raise InputError(
                f"calibration.{name} must be a table {{ xyz_m = [m], rpy_deg = [deg] }}, got {t!r}"
            )
        frames[name] = FrameUncertainty(
            xyz_m=_sigmas(t.get("xyz_m", 0.0), f"calibration.{name}.xyz_m"),
            rpy_deg=_sigmas(t.get("rpy_deg", 0.0), f"calibration.{name}.rpy_deg"),
        )
    for key in ("samples", "seed"):
        if key in table and (isinstance(table[key], bool) or not isinstance(table[key], int)):
            raise InputError(f"calibration.{key} must be an integer, got {table[key]!r}")
    return CalibrationSettings(
        frames=frames, samples=int(table.get("samples", 1000)), seed=int(table.get("seed", 0))
    )
