"""Shared fixtures of the exporter tests: a synthetic IRB 4600 trajectory and its problem."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from refine.frames import matrix_from_fixed_xyz, transform_from_xyz_rpy
from refine.paths import Trajectory
from refine.problem import (
    CadSettings,
    DemoSettings,
    Problem,
    ProcessParameter,
    ProcessSettings,
    RobotSettings,
    ToolSettings,
)
from refine.robot.registry import load_robot

ROBOT = "abb_irb4600_60_205"


@pytest.fixture(scope="session")
def irb4600():
    return load_robot(ROBOT)


@pytest.fixture(scope="session")
def problem() -> Problem:
    return Problem(
        name="glue bead-1",
        root=Path("."),
        robot=RobotSettings(
            model=ROBOT, base_in_world=transform_from_xyz_rpy([0.4, -0.3, 0.25], [0.0, 0.0, 30.0])
        ),
        tool=ToolSettings(
            name="glue gun",
            tcp_in_flange=transform_from_xyz_rpy([0.01, 0.0, 0.22], [0.0, 20.0, 0.0]),
            mass_kg=4.5,
            cog_in_flange_m=(0.0, 0.01, 0.08),
        ),
        cad=CadSettings(file=Path("part.csv")),
        demonstration=DemoSettings(file=Path("demo.txt")),
        process=ProcessSettings(
            kind="glue",
            output="doGlue",
            parameters=(
                ProcessParameter("flowRate", 1.25, "ml/s"),
                ProcessParameter("beadWidth", 0.0042, "m"),
            ),
        ),
    )


def make_trajectory(robot, problem: Problem, n: int, seed: int = 0) -> Trajectory:
    """A joint path swept smoothly through the workspace, its poses from the IRB 4600 FK."""
    rng = np.random.default_rng(seed)
    u = np.linspace(0.0, 1.0, n)[:, None]
    q0 = np.radians([-20.0, 10.0, -15.0, 40.0, 50.0, -60.0])
    q1 = np.radians([35.0, 30.0, 5.0, -70.0, -35.0, 120.0])
    q = q0 + (q1 - q0) * u + 0.05 * np.sin(3.0 * np.pi * u)
    T_world_base = problem.robot.base_in_world
    poses = np.array([T_world_base @ robot.fk(qk) @ problem.tool.tcp_in_flange for qk in q])
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    speed = 0.08 + 0.03 * np.sin(2.0 * np.pi * u[:, 0])
    t = np.concatenate([[0.0], np.cumsum(steps / (0.5 * (speed[1:] + speed[:-1])))])
    tilt = matrix_from_fixed_xyz(rng.normal(0.0, 1.0, (n, 3)))
    return Trajectory(
        t=t,
        s=s,
        q=q,
        positions_ref=poses[:, :3, 3] + rng.normal(0.0, 1e-7, (n, 3)),
        poses=poses,
        rotations_demo=poses[:, :3, :3] @ tilt,
        speed=speed,
    )


@pytest.fixture(scope="session")
def trajectory(irb4600, problem) -> Trajectory:
    return make_trajectory(irb4600, problem, 60)


@pytest.fixture(scope="session")
def trajectory_factory(irb4600, problem):
    """Build a synthetic trajectory with ``n`` waypoints: ``trajectory_factory(n)``."""
    return lambda n, seed=0: make_trajectory(irb4600, problem, n, seed)
