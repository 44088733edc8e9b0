"""Files captured with Polhemus's own Tracker Terminal (PiTerm): the device's bytes, unchanged.

Evidence: the source of Polhemus Tracker Terminal (PiTerm) 1.0.3 (Copyright 2009-2011 Polhemus,
GPL v3; "Capture Data" On/Off with a capture file) opens the capture file with ``fopen(filename,
"a")`` and, for every block read from the tracker, writes the block as read (``fwrite(buf, 1, len,
f)``) beside showing it: no header line, no time column, no separators of its own, sessions
appended to the same file, and blocks cut wherever a USB or serial read ended. So a capture holds
the device's records (ASCII or binary) plus whatever else the device sent while capturing (its
replies to commands typed meanwhile), and may start or stop inside a record.

No real example file was found; the records below are built from the record layout the readers
document (station, initiating command, error indicator, then x y z [in] and azimuth, elevation,
roll [deg] in fixed-width fields, CR LF). Expected values: inches x 0.0254 and
``Rz(az)·Ry(el)·Rx(roll)`` from scipy.
"""

from __future__ import annotations

import os
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from refine.demo.liberty import read_liberty_ascii
from refine.demo.liberty_binary import read_liberty_binary
from refine.errors import InputError

POSES = [
    ((12.3456, -4.5678, 9.8765), (-12.345, 45.678, 170.123)),
    ((12.3556, -4.5578, 9.8665), (-12.300, 45.600, 170.000)),
]


def _record(k: int, command: str = "C") -> str:
    (x, y, z), (a, e, r) = POSES[k % 2]
    return f"01{command} {x:10.4f}{y:10.4f}{z:10.4f}{a:10.3f}{e:10.3f}{r:10.3f}\r\n"


def test_a_capture_of_continuous_records_is_read(tmp_path):
    f = tmp_path / "capture.txt"
    f.write_bytes("".join(_record(k) for k in range(6)).encode())
    log = read_liberty_ascii(f)
    pos = np.array([POSES[k % 2][0] for k in range(6)]) * 0.0254
    rot = Rotation.from_euler("ZYX", [POSES[k % 2][1] for k in range(6)], degrees=True).as_matrix()
    np.testing.assert_allclose(log.positions, pos, atol=1e-12)
    np.testing.assert_allclose(log.rotations, rot, atol=1e-12)
    np.testing.assert_allclose(log.t, np.arange(6) / 240.0)


def test_a_reply_to_another_command_inside_a_capture_is_refused_with_its_line(tmp_path):
    # a reply with six numbers would otherwise be read as a sample
    f = tmp_path / "capture.txt"
    text = (
        _record(0)
        + _record(1)
        + "01B     1.0000    2.0000    3.0000    4.0000    5.0000    6.0000\r\n"
        + _record(0)
    )
    f.write_bytes(text.encode())
    with pytest.raises(
        InputError, match=r"capture\.txt:3: the device's reply to the 'B' command, not a position"
    ):
        read_liberty_ascii(f)


def test_another_station_s_reply_does_not_stop_the_read(tmp_path):
    f = tmp_path / "capture.txt"
    text = _record(0) + "02O 2,4,1\r\n" + _record(1)
    f.write_bytes(text.encode())
    assert len(read_liberty_ascii(f).t) == 2


def test_a_capture_stopped_mid_record_is_refused_naming_the_last_line(tmp_path):
    f = tmp_path / "capture.txt"
    # the last record (4 + 6 x 10 characters, CR LF) cut by 5 bytes: 61 characters, roll "170." instead of 170.123
    text = _record(0) + _record(1) + _record(0)[:-5]
    f.write_bytes(text.encode())
    with pytest.raises(
        InputError,
        match=r"capture\.txt:3: the last record has 61 characters and no line end, "
        r"the one before 64: .*partial record",
    ):
        read_liberty_ascii(f)


def test_a_capture_started_mid_record_is_refused_naming_the_first_line(tmp_path):
    f = tmp_path / "capture.txt"
    text = _record(1)[30:] + _record(0) + _record(1)
    f.write_bytes(text.encode())
    with pytest.raises(
        InputError, match=r"capture\.txt:1: a record must start with the station number.*partial record"
    ):
        read_liberty_ascii(f)


def _binary(k: int) -> bytes:
    (x, y, z), (a, e, r) = POSES[k % 2]
    # "LY", station 1, 'C', no error, reserved, 26 payload bytes: 6 float32 and CR LF
    return b"LY\x01C \x00" + struct.pack("<H", 26) + struct.pack("<6f", x, y, z, a, e, r) + b"\r\n"


def test_a_binary_capture_started_mid_record_is_refused_saying_so(tmp_path):
    f = tmp_path / "capture.lyb"
    f.write_bytes(_binary(0)[5:] + _binary(1) + _binary(0))
    with pytest.raises(
        InputError, match=r"bad record header at byte offset 0: expected b'LY'.*inside a record"
    ):
        read_liberty_binary(f)


def test_a_binary_capture_stopped_mid_record_is_refused_saying_so(tmp_path):
    f = tmp_path / "capture.lyb"
    # records of 8 + 26 = 34 bytes: the third starts at 68 and keeps 20 of its 26 payload bytes
    f.write_bytes(_binary(0) + _binary(1) + _binary(0)[:28])
    with pytest.raises(
        InputError,
        match=r"truncated record at byte offset 68: station 1, response size 26 bytes, "
        r"only 20 left.*inside a record",
    ):
        read_liberty_binary(f)


# ---- a capture switched on and off anywhere -------------------------------------------------------

