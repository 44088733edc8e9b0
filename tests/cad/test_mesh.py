"""Behaviour of the mesh path reader (refine.cad.mesh): plane sections and open boundaries."""

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from refine.cad.mesh import points_from_mesh
from refine.errors import InputError

DATA = Path(__file__).resolve().parents[1] / "data"


def _length(p):
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def _save(tmp_path, mesh, name="part.stl"):
    path = tmp_path / name
    mesh.export(path)
    return path


def _grid(nx=5, ny=4, size=(200.0, 100.0)):
    """An open flat plate in z = 0, faces wound counter-clockwise seen from +z [mm]."""
    u, v = np.meshgrid(np.linspace(0, size[0], nx), np.linspace(0, size[1], ny), indexing="ij")
    pts = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)])
    idx = np.arange(u.size).reshape(u.shape)
    faces = []
    for i in range(nx - 1):
        for j in range(ny - 1):
            a, b, c, d = idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]
            faces += [(a, b, c), (a, c, d)]
    return trimesh.Trimesh(pts, np.array(faces), process=False)


def _ccw_about(p, normal):
    area = np.cross(p[:-1] - p[0], p[1:] - p[0]).sum(axis=0)
    return float(area @ np.asarray(normal, float)) > 0.0


def test_section_of_a_box_is_its_closed_perimeter_counter_clockwise(tmp_path):
    f = _save(tmp_path, trimesh.creation.box(extents=(200.0, 100.0, 50.0)))
    p = points_from_mesh(f, "mm", section_origin=(0, 0, 10), section_normal=(0, 0, 2))
    assert np.array_equal(p[0], p[-1])
    assert _length(p) == pytest.approx(0.6, abs=1e-12)
    np.testing.assert_allclose(p[:, 2], 0.010)
    assert _ccw_about(p, (0, 0, 1))
    p_down = points_from_mesh(f, "mm", section_origin=(0, 0, 10), section_normal=(0, 0, -1))
    assert _ccw_about(p_down, (0, 0, -1))


def test_section_of_a_cylinder_is_its_inscribed_polygon(tmp_path):
    n, r = 64, 30.0
    f = _save(tmp_path, trimesh.creation.cylinder(radius=r, height=40.0, sections=n))
    p = points_from_mesh(f, "mm", section_origin=(0, 0, 5), section_normal=(0, 0, 1)) * 1000.0
    radii = np.hypot(p[:, 0], p[:, 1])  # STL stores float32: 1e-5 mm
    assert radii.max() == pytest.approx(r, abs=1e-5) and radii.min() >= r * math.cos(math.pi / n) - 1e-5
    assert _length(p) == pytest.approx(2 * n * r * math.sin(math.pi / n), abs=1e-4)


def test_boundary_of_an_open_plate_is_its_rectangle_in_face_winding(tmp_path):
    f = _save(tmp_path, _grid(), "plate.ply")
    p = points_from_mesh(f, "mm", boundary=True)
    assert np.array_equal(p[0], p[-1])
    assert _length(p) == pytest.approx(0.6, abs=1e-12)
    corners = {(0.0, 0.0), (0.2, 0.0), (0.2, 0.1), (0.0, 0.1)}
    assert corners <= {tuple(np.round(q[:2], 12)) for q in p}
    assert _ccw_about(p, (0, 0, 1))


def test_start_near_starts_a_closed_loop_at_its_nearest_point(tmp_path):
    f = _save(tmp_path, _grid(), "plate.obj")
    p = points_from_mesh(f, "mm", boundary=True, start_near=(130.0, -7.0, 3.0))
    np.testing.assert_allclose(p[0], [0.130, 0.0, 0.0], atol=1e-12)  # inside an edge: inserted
    assert np.array_equal(p[-1], p[0]) and _length(p) == pytest.approx(0.6, abs=1e-12)
    q = points_from_mesh(f, "mm", boundary=True, start_near=(205.0, 52.0, 0.0))
    np.testing.assert_allclose(q[0], [0.2, 0.052, 0.0], atol=1e-12)
    corner = points_from_mesh(f, "mm", boundary=True, start_near=(205.0, -5.0, 0.0))
    np.testing.assert_allclose(corner[0], [0.2, 0.0, 0.0], atol=1e-12)  # a vertex: nothing inserted
    assert len(corner) == len(p) - 1


def test_several_loops_longest_first_or_the_one_nearest_start_near():
    outer = points_from_mesh(DATA / "washer.obj", "mm", boundary=True)
    assert np.hypot(outer[:, 0], outer[:, 1]) == pytest.approx(0.050)
    inner = points_from_mesh(DATA / "washer.obj", "mm", boundary=True, start_near=(0.0, 21.0, 0.0))
    assert np.hypot(inner[:, 0], inner[:, 1]) == pytest.approx(0.020)
    np.testing.assert_allclose(inner[0], [0.0, 0.020, 0.0], atol=1e-12)


def test_open_section_chain_starts_at_the_end_nearer_start_near(tmp_path):
    f = _save(tmp_path, _grid(), "plate.stl")
    p = points_from_mesh(
        f, "mm", section_origin=(50, 0, 0), section_normal=(1, 0, 0), start_near=(50, 200, 0)
    )
    np.testing.assert_allclose(p[[0, -1]], [[0.05, 0.1, 0.0], [0.05, 0.0, 0.0]], atol=1e-12)


def test_units_scale_coordinates_and_the_plane(tmp_path):
    f = _save(tmp_path, trimesh.creation.box(extents=(2.0, 1.0, 1.0)))
    p = points_from_mesh(f, "in", section_origin=(0, 0, 0.25), section_normal=(0, 0, 1))
    assert _length(p) == pytest.approx(6 * 0.0254, abs=1e-12)
    np.testing.assert_allclose(p[:, 2], 0.25 * 0.0254)


def test_a_plane_that_misses_the_mesh_names_file_plane_and_units(tmp_path):
    f = _save(tmp_path, trimesh.creation.box(extents=(10.0, 10.0, 10.0)))
    with pytest.raises(InputError, match=r"part.stl.*\[0.0, 0.0, 50.0\] mm.*misses the mesh"):
        points_from_mesh(f, "mm", section_origin=(0, 0, 50), section_normal=(0, 0, 1))


def test_closed_mesh_has_no_boundary_and_bad_arguments_are_errors(tmp_path):
    f = _save(tmp_path, trimesh.creation.box(extents=(10.0, 10.0, 10.0)))
    with pytest.raises(InputError, match="no boundary"):
        points_from_mesh(f, "mm", boundary=True)
    with pytest.raises(InputError, match="either boundary"):
        points_from_mesh(f, "mm")
    with pytest.raises(InputError, match="either boundary"):
        points_from_mesh(f, "mm", boundary=True, section_origin=(0, 0, 0), section_normal=(0, 0, 1))
    with pytest.raises(InputError, match="zero length"):
        points_from_mesh(f, "mm", section_origin=(0, 0, 0), section_normal=(0, 0, 0))
    with pytest.raises(InputError, match="not found"):
        points_from_mesh(tmp_path / "missing.stl", "mm", boundary=True)


def test_bracket_example_sections():
    profile = points_from_mesh(
        DATA / "bracket.stl", "mm", section_origin=(0, 50, 0), section_normal=(0, 1, 0)
    )
    assert _length(profile) == pytest.approx(0.200, abs=1e-12)  # the L profile
    web = points_from_mesh(DATA / "bracket.stl", "mm", section_origin=(0, 0, 20), section_normal=(0, 0, 1))
    assert _length(web) == pytest.approx(0.216, abs=1e-12)  # 8 mm x 100 mm
