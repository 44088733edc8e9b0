"""Robot models: the registry of ``robots/`` and their Pinocchio kinematics.

Each robot is a folder ``robots/<name>/`` holding ``robot.urdf``, ``robot.toml`` (maker, model,
flange frame, reach, controller family and, optionally, the program it runs, default joint accelerations) and a ``README.md``.
``load_robot(name)`` reads one into a :class:`Robot`; joint limits and speeds come from the URDF,
accelerations from the TOML.
"""

from __future__ import annotations

import functools
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike, NDArray

from refine.errors import InputError
from refine.robot.geometry import CollisionShape, collision_shapes_from_urdf

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

logger = logging.getLogger(__name__)

CONTROLLERS = ("abb", "kuka", "ur")
DEFAULT_PROGRAM = {"abb": "rapid", "kuka": "krl", "ur": "urscript"}
"""The program format a controller family runs unless the robot names another (``program`` in
``robot.toml``): KUKA's KR C controllers run KRL, the LBR iiwa's Sunrise cabinet runs Sunrise Java."""
PROGRAMS = {"abb": ("rapid",), "kuka": ("krl", "sunrise"), "ur": ("urscript",)}
"""The program formats a controller family can run."""
SELF_COLLISION_FILE = "self_collision.toml"
"""The sampled self-collision matrix beside a robot's URDF."""
_TOML_KEYS = frozenset(
    {
        "maker",
        "model",
        "urdf",
        "flange_frame",
        "reach_m",
        "controller",
        "acceleration_rule",
        "joint_acceleration_deg_s2",
    }
)
_TOML_OPTIONAL = frozenset({"program"})


@dataclass(frozen=True, eq=False)
class RobotSpec:
    """What the registry knows about one robot.

    Attributes:
        name: registry name, the folder name under ``robots/``.
        maker: manufacturer, e.g. ``"ABB"``.
        urdf: absolute path of the URDF.
        flange_frame: name of the flange frame in the URDF (``"tool0"``).
        joint_names: actuated joints in configuration order, length n.
        lower: lower joint limits [rad], shape (n,).
        upper: upper joint limits [rad], shape (n,).
        velocity: joint speed limits [rad/s], shape (n,).
        acceleration: default joint acceleration limits [rad/s^2], shape (n,).
        reach_m: the maker's nominal reach [m].
        controller: program dialect, one of ``CONTROLLERS``.
        model: the maker's model designation, e.g. ``"IRB 4600-60/2.05"``.
        program: the program format the robot's controller runs (``robot.toml``); ``""`` for the
            controller family's :data:`DEFAULT_PROGRAM` (see :attr:`default_program`).
    """

    name: str
    maker: str
    urdf: Path
    flange_frame: str
    joint_names: tuple[str, ...]
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]
    velocity: NDArray[np.float64]
    acceleration: NDArray[np.float64]
    reach_m: float
    controller: str
    model: str = ""
    program: str = ""

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        for field_name in ("lower", "upper", "velocity", "acceleration"):
            arr = np.array(getattr(self, field_name), dtype=float)
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise InputError(
                    f"robot {self.name!r}: {field_name} must be {n} finite values "
                    f"(one per joint), got shape {arr.shape}"
                )
            arr.setflags(write=False)
            object.__setattr__(self, field_name, arr)
        if np.any(self.lower >= self.upper):
            raise InputError(f"robot {self.name!r}: every lower limit must be below its upper limit")
        for field_name in ("velocity", "acceleration"):
            if np.any(getattr(self, field_name) <= 0.0):
                raise InputError(f"robot {self.name!r}: {field_name} limits must all be positive")
        if not self.reach_m > 0.0:
            raise InputError(f"robot {self.name!r}: reach_m must be positive, got {self.reach_m}")
        if self.controller not in CONTROLLERS:
            raise InputError(
                f"robot {self.name!r}: controller {self.controller!r} is not one of {', '.join(CONTROLLERS)}"
            )
        if self.program and self.program not in PROGRAMS[self.controller]:
            raise InputError(
                f"robot {self.name!r}: program {self.program!r} does not run on a {self.controller} "
                f"controller; use one of {', '.join(PROGRAMS[self.controller])}"
            )

    @property
    def default_program(self) -> str:
        """The program format written when a problem names none: ``program``, else the family's."""
        return self.program or DEFAULT_PROGRAM[self.controller]

    @property
    def dof(self) -> int:
        """Number of actuated joints n."""
        return len(self.joint_names)


