"""The settings the page may change, applied to the problem file's TOML document and checked as it is.

A change from the browser is a mapping of dotted keys to values: a number for a scalar setting
(``tolerances.orientation_deg``), a pose ``{xyz = [m, m, m], rpy_deg = [deg, deg, deg]}`` for a
frame (``frames.cad_in_world``), or ``move``, the rigid move of the workpiece (a shift [m] in the
world frame {F} and fixed-axis X-Y-Z angles [deg] about the CAD frame's origin) that moves the CAD
frame, the tracker receiver and the cell objects marked ``workpiece`` together, as the placement
repair does (:func:`refine.optimise.moves.moved_problem`). Nothing else can be changed: a key not
listed in :data:`SCALARS` or :data:`POSES` is refused, and so is every file path.

The values are written into a copy of the TOML document (:mod:`tomlkit` keeps its comments and
order) and the copy is read by :func:`refine.problem.problem_from_data`, so a bad value gets the
message the problem file would get.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import tomlkit
from tomlkit.items import Table

from refine.errors import InputError
from refine.frames import fixed_xyz_from_matrix, invert_transform, transform_from_xyz_rpy
from refine.problem import Problem, problem_from_data

SCALARS: dict[str, str] = {
    "tolerances.orientation_deg": "deg",
    "tolerances.joint_margin_deg": "deg",
    "tolerances.singularity_margin": "-",
    "collision.margin_m": "m",
    "collision.self_margin_m": "m",
    "robot.velocity_scale": "-",
    "repair.placement.translate_m": "m",
    "repair.placement.rotate_deg": "deg",
}
"""The scalar settings the page may change, with their units."""

POSES: tuple[str, ...] = (
    "frames.cad_in_world",
    "frames.source_in_world",
    "tool.tcp_in_flange",
    "tool.sensor_in_tcp",
    "robot.base_in_world",
)
"""The frames the page may change, as poses ``{xyz, rpy_deg}``."""

MOVE = "move"
"""The key of the workpiece move."""

MAX_MOVE_M = 5.0
"""The largest workpiece shift the page may ask for [m]."""
MAX_MOVE_DEG = 180.0
"""The largest workpiece angle the page may ask for, per axis [deg]."""

DECIMALS_M = 6
"""Decimals kept of a position written into the problem file (a micrometre)."""
DECIMALS_DEG = 5
"""Decimals kept of an angle written into the problem file."""


def editable_keys() -> tuple[str, ...]:
    """Every key a change may hold."""
    return (*SCALARS, *POSES, MOVE)


def check_keys(changes: Mapping[str, Any]) -> None:
    """Refuse a change that is not a mapping or names a key the page may not change."""
    if not isinstance(changes, Mapping):
        raise InputError(f"a change must be a table of settings, got {type(changes).__name__}")
    unknown = sorted(k for k in changes if k not in editable_keys())
    if unknown:
        raise InputError(
            f"{', '.join(map(repr, unknown))}: not a setting the app changes (it changes "
            f"{', '.join(editable_keys())})"
        )


def pose_table(T: np.ndarray) -> dict[str, list[float]]:
    """A pose as the problem file writes it: translation [m] and fixed-axis X-Y-Z angles [deg]."""
    T = np.asarray(T, dtype=float)
    rpy = fixed_xyz_from_matrix(T[:3, :3], degrees=True)
    return {
        "xyz": [round(float(v), DECIMALS_M) + 0.0 for v in T[:3, 3]],
        "rpy_deg": [round(float(v), DECIMALS_DEG) + 0.0 for v in rpy],
    }


def move_transform(value: Any, cad_in_world: np.ndarray) -> np.ndarray:
    """The world-frame transform Δ of a workpiece move ``{xyz, rpy_deg}`` about the CAD frame's origin.

    Raises:
        InputError: not a pose, numbers missing or not finite, or beyond :data:`MAX_MOVE_M` and
            :data:`MAX_MOVE_DEG`.
    """
    form = "move must be a table { xyz = [m, m, m], rpy_deg = [deg, deg, deg] }"
    if not isinstance(value, Mapping) or set(value) - {"xyz", "rpy_deg"}:
        raise InputError(f"{form}, got {value!r}")
    parts = {}
    for key, unit, limit in (("xyz", "m", MAX_MOVE_M), ("rpy_deg", "deg", MAX_MOVE_DEG)):
        v = value.get(key, [0.0, 0.0, 0.0])
        if (
            not isinstance(v, list | tuple)
            or len(v) != 3
            or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        ):
            raise InputError(f"move.{key} must be a list of 3 numbers [{unit}], got {v!r}")
        if not all(math.isfinite(x) and abs(x) <= limit for x in v):
            raise InputError(f"move.{key} must lie within ±{limit:g} {unit}, got {list(v)!r}")
        parts[key] = np.asarray(v, dtype=float)
    origin = np.eye(4)
    origin[:3, 3] = np.asarray(cad_in_world, dtype=float)[:3, 3]
    turn = transform_from_xyz_rpy(parts["xyz"], parts["rpy_deg"])
    return origin @ turn @ invert_transform(origin)


def _toml_value(value: Any, key: str) -> Any:
    try:
        return tomlkit.item(value)
    except (TypeError, ValueError) as e:
        raise InputError(f"{key}: {value!r} is not a value a problem file can hold") from e


def _set(doc: Any, dotted: str, value: Any) -> None:
    """Set ``doc[a][b][c] = value`` for ``a.b.c``, creating the tables on the way."""
    *tables, last = dotted.split(".")
    node = doc
    for name in tables:
        if name not in node:
            node[name] = tomlkit.table()
        node = node[name]
        if not isinstance(node, Table | dict) and not hasattr(node, "keys"):
            raise InputError(f"{dotted}: {name} is not a table in the problem file")
    if isinstance(value, Mapping):
        inline = tomlkit.inline_table()
        for k, v in value.items():
            inline[k] = _toml_value(v, f"{dotted}.{k}")
        node[last] = inline
    else:
        node[last] = _toml_value(value, dotted)


def _pose_of(node: Any) -> np.ndarray:
    """The transform of a pose table of the document (identity when absent)."""
    value = node.unwrap() if hasattr(node, "unwrap") else (node or {})
    return transform_from_xyz_rpy(value.get("xyz", [0.0] * 3), value.get("rpy_deg", [0.0] * 3))


def _frame(doc: Any, dotted: str) -> np.ndarray:
    """The pose at ``dotted`` in ``doc`` as the loader reads it (identity when absent)."""
    node: Any = doc
    for name in dotted.split("."):
        if not hasattr(node, "get") or name not in node:
            return np.eye(4)
        node = node[name]
    return _pose_of(node)


def apply_changes(base: Any, changes: Mapping[str, Any], path: Path) -> tuple[Any, Problem]:
    """The TOML document ``base`` with ``changes`` applied, and the problem it describes.

    The frames and scalars are set first and the workpiece move is applied on top of them.
    ``base`` is left as it was.

    Raises:
        InputError: a key the page may not change, or a value the problem file would refuse
            (the loader's message, which names the key and its unit).
    """
    check_keys(changes)
    doc = copy.deepcopy(base)
    for key, value in changes.items():
        if key in SCALARS and (not isinstance(value, int | float) or isinstance(value, bool)):
            unit = SCALARS[key]
            raise InputError(f"{path}: {key} must be a number [{unit}], got {value!r}")
        if key != MOVE:
            _set(doc, key, value)
    problem = problem_from_data(doc.unwrap(), path)  # the frames checked before a move uses them
    if MOVE in changes:
        D = move_transform(changes[MOVE], problem.frames.cad_in_world)
        if np.array_equal(D, np.eye(4)):  # no move: the file keeps its own text
            return doc, problem
        for key in ("frames.cad_in_world", "frames.source_in_world"):
            _set(doc, key, pose_table(D @ _frame(doc, key)))
        for obj in doc.get("cell", {}).get("objects", []):
            if obj.get("workpiece", False):
                inline = tomlkit.inline_table()
                inline.update(pose_table(D @ _pose_of(obj.get("pose"))))
                obj["pose"] = inline
        problem = problem_from_data(doc.unwrap(), path)
    return doc, problem
