"""Every example file in tests/data parses, and the stage entry points dispatch to the new readers."""

from pathlib import Path

import numpy as np
import pytest

from refine.cad import read_cad_path
from refine.cad.gcode import points_from_gcode
from refine.cad.mesh import points_from_mesh
from refine.demo.liberty_binary import read_liberty_binary
from refine.frames import transform_from_xyz_rpy, transform_points
from refine.problem import CadSettings

DATA = Path(__file__).resolve().parent / "data"

READERS = {
    ".nc": lambda f: points_from_gcode(f, "mm"),
    ".stl": lambda f: points_from_mesh(f, "mm", section_origin=(0, 50, 0), section_normal=(0, 1, 0)),
    ".ply": lambda f: points_from_mesh(f, "mm", boundary=True),
    ".obj": lambda f: points_from_mesh(f, "mm", boundary=True),
    ".lyb": lambda f: read_liberty_binary(f).positions,
}
FILES = sorted(f for f in DATA.iterdir() if f.name != "README.md")


def test_every_example_file_has_a_reader_and_is_listed_in_the_readme():
    readme = (DATA / "README.md").read_text()
    for f in FILES:
        assert f.suffix in READERS, f"no reader registered for {f.name}"
        assert f"`{f.name}`" in readme, f"{f.name} is not described in tests/data/README.md"


@pytest.mark.parametrize("path", FILES, ids=lambda f: f.name)
def test_example_file_parses(path):
    points = READERS[path.suffix](path)
    assert points.ndim == 2 and points.shape[1] == 3 and len(points) >= 2
    assert np.all(np.isfinite(points))


def test_read_cad_path_reads_gcode_in_the_world_frame():
    T = transform_from_xyz_rpy([1.0, 0.5, 0.2], [0.0, 0.0, 90.0])
    path = read_cad_path(CadSettings(file=DATA / "seam.nc", format="gcode", spacing_m=0.002, track="1"), T)
    raw = points_from_gcode(DATA / "seam.nc")
    np.testing.assert_allclose(path.positions[[0, -1]], transform_points(T, raw[[0, -1]]), atol=1e-12)
    assert not path.closed and np.diff(path.s).max() <= 0.002 + 1e-12


def test_read_cad_path_reads_a_mesh_boundary_as_a_closed_path():
    settings = CadSettings(
        file=DATA / "washer.obj", format="mesh", boundary=True, start_near=(50.0, 0.0, 0.0)
    )
    path = read_cad_path(settings, np.eye(4))
    assert path.closed
    np.testing.assert_allclose(path.positions[0], [0.05, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(np.hypot(path.positions[:, 0], path.positions[:, 1]).max(), 0.05)
