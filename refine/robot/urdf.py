"""A robot's spec and kinematic model read straight from its URDF, and per-problem limit overrides.

:func:`read_urdf` reads any URDF or xacro (expanded, ROS packages found, by
:mod:`refine.robot.description`) of a serial arm with revolute or prismatic joints into a
:class:`~refine.robot.spec.RobotSpec` and a Pinocchio model: the kinematics and the joint limits and
speeds from the URDF's ``<joint>``/``<limit>``, the program language from the controller family
(the collision geometry is read by :class:`~refine.robot.model.Robot` from the same file's
``<collision>`` elements, see :mod:`refine.robot.geometry`). A URDF has no acceleration limits:
unless given, each joint may reach its full speed from rest in :data:`DEFAULT_ACCELERATION_TIME_S`
(a conservative rule, that of the registry's collaborative arm). :func:`with_overrides` applies a
problem's joint-limit and speed overrides to a spec. This module knows no ``Robot``:
:func:`refine.robot.model.robot_from_urdf` builds one from what it reads.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from refine.errors import InputError
from refine.robot.description import resolve_description
from refine.robot.reach import wrist_centre_reach
from refine.robot.spec import RobotSpec, build_model
from refine.types import Array

logger = logging.getLogger(__name__)

DEFAULT_ACCELERATION_TIME_S = 1.0
"""Without acceleration limits, a joint's limit is its speed limit divided by this [s]: full speed
from rest in one second."""


def read_urdf(
    urdf: str | Path,
    *,
    controller: str,
    packages: Mapping[str, str | Path] | None = None,
    flange_frame: str = "tool0",
    name: str | None = None,
    maker: str = "",
    model: str = "",
    reach_m: float | None = None,
    joint_acceleration_deg_s2: Sequence[float] | None = None,
    joint_lower_deg: Sequence[float] | None = None,
    joint_upper_deg: Sequence[float] | None = None,
    joint_velocity_deg_s: Sequence[float] | None = None,
    base_link: str | None = None,
    locked_joints_deg: Mapping[str, float] | None = None,
) -> tuple[RobotSpec, pin.Model]:
    """A robot's spec and Pinocchio model read from its URDF file (not from the registry).

    A workcell's URDF (a turntable, a positioner, a second arm beside the robot) names the arm's
    chain by ``base_link`` and ``flange_frame`` and holds every other joint at a value of
    ``locked_joints_deg`` (:func:`chain_model`).

    Args:
        urdf: the URDF or xacro file; mesh files of ``<collision>`` elements are relative to its
            folder or ``package://`` URLs (expanded by :func:`refine.robot.description.resolve_description`).
        controller: the controller family, one of :data:`refine.robot.spec.CONTROLLERS` (``"abb"``,
            ``"kuka"``, ``"ur"``, ``"fanuc"``, ``"yaskawa"``): it sets the program language.
        packages: ROS package name -> folder, for packages not found beside the description.
        flange_frame: the URDF frame (link) the tool is mounted on.
        name: the robot's name in outputs; None for the URDF's ``<robot name>``.
        maker: the manufacturer, for reports.
        model: the maker's model designation, for reports.
        reach_m: reach [m] that scales the singularity measure; None for the reach as the makers
            quote it, the wrist centre's largest distance from axis 1
            (:func:`refine.robot.reach.wrist_centre_reach`), or, for a chain whose first joint is
            not revolute, the length of the chain from the second joint to the flange at zero.
        joint_acceleration_deg_s2: per-joint acceleration limits [deg/s^2]; None for the speed
            limits over :data:`DEFAULT_ACCELERATION_TIME_S`.
        joint_lower_deg: per-joint lower limits [deg] instead of the URDF's.
        joint_upper_deg: per-joint upper limits [deg] instead of the URDF's.
        joint_velocity_deg_s: per-joint speed limits [deg/s] instead of the URDF's.
        base_link: the URDF link the arm stands on, its base frame (every pose of the robot is
            relative to it); None for the URDF's root.
        locked_joints_deg: joints held still, by name, at these values [deg] (a prismatic joint's
            value in mm); every joint not on the chain to the flange must be among them.

    Raises:
        InputError: the file cannot be read, the flange frame is missing, a joint has more than
            one degree of freedom or no speed limit, an override has the wrong length, or the
            controller is unknown; the message names the value and its unit.
    """
    source = Path(urdf).resolve()
    path = resolve_description(source, packages)
    pin_model = chain_model(build_model(path), path, flange_frame, base_link, locked_joints_deg or {})
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
        name=name or urdf_robot_name(source),
        maker=maker,
        urdf=path,
        flange_frame=flange_frame,
        joint_names=joints,
        lower=np.array(pin_model.lowerPositionLimit, dtype=float),
        upper=np.array(pin_model.upperPositionLimit, dtype=float),
        velocity=np.where(velocity > 0.0, velocity, 1.0),  # replaced below when missing
        acceleration=np.ones(len(joints)),  # set below
        reach_m=float(reach_m) if reach_m is not None else _reach(pin_model, flange_frame),
        controller=controller,
        model=model,
    )
    spec = with_overrides(spec, joint_lower_deg, joint_upper_deg, joint_velocity_deg_s, None)
    accel = (
        np.radians(_values(joint_acceleration_deg_s2, len(joints), "joint_acceleration_deg_s2", "deg/s^2"))
        if joint_acceleration_deg_s2 is not None
        else spec.velocity / DEFAULT_ACCELERATION_TIME_S
    )
    return replace(spec, acceleration=accel), pin_model


def chain_model(
    model: pin.Model, path: Path, flange_frame: str, base_link: str | None, locked_deg: Mapping[str, float]
) -> pin.Model:
    """The arm's chain of a URDF's model: ``locked_deg`` joints held still, re-rooted at ``base_link``.

    The locked joints are removed (Pinocchio's ``buildReducedModel``, every other joint at zero
    for the reference); the rest must all carry the flange. With ``base_link``, which no joint may
    move once the locked joints are held, the model's root becomes that link: every placement fixed
    to the old root is expressed in it, so the base frame, the robot's poses and ``base_in_world``
    are that link's. Links fixed to the old root keep their collision geometry as bodies fixed to
    the base.

    Raises:
        InputError: an unknown or repeated joint or link, a joint off the chain left unlocked, or a
            base link that a joint still moves; the message names them.
    """
    names = [model.names[j] for j in range(1, model.njoints)]
    unknown = sorted(set(locked_deg) - set(names))
    if unknown:
        raise InputError(
            f"URDF {path}: robot.locked_joints_deg names {unknown}, not joints of the URDF; joints: {', '.join(names)}"
        )
    if locked_deg:
        q_ref = pin.neutral(model)
        for name, value in locked_deg.items():
            joint = model.joints[model.getJointId(name)]
            if joint.nq != 1:
                raise InputError(f"URDF {path}: joint {name!r} has {joint.nq} coordinates; only 1-DoF joints lock")
            prismatic = model.joints[model.getJointId(name)].shortname().startswith("JointModelP")
            q_ref[joint.idx_q] = float(value) * 1e-3 if prismatic else np.radians(float(value))
        model = pin.buildReducedModel(model, [model.getJointId(n) for n in locked_deg], q_ref)
    if not model.existFrame(flange_frame):
        return model  # read_urdf names the missing flange
    carrying = set(model.supports[model.frames[model.getFrameId(flange_frame)].parentJoint])
    loose = [model.names[j] for j in range(1, model.njoints) if j not in carrying]
    if loose:
        raise InputError(
            f"URDF {path}: joint(s) {', '.join(loose)} do not carry the flange {flange_frame!r}; "
            "hold them in robot.locked_joints_deg = {name = value [deg]}"
        )
    if base_link is None:
        return model
    if not model.existFrame(base_link):
        raise InputError(f"URDF {path}: robot.base_link {base_link!r} is not a frame of the URDF")
    frame = model.frames[model.getFrameId(base_link)]
    if frame.parentJoint != 0:
        raise InputError(
            f"URDF {path}: robot.base_link {base_link!r} is moved by joint {model.names[frame.parentJoint]!r}; "
            "lock it or name a link below the moving joints"
        )
    root_in_base = frame.placement.inverse()
    for j in range(1, model.njoints):
        if model.parents[j] == 0:
            model.jointPlacements[j] = root_in_base * model.jointPlacements[j]
    for i in range(1, len(model.frames)):  # the universe frame stays the root
        if model.frames[i].parentJoint == 0:
            model.frames[i].placement = root_in_base * model.frames[i].placement
    return model


def urdf_robot_name(path: str | Path) -> str:
    """The ``<robot name>`` of a URDF file (its stem when unnamed)."""
    path = Path(path)
    from lxml import etree

    try:
        return str(etree.parse(str(path)).getroot().get("name") or path.stem)
    except (OSError, etree.XMLSyntaxError) as e:
        raise InputError(f"cannot read URDF {path}: {e}") from e


def _reach(pin_model, flange_frame: str) -> float:  # noqa: ANN001 - pinocchio.Model
    """The wrist centre's reach, or the stretched chain where axis 1 is no revolute joint [m]."""
    try:
        return wrist_centre_reach(pin_model, flange_frame)
    except InputError as e:
        logger.warning("%s: the reach is the stretched chain's length instead", e)
        return _stretched_length(pin_model, flange_frame)


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