class Robot:
    """A robot model: Pinocchio kinematics plus the registry data and collision primitives.

    Attributes:
        spec: the registry entry.
        model: the Pinocchio model built from the URDF.
        data: Pinocchio work data for ``model`` (shared; not thread-safe).
        nq: number of configuration variables (the joint count for revolute arms).
        flange_id: Pinocchio frame index of ``spec.flange_frame``.
    """

    def __init__(self, spec: RobotSpec, model: pin.Model | None = None) -> None:
        self.spec = spec
        self.model = _build_model(spec.urdf) if model is None else model
        self.data = self.model.createData()
        self.nq = int(self.model.nq)
        self.flange_id = self.frame_id(spec.flange_frame)
        self._shapes: tuple[CollisionShape, ...] | None = None
        self._matrix: dict[frozenset[str], str] | None = None

    def __repr__(self) -> str:
        return f"Robot({self.spec.name!r}, nq={self.nq})"

    @classmethod
    def from_urdf(
        cls, urdf: str | Path, *, controller: str, flange_frame: str = "tool0", **options: Any
    ) -> Robot:
        """A robot from its URDF file instead of the registry (:func:`refine.robot.urdf.robot_from_urdf`).

        Args:
            urdf: the URDF file (collision meshes relative to its folder).
            controller: the controller family (``"abb"``, ``"kuka"``, ``"ur"``): the program language.
            flange_frame: the frame the tool is mounted on.
            **options: ``name``, ``maker``, ``model``, ``reach_m``, ``joint_acceleration_deg_s2``,
                ``joint_lower_deg``, ``joint_upper_deg``, ``joint_velocity_deg_s``.
        """
        from refine.robot.urdf import robot_from_urdf

        return robot_from_urdf(urdf, controller=controller, flange_frame=flange_frame, **options)

    def frame_id(self, frame_name: str) -> int:
        """Pinocchio frame index of ``frame_name``; InputError listing the frames if unknown."""
        if not self.model.existFrame(frame_name):
            names = ", ".join(f.name for f in self.model.frames)
            raise InputError(
                f"robot {self.spec.name!r} has no frame {frame_name!r}; available frames: {names}"
            )
        return int(self.model.getFrameId(frame_name))

    def _check_q(self, q: ArrayLike) -> NDArray[np.float64]:
        q = np.asarray(q, dtype=float)
        if q.shape != (self.nq,):
            raise InputError(f"q: expected shape ({self.nq},) [rad], got {q.shape}")
        return q

    def fk(self, q: ArrayLike) -> NDArray[np.float64]:
        """Flange pose T_base_flange (4, 4) [m] for joints q [rad], shape (n,)."""
        pin.forwardKinematics(self.model, self.data, self._check_q(q))
        return pin.updateFramePlacement(self.model, self.data, self.flange_id).homogeneous.copy()

    def fk_many(self, qs: ArrayLike) -> NDArray[np.float64]:
        """Flange poses (N, 4, 4) [m] for joint rows qs [rad], shape (N, n)."""
        qs = np.asarray(qs, dtype=float)
        if qs.ndim != 2 or qs.shape[1] != self.nq:
            raise InputError(f"qs: expected shape (N, {self.nq}) [rad], got {qs.shape}")
        out = np.empty((len(qs), 4, 4))
        for k, q in enumerate(qs):
            pin.forwardKinematics(self.model, self.data, q)
            out[k] = pin.updateFramePlacement(self.model, self.data, self.flange_id).homogeneous
        return out

    def frame_pose(self, q: ArrayLike, frame_name: str) -> NDArray[np.float64]:
        """Pose (4, 4) [m] of any model frame in the base frame for joints q [rad], shape (n,)."""
        fid = self.frame_id(frame_name)
        pin.forwardKinematics(self.model, self.data, self._check_q(q))
        return pin.updateFramePlacement(self.model, self.data, fid).homogeneous.copy()

    def jacobian(self, q: ArrayLike) -> NDArray[np.float64]:
        """Geometric flange Jacobian (6, n), base-aligned axes, linear rows first.

        Maps joint speeds [rad/s] to the flange origin's linear velocity [m/s] and the angular
        velocity [rad/s], both expressed in the base frame (Pinocchio's LOCAL_WORLD_ALIGNED).
        """
        return pin.computeFrameJacobian(
            self.model, self.data, self._check_q(q), self.flange_id, pin.LOCAL_WORLD_ALIGNED
        ).copy()

    def link_poses(self, q: ArrayLike) -> dict[str, NDArray[np.float64]]:
        """Pose (4, 4) [m] in the base frame of every URDF link, keyed by link name."""
        pin.forwardKinematics(self.model, self.data, self._check_q(q))
        pin.updateFramePlacements(self.model, self.data)
        return {
            frame.name: self.data.oMf[k].homogeneous.copy()
            for k, frame in enumerate(self.model.frames)
            if frame.type == pin.FrameType.BODY
        }

    def collision_shapes(self) -> list[CollisionShape]:
        """Collision primitives of every link, parsed once from the URDF's ``<collision>``."""
        if self._shapes is None:
            self._shapes = tuple(collision_shapes_from_urdf(self.spec.urdf))
        return list(self._shapes)

    def self_collision(self) -> dict[frozenset[str], str] | None:
        """The link pairs never checked against each other, ``{frozenset({a, b}): reason}``.

        Read from ``self_collision.toml`` beside the URDF (the sampled matrix, see
        :mod:`refine.robot.self_collision`); None when the robot has none, and then the
        kinematic rules of :mod:`refine.collision.pairs` decide.
        """
        path = Path(self.spec.urdf).parent / SELF_COLLISION_FILE
        if self._matrix is None and path.is_file():
            from refine.robot.self_collision import read_matrix  # the collision package imports us

            self._matrix = read_matrix(path)
        return None if self._matrix is None else dict(self._matrix)


