"""Finite but absurd values in every reader: refused with the file and the line (or record, entity).

Expected numbers are worked by hand: 1e308 in x 0.0254 m/in = 2.54e306 m; 400 in = 10.16 m is
beyond the 10 m range and 390 in = 9.906 m within it; 1e308 mm = 1e305 m; 2,000,000 mm = 2000 m.
"""

from __future__ import annotations

import struct

import ezdxf
import numpy as np
import pytest
import trimesh

from refine.cad.csv_ import points_from_csv
from refine.cad.dxf import points_from_dxf
from refine.cad.gcode import points_from_gcode
from refine.cad.mesh import points_from_mesh
from refine.demo.csv_ import read_demo_csv
from refine.demo.liberty import read_liberty_ascii
from refine.demo.liberty_binary import read_liberty_binary
from refine.errors import InputError


def _liberty(tmp_path, lines, name="log.txt"):
    f = tmp_path / name
    f.write_text("".join(line + "\n" for line in lines))
    return f


GOOD = "01 {x} 2.0000 3.0000 10.000 20.000 30.000"


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ("1e308", r"position x = 2\.54e\+306 m is outside the plausible range ±10 m"),
        ("400", r"position x = 10\.16 m is outside the plausible range ±10 m"),
        ("-400", r"position x = -10\.16 m is outside"),
    ],
)
def test_an_absurd_liberty_position_is_refused_with_its_line(tmp_path, bad, message):
    f = _liberty(tmp_path, [GOOD.format(x=1.0), GOOD.format(x=1.1), GOOD.format(x=bad), GOOD.format(x=1.2)])
    with pytest.raises(InputError, match=rf"log\.txt:3: {message}"):
        read_liberty_ascii(f)


def test_a_liberty_position_just_inside_the_range_is_read(tmp_path):
    f = _liberty(tmp_path, [GOOD.format(x=1.0), GOOD.format(x=390.0)])
    log = read_liberty_ascii(f)
    assert log.positions[1, 0] == pytest.approx(9.906)


@pytest.mark.parametrize(
    ("angles", "name", "value"),
    [
        ("181.000 20.000 30.000", "azimuth", "181"),
        ("10.000 95.000 30.000", "elevation", "95"),
        ("10.000 20.000 -200.000", "roll", "-200"),
        ("10.000 1e308 30.000", "elevation", "1e\\+308"),
    ],
)
def test_liberty_angles_beyond_the_devices_range_are_refused(tmp_path, angles, name, value):
    f = _liberty(tmp_path, [GOOD.format(x=1.0), f"01 1.0 2.0 3.0 {angles}"])
    with pytest.raises(InputError, match=rf"log\.txt:2: {name} {value} deg is outside the plausible range"):
        read_liberty_ascii(f)


def test_liberty_angles_at_the_ends_of_the_range_are_read(tmp_path):
    f = _liberty(
        tmp_path, ["01 1.0 2.0 3.0 180.000 90.000 -180.000", "01 1.0 2.0 3.0 -180.000 -90.000 180.000"]
    )
    assert len(read_liberty_ascii(f).t) == 2


def test_a_frame_count_jump_of_years_is_refused(tmp_path):
    # frames 0, 1, 10^12: at 240 Hz the third sample is 10^12 / 240 = 4.17e9 s after the first
    f = _liberty(
        tmp_path,
        [
            "01 0 1.0 2.0 3.0 10.0 20.0 30.0",
            "01 1 1.0 2.0 3.0 10.0 20.0 30.0",
            "01 1000000000000 1.0 2.0 3.0 10.0 20.0 30.0",
        ],
    )
    with pytest.raises(
        InputError,
        match=r"log\.txt:3: time 4\.16667e\+09 s after the first sample; a "
        r"demonstration lasts at most 86400 s",
    ):
        read_liberty_ascii(f)


def _binary_record(values, station=1, size=24):
    return b"LY" + bytes([station, ord("C"), 0x20, 0]) + struct.pack("<H", size) + struct.pack("<6f", *values)


def test_an_absurd_binary_position_is_refused_with_its_byte_offset(tmp_path):
    f = tmp_path / "demo.lyb"
    # each record: 8-byte header + 6 float32 = 32 bytes, so the third starts at byte 64
    recs = [_binary_record((1.0, 2.0, 3.0, 10.0, 20.0, 30.0))] * 2 + [
        _binary_record((1e30, 2.0, 3.0, 10.0, 20.0, 30.0))
    ]
    f.write_bytes(b"".join(recs))
    with pytest.raises(InputError, match=r"demo\.lyb: record at byte offset 64: position x = 2\.54e\+28 m"):
        read_liberty_binary(f, output_list=(2, 4))


def test_binary_euler_angles_beyond_the_range_are_refused(tmp_path):
    f = tmp_path / "demo.lyb"
    recs = [
        _binary_record((1.0, 2.0, 3.0, 10.0, 20.0, 30.0)),
        _binary_record((1.0, 2.0, 3.0, 10.0, 120.0, 30.0)),
    ]
    f.write_bytes(b"".join(recs))
    with pytest.raises(InputError, match=r"record at byte offset 32: elevation 120 deg is outside"):
        read_liberty_binary(f, output_list=(2, 4))


