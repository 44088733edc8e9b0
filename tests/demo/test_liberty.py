"""Behaviour of the Polhemus Liberty ASCII reader and writer (refine.demo.liberty)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.demo import read_tracker_log
from refine.demo.liberty import read_liberty_ascii, write_liberty_ascii
from refine.errors import InputError
from refine.frames import matrix_from_tracker_angles, rotation_angle_deg
from refine.paths import TrackerLog
from refine.problem import DemoSettings


@pytest.fixture
def log():
    rng = np.random.default_rng(7)
    m = 50
    return TrackerLog(
        t=np.arange(m) / 240.0,
        positions=rng.uniform(-0.5, 0.5, size=(m, 3)),
        rotations=Rotation.random(m, random_state=11).as_matrix(),
        station=2,
        source="synthetic",
    )


@pytest.mark.parametrize("units", ["in", "cm"])
@pytest.mark.parametrize("with_frame_count", [False, True])
def test_write_then_read_round_trips_to_the_printed_precision(tmp_path, log, units, with_frame_count):
    f = tmp_path / "demo.txt"
    write_liberty_ascii(f, log, units=units, with_frame_count=with_frame_count)
    back = read_liberty_ascii(f, units=units, station=2)
    np.testing.assert_allclose(back.t, log.t, atol=1e-12)
    unit_m = {"in": 0.0254, "cm": 0.01}[units]
    np.testing.assert_allclose(back.positions, log.positions, atol=0.5e-4 * unit_m + 1e-12)
    assert rotation_angle_deg(back.rotations, log.rotations).max() < 2e-3
    assert back.station == 2


def test_frame_counts_give_the_time_from_the_first_frame(tmp_path):
    f = tmp_path / "demo.txt"
    f.write_text(
        "# rate_hz: 120\n"
        "01 1000 1.0 2.0 3.0 10.0 20.0 30.0\n"
        "01 1001 1.0 2.0 3.0 10.0 20.0 30.0\n"
        "01 1004 1.0 2.0 3.0 10.0 20.0 30.0\n"
    )
    log = read_liberty_ascii(f)
    np.testing.assert_allclose(log.t, [0.0, 1 / 120, 4 / 120])
    np.testing.assert_allclose(log.positions[0], [0.0254, 0.0508, 0.0762])
    np.testing.assert_allclose(log.rotations[0], matrix_from_tracker_angles(10.0, 20.0, 30.0))


def test_other_stations_and_blank_lines_are_skipped(tmp_path):
    f = tmp_path / "demo.txt"
    f.write_text("01 0 0 0 0 0 0\n\n02 1 1 1 0 0 0\n01 1 0 0 0 0 0\n02 2 2 2 0 0 0\n02 3 3 3 0 0 0\n")
    log = read_liberty_ascii(f, station=2, rate_hz=10.0)
    np.testing.assert_allclose(log.positions[:, 0], np.array([1, 2, 3]) * 0.0254)
    np.testing.assert_allclose(log.t, [0.0, 0.1, 0.2])
    with pytest.raises(InputError, match="no samples of station 3; stations found: 1, 2"):
        read_liberty_ascii(f, station=3)


def test_malformed_line_error_names_file_and_line(tmp_path):
    f = tmp_path / "demo.txt"
    f.write_text("# units: in\n01 0 0 0 0 0 0\n01 0 0 0 0 0\n")
    with pytest.raises(InputError, match=r"demo\.txt:3: expected 6 values.*got 5"):
        read_liberty_ascii(f)
    f.write_text("01 0 0 0 0 0 0\n01 0 0 x 0 0 0\n")
    with pytest.raises(InputError, match=r"demo\.txt:2: not a number"):
        read_liberty_ascii(f)
    f.write_text("01 5 0 0 0 0 0 0\n01 5 0 0 0 0 0 0\n")
    with pytest.raises(InputError, match=r"demo\.txt:2: frame count 5 does not increase"):
        read_liberty_ascii(f)


def test_header_unit_differing_from_the_settings_names_both(tmp_path, log):
    f = tmp_path / "demo.txt"
    write_liberty_ascii(f, log, units="cm")
    with pytest.raises(InputError, match=r"'# units: cm'.*units = 'in'"):
        read_liberty_ascii(f, units="in", station=2)
    np.testing.assert_allclose(
        read_liberty_ascii(f, units=None, station=2).positions, log.positions, atol=1e-6
    )


def test_read_tracker_log_uses_the_settings(tmp_path, log):
    f = tmp_path / "demo.txt"
    write_liberty_ascii(f, log, units="cm", with_frame_count=True)
    settings = DemoSettings(file=f, format="liberty_ascii", units="cm", station=2, rate_hz=60.0)
    back = read_tracker_log(settings)
    np.testing.assert_allclose(back.t, log.t, atol=1e-12)  # the header's 240 Hz wins


def test_an_unknown_unit_is_refused_on_writing_and_reading(tmp_path, log):
    f = tmp_path / "demo.txt"
    with pytest.raises(InputError, match="unknown Liberty unit 'mm'; use 'in' or 'cm'"):
        write_liberty_ascii(f, log, units="mm")
    write_liberty_ascii(f, log, units="cm")
    f.write_text("".join(line for line in f.read_text().splitlines(True) if "units" not in line))
    with pytest.raises(InputError, match="unknown Liberty unit 'mm'"):
        read_liberty_ascii(f, units="mm", station=log.station)


def test_a_non_finite_value_is_an_error_naming_the_line(tmp_path, log):
    f = tmp_path / "demo.txt"
    write_liberty_ascii(f, log, units="in")
    lines = f.read_text().splitlines()
    lines[5] = lines[5].rsplit(" ", 1)[0] + " nan"  # roll of the third record
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="non-finite value"):
        read_liberty_ascii(f, station=log.station)


def test_times_that_the_format_cannot_hold_are_warned_about(tmp_path, log, caplog):
    """Without a frame count the file keeps only the rate: uneven sample times are lost, and said so."""
    uneven = TrackerLog(
        t=log.t + np.where(np.arange(len(log.t)) == 10, 1e-3, 0.0),
        positions=log.positions,
        rotations=log.rotations,
        station=log.station,
    )
    with caplog.at_level("WARNING", logger="refine.demo.liberty"):
        write_liberty_ascii(tmp_path / "even.txt", log, units="in", rate_hz=240.0)
        assert not caplog.records
        write_liberty_ascii(
            tmp_path / "counted.txt", uneven, units="in", rate_hz=240.0, with_frame_count=True
        )
        assert not caplog.records
        write_liberty_ascii(tmp_path / "uneven.txt", uneven, units="in", rate_hz=240.0)
    assert len(caplog.records) == 1 and "times will be lost" in caplog.records[0].getMessage()


def test_a_position_that_rounds_to_zero_is_written_without_a_sign(tmp_path, log):
    tiny = TrackerLog(
        t=log.t[:2], positions=np.array([[-1e-9, 0.1, -0.2], [0.0, -1e-9, 0.3]]), rotations=log.rotations[:2]
    )
    f = tmp_path / "demo.txt"
    write_liberty_ascii(f, tiny, units="in")
    assert "-0.0000" not in f.read_text()
    assert "0.0000" in f.read_text()
