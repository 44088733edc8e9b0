"""Behaviour of the CSV CAD path reader (refine.cad.csv_) and read_cad_path."""

import numpy as np
import pytest

from refine.cad import read_cad_path
from refine.cad.csv_ import points_from_csv
from refine.errors import InputError
from refine.frames import make_transform, rotation_about
from refine.problem import CadSettings


def test_header_is_case_and_whitespace_tolerant_and_units_become_metres(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("# a comment\n  X , y,Z \n0,0,0\n\n10, 20 ,30\n")
    np.testing.assert_allclose(points_from_csv(f, "mm"), [[0, 0, 0], [0.01, 0.02, 0.03]])


def test_file_without_header_is_read_in_inches(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("0,0,0\n1,2,3\n")
    np.testing.assert_allclose(points_from_csv(f, "in"), [[0, 0, 0], [0.0254, 0.0508, 0.0762]])


def test_header_columns_may_come_in_any_order_with_extra_columns(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("z,feed,x,y\n3,100,1,2\n6,100,4,5\n")
    np.testing.assert_allclose(points_from_csv(f, "m"), [[1, 2, 3], [4, 5, 6]])


def test_malformed_line_error_names_file_and_line(tmp_path):
    f = tmp_path / "bad.csv"
    f.write_text("x,y,z\n0,0,0\n1,two,3\n")
    with pytest.raises(InputError, match=r"bad\.csv:3.*two"):
        points_from_csv(f, "mm")


def test_header_missing_a_column_is_named(tmp_path):
    f = tmp_path / "bad.csv"
    f.write_text("x,y,w\n0,0,0\n1,2,3\n")
    with pytest.raises(InputError, match=r"bad\.csv:1.*lacks column\(s\) z"):
        points_from_csv(f, "mm")


def test_unknown_unit_and_single_point_are_rejected(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("0,0,0\n")
    with pytest.raises(InputError, match="at least 2 points"):
        points_from_csv(f, "mm")
    with pytest.raises(InputError, match="'ft'"):
        points_from_csv(f, "ft")


def test_read_cad_path_reverses_transforms_and_resamples(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("x,y,z\n0,0,0\n100,0,0\n100,50,0\n")
    T = make_transform(rotation_about("z", np.pi / 2), [1.0, 2.0, 3.0])
    path = read_cad_path(CadSettings(file=f, units="mm", spacing_m=0.01, reverse=True), T)
    assert not path.closed
    assert path.length == pytest.approx(0.15)
    np.testing.assert_allclose(path.positions[0], [1.0 - 0.05, 2.1, 3.0], atol=1e-12)
    np.testing.assert_allclose(path.positions[-1], [1.0, 2.0, 3.0], atol=1e-12)
    assert np.all(np.diff(path.s) <= 0.01 + 1e-15)


def test_read_cad_path_marks_a_path_ending_at_its_start_closed(tmp_path):
    f = tmp_path / "loop.csv"
    f.write_text("0,0,0\n100,0,0\n100,100,0\n0,0,0\n")
    path = read_cad_path(CadSettings(file=f, units="mm", spacing_m=0.02), np.eye(4))
    assert path.closed
    assert np.array_equal(path.positions[0], path.positions[-1])
