"""Bounded work: the limits on samples, waypoints and collision checks, and memory-bounded filters."""

from __future__ import annotations

import numpy as np
import pytest

import refine.demo.filters as filters
import refine.demo.liberty as liberty
from refine.demo.liberty import read_liberty_ascii
from refine.demo.quality import gate_dropouts
from refine.errors import InputError
from refine.settings import MAX_WAYPOINTS, check_waypoint_count


def _records(n: int, header: str = "01") -> str:
    return "".join(f"{header} {k} {0.01 * k:.4f} 1.0 2.0 10.0 20.0 30.0\n" for k in range(n))


def test_the_liberty_record_header_with_command_and_error_indicator_is_read(tmp_path):
    f = tmp_path / "pimgr.txt"
    lines = _records(10).splitlines()
    lines[3] = lines[3].replace("01 ", "01PE ", 1)  # the device flagged this record
    lines = [line.replace("01 ", "01P ", 1) for line in lines]
    f.write_text("\n".join(lines) + "\n")
    log = read_liberty_ascii(f, rate_hz=240.0)
    assert len(log.t) == 10
    np.testing.assert_array_equal(log.device_error, [0, 0, 0, ord("E"), 0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(log.positions[:, 0], 0.01 * np.arange(10) * 0.0254)
    fixed, quality = gate_dropouts(log)
    assert quality.device_errors == {
        "n_flagged": 1,
        "by_indicator": {"E": 1},
        "samples": {"E": [[3, 3]]},
        "n_runs": {"E": 1},
        "meaning": {"E": "source failure, axes XZ"},  # PDItracker.h: PI_DEVERR_RT_SRC_FAIL_E_XZ
    }
    (run,) = quality.bad_runs
    assert (run.kind, run.first, run.last, run.action) == ("device-error", 3, 3, "bridged")


@pytest.mark.parametrize("token", ["x01", "P01", "0001", "01P E", "01PEX"])
def test_a_record_that_does_not_start_with_a_station_is_refused_with_its_line(tmp_path, token):
    f = tmp_path / "bad.txt"
    f.write_text(_records(3) + f"{token} 3 0 0 0 0 0 0\n")
    with pytest.raises(InputError, match=r"bad\.txt:4: "):
        read_liberty_ascii(f)


def test_a_log_beyond_the_sample_limit_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(liberty, "MAX_SAMPLES", 50)
    f = tmp_path / "long.txt"
    f.write_text(_records(51))
    with pytest.raises(InputError, match=r"long\.txt:51: more than 50 samples"):
        read_liberty_ascii(f)


def test_reading_in_blocks_gives_the_same_log(tmp_path, monkeypatch):
    f = tmp_path / "log.txt"
    f.write_text(_records(1000))
    whole = read_liberty_ascii(f)
    monkeypatch.setattr(liberty, "_CHUNK_LINES", 7)
    blocks = read_liberty_ascii(f)
    np.testing.assert_array_equal(whole.positions, blocks.positions)
    np.testing.assert_array_equal(whole.t, blocks.t)


def test_hampel_in_blocks_equals_hampel_at_once(monkeypatch):
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.normal(size=(3000, 3)), axis=0)
    x[::97] += 40.0
    once = filters.hampel(x, 7, 3.0)
    monkeypatch.setattr(filters, "_CHUNK_ELEMENTS", 1)  # the smallest blocks: 64 samples
    blocks = filters.hampel(x, 7, 3.0)
    np.testing.assert_array_equal(once[0], blocks[0])
    np.testing.assert_array_equal(once[1], blocks[1])


def test_a_path_of_too_many_waypoints_is_refused_before_resampling():
    check_waypoint_count(MAX_WAYPOINTS * 0.005, 0.005, "cad.file 'x.csv'")  # exactly at the limit
    with pytest.raises(InputError, match=r"cad.file 'x.csv': a 100.000 m path .* 1000000 waypoints"):
        check_waypoint_count(100.0, 1e-4, "cad.file 'x.csv'")
