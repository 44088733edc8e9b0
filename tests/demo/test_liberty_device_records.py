"""Liberty records as the device sends them, built by hand from the record layout.

The layout (Polhemus PDI SDK ``PDItracker.h``, ``BINHDR``; the same fields lead an ASCII record):
station number, the initiating command (``P`` a single record, ``C`` continuous output), the error
indicator (blank, or a byte: space or 0 in binary, when there is none), then the items of the
output list; the Liberty's default list is ``2,4,1``: position x y z [in], Euler angles azimuth,
elevation, roll [deg], CR LF. Expected values here come from the numbers written into the files:
inches times 0.0254, and the tracker rotation ``Rz(az)·Ry(el)·Rx(roll)`` from scipy.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.demo.liberty import read_liberty_ascii
from refine.demo.liberty_binary import read_liberty_binary, write_liberty_binary
from refine.demo.quality import gate_dropouts
from refine.errors import InputError

IN = 0.0254
# (x, y, z) [in], (azimuth, elevation, roll) [deg] of six samples, and the error indicator of each
POSES = [
    ((12.3456, -4.5678, 9.8765), (-12.345, 45.678, 170.123)),
    ((12.3556, -4.5578, 9.8665), (-12.300, 45.600, 170.000)),
    ((12.3656, -4.5478, 9.8565), (-12.250, 45.500, 169.900)),
    ((-1.2345, -4.5378, 9.8465), (-12.200, 45.400, 169.800)),
    ((12.3856, -4.5278, 9.8365), (-12.150, 45.300, 169.700)),
    ((12.3956, -4.5178, 9.8265), (-12.100, 45.200, 169.600)),
]
ERRORS = [" ", " ", "u", "u", " ", "I"]


def _expected():
    pos = np.array([p for p, _ in POSES]) * IN
    rot = Rotation.from_euler("ZYX", [a for _, a in POSES], degrees=True).as_matrix()
    return pos, rot


def _check(log, errors=ERRORS):
    pos, rot = _expected()
    np.testing.assert_allclose(log.positions, pos, atol=1e-12)
    np.testing.assert_allclose(log.rotations, rot, atol=1e-12)
    codes = [0 if e == " " else ord(e) for e in errors]
    if any(codes):
        np.testing.assert_array_equal(log.device_error, codes)
    else:
        assert log.device_error is None


def _values(k: int) -> str:
    (x, y, z), (a, e, r) = POSES[k]
    return f"{x:10.4f}{y:10.4f}{z:10.4f}{a:10.3f}{e:10.3f}{r:10.3f}"


@pytest.mark.parametrize(
    "header",
    [
        pytest.param(lambda k: "01", id="station only"),
        pytest.param(lambda k: "01C ", id="continuous, no error"),
        pytest.param(lambda k: "01P ", id="single record, no error"),
        pytest.param(lambda k: "01C" + ERRORS[k], id="continuous, error indicator"),
    ],
)
def test_ascii_records_with_the_devices_header_are_read(tmp_path, header):
    f = tmp_path / "liberty.txt"
    # each record as the device prints it: the header bytes, then the fixed-width values, CR LF
    f.write_bytes("".join(header(k) + _values(k) + "\r\n" for k in range(len(POSES))).encode())
    log = read_liberty_ascii(f)
    with_errors = header(2).endswith("u")
    _check(log, ERRORS if with_errors else [" "] * len(POSES))


def test_a_value_right_after_the_error_indicator_is_read(tmp_path):
    f = tmp_path / "liberty.txt"
    lines = [
        f"01Cu{-1.2345:.4f} 2.0000 3.0000 10.000 20.000 30.000",
        "01C  1.0000 2.0000 3.0000 10.000 20.000 30.000",
    ]
    f.write_text("\n".join(lines) + "\n")
    log = read_liberty_ascii(f)
    np.testing.assert_allclose(log.positions[:, 0], [-1.2345 * IN, 1.0 * IN])
    np.testing.assert_array_equal(log.device_error, [ord("u"), 0])


def test_ascii_records_of_position_and_quaternion_are_read(tmp_path):
    q = Rotation.from_euler("ZYX", [30.0, -20.0, 10.0], degrees=True).as_quat()  # x y z w
    w, x, y, z = (round(v, 4) for v in (q[3], q[0], q[1], q[2]))
    f = tmp_path / "liberty.txt"
    f.write_text(
        "".join(
            f"01C {1.1 + 0.25 * k:10.4f}{2.0:10.4f}{3.0:10.4f}{w:8.4f}{x:8.4f}{y:8.4f}{z:8.4f}\n"
            for k in range(5)
        )
    )
    log = read_liberty_ascii(f)
    np.testing.assert_allclose(log.positions[:, 0], (1.1 + 0.25 * np.arange(5)) * IN)
    expected = Rotation.from_quat([x, y, z, w]).as_matrix()
    np.testing.assert_allclose(log.rotations, np.repeat(expected[None], 5, axis=0), atol=1e-12)
    # x = 1, 2, 3, ... in whole inches also reads as increasing frame counts: refused, not guessed
    f.write_text(
        "".join(
            f"01C {1.0 + k:10.4f}{2.0:10.4f}{3.0:10.4f}{w:8.4f}{x:8.4f}{y:8.4f}{z:8.4f}\n" for k in range(5)
        )
    )
    with pytest.raises(InputError, match="read both as a frame count"):
        read_liberty_ascii(f)


def test_the_devices_error_indicators_are_reported_per_sample(tmp_path):
    f = tmp_path / "liberty.txt"
    n = 40
    flagged = {10: "u", 11: "u", 25: "I"}
    f.write_text(
        "".join(
            f"01C{flagged.get(k, ' ')}{0.1 * k:10.4f}{2.0:10.4f}{3.0:10.4f}{10.0:10.3f}{20.0:10.3f}{30.0:10.3f}\n"
            for k in range(n)
        )
    )
    _, quality = gate_dropouts(read_liberty_ascii(f))
    d = quality.as_json()["device_errors"]
    assert d["n_flagged"] == 3
    assert d["by_indicator"] == {"u": 2, "I": 1}
    assert d["samples"] == {"u": [[10, 11]], "I": [[25, 25]]}
    assert d["meaning"] == {"u": "out of map", "I": "built-in test error"}
    kinds = {(r.kind, r.first, r.last, r.action) for r in quality.bad_runs}
    assert kinds == {("device-error", 10, 11, "bridged"), ("device-error", 25, 25, "bridged")}


def _binary_record(station: int, cmd: str, err: int, payload: bytes) -> bytes:
    # LY preamble, station, initiating command, error indicator, reserved, response size (uint16)
    return b"LY" + bytes([station, ord(cmd), err, 0]) + struct.pack("<H", len(payload)) + payload


@pytest.mark.parametrize("no_error", [0, 0x20])
def test_binary_records_of_the_default_output_list_are_read(tmp_path, no_error):
    f = tmp_path / "liberty.lyb"
    out = b""
    for k, ((x, y, z), (a, e, r)) in enumerate(POSES):
        err = no_error if ERRORS[k] == " " else ord(ERRORS[k])
        out += _binary_record(1, "C", err, struct.pack("<6f", x, y, z, a, e, r) + b"\r\n")  # O*,2,4,1
        out += _binary_record(2, "C", no_error, struct.pack("<6f", 0, 0, 0, 0, 0, 0) + b"\r\n")
    f.write_bytes(out)
    log = read_liberty_binary(f)
    pos, rot = _expected()
    np.testing.assert_allclose(log.positions, pos, rtol=1e-6)  # float32
    np.testing.assert_allclose(log.rotations, rot, atol=1e-6)
    np.testing.assert_array_equal(log.device_error, [0, 0, ord("u"), ord("u"), 0, ord("I")])


def test_binary_euler_layouts_round_trip_and_an_ambiguous_list_is_refused(tmp_path):
    f = tmp_path / "liberty.lyb"
    pos, rot = _expected()
    from refine.paths import TrackerLog

    log = TrackerLog(t=np.arange(6) / 240.0, positions=pos, rotations=rot, station=1)
    for layout in [(2, 4, 1), (8, 2, 4), (2, 4), (2, 4, 8, 0)]:
        write_liberty_binary(f, log, output_list=layout)
        back = read_liberty_binary(f)
        np.testing.assert_allclose(back.positions, pos, rtol=1e-6)
        np.testing.assert_allclose(back.rotations, rot, atol=1e-5)
    with pytest.raises(InputError, match="one orientation"):
        write_liberty_binary(f, log, output_list=(2, 4, 7))


def test_a_file_with_the_devices_header_reaches_result_json_figures(tmp_path):
    """A glass demonstration whose records carry the header, three of them flagged by the device."""
    import shutil

    from refine.problem import load_problem
    from refine.run.stages import fused_path

    src = Path(__file__).resolve().parents[2] / "problems" / "glass_adhesive"
    dst = tmp_path / "glass"
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("generate.py", "README.md"))
    lines = (dst / "demo.liberty").read_text().splitlines()
    data = [i for i, line in enumerate(lines) if line and not line.startswith("#")]
    for n, i in enumerate(data):
        err = "u" if n in (2000, 2001, 2002) else " "
        lines[i] = "01C" + err + lines[i][2:]  # "01" + values -> "01C" + indicator + values
    (dst / "demo.liberty").write_text("\n".join(lines) + "\n")
    qualities = []
    fused_path(load_problem(dst), qualities=qualities)
    d = qualities[0].as_json()["device_errors"]
    assert d["by_indicator"] == {"u": 3} and d["samples"] == {"u": [[2000, 2002]]}
