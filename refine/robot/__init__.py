"""The robot wing: what a robot is, where it comes from, and how it moves.

The floor every other wing stands on (``docs/design.md``); nothing here imports the optimiser or
the application.

* :mod:`~refine.robot.spec`: :class:`RobotSpec` (the registry entry: limits, reach, controller
  family and program) and the controller families' facts; the Pinocchio model of a URDF.
* :mod:`~refine.robot.urdf`: a spec and a model read from any URDF, and limit overrides;
  :mod:`~refine.robot.description`: a xacro expanded and its ROS packages found;
  :mod:`~refine.robot.reach`: the reach as the makers quote it.
* :mod:`~refine.robot.importer`: a registry folder made from a ROS-Industrial support package
  (``refine robots import``), its link shapes by :mod:`~refine.robot.shapes`.
* :mod:`~refine.robot.model`: :class:`Robot`, the model with its collision shapes and
  self-collision matrix.
* :mod:`~refine.robot.registry`: the robots of ``robots/`` by name, and the robot of a
  problem's ``[robot]`` table.
* :mod:`~refine.robot.kinematics`: numeric TCP kinematics and damped least-squares IK.
* :mod:`~refine.robot.geometry`, :mod:`~refine.robot.convex`, :mod:`~refine.robot.self_collision`:
  the links' collision shapes, their convex pieces, and the sampled self-collision matrix.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from refine.lazy import lazy_names

if TYPE_CHECKING:
    from refine.robot.kinematics import TcpKinematics, solve_ik
    from refine.robot.model import Robot, robot_from_urdf
    from refine.robot.registry import available_robots, load_robot, robot_for
    from refine.robot.spec import RobotSpec

_LAZY = {
    "Robot": "refine.robot.model",
    "robot_from_urdf": "refine.robot.model",
    "RobotSpec": "refine.robot.spec",
    "available_robots": "refine.robot.registry",
    "load_robot": "refine.robot.registry",
    "robot_for": "refine.robot.registry",
    "TcpKinematics": "refine.robot.kinematics",
    "solve_ik": "refine.robot.kinematics",
}

__all__ = [
    "Robot",
    "RobotSpec",
    "TcpKinematics",
    "available_robots",
    "load_robot",
    "robot_for",
    "robot_from_urdf",
    "solve_ik",
]

__getattr__, __dir__ = lazy_names("refine.robot", _LAZY, globals())
