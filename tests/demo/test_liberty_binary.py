"""Behaviour of the Polhemus Liberty binary reader and writer (refine.demo.liberty_binary)."""

import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.demo import read_tracker_log
from refine.demo.liberty_binary import read_liberty_binary, write_liberty_binary
from refine.errors import InputError
from refine.frames import rotation_angle_deg
from refine.paths import TrackerLog
from refine.problem import DemoSettings

DATA = Path(__file__).resolve().parents[1] / "data"


def _log(n=50, station=1, seed=0, rate=240.0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    positions = np.column_stack([0.3 + 0.1 * t, -0.2 + 0.05 * np.sin(t), 0.25 + 0.0 * t]) + rng.normal(
        0, 1e-3, (n, 3)
    )
    rotations = Rotation.random(n, random_state=seed).as_matrix()
    return TrackerLog(t=t, positions=positions, rotations=rotations, station=station)


def _assert_same_poses(a, b):
    np.testing.assert_allclose(a.positions, b.positions, rtol=2e-7, atol=1e-8)  # float32 inches
    assert rotation_angle_deg(a.rotations, b.rotations).max() < 1e-4


def test_round_trip_without_timestamps_uses_the_rate(tmp_path):
    log = _log()
    f = tmp_path / "demo.lyb"
    write_liberty_binary(f, log)
    assert f.stat().st_size == len(log.t) * (8 + 28)
    back = read_liberty_binary(f, rate_hz=120.0)
    _assert_same_poses(log, back)
    np.testing.assert_allclose(back.t, np.arange(len(log.t)) / 120.0)


def test_round_trip_with_timestamps_keeps_the_millisecond_times(tmp_path):
    log = _log()
    f = tmp_path / "demo.lyb"
    write_liberty_binary(f, log, with_timestamp=True)
    back = read_liberty_binary(f, rate_hz=30.0)  # the rate is not used
    _assert_same_poses(log, back)
    np.testing.assert_allclose(back.t, np.round(log.t * 1000.0) / 1000.0)


@pytest.mark.parametrize("layout", [(2, 7), (8, 2, 7), (2, 7, 8), (2, 7, 0), (8, 2, 7, 1), (2, 7, 8, 0)])
def test_layouts_are_recognised_without_an_output_list(tmp_path, layout):
    log = _log(n=20)
    f = tmp_path / "demo.lyb"
    write_liberty_binary(f, log, output_list=layout)
    back = read_liberty_binary(f)
    _assert_same_poses(log, back)
    if 8 in layout:
        np.testing.assert_allclose(back.t, np.round(log.t * 1000.0) / 1000.0)


def test_explicit_output_list_with_frame_count_and_distortion(tmp_path):
    log = _log(n=20)
    f = tmp_path / "demo.lyb"
    write_liberty_binary(f, log, output_list=(8, 9, 11, 3, 7), rate_hz=240.0)
    back = read_liberty_binary(f, output_list=(8, 9, 11, 3, 7))
    _assert_same_poses(log, back)
    write_liberty_binary(f, log, output_list=(9, 2, 7), rate_hz=240.0)
    counted = read_liberty_binary(f, output_list=(9, 2, 7), rate_hz=240.0)
    np.testing.assert_allclose(counted.t, log.t, atol=1e-12)  # time from frame counts
    write_liberty_binary(f, log, output_list=(8, 9, 11, 3, 7), rate_hz=240.0)
    with pytest.raises(InputError, match="needs 28 bytes, the records hold 40"):
        read_liberty_binary(f, output_list=(2, 7))


def test_centimetre_logs_scale_by_the_unit(tmp_path):
    log = _log(n=10)
    f = tmp_path / "demo.lyb"
    write_liberty_binary(f, log, units="cm")
    _assert_same_poses(log, read_liberty_binary(f, units="cm"))
    inches = read_liberty_binary(f, units="in")
    np.testing.assert_allclose(inches.positions, log.positions * 2.54, rtol=1e-6)


def test_records_of_other_stations_are_skipped(tmp_path):
    one, two = _log(n=30, station=1, seed=1), _log(n=30, station=2, seed=2)
    f1, f2 = tmp_path / "a.lyb", tmp_path / "b.lyb"
    write_liberty_binary(f1, one, with_timestamp=True)
    write_liberty_binary(f2, two, with_timestamp=True)
    a, b = f1.read_bytes(), f2.read_bytes()
    size = 8 + 32
    mixed = b"".join(a[k : k + size] + b[k : k + size] for k in range(0, len(a), size))
    f = tmp_path / "mixed.lyb"
    f.write_bytes(mixed)
    got = read_liberty_binary(f, station=2)
    assert got.station == 2
    _assert_same_poses(two, got)
    with pytest.raises(InputError, match="no P&O records of station 3; stations found: 1, 2"):
        read_liberty_binary(f, station=3)


def test_truncated_record_names_its_byte_offset(tmp_path):
    f = tmp_path / "demo.lyb"
    write_liberty_binary(f, _log(n=10))
    data = f.read_bytes()
    f.write_bytes(data[:-5])
    with pytest.raises(InputError, match=r"truncated record at byte offset 324"):
        read_liberty_binary(f)
    f.write_bytes(data + b"LY\x01")
    with pytest.raises(InputError, match=r"truncated record header at byte offset 360"):
        read_liberty_binary(f)


def test_bad_header_names_its_byte_offset(tmp_path):
    f = tmp_path / "demo.lyb"
    write_liberty_binary(f, _log(n=10))
    data = bytearray(f.read_bytes())
    data[72:74] = b"PA"
    f.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"bad record header at byte offset 72: expected b'LY', got b'PA'"):
        read_liberty_binary(f)