def robots_dir() -> Path:
    """The robot registry folder: ``$REFINE_ROBOTS_DIR`` if set, else ``robots/`` of the repo."""
    override = os.environ.get("REFINE_ROBOTS_DIR")
    return Path(override) if override else Path(__file__).resolve().parents[2] / "robots"


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
    return _load_robot(name, str(robots_dir().resolve()))


@functools.cache
def _load_robot(name: str, root: str) -> Robot:
    folder = Path(root) / name
    if not (folder / "robot.toml").is_file():
        raise InputError(
            f"unknown robot {name!r}; available robots: {', '.join(available_robots()) or 'none'}"
        )
    meta = _read_toml(folder / "robot.toml")
    urdf = (folder / str(meta["urdf"])).resolve()
    model = _build_model(urdf)
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
    )
    if model.nq != spec.dof:
        raise InputError(
            f"robot {name!r}: only 1-DoF joints are supported, but nq = {model.nq} for {spec.dof} joints"
        )
    logger.debug("loaded robot %s (%d joints) from %s", name, spec.dof, urdf)
    return Robot(spec, model)


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        meta = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise InputError(f"cannot read {path}: {e}") from e
    unknown = sorted(set(meta) - _TOML_KEYS - _TOML_OPTIONAL)
    missing = sorted(_TOML_KEYS - set(meta))
    if unknown or missing:
        raise InputError(
            f"{path}: unknown keys {unknown} / missing keys {missing}; "
            f"allowed keys: {', '.join(sorted(_TOML_KEYS | _TOML_OPTIONAL))}"
        )
    return meta


def _build_model(urdf: Path) -> pin.Model:
    if not Path(urdf).is_file():
        raise InputError(f"URDF file not found: {urdf}")
    try:
        return pin.buildModelFromUrdf(str(urdf))
    except (RuntimeError, ValueError) as e:
        raise InputError(f"Pinocchio cannot read URDF {urdf}: {e}") from e
