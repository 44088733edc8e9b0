"""Checks of the arrays and settings a library call is given (``refine.refine_path``, ``refine.solve``).

Each function turns one argument into what the pipeline takes, or raises an
:class:`~refine.errors.InputError` that names the argument, the value and the unit.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from refine.errors import ArgumentError, InputError, NotExecutable, checked_call  # noqa: F401
from refine.plausible import CAD_SPEED_LIMIT_M_S
from refine.settings import Shape
from refine.types import Array

MM_SUSPECT_REACHES = 10.0
"""Positions whose nearest point is this many reaches from the robot's base are refused: no cell
puts a path that far, while millimetres read as metres put it a thousand times too far."""

QUATERNION_ORDERS = ("wxyz", "xyzw")
"""The quaternion orders :func:`refine_path` reads, one of which the caller must state."""

SPEED_CAP_WITHOUT_DEMO_M_S = 5.0
"""TCP speed cap [m/s] when :func:`refine.refine_path` gets no speeds: above what industrial arms
reach along a process path, so the joint speed and acceleration limits alone set the timing. The
``slow_segments`` of such a result compare against this cap."""


def joints_from(q: ArrayLike | None, N: int | None, n: int | None) -> Array | None:
    """``initial_joints`` as an (N, n) array [rad] (any N when ``N`` is None), or None."""
    if q is None:
        return None
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or (N is not None and q.shape != (N, n)):
        want = f"({N}, {n})" if N is not None else "(N, n)"
        raise InputError(
            f"initial_joints: expected shape {want} [rad], got {q.shape}",
            key="initial_joints",
            value=q.shape,
            expected=f"joints of shape {want} [rad]",
        )
    if not np.all(np.isfinite(q)):
        raise InputError("initial_joints: contains NaN or infinite values [rad]")
    return q


def settings_from(value: Any, cls: type, name: str) -> Any:
    """``value`` as a ``cls``: an instance, a mapping of its fields, or None for the defaults.

    Anything else, or an unknown field, is an InputError naming the argument and the fields.
    """
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    fields = [f.name for f in dataclasses.fields(cls)]
    if not isinstance(value, Mapping):
        raise InputError(
            f"{name}: expected a refine.{cls.__name__} or a mapping of its fields, got {type(value).__name__}",
            key=name,
            value=value,
            expected=f"refine.{cls.__name__} or a mapping of {', '.join(fields)}",
        )
    unknown = sorted(set(value) - set(fields))
    if unknown:
        raise InputError(
            f"{name}: unknown field(s) {', '.join(map(repr, unknown))}; the fields are {', '.join(fields)}",
            key=f"{name}.{unknown[0]}",
            value=value[unknown[0]],
            expected=f"one of the fields {', '.join(fields)}",
        )
    return cls(**dict(value))


def shapes_from(shapes: Any, name: str) -> tuple:
    """``shapes`` as a tuple of :class:`refine.settings.Shape`; anything else is an InputError."""
    if isinstance(shapes, (Mapping, str, Shape)) or not isinstance(shapes or (), Sequence):
        raise InputError(
            f"{name}: expected a list of refine.Shape, got {type(shapes).__name__}",
            key=name,
            value=shapes,
            expected="a list of refine.Shape",
        )
    items = tuple(shapes or ())
    for k, shape in enumerate(items):
        if not isinstance(shape, Shape):
            raise InputError(
                f"{name}[{k}]: expected a refine.Shape, got {type(shape).__name__} (a problem file's "
                f"table becomes one with refine.Shape(kind=..., name=..., ...))",
                key=f"{name}[{k}]",
                value=shape,
                expected="refine.Shape",
            )
    return items


def finite_array(a: ArrayLike, name: str, unit: str) -> Array:
    """``a`` as a float array with no NaN or infinity; ``name`` and ``unit`` for the message."""
    try:
        arr = np.asarray(a, dtype=float)
    except (TypeError, ValueError) as e:
        raise InputError(
            f"{name}: not an array of numbers [{unit}]: {e}", key=name, value=a, expected=f"numbers [{unit}]"
        ) from e
    if not np.all(np.isfinite(arr)):
        raise InputError(
            f"{name}: contains NaN or infinite values [{unit}]",
            key=name,
            value=a,
            expected=f"finite numbers [{unit}]",
        )
    return arr


def rotations_from(orientations: ArrayLike, N: int, order: str | None) -> Array:
    """``orientations`` ((N, 4) quaternions in ``order``, or (N, 3, 3) matrices) as (N, 3, 3) rotations."""
    from refine.frames import check_rotation, matrix_from_quaternion

    if order is not None and order not in QUATERNION_ORDERS:
        raise InputError(
            f"quaternion_order: expected 'wxyz' (scalar first) or 'xyzw' (scalar last), got {order!r}",
            key="quaternion_order",
            value=order,
            expected="'wxyz' or 'xyzw'",
        )
    o = finite_array(orientations, "orientations", "-")
    if o.shape == (N, 4):
        if order not in QUATERNION_ORDERS:
            raise InputError(
                f"orientations: (N, 4) quaternions need quaternion_order='wxyz' (scalar first, as in "
                f"trajectory.csv) or 'xyzw' (scalar last, as scipy's Rotation.as_quat()), got "
                f"{order!r}: every unit quaternion is valid in both orders, so the order cannot be "
                "told from the numbers",
                key="quaternion_order",
                value=order,
                expected="'wxyz' or 'xyzw'",
            )
        if order == "xyzw":
            o = np.column_stack([o[:, 3], o[:, :3]])
        norms = np.linalg.norm(o, axis=1)
        if np.any(np.abs(norms - 1.0) > 1e-3):
            k = int(np.argmax(np.abs(norms - 1.0)))
            raise InputError(
                f"orientations: quaternion {k} has length {norms[k]:.6f}; expected unit quaternions "
                "(qw, qx, qy, qz)"
            )
        return matrix_from_quaternion(o)
    if o.shape == (N, 3, 3):
        return check_rotation(o, "orientations").copy()
    raise InputError(
        f"orientations: expected (N, 4) quaternions (qw, qx, qy, qz) or (N, 3, 3) rotation matrices "
        f"with N = {N} (the number of positions), got {o.shape}"
    )


def arc_length_from(p: Array, arc_length: ArrayLike | None) -> Array:
    """The arc length [m] of each waypoint: ``arc_length`` checked, or the cumulative distance of ``p``."""
    if arc_length is None:
        steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
        if np.any(steps <= 0.0):
            k = int(np.flatnonzero(steps <= 0.0)[0])
            raise InputError(f"positions: waypoints {k} and {k + 1} coincide; the path must move [m]")
        return np.concatenate([[0.0], np.cumsum(steps)])
    s = finite_array(arc_length, "arc_length", "m")
    if s.shape != (len(p),):
        raise InputError(f"arc_length: expected shape ({len(p)},) [m], got {s.shape}")
    if np.any(np.diff(s) <= 0.0):
        raise InputError("arc_length: must strictly increase along the path [m]")
    return s - s[0]


def speeds_from(speeds: ArrayLike | float | None, N: int) -> Array:
    """The demonstrated TCP speed [m/s] per waypoint, (N,): positive, at most 10 m/s."""
    if speeds is None:
        return np.full(N, SPEED_CAP_WITHOUT_DEMO_M_S)
    v = finite_array(speeds, "speeds", "m/s")
    if v.ndim == 0:
        v = np.full(N, float(v))
    if v.shape != (N,):
        raise InputError(f"speeds: expected shape ({N},) or one number [m/s], got {v.shape}")
    if np.any(v <= 0.0):
        raise InputError(f"speeds: every speed must be > 0 m/s, got min {v.min():g} m/s")
    if v.max() > CAD_SPEED_LIMIT_M_S:
        k = int(np.argmax(v))
        raise InputError(
            f"speeds: {v[k]:g} m/s at waypoint {k} is beyond {CAD_SPEED_LIMIT_M_S:g} m/s, faster than "
            f"industrial robots move their tool; speeds are in m/s ({v[k]:g} mm/s would be "
            f"{v[k] / 1000:g} m/s)"
        )
    return v


def check_position_units(p: Array, robot: Any, base_in_world: Array) -> None:
    """Refuse positions no part of which the robot could reach in metres but could in millimetres."""
    reach = float(robot.spec.reach_m)
    base = base_in_world[:3, 3]
    nearest = float(np.linalg.norm(p - base, axis=1).min())
    if nearest <= MM_SUSPECT_REACHES * reach:
        return
    in_mm = float(np.linalg.norm(p / 1000.0 - base, axis=1).max())
    hint = (
        f"; read as millimetres they would be within {in_mm:.3g} m of it: positions are in metres"
        if in_mm <= reach
        else ""
    )
    raise InputError(
        f"positions: the nearest is {nearest:.4g} m from the robot's base, {nearest / reach:.3g} times "
        f"its reach of {reach:g} m{hint}"
    )


def transform_from(T: ArrayLike | None, name: str) -> Array:
    """``T`` as a checked 4x4 transform [m], the identity when None."""
    from refine.frames import check_transform

    if T is None:
        return np.eye(4)
    return check_transform(finite_array(T, name, "m"), name).copy()


def check_hooks(cancel: Any, progress: Any) -> None:
    """``cancel`` is None, a threading.Event or a callable; ``progress`` None or a callable."""
    if cancel is not None and not (isinstance(cancel, threading.Event) or callable(cancel)):
        raise ArgumentError(
            f"cancel: expected a threading.Event or a callable returning bool, got {type(cancel).__name__}",
            key="cancel",
            value=cancel,
            expected="a threading.Event, a callable returning bool, or None",
        )
    if progress is not None and not callable(progress):
        raise ArgumentError(
            f"progress: expected a callable taking a refine.Progress, got {type(progress).__name__}",
            key="progress",
            value=progress,
            expected="a callable taking a refine.Progress, or None",
        )


def typed(value: Any, name: str, kind: type | tuple[type, ...], expected: str) -> Any:
    """``value`` when it is a ``kind``, else an ArgumentError naming ``name`` and ``expected``."""
    if not isinstance(value, kind):
        raise ArgumentError(
            f"{name}: expected {expected}, got {type(value).__name__} {value!r}",
            key=name,
            value=value,
            expected=expected,
        )
    return value


def home_from(home_deg: Any, n: int) -> tuple[float, ...] | None:
    """``home_deg`` as ``n`` joint angles [deg], or None."""
    if home_deg is None:
        return None
    h = finite_array(home_deg, "home_deg", "deg")
    if h.shape != (n,):
        raise InputError(
            f"home_deg: expected {n} joint angles [deg], got shape {h.shape}",
            key="home_deg",
            value=home_deg,
            expected=f"{n} joint angles [deg]",
        )
    return tuple(float(a) for a in h)


def check_previous(previous: Any, result_type: type) -> None:
    """``previous`` is None or a ``result_type`` (a ``refine.Result``) that holds its run."""
    if previous is None:
        return
    typed(previous, "previous", result_type, "a refine.Result of an earlier call, or None")
    require_run(previous, "previous", "previous: a result rebuilt from a dictionary holds no run to start from")


def require_run(result: Any, key: str, message: str) -> None:
    """:class:`NotExecutable` with ``message`` when ``result`` (a ``refine.Result``) holds no run.

    A result rebuilt by ``Result.from_dict`` holds its figures but not the run they came from.
    """
    if result.run is None:
        raise NotExecutable(
            message,
            key=key,
            value=result.status,
            expected="a result of refine.solve or refine.refine_path (pickled is fine)",
        )