CAPTURE_EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "40"))
_STREAM_POSES = [
    (
        (10.0 + 0.0137 * k, -4.5 + 0.0211 * k, 9.25 - 0.0101 * k),
        (-12.345 + 0.5 * k, 45.678 - 0.25 * k, 170.1 - k),
    )
    for k in range(12)
]


def _stream_record(k: int, station: int = 1) -> str:
    (x, y, z), (a, e, r) = _STREAM_POSES[k]
    return f"{station:02d}C {x:10.4f}{y:10.4f}{z:10.4f}{a:10.3f}{e:10.3f}{r:10.3f}\r\n"


@settings(
    max_examples=CAPTURE_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=st.data())
def test_a_capture_cut_anywhere_gives_whole_records_or_a_named_error(tmp_path, data):
    """Cut the device's stream at two random bytes, as a capture switched on and off would.

    Whatever is read must be a run of the records as sent, value for value (inches x 0.0254);
    anything else must be refused naming the file. Station 2's records are interleaved.
    """
    records = [_stream_record(k) + (_stream_record(k, 2) if k % 3 == 0 else "") for k in range(12)]
    stream = "".join(records).encode()
    bounds = np.cumsum([0] + [len(r) for r in records]).tolist()  # where station 1's records start
    # cuts anywhere, and cuts at a record's start or a few bytes before a record's end (in the roll,
    # the last value), where a cut record still holds six numbers
    a = data.draw(st.sampled_from(bounds[:-1]) | st.integers(0, len(stream) - 1))
    near_end = st.tuples(st.sampled_from(bounds[1:]), st.integers(0, 12)).map(lambda e: e[0] - e[1])
    b = data.draw((near_end | st.integers(a + 1, len(stream))).filter(lambda b: b > a))
    f = tmp_path / "cut.txt"
    f.write_bytes(stream[a:b])
    try:
        log = read_liberty_ascii(f)
    except InputError as e:
        assert "cut.txt" in str(e) or "tracker log" in str(e)
        return
    sent = np.array([p for p, _ in _STREAM_POSES]) * 0.0254
    first = int(np.argmin(np.abs(sent[:, 0] - log.positions[0, 0])))
    np.testing.assert_array_equal(log.positions, sent[first : first + len(log.t)])
    angles = np.array([o for _, o in _STREAM_POSES])[first : first + len(log.t)]
    np.testing.assert_allclose(
        log.rotations, Rotation.from_euler("ZYX", angles, degrees=True).as_matrix(), atol=1e-12
    )


def test_a_capture_stopped_at_any_byte_gives_whole_records_or_a_named_error(tmp_path):
    """Every cut of the first records (started at a record): a run of whole records, or refused."""
    stream = "".join(
        _stream_record(k) + (_stream_record(k, 2) if k % 3 == 0 else "") for k in range(4)
    ).encode()
    sent = np.array([p for p, _ in _STREAM_POSES]) * 0.0254
    turns = Rotation.from_euler("ZYX", [o for _, o in _STREAM_POSES], degrees=True).as_matrix()
    f = tmp_path / "cut.txt"
    read = 0
    for b in range(1, len(stream) + 1):
        f.write_bytes(stream[:b])
        try:
            log = read_liberty_ascii(f)
        except InputError as e:
            assert "cut.txt" in str(e)
            continue
        read += 1
        np.testing.assert_array_equal(log.positions, sent[: len(log.t)])
        np.testing.assert_allclose(log.rotations, turns[: len(log.t)], atol=1e-12)
    assert read >= 4  # at least each whole record's end (before or after its CR LF)


def test_a_binary_capture_cut_at_any_byte_gives_whole_records_or_a_named_error(tmp_path):
    """Every start and every end cut of eight binary records: whole records (float32), or refused."""

    def record(k: int) -> bytes:
        (x, y, z), (az, el, ro) = _STREAM_POSES[k]
        return b"LY\x01C \x00" + struct.pack("<H", 26) + struct.pack("<6f", x, y, z, az, el, ro) + b"\r\n"

    stream = b"".join(record(k) for k in range(8))
    sent = np.array([struct.unpack("<3f", struct.pack("<3f", *p)) for p, _ in _STREAM_POSES[:8]]) * 0.0254
    f = tmp_path / "cut.lyb"
    read = 0
    for a, b in [(a, len(stream)) for a in range(len(stream))] + [(0, b) for b in range(1, len(stream))]:
        f.write_bytes(stream[a:b])
        try:
            log = read_liberty_binary(f, output_list=(2, 4, 1))
        except InputError as e:
            assert "cut.lyb" in str(e) or "tracker log" in str(e)
            continue
        read += 1
        first = a // 34  # 34 bytes a record: only a cut at a record's start may be read
        assert a % 34 == 0
        np.testing.assert_array_equal(log.positions, sent[first : first + len(log.t)])
    assert read >= 8


def test_binary_replies_of_the_station_are_skipped_with_a_warning_that_counts_them(tmp_path, caplog):
    # a reply initiated by ^U (0x15): the header, then detected and active station maps as two uint16
    # (TUM/IAS liberty_protocol.h, active_station_state_response_t), between two P&O records
    f = tmp_path / "capture.lyb"
    reply = b"LY\x01\x15 \x00" + struct.pack("<H", 4) + struct.pack("<HH", 1, 1)
    f.write_bytes(_binary(0) + reply + _binary(1))
    log = read_liberty_binary(f)
    assert len(log.t) == 2
    assert (
        "skipped 1 record(s) of station 1 that other commands initiated (replies, not P&O): 0x15 x1"
        in caplog.text
    )