def _csv(tmp_path, rows):
    f = tmp_path / "demo.csv"
    f.write_text("t,x,y,z,azimuth,elevation,roll\n" + "".join(r + "\n" for r in rows))
    return f


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ("0.02,1e308,0,0,0,0,0", r"demo\.csv:4: position x = 1e\+305 m is outside"),
        ("0.02,0,0,0,0,0,400", r"demo\.csv:4: roll 400 deg is outside the plausible range ±360 deg"),
        ("0.0100001,0,0,0,0,0,0", r"demo\.csv:4: time 0\.0100001 s is 1e-07 s after the sample before"),
        ("1e12,0,0,0,0,0,0", r"demo\.csv:4: time 1e\+12 s is outside the plausible range ±1e\+10 s"),
        ("90000,0,0,0,0,0,0", r"demo\.csv:4: time 90000 s after the first sample"),
    ],
)
def test_absurd_demo_csv_values_are_refused_with_their_line(tmp_path, row, message):
    f = _csv(tmp_path, ["0,0,0,0,0,0,0", "0.01,1,0,0,0,0,0", row])
    with pytest.raises(InputError, match=message):
        read_demo_csv(f, units="mm")


def test_a_cad_csv_coordinate_of_1e308_is_refused_with_its_line(tmp_path):
    f = tmp_path / "path.csv"
    f.write_text("x,y,z\n0,0,0\n10,0,0\n0,1e308,0\n")
    with pytest.raises(
        InputError, match=r"path\.csv:4: coordinate y = 1e\+305 m is outside the plausible range ±1000 m"
    ):
        points_from_csv(f, units="mm")


def test_a_dxf_arc_of_a_million_kilometres_is_refused_before_it_is_flattened(tmp_path):
    doc = ezdxf.new()
    msp = doc.modelspace()
    msp.add_line((0, 0, 0), (100, 0, 0))
    arc = msp.add_arc((100, 1e12, 0), radius=1e12, start_angle=270, end_angle=280)
    f = tmp_path / "path.dxf"
    doc.saveas(f)
    with pytest.raises(
        InputError, match=rf"path\.dxf.*ARC #{arc.dxf.handle} .* value 1e\+12 mm \(1e\+09 m\), outside"
    ):
        points_from_dxf(f, units="mm")


def test_a_mesh_vertex_beyond_the_range_is_refused(tmp_path):
    vertices = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 2e6]], dtype=float)
    mesh = trimesh.Trimesh(vertices=vertices, faces=[[0, 1, 2], [0, 1, 3]], process=False)
    f = tmp_path / "part.stl"
    mesh.export(f)
    with pytest.raises(InputError, match=r"part\.stl.*: vertex \d+: coordinate z = 2000 m is outside"):
        points_from_mesh(f, units="mm", boundary=True)


def _bulged(tmp_path, bulge):
    doc = ezdxf.new()
    pl = doc.modelspace().add_lwpolyline([(0, 0, bulge), (100, 0, 0), (100, 50, 0)], format="xyb")
    f = tmp_path / "bulge.dxf"
    doc.saveas(f)
    return f, pl.dxf.handle


@pytest.mark.parametrize("bulge", [1e-300, 1e-12])
def test_a_dxf_bulge_too_small_to_leave_its_chord_is_a_straight_segment(tmp_path, bulge):
    # sagitta = bulge x chord / 2 = 5e-11 mm at most, far inside the flattening tolerance
    f, _ = _bulged(tmp_path, bulge)
    np.testing.assert_allclose(
        points_from_dxf(f, units="mm"), [[0, 0, 0], [0.1, 0, 0], [0.1, 0.05, 0]], atol=1e-15
    )


def test_a_dxf_bulge_of_1e300_is_refused_naming_the_entity_and_vertex(tmp_path):
    # radius = chord / 4 x (1 / bulge + bulge) = 100 mm / 4 x 1e300 = 2.5e301 mm = 2.5e298 m
    f, handle = _bulged(tmp_path, 1e300)
    with pytest.raises(
        InputError,
        match=rf"LWPOLYLINE #{handle} .* vertex 0: the bulge 1e\+300 makes an arc of "
        r"radius 2\.5e\+298 m, outside the plausible range 1000 m",
    ):
        points_from_dxf(f, units="mm")


def test_a_dxf_bulge_that_is_not_a_number_is_refused(tmp_path):
    f, handle = _bulged(tmp_path, float("nan"))
    with pytest.raises(InputError, match=rf"LWPOLYLINE #{handle} .* vertex 0 has the bulge nan"):
        points_from_dxf(f, units="mm")


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("G1 X2000000", r"seam\.nc:4: end point x = 2000 m is outside"),  # 2,000,000 mm
        ("G3 X10 Y0 Z5 I-10 J0 P1000000000", r"seam\.nc:4: P1e\+09: an arc's turns must be 1\.\.1000"),
        (
            "G2 X20 Y0 R1" + "0" * 100,
            r"seam\.nc:4: arc radius R = 1e\+97 m is outside the plausible range 1000 m",
        ),
        ("G1 X1e308", r"seam\.nc:4: unsupported word E308 .*exponent notation such as 1e3 are not G-code"),
    ],
    ids=["end point 2 km away", "a billion helix turns", "radius of a googol mm", "exponent notation"],
)
def test_absurd_gcode_words_are_refused_with_their_line(tmp_path, line, message):
    f = tmp_path / "seam.nc"
    f.write_text(f"G21 G90\nG1 X0 Y0 Z0 F100\nG1 X10\n{line}\n")
    with pytest.raises(InputError, match=message):
        points_from_gcode(f, units="mm")
