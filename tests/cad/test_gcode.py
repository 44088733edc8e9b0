"""Behaviour of the G-code reader (refine.cad.gcode)."""

import math
from pathlib import Path

import numpy as np
import pytest

from refine.cad.gcode import points_from_gcode
from refine.errors import InputError

DATA = Path(__file__).resolve().parents[1] / "data"


def _write(tmp_path, text, name="part.nc"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _length(p):
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def _radii(p, centre, axes=(0, 1)):
    return np.hypot(p[:, axes[0]] - centre[0], p[:, axes[1]] - centre[1])


def _sweep(p, centre=(0.0, 0.0), axes=(0, 1)):
    """Signed angle [rad] the points turn about the centre in the (u, v) plane (+: u towards v)."""
    a = np.unwrap(np.arctan2(p[:, axes[1]] - centre[1], p[:, axes[0]] - centre[0]))
    return float(a[-1] - a[0])


def test_clockwise_ijk_arc_lies_on_its_circle_and_turns_clockwise(tmp_path):
    f = _write(tmp_path, "G21 G90\nG0 X10 Y0\nG2 X0 Y-10 I-10 J0\n")
    p = points_from_gcode(f, "mm")
    np.testing.assert_allclose(_radii(p, (0.0, 0.0)), 0.01, atol=1e-9)
    assert np.all(p[:, 0] >= -1e-12) and np.all(p[:, 1] <= 1e-12)  # the short way through -y
    assert _sweep(p) == pytest.approx(-0.5 * math.pi)
    np.testing.assert_allclose(p[-1], [0.0, -0.01, 0.0], atol=1e-15)


def test_counter_clockwise_arc_between_the_same_points_goes_the_long_way(tmp_path):
    f = _write(tmp_path, "G21\nG0 X10 Y0\nG3 X0 Y-10 I-10 J0\n")
    p = points_from_gcode(f, "mm")
    np.testing.assert_allclose(_radii(p, (0.0, 0.0)), 0.01, atol=1e-9)
    assert p[:, 1].max() == pytest.approx(0.01, abs=1e-5) and p[:, 0].min() == pytest.approx(-0.01, abs=1e-5)
    assert _sweep(p) == pytest.approx(1.5 * math.pi)


def test_chords_stay_within_the_arc_tolerance(tmp_path):
    f = _write(tmp_path, "G21\nG0 X100 Y0\nG3 X-100 Y0 I-100 J0\n")
    p = points_from_gcode(f, "mm")
    mid = 0.5 * (p[1:] + p[:-1])
    assert (0.1 - _radii(mid, (0.0, 0.0))).max() <= 1e-5


@pytest.mark.parametrize(
    ("code", "r", "centre", "sweep"),
    [
        ("G2", 10, (0, 0), -0.5),
        ("G2", -10, (10, -10), -1.5),
        ("G3", 10, (10, -10), 0.5),
        ("G3", -10, (0, 0), 1.5),
    ],
)
def test_radius_form_picks_the_short_or_long_arc_by_its_sign(tmp_path, code, r, centre, sweep):
    f = _write(tmp_path, f"G21\nG0 X10 Y0\n{code} X0 Y-10 R{r}\n")
    p = points_from_gcode(f, "mm") * 1000.0
    np.testing.assert_allclose(_radii(p, centre), 10.0, atol=1e-6)  # 1e-9 m
    assert _sweep(p, centre) == pytest.approx(sweep * math.pi)


def test_radius_and_offset_forms_give_the_same_points(tmp_path):
    a = points_from_gcode(_write(tmp_path, "G21\nG0 X10\nG2 X0 Y-10 R10\n", "a.nc"))
    b = points_from_gcode(_write(tmp_path, "G21\nG0 X10\nG2 X0 Y-10 I-10 J0\n", "b.nc"))
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_g18_arc_turns_clockwise_seen_from_plus_y(tmp_path):
    f = _write(tmp_path, "G21 G18\nG0 X10 Y0 Z0\nG2 X0 Z10 I-10 K0\n")
    p = points_from_gcode(f, "mm")
    np.testing.assert_allclose(_radii(p, (0.0, 0.0), axes=(2, 0)), 0.01, atol=1e-9)
    np.testing.assert_allclose(p[:, 1], 0.0)
    assert np.all(p[:, [0, 2]] >= -1e-12)  # the quarter through +x +z
    assert _sweep(p, axes=(2, 0)) == pytest.approx(-0.5 * math.pi)  # (z, x) plane: z x x = +y


def test_g19_arc_turns_counter_clockwise_seen_from_plus_x(tmp_path):
    ccw = points_from_gcode(_write(tmp_path, "G21 G19\nG0 Y10\nG3 Y0 Z10 J-10 K0\n", "a.nc"))
    cw = points_from_gcode(_write(tmp_path, "G21 G19\nG0 Y10\nG2 Y0 Z10 J-10 K0\n", "b.nc"))
    for p in (ccw, cw):
        np.testing.assert_allclose(_radii(p, (0.0, 0.0), axes=(1, 2)), 0.01, atol=1e-9)
    assert np.all(ccw[:, 1:] >= -1e-12)
    assert _sweep(ccw, axes=(1, 2)) == pytest.approx(0.5 * math.pi)
    assert _sweep(cw, axes=(1, 2)) == pytest.approx(-1.5 * math.pi)


def test_full_circle_with_a_linear_third_axis_is_a_helix(tmp_path):
    f = _write(tmp_path, "G21\nG0 X10 Y0 Z0\nG3 X10 Y0 Z5 I-10 J0 P2\n")
    p = points_from_gcode(f, "mm") * 1000.0
    np.testing.assert_allclose(_radii(p, (0.0, 0.0)), 10.0, atol=1e-6)
    angle = np.unwrap(np.arctan2(p[:, 1], p[:, 0]))
    np.testing.assert_allclose(p[:, 2], 5.0 * angle / (4.0 * math.pi), atol=1e-9)  # two turns
    np.testing.assert_allclose(p[-1], [10.0, 0.0, 5.0], atol=1e-12)


def test_inch_relative_program_equals_the_mm_absolute_one():
    a = points_from_gcode(DATA / "seam.nc", "m")  # G21 in the file overrides the argument
    b = points_from_gcode(DATA / "seam_inch_relative.nc", "mm")
    assert a.shape == b.shape
    np.testing.assert_allclose(a, b, atol=1e-12)
    np.testing.assert_allclose(a[0], [0.0, 0.0, 0.00508], atol=1e-15)
    np.testing.assert_allclose(a[-1], [0.3048, -0.1524, 0.00508], atol=1e-15)


def test_units_argument_applies_until_the_file_says_otherwise(tmp_path):
    p = points_from_gcode(_write(tmp_path, "G1 X1\nG21\nG1 X30\n"), "in")
    np.testing.assert_allclose(p[:, 0], [0.0, 0.0254, 0.030])


def test_coordinate_only_lines_repeat_the_motion_and_comments_are_ignored(tmp_path):
    text = "N5 G21 (mm) G90 ; abs\n/N10 G1 X10 F500 (feed)\nN20 Y10 S1000 M3\nX0 ; back\n"
    p = points_from_gcode(_write(tmp_path, text))
    np.testing.assert_allclose(p * 1000.0, [[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]], atol=1e-12)


SEVERAL = "G21\nG0 X0 Y0\nG1 X10\nG1 Y10\nG0 X50 Y0\nG1 X60\nG0 Z10\n"


def test_several_feed_sequences_need_a_choice_and_the_error_lists_them(tmp_path):
    f = _write(tmp_path, SEVERAL)
    with pytest.raises(InputError) as e:
        points_from_gcode(f)
    msg = str(e.value)
    assert "part.nc" in msg and "2 feed sequences" in msg
    assert "starts at [50.0, 0.0, 0.0] mm" in msg and "length 10.000 mm" in msg and "length 20.000 mm" in msg


@pytest.mark.parametrize("program", [2, "2", " 2 "])
def test_a_feed_sequence_is_chosen_by_number_or_numeric_string(tmp_path, program):
    p = points_from_gcode(_write(tmp_path, SEVERAL), program=program)
    np.testing.assert_allclose(p * 1000.0, [[50, 0, 0], [60, 0, 0]], atol=1e-12)


@pytest.mark.parametrize("program", [0, 3, "two"])
def test_a_missing_feed_sequence_is_an_error(tmp_path, program):
    with pytest.raises(InputError, match="feed sequence"):
        points_from_gcode(_write(tmp_path, SEVERAL), program=program)


@pytest.mark.parametrize(
    ("line", "why"),
    [
        ("G1 X12.5.3", "cannot read"),
        ("G1 X", "cannot read"),
        ("G28 X0", "unsupported code G28"),
        ("G1 A30", "unsupported word A30"),
        ("G2 X5 Y5", "needs I/J/K or R"),
        ("G2 X20 Y0 I3", "not on one circle"),
        ("G1 X1 (open", "unclosed comment"),
        ("G2 X40 Y0 R10", "smaller than half the chord"),
    ],
)
def test_a_malformed_line_names_the_file_and_line(tmp_path, line, why):
    f = _write(tmp_path, f"G21\nG1 X1\n{line}\n")
    with pytest.raises(InputError, match=why) as e:
        points_from_gcode(f)
    assert f"{f}:3" in str(e.value)


def test_coordinates_before_a_motion_code_and_rapids_only_are_errors(tmp_path):
    with pytest.raises(InputError, match=r"part.nc:2: coordinates before any motion"):
        points_from_gcode(_write(tmp_path, "G21\nX10\n"))
    with pytest.raises(InputError, match="no feed moves"):
        points_from_gcode(_write(tmp_path, "G21\nG0 X10\nY5\n"))
