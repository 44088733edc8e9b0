"""The robot model: :class:`Robot`, Pinocchio kinematics with the registry data and collision shapes.

A :class:`Robot` joins a :class:`~refine.robot.spec.RobotSpec` (a registry folder's ``robot.toml``,
or a URDF read by :func:`refine.robot.urdf.read_urdf`) to the Pinocchio model of its URDF, the
links' collision shapes (:mod:`refine.robot.geometry`) and the sampled self-collision matrix beside
the URDF. Registry robots are loaded by :func:`refine.robot.registry.load_robot`; any URDF by
:func:`robot_from_urdf` (also ``Robot.from_urdf``).
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike, NDArray

from refine.arguments import typed
from refine.errors import InputError, checked_call
from refine.robot.compiled_chain import CompiledChain
from refine.robot.geometry import CollisionShape, collision_shapes_from_urdf
from refine.robot.self_collision import read_matrix
from refine.robot.spec import SELF_COLLISION_FILE, RobotSpec, build_model
from refine.robot.urdf import read_urdf

logger = logging.getLogger(__name__)


class Robot:
    """A robot model: Pinocchio kinematics plus the registry data and collision primitives.

    Attributes:
        spec: the registry entry.
        model: the Pinocchio model built from the URDF.
        data: Pinocchio work data for ``model``, one per thread (see :attr:`data`).
        nq: number of configuration variables (the joint count for revolute arms).
        flange_id: Pinocchio frame index of ``spec.flange_frame``.
    """

    def __init__(self, spec: RobotSpec, model: pin.Model | None = None) -> None:
        self.spec = spec
        self.model = build_model(spec.urdf) if model is None else model
        self._local = threading.local()  # each thread's Pinocchio data
        self.nq = int(self.model.nq)
        self.flange_id = self.frame_id(spec.flange_frame)
        self._shapes: tuple[CollisionShape, ...] | None = None
        self._matrix: dict[frozenset[str], str] | None = None
        self.chain = CompiledChain.from_model(self.model, self.flange_id)
        """The model's batched kinematics (:class:`~refine.robot.compiled_chain.CompiledChain`, compiled
        where it can be, else :class:`~refine.robot.chain.BatchChain`'s NumPy), or None for joints it does not take."""

    def __repr__(self) -> str:
        return f"Robot({self.spec.name!r}, nq={self.nq})"

    @property
    def data(self) -> pin.Data:
        """Pinocchio's work data for :attr:`model`, one per thread, made on first use in each thread.

        The model itself is only read, so calls from several threads on one robot never share
        scratch memory.
        """
        data = getattr(self._local, "data", None)
        if data is None:
            data = self._local.data = self.model.createData()
        return data

    @classmethod
    @checked_call
    def from_urdf(
        cls, urdf: str | Path, *, controller: str, flange_frame: str = "tool0", **options: Any
    ) -> Robot:
        """A robot from its URDF file instead of the registry (:func:`refine.robot.urdf.robot_from_urdf`).

        Args:
            urdf: the URDF or xacro file (collision meshes relative to its folder or
                ``package://`` URLs, packages found beside it: :mod:`refine.robot.description`).
            controller: the controller family (``"abb"``, ``"kuka"``, ``"ur"``, ``"fanuc"``,
                ``"yaskawa"``): the program language.
            flange_frame: the frame the tool is mounted on.
            **options: ``packages`` (ROS package name -> folder), ``name``, ``maker``, ``model``,
                ``reach_m``, ``joint_acceleration_deg_s2``, ``joint_lower_deg``, ``joint_upper_deg``,
                ``joint_velocity_deg_s``.
        """
        typed(urdf, "urdf", (str, Path), "the path of a .urdf or .xacro file")
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
        if self.chain is not None and len(qs) >= self.chain.min_rows:
            return self.chain.frame(qs, self.flange_id, jacobian=False)[0]
        out = np.empty((len(qs), 4, 4))
        model, data = self.model, self.data
        for k, q in enumerate(qs):
            pin.forwardKinematics(model, data, q)
            out[k] = pin.updateFramePlacement(model, data, self.flange_id).homogeneous
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

    def __getstate__(self) -> dict[str, Any]:
        # the parsed collision shapes (FCL geometry) and Pinocchio's data are rebuilt on the other side
        return {**self.__dict__, "_local": None, "_shapes": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._local = threading.local()
        if "chain" not in state:
            self.chain = CompiledChain.from_model(self.model, self.flange_id)

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
            self._matrix = read_matrix(path)
        return None if self._matrix is None else dict(self._matrix)


def robot_from_urdf(
    urdf: str | Path, *, controller: str, flange_frame: str = "tool0", **options: Any
) -> Robot:
    """A robot built from its URDF file (not from the registry).

    The spec and model of :func:`refine.robot.urdf.read_urdf`, with the collision geometry of the
    URDF's ``<collision>`` elements. Arguments and errors as :func:`~refine.robot.urdf.read_urdf`.
    """
    spec, model = checked_call(read_urdf)(urdf, controller=controller, flange_frame=flange_frame, **options)
    return Robot(spec, model)
