"""Shared fixtures of the collision tests: the IRB 4600, a nozzle, a cell with a mesh part."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from refine.collision import CollisionModel
from refine.frames import make_transform, matrix_from_fixed_xyz
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot
from refine.settings import Shape

PRIMITIVE_ROBOTS = Path(__file__).resolve().parent / "primitive_robots"


def load_primitive_robot(name):
    """A registry robot with hand-sized primitive shapes and no self-collision matrix (see the README)."""
    old = os.environ.get("REFINE_ROBOTS_DIR")
    os.environ["REFINE_ROBOTS_DIR"] = str(PRIMITIVE_ROBOTS)
    try:
        return load_robot(name)
    finally:
        if old is None:
            del os.environ["REFINE_ROBOTS_DIR"]
        else:
            os.environ["REFINE_ROBOTS_DIR"] = old


@pytest.fixture(scope="session")
def primitive_robot():
    """Factory: a registry robot with hand-sized primitive shapes (see primitive_robots/README.md)."""
    return load_primitive_robot


@pytest.fixture(scope="session")
def irb4600():
    return load_primitive_robot("abb_irb4600_60_205")


@pytest.fixture(scope="session")
def tcp_in_flange():
    return make_transform(p=[0.0, 0.0, 0.35])


@pytest.fixture(scope="session")
def nozzle():
    return Shape("nozzle", "cylinder", pose=make_transform(p=[0.0, 0.0, 0.15]), radius_m=0.03, length_m=0.3)


@pytest.fixture(scope="session")
def box_mesh_file(tmp_path_factory):
    """A closed 0.3 x 0.3 x 0.1 m box as an STL in millimetres."""
    path = tmp_path_factory.mktemp("meshes") / "part_mm.stl"
    trimesh.creation.box((300.0, 300.0, 100.0)).export(path)
    return path


@pytest.fixture(scope="session")
def base_in_world():
    """A robot base turned 30 deg about z and lifted onto a 0.1 m plinth."""
    return make_transform(matrix_from_fixed_xyz([0.0, 0.0, 30.0]), [0.2, -0.1, 0.1])


def _make_model(robot, cell=(), tool=(), base=None, tcp=None, margin_m=0.01, self_margin_m=0.005):
    base = np.eye(4) if base is None else base
    tcp = make_transform(p=[0.0, 0.0, 0.35]) if tcp is None else tcp
    return CollisionModel(
        robot, base, tcp, tuple(tool), tuple(cell), margin_m=margin_m, self_margin_m=self_margin_m
    )


@pytest.fixture(scope="session")
def make_model():
    """Factory: CollisionModel(robot, cell=(), tool=(), base=I, tcp=0.35 m along z, margins)."""
    return _make_model


@pytest.fixture(scope="session")
def table_cell(box_mesh_file):
    """A table top at z = 0.425 m in front of the robot, a fixture box and a mesh part on it."""
    return (
        Shape("table", "box", pose=make_transform(p=[1.3, 0.0, 0.4]), size_m=(1.0, 1.2, 0.05)),
        Shape("fixture", "box", pose=make_transform(p=[1.3, 0.35, 0.5]), size_m=(0.2, 0.2, 0.15)),
        Shape(
            "part",
            "mesh",
            pose=make_transform(p=[1.3, -0.25, 0.475]),
            file=box_mesh_file,
            units="mm",
            workpiece=True,
        ),
    )


@pytest.fixture(scope="session")
def cell_model(irb4600, table_cell, nozzle, base_in_world):
    return _make_model(irb4600, table_cell, (nozzle,), base=base_in_world)


@pytest.fixture(scope="session")
def kin(irb4600, tcp_in_flange):
    return TcpKinematics(irb4600, np.eye(4), tcp_in_flange)