def test_invalid_quaternion_and_backward_time_are_errors(tmp_path):
    f = tmp_path / "demo.lyb"
    write_liberty_binary(f, _log(n=10), output_list=(8, 2, 7))
    data = bytearray(f.read_bytes())
    struct.pack_into("<4f", data, 3 * 40 + 8 + 16, 0.0, 0.0, 0.0, 0.0)
    f.write_bytes(bytes(data))
    with pytest.raises(InputError, match="byte offset 120"):
        read_liberty_binary(f, output_list=(8, 2, 7))
    write_liberty_binary(f, _log(n=10), output_list=(8, 2, 7))
    data = bytearray(f.read_bytes())
    struct.pack_into("<I", data, 5 * 40 + 8, 0)
    f.write_bytes(bytes(data))
    with pytest.raises(InputError, match="byte offset 200: time 0.000 s does not increase"):
        read_liberty_binary(f)


def test_demonstration_settings_dispatch_to_the_binary_reader():
    log = read_tracker_log(DemoSettings(file=DATA / "demo.lyb", format="liberty_binary", units="in"))
    assert len(log.t) == 240 and log.t[-1] == pytest.approx(239 / 240, abs=1e-3)
    np.testing.assert_allclose(log.positions[0], [0.30, 0.05, 0.20], atol=1e-6)


def test_wrapped_timestamps_and_replies_to_commands_are_handled(tmp_path):
    f = tmp_path / "demo.lyb"
    write_liberty_binary(f, _log(n=6), output_list=(8, 2, 7))
    data = bytearray(f.read_bytes())
    for k in range(6):
        struct.pack_into("<I", data, k * 40 + 8, (2**32 - 8 + 4 * k) % 2**32)
    reply = struct.pack("<2sBBBBH", b"LY", 1, 0x15, 0, 0, 4) + struct.pack("<HH", 3, 3)  # ^U station state
    f.write_bytes(reply + bytes(data))
    got = read_liberty_binary(f)
    np.testing.assert_allclose(got.t, 0.004 * np.arange(6))


@pytest.mark.parametrize("rate", [0.0, -240.0, float("nan")])
def test_a_rate_that_is_not_positive_is_refused(tmp_path, rate):
    f = tmp_path / "demo.lyb"
    write_liberty_binary(f, _log(n=5))
    with pytest.raises(InputError, match="rate_hz must be a number > 0 Hz"):
        read_liberty_binary(f, rate_hz=rate)


def test_records_of_one_station_with_different_sizes_are_an_error(tmp_path):
    a, b = tmp_path / "a.lyb", tmp_path / "b.lyb"
    write_liberty_binary(a, _log(n=4))
    write_liberty_binary(b, _log(n=4), output_list=(8, 2, 7))
    f = tmp_path / "mixed.lyb"
    f.write_bytes(a.read_bytes() + b.read_bytes())
    size_a = len(a.read_bytes()) // 4 - 8  # payload bytes of one record of the first file
    with pytest.raises(
        InputError, match=rf"byte offset {4 * (size_a + 8)} has \d+ payload bytes, the first record"
    ):
        read_liberty_binary(f)


def test_an_output_list_that_does_not_match_the_record_size_is_an_error(tmp_path):
    f = tmp_path / "demo.lyb"
    write_liberty_binary(f, _log(n=4))
    with pytest.raises(InputError, match=r"output list \[8, 2, 7\] needs \d+ bytes, the records hold"):
        read_liberty_binary(f, output_list=(8, 2, 7))
