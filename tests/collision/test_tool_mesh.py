"""A tool shape given as a mesh file: read from the problem folder, used as its convex hull."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh

from refine.collision import CollisionModel
from refine.errors import InputError
from refine.frames import make_transform
from refine.problem import load_problem
from refine.settings import Shape

BUNDLED = Path(__file__).resolve().parents[2] / "problems" / "glass_adhesive"


def _torch(path: Path) -> None:
    """A bent torch in mm: a 20 mm square neck 200 mm down z, then a 150 mm arm along +x (concave)."""
    neck = trimesh.creation.box([20.0, 20.0, 200.0])
    neck.apply_translation([0.0, 0.0, 100.0])
    arm = trimesh.creation.box([150.0, 20.0, 20.0])
    arm.apply_translation([75.0, 0.0, 190.0])
    trimesh.util.concatenate([neck, arm]).export(path)


def test_a_tool_mesh_is_measured_as_its_convex_hull(irb4600, tmp_path):
    _torch(tmp_path / "torch.stl")
    torch = Shape(
        "torch", "mesh", pose=make_transform(p=[0.0, 0.0, 0.01]), file=tmp_path / "torch.stl", units="mm"
    )
    q = np.zeros(6)
    flange = irb4600.fk(q)
    # the hull's slanted face runs from the neck's foot (x 10, z 0 mm) to the arm's lower far corner
    # (x 150, z 180 mm) in the shape frame; a ball in the notch between neck and arm (x 60, z 120 mm)
    # is inside the hull though outside the torch itself
    notch = flange @ np.array([0.06, 0.0, 0.12 + 0.01, 1.0])
    ball = Shape("ball", "sphere", pose=make_transform(p=notch[:3]), radius_m=0.005)
    model = CollisionModel(irb4600, np.eye(4), np.eye(4), (torch,), (ball,), margin_m=0.0, self_margin_m=0.0)
    (contact,) = [c for c in model.contacts(q, np.inf) if c.body == "tool:torch" and c.other == "ball"]
    assert contact.distance_m < 0.0
    # beyond the slanted face along its outward normal: the distance is the offset minus the radius
    hull = trimesh.convex.convex_hull(trimesh.load(tmp_path / "torch.stl").vertices * 1e-3)
    assert hull.volume > 0.0
    a, b = np.array([0.010, 0.0, 0.0]), np.array([0.150, 0.0, 0.180])
    edge = (b - a) / np.linalg.norm(b - a)
    normal = np.array([edge[2], 0.0, -edge[0]])  # in the x-z plane, pointing away from the torch
    point = (a + b) / 2 + 0.03 * normal + [0.0, 0.0, 0.01]
    ball = Shape(
        "ball", "sphere", pose=make_transform(p=(flange @ np.append(point, 1.0))[:3]), radius_m=0.005
    )
    model = CollisionModel(irb4600, np.eye(4), np.eye(4), (torch,), (ball,), margin_m=0.0, self_margin_m=0.0)
    (contact,) = [c for c in model.contacts(q, np.inf) if c.body == "tool:torch" and c.other == "ball"]
    assert contact.distance_m == pytest.approx(0.025, abs=1e-5)


def test_tool_collision_takes_a_mesh_file_relative_to_the_problem_folder(tmp_path):
    folder = tmp_path / "p"
    shutil.copytree(BUNDLED, folder)
    _torch(folder / "torch.stl")
    toml = folder / "problem.toml"
    toml.write_text(
        toml.read_text()
        + '\n[[tool.collision]]\nname = "torch_model"\nshape = "mesh"\nfile = "torch.stl"\nunits = "mm"\n'
    )
    problem = load_problem(folder)
    (shape,) = [s for s in problem.tool.collision if s.name == "torch_model"]
    assert Path(shape.file) == folder / "torch.stl"


def test_a_flat_tool_mesh_is_an_input_error_naming_the_shape(irb4600, tmp_path):
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]])
    flat.export(tmp_path / "flat.stl")
    shape = Shape("plate", "mesh", file=tmp_path / "flat.stl")
    with pytest.raises(InputError, match="tool shape 'plate'.*one plane"):
        CollisionModel(irb4600, np.eye(4), np.eye(4), (shape,), (), margin_m=0.0, self_margin_m=0.0)
