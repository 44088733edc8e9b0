"""Behaviour of the DXF CAD path reader (refine.cad.dxf)."""

import math

import ezdxf
import numpy as np
import pytest

from refine.cad.dxf import points_from_dxf
from refine.errors import InputError


def _save(tmp_path, build, name="part.dxf"):
    doc = ezdxf.new()
    build(doc.modelspace())
    path = tmp_path / name
    doc.saveas(path)
    return path


def test_3d_polyline_keeps_its_vertices_in_metres(tmp_path):
    verts = [(0, 0, 0), (100, 0, 10), (100, 50, 20)]
    f = _save(tmp_path, lambda msp: msp.add_polyline3d(verts))
    np.testing.assert_allclose(points_from_dxf(f, "mm"), np.array(verts) / 1000.0)


def test_closed_3d_polyline_repeats_its_first_point_last(tmp_path):
    verts = [(0, 0, 0), (1, 0, 1), (1, 1, 2)]
    f = _save(tmp_path, lambda msp: msp.add_polyline3d(verts, close=True))
    pts = points_from_dxf(f, "m")
    np.testing.assert_allclose(pts[:3], verts)
    assert np.array_equal(pts[-1], pts[0]) and len(pts) == 4


def test_lwpolyline_bulge_becomes_an_arc_at_the_elevation(tmp_path):
    # (0,0) -> (10,0) straight, then a half circle (bulge 1) to (10,10), centre (10,5), r 5
    def build(msp):
        msp.add_lwpolyline([(0, 0, 0), (10, 0, 1), (10, 10, 0)], format="xyb", dxfattribs={"elevation": 5.0})

    pts = points_from_dxf(_save(tmp_path, build), "mm", flatten_tolerance_m=1e-7) * 1000.0
    np.testing.assert_allclose(pts[:, 2], 5.0)
    np.testing.assert_allclose(pts[0], [0, 0, 5])
    np.testing.assert_allclose(pts[-1], [10, 10, 5])
    arc = pts[2:]
    np.testing.assert_allclose(np.hypot(arc[:, 0] - 10, arc[:, 1] - 5), 5.0, atol=1e-12)
    assert arc[:, 0].max() == pytest.approx(15.0, abs=1e-3)  # bulge 1 > 0: counter-clockwise
    chord = np.linalg.norm(np.diff(arc, axis=0), axis=1).max()
    assert 5.0 * (1 - math.cos(chord / 5.0 / 2)) <= 1e-4 + 1e-12  # sagitta <= tolerance [mm]


def test_negative_bulge_turns_clockwise(tmp_path):
    f = _save(tmp_path, lambda m: m.add_lwpolyline([(0, 0, -1), (0, 10, 0)], format="xyb"))
    pts = points_from_dxf(f, "mm")
    assert pts[:, 0].min() == pytest.approx(-0.005, abs=1e-6)  # going up +y it bulges to -x
    assert pts[:, 0].max() < 1e-12


def test_spline_is_flattened_and_closed_spline_is_closed(tmp_path):
    ctrl = [(0, 0, 0), (1, 1, 0), (2, 0, 0), (3, 1, 0)]
    pts = points_from_dxf(_save(tmp_path, lambda m: m.add_spline_control_frame(ctrl)), "m")
    assert len(pts) > 10
    np.testing.assert_allclose(pts[0], ctrl[0], atol=1e-12)
    np.testing.assert_allclose(pts[-1], ctrl[-1], atol=1e-12)

    def build(msp):
        msp.add_spline([(0, 0, 0), (2, 0, 0), (2, 2, 0), (0, 2, 0)]).closed = True

    loop = points_from_dxf(_save(tmp_path, build, "loop.dxf"), "m")
    assert np.array_equal(loop[0], loop[-1])


