"""The robot registry: robots by name, and the robot of a problem's ``[robot]`` table.

The robot registry (``robots/``, or ``$REFINE_ROBOTS_DIR``): robots by name, cached per folder,
and :func:`robot_for`, the robot of a problem's ``[robot]`` table (the registry's, or a URDF's),
with the problem's joint-limit and speed overrides applied.
"""

from __future__ import annotations

import functools
import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from refine.errors import InputError
from refine.robot.coupling import interactions_from_toml
from refine.robot.model import Robot, robot_from_urdf
from refine.robot.spec import RobotSpec, build_model, read_registry_toml
from refine.robot.urdf import with_overrides

if TYPE_CHECKING:
    from refine.settings import RobotSettings
logger = logging.getLogger(__name__)


ROBOTS_MAX = 32
"""Robots kept in the process per kind (registry entries with their overrides, URDF files), least
recently used dropped first."""

PACKAGED_ROBOTS = Path(__file__).resolve().parents[1] / "robots_data"
"""The registry a built wheel carries (copied from ``robots/`` by ``setup.py``)."""


def robots_dir() -> Path:
    """The robot registry folder.

    ``$REFINE_ROBOTS_DIR`` if set; else ``robots/`` beside the package in a source checkout or an
    editable install; else the copy an installed wheel carries (:data:`PACKAGED_ROBOTS`).
    """
    override = os.environ.get("REFINE_ROBOTS_DIR")
    if override:
        return Path(override)
    return _SOURCE_ROBOTS if _SOURCE_ROBOTS.is_dir() or not PACKAGED_ROBOTS.is_dir() else PACKAGED_ROBOTS


_SOURCE_ROBOTS = Path(__file__).resolve().parents[2] / "robots"
"""``robots/`` beside the package (a source checkout or an editable install)."""


@functools.cache
def _resolved_default(folder: Path) -> str:
    """A default registry folder resolved, once per process (the package's place does not move)."""
    return str(folder.resolve())


def available_robots() -> list[str]:
    """Sorted names of the robots in :func:`robots_dir` (folders holding a ``robot.toml``)."""
    root = robots_dir()
    if not root.is_dir():
        return []
    return sorted(p.name for p in root.iterdir() if (p / "robot.toml").is_file())


def load_robot(name: str) -> Robot:
    """Load a robot of the registry by name; cached per registry folder.

    Raises:
        InputError: if the name is unknown (the message lists the available robots) or the
            robot's files are inconsistent.
    """
    root = robots_dir()
    return _load_robot(
        name, _resolved_default(root) if root in (_SOURCE_ROBOTS, PACKAGED_ROBOTS) else str(root.resolve())
    )


def robot_argument(robot: object) -> Robot:
    """A library call's ``robot`` argument: a :class:`Robot` as given, or the registry's by name.

    Raises:
        InputError: an unknown name, with ``key`` ``"robot"`` (the argument), the name as ``value``
            and the registry's robots as ``expected``.
        ArgumentError: neither a Robot nor a str.
    """
    if isinstance(robot, Robot):
        return robot
    if not isinstance(robot, str):
        from refine.arguments import typed

        typed(robot, "robot", Robot, "a refine.Robot or a registry name")
    try:
        return load_robot(robot)
    except InputError as e:
        if e.key != "robot.model":
            raise
        raise InputError(str(e), key="robot", value=e.value, expected=e.expected, file=e.file) from None


@functools.cache
def _load_robot(name: str, root: str) -> Robot:
    folder = Path(root) / name
    if not (folder / "robot.toml").is_file():
        known = ", ".join(available_robots()) or "none"
        raise InputError(
            f"unknown robot {name!r}; available robots: {known}",
            key="robot.model",
            value=name,
            expected=f"a robot of the registry {root}: {known}",
        )
    meta = read_registry_toml(folder / "robot.toml")
    urdf = (folder / str(meta["urdf"])).resolve()
    model = build_model(urdf)
    joint_ids = range(1, model.njoints)
    acceleration_deg = np.asarray(meta["joint_acceleration_deg_s2"], dtype=float)
    spec = RobotSpec(
        name=name,
        maker=str(meta["maker"]),
        urdf=urdf,
        flange_frame=str(meta["flange_frame"]),
        joint_names=tuple(model.names[j] for j in joint_ids),
        lower=np.array(model.lowerPositionLimit),
        upper=np.array(model.upperPositionLimit),
        velocity=np.array(model.velocityLimit),
        acceleration=np.radians(acceleration_deg),
        reach_m=float(meta["reach_m"]),
        controller=str(meta["controller"]),
        model=str(meta["model"]),
        program=str(meta.get("program", "")),
        joint_coupling=str(meta.get("joint_coupling", "")),
        controller_frame=str(meta.get("controller_frame", "")),
        joint_interaction=interactions_from_toml(
            meta.get("joint_interaction", []), model.nq, str(folder / "robot.toml")
        ),
    )
    if model.nq != spec.dof:
        raise InputError(
            f"robot {name!r}: only 1-DoF joints are supported, but nq = {model.nq} for {spec.dof} joints"
        )
    logger.debug("loaded robot %s (%d joints) from %s", name, spec.dof, urdf)
    return Robot(spec, model)


def robot_for(settings: RobotSettings) -> Robot:
    """The robot of a problem's ``[robot]`` table, with its limit overrides (cached per process)."""
    if settings.urdf is not None:
        path = Path(settings.urdf).resolve()
        stamp = path.stat().st_mtime_ns if path.is_file() else 0
        return _urdf_robot(
            str(path),
            stamp,
            settings.controller or "",
            tuple(settings.packages),
            settings.flange_frame,
            settings.model or None,
            settings.reach_m,
            settings.joint_lower_deg,
            settings.joint_upper_deg,
            settings.joint_velocity_deg_s,
            settings.base_link,
            settings.locked_joints_deg,
        )
    return _registry_robot(
        settings.model,
        settings.joint_lower_deg,
        settings.joint_upper_deg,
        settings.joint_velocity_deg_s,
        str(robots_dir()),
    )


@functools.lru_cache(maxsize=ROBOTS_MAX)
def _urdf_robot(
    urdf: str,
    stamp: int,
    controller: str,
    packages: tuple[tuple[str, Path], ...],
    flange_frame: str,
    name: str | None,
    reach_m: float | None,
    lower: tuple[float, ...] | None,
    upper: tuple[float, ...] | None,
    velocity: tuple[float, ...] | None,
    base_link: str | None = None,
    locked: tuple[tuple[str, float], ...] = (),
) -> Robot:
    del stamp  # part of the cache key only: an edited URDF is read again
    return robot_from_urdf(
        urdf,
        controller=controller,
        packages=dict(packages),
        flange_frame=flange_frame,
        name=name,
        reach_m=reach_m,
        joint_lower_deg=lower,
        joint_upper_deg=upper,
        joint_velocity_deg_s=velocity,
        base_link=base_link,
        locked_joints_deg=dict(locked),
    )


@functools.lru_cache(maxsize=ROBOTS_MAX)
def _registry_robot(
    name: str,
    lower: tuple[float, ...] | None,
    upper: tuple[float, ...] | None,
    velocity: tuple[float, ...] | None,
    root: str,
) -> Robot:
    del root  # part of the cache key only: a robot of another registry folder is another robot
    robot = load_robot(name)
    spec = with_overrides(robot.spec, lower, upper, velocity, None)
    return robot if spec is robot.spec else Robot(spec, robot.model)
