"""What a robot is, as data: its spec, its controller family, and its URDF's model.

What a robot is, as data: :class:`RobotSpec` (the registry entry: joints, limits, reach,
controller family and program), the controller families and their program formats, the registry's
``robot.toml`` keys, and the Pinocchio model of a URDF (:func:`build_model`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from refine.errors import InputError
from refine.robot.coupling import JointInteraction, check_coupling, from_controller, to_controller

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

logger = logging.getLogger(__name__)


CONTROLLERS = ("abb", "kuka", "ur", "fanuc", "yaskawa")


DEFAULT_PROGRAM = {"abb": "rapid", "kuka": "krl", "ur": "urscript", "fanuc": "tp", "yaskawa": "inform"}
"""The program format a controller family runs unless the robot names another (``program`` in
``robot.toml``): KUKA's KR C controllers run KRL, the LBR iiwa's Sunrise cabinet runs Sunrise Java."""


PROGRAMS = {
    "abb": ("rapid",),
    "kuka": ("krl", "sunrise"),
    "ur": ("urscript",),
    "fanuc": ("tp",),
    "yaskawa": ("inform",),
}
"""The program formats a controller family can run (FANUC R-30iB: TP ``.ls``; Yaskawa YRC/DX: INFORM ``.JBI``)."""


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


_TOML_OPTIONAL = frozenset({"program", "joint_coupling", "joint_interaction", "controller_frame"})


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
        joint_coupling: how the controller counts the joints where it differs from the URDF, one
            of :data:`refine.robot.coupling.JOINT_COUPLINGS` (``"fanuc_j2_j3"``); ``""`` when the
            controller's joints are the URDF's.
        joint_interaction: linear limits on the controller's joints (FANUC's J2/J3 interaction
            limit), :class:`refine.robot.coupling.JointInteraction`; kept by the optimisation.
        controller_frame: the URDF frame the controller measures positions in (ROS-Industrial's
            ``base``: FANUC's world frame, Yaskawa's robot frame); ``""`` for the URDF's root link.
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
    joint_coupling: str = ""
    joint_interaction: tuple[JointInteraction, ...] = ()
    controller_frame: str = ""

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
        check_coupling(self.joint_coupling, n, f"robot {self.name!r}")
        for it in self.joint_interaction:
            if len(it.coefficients) != n:
                raise InputError(
                    f"robot {self.name!r}: {it.label} has {len(it.coefficients)} coefficients for {n} joints"
                )

    def to_controller(self, q: Any) -> NDArray[np.float64]:
        """URDF joints (..., n) as the robot's controller shows them (same unit): :attr:`joint_coupling`."""
        return to_controller(self.joint_coupling, q)

    def from_controller(self, q_controller: Any) -> NDArray[np.float64]:
        """The controller's joints (..., n) as URDF joints (same unit); inverse of :meth:`to_controller`."""
        return from_controller(self.joint_coupling, q_controller)

    @property
    def default_program(self) -> str:
        """The program format written when a problem names none: ``program``, else the family's."""
        return self.program or DEFAULT_PROGRAM[self.controller]

    @property
    def programs(self) -> tuple[str, ...]:
        """The program formats the robot's controller runs.

        ``program`` alone when the robot names one (an LBR iiwa's Sunrise cabinet runs Sunrise only,
        a KR C controller KRL only), else every format of the controller family (:data:`PROGRAMS`).
        """
        return (self.program,) if self.program else PROGRAMS[self.controller]

    @property
    def dof(self) -> int:
        """Number of actuated joints n."""
        return len(self.joint_names)


def read_registry_toml(path: Path) -> dict[str, Any]:
    """A registry ``robot.toml`` read and its keys checked (InputError naming unknown and missing keys)."""
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


def build_model(urdf: Path) -> pin.Model:
    """The Pinocchio model of a URDF file (InputError when the file is missing or unreadable)."""
    if not Path(urdf).is_file():
        raise InputError(f"URDF file not found: {urdf}")
    try:
        return pin.buildModelFromUrdf(str(urdf))
    except (RuntimeError, ValueError) as e:
        raise InputError(f"Pinocchio cannot read URDF {urdf}: {e}") from e