def test_lines_and_arcs_in_any_order_and_direction_are_chained(tmp_path):
    def build(msp):
        msp.add_line((10, 10, 0), (10, 0, 0))  # stored backwards
        msp.add_line((0, 0, 0), (10, 0, 0)).dxf.layer = "other"
        msp.add_arc(center=(10, 15, 0), radius=5, start_angle=-90, end_angle=90)  # up to (10, 20)

    pts = points_from_dxf(_save(tmp_path, build), "mm") * 1000.0
    # the first line has no loose end, so the chain starts at the second line's
    np.testing.assert_allclose(pts[0], [0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(pts[-1], [10, 20, 0], atol=1e-9)
    np.testing.assert_allclose(pts[1:3], [[10, 0, 0], [10, 10, 0]], atol=1e-9)
    arc = pts[2:]
    np.testing.assert_allclose(np.hypot(arc[:, 0] - 10, arc[:, 1] - 15), 5.0, atol=1e-9)
    assert len(arc) > 10


def test_lines_that_meet_at_both_ends_make_a_closed_path(tmp_path):
    corners = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]

    def build(msp):
        for a, b in zip(corners, corners[1:] + corners[:1], strict=True):
            msp.add_line(a, b)

    pts = points_from_dxf(_save(tmp_path, build), "m")
    assert len(pts) == 5 and np.array_equal(pts[0], pts[-1])


def test_several_paths_without_layer_list_the_layers(tmp_path):
    def build(msp):
        msp.add_lwpolyline([(0, 0), (1, 0)], dxfattribs={"layer": "BEAD"})
        msp.add_lwpolyline([(0, 1), (1, 1)], dxfattribs={"layer": "CONTOUR"})

    with pytest.raises(InputError, match=r"layer 'BEAD': LWPOLYLINE.*layer 'CONTOUR'"):
        points_from_dxf(_save(tmp_path, build), "mm")


def test_a_layer_picks_its_entities_and_chains_them(tmp_path):
    def build(msp):
        msp.add_lwpolyline([(0, 0), (5, 0)], dxfattribs={"layer": "BEAD"})
        msp.add_line((5, 0, 0), (5, 5, 0), dxfattribs={"layer": "bead"})
        msp.add_lwpolyline([(0, 9), (9, 9)], dxfattribs={"layer": "CONTOUR"})

    f = _save(tmp_path, build)
    np.testing.assert_allclose(points_from_dxf(f, "m", layer="Bead"), [[0, 0, 0], [5, 0, 0], [5, 5, 0]])
    np.testing.assert_allclose(points_from_dxf(f, "m", layer="CONTOUR"), [[0, 9, 0], [9, 9, 0]])
    with pytest.raises(InputError, match="no path entities on layer 'MISSING'.*'BEAD'"):
        points_from_dxf(f, "m", layer="MISSING")


def test_pieces_with_a_gap_are_rejected_naming_the_loose_ends(tmp_path):
    def build(msp):
        msp.add_line((0, 0, 0), (1, 0, 0))
        msp.add_line((2, 0, 0), (3, 0, 0))

    with pytest.raises(InputError, match="4 loose ends"):
        points_from_dxf(_save(tmp_path, build), "m")


def test_unreadable_file_is_an_input_error(tmp_path):
    f = tmp_path / "broken.dxf"
    f.write_text("not a dxf")
    with pytest.raises(InputError, match="broken.dxf"):
        points_from_dxf(f, "mm")


def test_read_cad_path_reads_a_closed_dxf_loop_on_a_layer(tmp_path):
    from refine.cad import read_cad_path
    from refine.problem import CadSettings

    def build(msp):
        msp.add_lwpolyline([(0, 0), (100, 0), (100, 50), (0, 50)], close=True, dxfattribs={"layer": "PANE"})
        msp.add_line((0, 0, 0), (1, 1, 0), dxfattribs={"layer": "NOTES"})

    f = _save(tmp_path, build)
    path = read_cad_path(
        CadSettings(file=f, format="dxf", units="mm", layer="PANE", spacing_m=0.007), np.eye(4)
    )
    assert path.closed and path.length == pytest.approx(0.3)
    assert np.array_equal(path.positions[0], path.positions[-1])
    assert np.all(np.diff(path.s) <= 0.007)


def test_a_drawing_read_again_is_parsed_once_and_a_changed_file_is_parsed_again(tmp_path, monkeypatch):
    """The path and the arcs of one file parse it once; new bytes under the same name (same size,
    so only the content tells) are parsed again and give the new points; another thread parses its own."""
    import threading

    import refine.cad.dxf as dxf

    parsed = []
    readfile = ezdxf.readfile
    monkeypatch.setattr(dxf.ezdxf, "readfile", lambda p: parsed.append(p) or readfile(p))
    f = _save(tmp_path, lambda msp: msp.add_lwpolyline([(0, 0, 0), (10, 0, 1), (10, 10, 0)], format="xyb"))
    first = points_from_dxf(f, "mm")
    circles = dxf.dxf_circles(f, "mm")
    assert len(parsed) == 1 and len(circles) == 1
    np.testing.assert_allclose(circles[0][0], [0.010, 0.005, 0.0], atol=1e-12)  # the bulge's centre [m]
    np.testing.assert_allclose(points_from_dxf(f, "mm"), first)
    assert len(parsed) == 1
    size = f.stat().st_size
    text = f.read_text().replace("\n10.0\n", "\n20.0\n")  # the polyline's x = 10 vertices now at x = 20
    assert len(text) == size and text != f.read_text()
    f.write_text(text)
    moved = points_from_dxf(f, "mm")
    assert len(parsed) == 2 and not np.array_equal(moved, first)
    copy = tmp_path / "copy.dxf"  # the new bytes under another name: parsed afresh
    copy.write_text(text)
    np.testing.assert_array_equal(points_from_dxf(copy, "mm"), moved)
    assert len(parsed) == 3
    other = []
    thread = threading.Thread(target=lambda: other.append(points_from_dxf(copy, "mm")))
    thread.start()
    thread.join()
    assert len(parsed) == 4  # another thread parses its own, though this thread's last is that file
    np.testing.assert_array_equal(other[0], moved)
