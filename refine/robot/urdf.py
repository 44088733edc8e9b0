"""Robots outside the registry, straight from their URDF, and per-problem limit overrides.

:func:`robot_from_urdf` (also ``Robot.from_urdf``) builds a :class:`~refine.robot.model.Robot` from any
URDF of a serial arm with revolute or prismatic joints: the kinematics and the joint limits and
speeds from the URDF's ``<joint>``/``<limit>``, the collision geometry from its ``<collision>``
elements (primitives as they are, meshes as the convex hull of their vertices; see
:mod:`refine.robot.geometry`), the program language from the controller family. A URDF has no
acceleration limits: unless given, each joint may reach its full speed from rest in
:data:`DEFAULT_ACCELERATION_TIME_S` (a conservative rule, that of the registry's collaborative arm).

:func:`robot_for` is what a run uses: the registry robot of ``[robot] model``, or the URDF robot of
``[robot] urdf``, with the problem's joint-limit and speed overrides applied.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from refine.errors import InputError

if TYPE_CHECKING:
    from refine.robot.model import Robot
    from refine.settings import RobotSettings

Array = NDArray[np.float64]

DEFAULT_ACCELERATION_TIME_S = 1.0
"""Without acceleration limits, a joint's limit is its speed limit divided by this [s]: full speed
from rest in one second."""


def robot_from_urdf(
    urdf: str | Path,
    *,
    controller: str,
    flange_frame: str = "tool0",
    name: str | None = None,
    maker: str = "",
    model: str = "",
    reach_m: float | None = None,
    joint_acceleration_deg_s2: Sequence[float] | None = None,
    joint_lower_deg: Sequence[float] | None = None,
    joint_upper_deg: Sequence[float] | None = None,
    joint_velocity_deg_s: Sequence[float] | None = None,
) -> Robot:
    """A robot built from its URDF file (not from the registry).

    Args:
        urdf: the URDF file; mesh files of ``<collision>`` elements are relative to its folder.
        controller: the controller family, one of :data:`refine.robot.model.CONTROLLERS` (``"abb"``,
            ``"kuka"``, ``"ur"``): it sets the program language.
        flange_frame: the URDF frame (link) the tool is mounted on.
        name: the robot's name in outputs; None for the URDF's ``<robot name>``.
        maker: the manufacturer, for reports.
        model: the maker's model designation, for reports.
        reach_m: reach [m] that scales the singularity measure; None for the length of the chain
            from the second joint to the flange with every joint at zero (the arm stretched).
        joint_acceleration_deg_s2: per-joint acceleration limits [deg/s^2]; None for the speed
            limits over :data:`DEFAULT_ACCELERATION_TIME_S`.
        joint_lower_deg: per-joint lower limits [deg] instead of the URDF's.
        joint_upper_deg: per-joint upper limits [deg] instead of the URDF's.
        joint_velocity_deg_s: per-joint speed limits [deg/s] instead of the URDF's.

    Raises:
        InputError: the file cannot be read, the flange frame is missing, a joint has more than
            one degree of freedom or no speed limit, an override has the wrong length, or the
            controller is unknown; the message names the value and its unit.
    """
    from refine.robot.model import Robot, RobotSpec, _build_model

    path = Path(urdf).resolve()
    pin_model = _build_model(path)
    joints = tuple(pin_model.names[j] for j in range(1, pin_model.njoints))
    if pin_model.nq != len(joints) or pin_model.nv != len(joints):
        raise InputError(
            f"URDF {path}: only 1-DoF joints are supported (revolute, prismatic), but nq = "
            f"{pin_model.nq} for {len(joints)} joints (a continuous or floating joint?)"
        )
    if not pin_model.existFrame(flange_frame):
        frames = ", ".join(f.name for f in pin_model.frames)
        raise InputError(f"URDF {path}: no frame {flange_frame!r} for the flange; frames: {frames}")
    velocity = np.array(pin_model.velocityLimit, dtype=float)
    if np.any(~np.isfinite(velocity) | (velocity <= 0.0)) and joint_velocity_deg_s is None:
        bad = [joints[j] for j in np.flatnonzero(~np.isfinite(velocity) | (velocity <= 0.0))]
        raise InputError(
            f"URDF {path}: joint(s) {', '.join(bad)} have no speed limit (<limit velocity>); "
            "give joint_velocity_deg_s [deg/s]"
        )
    spec = RobotSpec(
        name=name or urdf_robot_name(path),
        maker=maker,
        urdf=path,
        flange_frame=flange_frame,
        joint_names=joints,
        lower=np.array(pin_model.lowerPositionLimit, dtype=float),
        upper=np.array(pin_model.upperPositionLimit, dtype=float),
        velocity=np.where(velocity > 0.0, velocity, 1.0),  # replaced below when missing
        acceleration=np.ones(len(joints)),  # set below
        reach_m=float(reach_m) if reach_m is not None else _stretched_length(pin_model, flange_frame),
        controller=controller,
        model=model,
    )
    spec = with_overrides(spec, joint_lower_deg, joint_upper_deg, joint_velocity_deg_s, None)
    accel = (
        np.radians(_values(joint_acceleration_deg_s2, len(joints), "joint_acceleration_deg_s2", "deg/s^2"))
        if joint_acceleration_deg_s2 is not None
        else spec.velocity / DEFAULT_ACCELERATION_TIME_S
    )
    return Robot(replace(spec, acceleration=accel), pin_model)


def urdf_robot_name(path: str | Path) -> str:
    """The ``<robot name>`` of a URDF file (its stem when unnamed)."""
    path = Path(path)
    from lxml import etree

    try:
        return str(etree.parse(str(path)).getroot().get("name") or path.stem)
    except (OSError, etree.XMLSyntaxError) as e:
        raise InputError(f"cannot read URDF {path}: {e}") from e


def _stretched_length(pin_model, flange_frame: str) -> float:  # noqa: ANN001 - pinocchio.Model
    """Distance along the chain from the second joint to the flange at the zero pose [m]."""
    import pinocchio as pin

    data = pin_model.createData()
    pin.forwardKinematics(pin_model, data, pin.neutral(pin_model))
    pin.updateFramePlacements(pin_model, data)
    fid = pin_model.getFrameId(flange_frame)
    chain = list(pin_model.supports[pin_model.frames[fid].parentJoint])[2:]  # from the second joint
    points = [data.oMi[j].translation for j in chain] + [data.oMf[fid].translation]
    length = float(sum(np.linalg.norm(b - a) for a, b in zip(points[:-1], points[1:], strict=True)))
    if not length > 0.0:
        raise InputError(
            f"cannot derive the reach from the URDF's chain to {flange_frame!r}; give reach_m [m]"
        )
    return length


def _values(values: Sequence[float], n: int, key: str, unit: str) -> Array:
    arr = np.asarray(values, dtype=float)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise InputError(
            f"robot.{key}: expected {n} finite values [{unit}] (one per joint), got {list(values)}"
        )
    return arr


def with_overrides(
    spec,  # noqa: ANN001 - RobotSpec
    joint_lower_deg: Sequence[float] | None,
    joint_upper_deg: Sequence[float] | None,
    joint_velocity_deg_s: Sequence[float] | None,
    joint_acceleration_deg_s2: Sequence[float] | None,
):  # noqa: ANN201 - RobotSpec
    """``spec`` with the given per-joint limits [deg, deg/s, deg/s^2] in place of its own."""
    n = spec.dof
    changes = {}
    if joint_lower_deg is not None:
        changes["lower"] = np.radians(_values(joint_lower_deg, n, "joint_lower_deg", "deg"))
    if joint_upper_deg is not None:
        changes["upper"] = np.radians(_values(joint_upper_deg, n, "joint_upper_deg", "deg"))
    if joint_velocity_deg_s is not None:
        changes["velocity"] = np.radians(_values(joint_velocity_deg_s, n, "joint_velocity_deg_s", "deg/s"))
    if joint_acceleration_deg_s2 is not None:
        changes["acceleration"] = np.radians(
            _values(joint_acceleration_deg_s2, n, "joint_acceleration_deg_s2", "deg/s^2")
        )
    return replace(spec, **changes) if changes else spec


def robot_for(settings: RobotSettings) -> Robot:
    """The robot of a problem's ``[robot]`` table, with its limit overrides (cached per process)."""
    if settings.urdf is not None:
        path = Path(settings.urdf).resolve()
        stamp = path.stat().st_mtime_ns if path.is_file() else 0
        return _urdf_robot(
            str(path),
            stamp,
            settings.controller or "",
            settings.flange_frame,
            settings.model or None,
            settings.reach_m,
            settings.joint_lower_deg,
            settings.joint_upper_deg,
            settings.joint_velocity_deg_s,
        )
    return _registry_robot(
        settings.model, settings.joint_lower_deg, settings.joint_upper_deg, settings.joint_velocity_deg_s
    )


@functools.cache
def _urdf_robot(
    urdf: str,
    stamp: int,
    controller: str,
    flange_frame: str,
    name: str | None,
    reach_m: float | None,
    lower: tuple[float, ...] | None,
    upper: tuple[float, ...] | None,
    velocity: tuple[float, ...] | None,
) -> Robot:
    del stamp  # part of the cache key only: an edited URDF is read again
    return robot_from_urdf(
        urdf,
        controller=controller,
        flange_frame=flange_frame,
        name=name,
        reach_m=reach_m,
        joint_lower_deg=lower,
        joint_upper_deg=upper,
        joint_velocity_deg_s=velocity,
    )


@functools.cache
def _registry_robot(
    name: str,
    lower: tuple[float, ...] | None,
    upper: tuple[float, ...] | None,
    velocity: tuple[float, ...] | None,
) -> Robot:
    from refine.robot.model import Robot, load_robot

    robot = load_robot(name)
    spec = with_overrides(robot.spec, lower, upper, velocity, None)
    return robot if spec is robot.spec else Robot(spec, robot.model)
