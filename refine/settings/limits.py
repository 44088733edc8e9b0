"""The settings of a problem file, one frozen, self-checking dataclass per table.

``refine.problem`` reads ``problem.toml`` into these; every key is documented in
``docs/problem-file.md``. Each ``__post_init__`` rejects a bad value with a message naming the table,
the key, the value and what is allowed.
"""

from __future__ import annotations

import math

import numpy as np

from refine.errors import InputError

Matrix4 = np.ndarray

CAD_FORMATS = ("csv", "dxf", "gcode", "mesh", "pathml", "toolpath")
DEMO_FORMATS = ("liberty_ascii", "liberty_binary", "csv")
PROGRAM_FORMATS = ("rapid", "krl", "urscript", "sunrise", "tp", "inform")
URSCRIPT_MODES = ("program", "script_node")
SHAPES = ("box", "cylinder", "sphere", "mesh")
CAUSES = ("reach", "joint limit", "joint wrap", "singularity", "collision", "self-collision", "orientation")

# ---- documented ranges that bound the work (docs/problem-file.md, "Ranges and limits")
MIN_SPACING_M = 1e-4
"""Finest waypoint spacing [m]: 0.1 mm, a tenth of the finest tracker resolution that matters."""
MIN_CHORD_TOLERANCE_M = 1e-5
"""Finest chord tolerance of the resampling [m]: 10 µm, ten times the CAD readers' flattening."""
MAX_HAMPEL_WINDOW = 50
"""Widest Hampel half-window [samples]: 0.2 s at 240 Hz; wider windows only blur real motion."""
MAX_SMOOTHING_S = 1.0
"""Heaviest demonstration smoothing [s]: more would flatten every bend of a hand-held path."""
MAX_WAYPOINTS = 20_000
"""Most waypoints a path may be resampled to (path length / ``cad.spacing_m``): the refinement's
memory and time grow linearly with it (docs/problem-file.md, "Ranges and limits")."""
MAX_CHECK_STEPS = 2_000_000
"""Most poses of the dense collision check, counted as path length / ``collision.check_step_m``
(a lower bound: joint sweeps add more)."""
MIN_CHECK_STEP_M = 1e-4
"""Finest step of the dense collision check [m]."""
MIN_ORIENTATION_DEG = 0.01
"""Narrowest orientation cone [deg]: well above the verifier's accuracy (1e-6 deg)."""


def positive(owner: str, name: str, value: float) -> None:
    """InputError unless ``value`` > 0; the message names ``owner.name``."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise InputError(f"{owner}.{name} must be a finite number > 0, got {value!r}")


def non_negative(owner: str, name: str, value: float) -> None:
    """InputError unless ``value`` >= 0; the message names ``owner.name``."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
        raise InputError(f"{owner}.{name} must be a finite number >= 0, got {value!r}")


def check_waypoint_count(length_m: float, spacing_m: float, where: str) -> None:
    """Refuse a path that would be resampled to more than :data:`MAX_WAYPOINTS` waypoints."""
    count = length_m / spacing_m
    if not math.isfinite(count) or count > MAX_WAYPOINTS:
        raise InputError(
            f"{where}: a {length_m:.3f} m path at cad.spacing_m = {spacing_m:g} m gives {count:.0f} "
            f"waypoints, more than the limit of {MAX_WAYPOINTS}; use a larger spacing "
            f"(at least {length_m / MAX_WAYPOINTS:.2g} m)"
        )


SOLVERS = ("ipopt", "fatrop")
"""The NLP solvers a refinement can be built for (``[optimise] solver``)."""


def check_solver(name: str) -> str:
    """``name`` if it is one of :data:`SOLVERS`, else an :class:`InputError` listing them."""
    if name not in SOLVERS:
        raise InputError(f"optimise.solver must be one of {', '.join(map(repr, SOLVERS))}, got {name!r}")
    return name


def in_range(owner: str, name: str, value: float, lo: float, hi: float, unit: str = "") -> None:
    """Reject a value that is not a finite number in [lo, hi] (the documented range)."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not (ok and lo <= value <= hi):
        u = f" {unit}" if unit else ""
        raise InputError(
            f"{owner}.{name} must be a finite number in [{lo:g}, {hi:g}]{u}, got {value!r}",
            key=f"{owner}.{name}",
            value=value,
            expected=f"a finite number in [{lo:g}, {hi:g}]{u}",
        )


def integer_in(owner: str, name: str, value: int, low: int, high: int) -> None:
    """InputError unless ``value`` is an integer in ``low..high``."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise InputError(
            f"{owner}.{name} must be an integer in {low}..{high}, got {value!r}",
            key=f"{owner}.{name}",
            value=value,
            expected=f"an integer in {low}..{high}",
        )


def one_of(owner: str, name: str, value: str, allowed: tuple[str, ...]) -> None:
    """InputError unless ``value`` is one of ``allowed``."""
    if value not in allowed:
        raise InputError(
            f"{owner}.{name} = {value!r} is not one of {', '.join(allowed)}",
            key=f"{owner}.{name}",
            value=value,
            expected=f"one of {', '.join(allowed)}",
        )
