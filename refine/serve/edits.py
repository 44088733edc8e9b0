"""The settings the page may change, applied to the problem file's TOML document and checked as it is.

A change from the browser is a mapping of dotted keys to values: a number for a scalar setting
(``tolerances.orientation_deg``), a pose ``{xyz = [m, m, m], rpy_deg = [deg, deg, deg]}`` for a
frame (``frames.cad_in_world``), or ``move``, the rigid move of the workpiece (a shift [m] in the
world frame {F} and fixed-axis X-Y-Z angles [deg] about the CAD frame's origin) that moves the CAD
frame, the tracker receiver and the cell objects marked ``workpiece`` together, as the placement
repair does (:func:`refine.optimise.moves.moved_problem`). Nothing else can be changed: a key not
listed in :data:`SCALARS` or :data:`POSES` is refused, and so is every file path.

The values are written into a copy of the document's plain data, which
:func:`refine.problem.problem_from_data` reads (:func:`edit_data`: a bad value gets the message the
problem file would get), and, only when the file is shown or saved, into a copy of the TOML
document itself (:func:`edit_document`: :mod:`tomlkit` keeps its comments and order). Both take
the same steps, so the file saved is the problem solved.
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

MOVED_FRAMES = ("frames.cad_in_world", "frames.source_in_world")
"""The frames a workpiece move rewrites (with the poses of the cell objects marked ``workpiece``)."""

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


def _set(doc: Any, dotted: str, value: Any, plain: bool = False) -> None:
    """Set ``doc[a][b][c] = value`` for ``a.b.c``, creating the tables on the way.

    ``plain``: ``doc`` is plain data (dicts and lists), given the value as the document would hold it.
    """
    *tables, last = dotted.split(".")
    node = doc
    for name in tables:
        if name not in node:
            node[name] = {} if plain else tomlkit.table()
        node = node[name]
        if not isinstance(node, Table | dict) and not hasattr(node, "keys"):
            raise InputError(f"{dotted}: {name} is not a table in the problem file")
    if isinstance(value, Mapping):
        inline = tomlkit.inline_table()
        for k, v in value.items():
            inline[k] = _toml_value(v, f"{dotted}.{k}")
        node[last] = inline.unwrap() if plain else inline
    else:
        item = _toml_value(value, dotted)
        node[last] = item.unwrap() if plain else item


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


def _edited(tree: Any, changes: Mapping[str, Any], path: Path, plain: bool) -> Any:
    """A copy of ``tree`` (the TOML document, or its plain data when ``plain``) with ``changes`` applied.

    The frames and scalars are set first and the workpiece move is applied on top of them, about
    the CAD frame as set: a frame the move rewrites, when changed, is first read by the loader (a
    value it refuses is not rewritten into one it takes); the file's own frames it read already.
    """
    check_keys(changes)
    doc = copy.deepcopy(tree)
    for key, value in changes.items():
        if key in SCALARS and (not isinstance(value, int | float) or isinstance(value, bool)):
            unit = SCALARS[key]
            raise InputError(f"{path}: {key} must be a number [{unit}], got {value!r}")
        if key != MOVE:
            _set(doc, key, value, plain)
    if MOVE not in changes:
        return doc
    if any(key in changes for key in MOVED_FRAMES):  # checked as set, before the move rewrites them
        problem_from_data(doc if plain else doc.unwrap(), path)
    D = move_transform(changes[MOVE], _frame(doc, "frames.cad_in_world"))
    if np.array_equal(D, np.eye(4)):  # no move: the file keeps its own text
        return doc
    for key in MOVED_FRAMES:
        _set(doc, key, pose_table(D @ _frame(doc, key)), plain)
    for obj in doc.get("cell", {}).get("objects", []):
        if obj.get("workpiece", False):
            pose = pose_table(D @ _pose_of(obj.get("pose")))
            if plain:
                obj["pose"] = pose
            else:
                inline = tomlkit.inline_table()
                inline.update(pose)
                obj["pose"] = inline
    return doc


def edit_data(data: Mapping[str, Any], changes: Mapping[str, Any], path: Path) -> tuple[dict[str, Any], Problem]:
    """The problem file's plain data ``data`` with ``changes`` applied, and the problem it describes.

    ``data`` (the TOML document's ``unwrap()``) is left as it was.

    Raises:
        InputError: a key the page may not change, or a value the problem file would refuse
            (the loader's message, which names the key and its unit).
    """
    edited = _edited(data, changes, path, plain=True)
    return edited, problem_from_data(edited, path)


def edit_document(base: Any, changes: Mapping[str, Any], path: Path) -> Any:
    """The TOML document ``base`` with ``changes`` applied as :func:`edit_data` applies them (``base`` kept)."""
    return _edited(base, changes, path, plain=False)


def apply_changes(base: Any, changes: Mapping[str, Any], path: Path) -> tuple[Any, Problem]:
    """The TOML document ``base`` with ``changes`` applied, and the problem it describes.

    The frames and scalars are set first and the workpiece move is applied on top of them.
    ``base`` is left as it was.

    Raises:
        InputError: a key the page may not change, or a value the problem file would refuse
            (the loader's message, which names the key and its unit).
    """
    problem = edit_data(base.unwrap(), changes, path)[1]
    return edit_document(base, changes, path), problem
