"""COLLADA meshes (``.dae``, through pycollada) as cell objects and URDF collision meshes, in metres."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import trimesh

from refine.collision.geometry import load_mesh
from refine.errors import InputError
from refine.robot.geometry import mesh_hull, read_mesh
from refine.settings import Shape


def _box_dae(path, unit_line: str):
    """A 200 x 100 x 50 box in a COLLADA file whose asset states ``unit_line``."""
    pytest.importorskip("collada")
    trimesh.creation.box(extents=[200.0, 100.0, 50.0]).export(path)
    text = path.read_text()
    assert "<up_axis>" in text
    path.write_text(text.replace("<up_axis>Y_UP</up_axis>", f"{unit_line}<up_axis>Z_UP</up_axis>"))
    return path


def test_a_collada_file_in_millimetres_comes_in_metres(tmp_path):
    path = _box_dae(tmp_path / "box.dae", '<unit meter="0.001" name="millimeter"/>')
    mesh = read_mesh(path, "test")
    assert np.sort(mesh.extents) == pytest.approx([0.05, 0.1, 0.2])
    shape = Shape("fixture", "mesh", file=path)
    assert np.sort(load_mesh(shape).extents) == pytest.approx([0.05, 0.1, 0.2])
    hull = mesh_hull(path, (1.0, 1.0, 2.0), "urdf link")  # a URDF's scale on top of the file's unit
    extent = hull.vertices.max(axis=0) - hull.vertices.min(axis=0)
    assert extent == pytest.approx([0.2, 0.1, 0.1])


def test_a_collada_file_in_metres_is_read_as_it_stands(tmp_path):
    path = _box_dae(tmp_path / "box.dae", '<unit meter="1" name="meter"/>')
    assert np.sort(read_mesh(path, "test").extents) == pytest.approx([50.0, 100.0, 200.0])


def test_collada_without_pycollada_names_the_package(tmp_path, monkeypatch):
    path = tmp_path / "part.dae"
    path.write_text("<COLLADA/>")
    monkeypatch.setitem(sys.modules, "collada", None)
    with pytest.raises(InputError, match=r"part\.dae is COLLADA, which needs pycollada"):
        read_mesh(path, "cell object 'part'")
