"""Liberty logs written by hand from the record layout, read with the readers' defaults and options.

The expected values come from the layout alone (Polhemus Liberty manual: 240 Hz per sensor, ASCII
records ``station x y z azimuth elevation roll`` in inches and degrees, binary records an 8-byte
``LY`` header then the output list's items as little-endian float32), never from the writers.
"""

from __future__ import annotations

import re
import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.demo.liberty import read_liberty_ascii, write_liberty_ascii
from refine.demo.liberty_binary import read_liberty_binary, write_liberty_binary
from refine.errors import InputError
from refine.paths import TrackerLog

INCH_M = 0.0254


def test_an_ascii_log_without_rate_or_frame_counts_is_timed_at_the_liberty_s_240_hz(tmp_path):
    f = tmp_path / "plain.txt"
    f.write_text("".join(f"01 {k}.0 2.0 3.0 10.0 20.0 30.0\n" for k in range(5)))
    log = read_liberty_ascii(f)
    np.testing.assert_allclose(log.t, np.arange(5) / 240.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(log.positions[:, 0], np.arange(5) * INCH_M)


def test_a_written_frame_count_column_keeps_a_dropped_sample_s_gap(tmp_path):
    """Samples at frames 0, 1, 2, 4, 5 of 240 Hz (frame 3 lost): the frame count is the second
    column of each record, and reading it back gives the gap, not a uniform 1/240 s step."""
    frames = np.array([0, 1, 2, 4, 5])
    log = TrackerLog(
        t=frames / 240.0,
        positions=np.tile([0.0254, 0.0508, 0.0762], (5, 1)),
        rotations=np.tile(np.eye(3), (5, 1, 1)),
        station=1,
    )
    f = tmp_path / "counted.txt"
    write_liberty_ascii(f, log, units="in", with_frame_count=True, rate_hz=240.0)
    records = [line.split() for line in f.read_text().splitlines() if not line.startswith("#")]
    assert [len(r) for r in records] == [8] * 5  # station, frame, x, y, z, azimuth, elevation, roll
    assert [int(r[1]) for r in records] == frames.tolist()
    assert [float(v) for v in records[0][2:5]] == [1.0, 2.0, 3.0]  # inches
    back = read_liberty_ascii(f, units="in")
    np.testing.assert_allclose(back.t, frames / 240.0, rtol=0, atol=1e-12)


def test_a_binary_writer_refuses_an_unknown_unit(tmp_path):
    log = TrackerLog(
        t=np.arange(3) / 240.0, positions=np.zeros((3, 3)), rotations=np.tile(np.eye(3), (3, 1, 1))
    )
    with pytest.raises(InputError, match="unknown Liberty unit 'mm'; use 'in' or 'cm'"):
        write_liberty_binary(tmp_path / "x.bin", log, units="mm")
    assert not (tmp_path / "x.bin").exists()


def test_a_cr_lf_inside_the_output_list_is_two_bytes_and_one_item(tmp_path):
    """Output list ``2, 1, 7``: x y z (3 float32), CR LF (2 bytes), w x y z (4 float32): 30 bytes."""
    rng = np.random.default_rng(3)
    quats = Rotation.random(4, random_state=5).as_quat()  # x y z w
    xyz = rng.uniform(-20.0, 20.0, (4, 3))  # inches
    data = bytearray()
    for p, (qx, qy, qz, qw) in zip(xyz, quats, strict=True):
        body = struct.pack("<3f", *p) + b"\r\n" + struct.pack("<4f", qw, qx, qy, qz)
        data += struct.pack("<2sBBBBH", b"LY", 1, ord("C"), 0, 0, len(body)) + body
    f = tmp_path / "crlf.bin"
    f.write_bytes(bytes(data))
    log = read_liberty_binary(f, output_list=(2, 1, 7))
    np.testing.assert_allclose(log.positions, xyz.astype(np.float32) * INCH_M, rtol=1e-7)
    expected = Rotation.from_quat(quats.astype(np.float32)).as_matrix()
    np.testing.assert_allclose(log.rotations, expected, atol=1e-6)
    np.testing.assert_allclose(log.t, np.arange(4) / 240.0)


@pytest.mark.parametrize("rate", ["0", "-240", "fast", "0.5", "1e308", "20000"])
def test_an_ascii_log_s_rate_header_must_be_a_plausible_rate(tmp_path, rate):
    f = tmp_path / "rate.txt"
    f.write_text(f"# rate_hz: {rate}\n01 1.0 2.0 3.0 10.0 20.0 30.0\n01 1.0 2.0 3.0 10.0 20.0 30.0\n")
    with pytest.raises(
        InputError, match=rf"rate\.txt:1: rate_hz must be a number in \[1, 10000\] Hz, got '{rate}'"
    ):
        read_liberty_ascii(f)


def test_an_ascii_log_that_is_not_utf8_is_refused_naming_the_line(tmp_path):
    f = tmp_path / "latin1.txt"
    f.write_bytes(b"01 1.0 2.0 3.0 10.0 20.0 30.0\n# op\xe9rateur\n01 1.0 2.0 3.0 10.0 20.0 30.0\n")
    with pytest.raises(InputError, match="not UTF-8 text"):
        read_liberty_ascii(f)


def test_one_flagged_ascii_record_is_warned_about(tmp_path, caplog):
    f = tmp_path / "flagged.txt"
    f.write_text("".join(f"01P{'E' if k == 2 else ''} {k}.0 2.0 3.0 10.0 20.0 30.0\n" for k in range(5)))
    with caplog.at_level("WARNING", logger="refine.demo.liberty"):
        read_liberty_ascii(f)
    assert len(caplog.records) == 1 and "1 of 5 samples" in caplog.records[0].getMessage()


def test_an_angle_that_rounds_to_zero_is_written_without_a_sign(tmp_path):
    """A roll of -0.0001 deg prints as 0.000 at the format's 3 decimals, not -0.000."""
    R = Rotation.from_euler("ZYX", [0.0, 0.0, -1e-4], degrees=True).as_matrix()
    log = TrackerLog(t=np.arange(2) / 240.0, positions=np.zeros((2, 3)), rotations=np.stack([R, R]))
    f = tmp_path / "zero.txt"
    write_liberty_ascii(f, log, units="in", rate_hz=240.0)
    records = [line.split() for line in f.read_text().splitlines() if not line.startswith("#")]
    assert all(r[4:7] == ["0.000", "0.000", "0.000"] for r in records), records


def _binary_records(errors: list[int]) -> bytes:
    """Records of station 1, output list 2, 7 (identity quaternion), with the given error bytes."""
    data = bytearray()
    for k, err in enumerate(errors):
        body = struct.pack("<3f", float(k), 0.0, 0.0) + struct.pack("<4f", 1.0, 0.0, 0.0, 0.0)
        data += struct.pack("<2sBBBBH", b"LY", 1, ord("C"), err, 0, len(body)) + body
    return bytes(data)


@pytest.mark.parametrize(("errors", "flagged"), [([0, 0x20, 0, 0x20], 0), ([0, ord("E"), 0x20, ord("D")], 2)])
def test_binary_records_flagged_by_their_error_byte_are_counted_in_a_warning(
    tmp_path, caplog, errors, flagged
):
    """0 and an ASCII space mean no error (Liberty manual); anything else flags the record, which is
    kept with its indicator (``TrackerLog.device_error``, 0 for none) and counted in one warning."""
    f = tmp_path / "err.bin"
    f.write_bytes(_binary_records(errors))
    with caplog.at_level("WARNING", logger="refine.demo.liberty_binary"):
        log = read_liberty_binary(f, output_list=(2, 7))
    np.testing.assert_allclose(log.positions[:, 0], np.arange(4) * INCH_M)  # every sample kept
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    if flagged:
        assert len(warnings) == 1 and re.search(rf"\b{flagged} of 4\b", warnings[0]), warnings
        np.testing.assert_array_equal(log.device_error, [0 if e in (0, 0x20) else e for e in errors])
    else:
        assert warnings == []
        assert log.device_error is None or not np.any(log.device_error)
