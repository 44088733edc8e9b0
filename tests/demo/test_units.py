"""Units of a demonstration CSV are never guessed silently.

A straight bead demonstrated with the tool tilting from 0 to 15 deg (``write_line_problem``, its
``demo.csv`` in metres and degrees) is rewritten here in radians, in millimetres, or read with the
wrong unit: each must stop naming the likely unit and the key to set, and the right key must give
the generator's 15 deg back.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from refine.demo import read_tracker_log
from refine.demo.csv_ import read_demo_csv
from refine.errors import InputError
from refine.problem import load_problem
from refine.run.solve import solve_problem
from refine.synthetic import write_line_problem

TILT_DEG = 15.0
HEADER = "t,x,y,z,azimuth,elevation,roll"


@pytest.fixture(scope="module")
def line(tmp_path_factory) -> Path:
    return write_line_problem(tmp_path_factory.mktemp("line"), tilt_deg=TILT_DEG).parent


def _rewrite(folder: Path, out: Path, position_scale: float = 1.0, radians: bool = False) -> Path:
    """The line problem with its demo.csv's positions scaled and its angles turned into radians."""
    out.mkdir()
    for f in folder.iterdir():
        (out / f.name).write_bytes(f.read_bytes())
    data = np.loadtxt(folder / "demo.csv", delimiter=",", skiprows=1)
    data[:, 1:4] *= position_scale
    if radians:
        data[:, 4:7] *= math.pi / 180.0
    np.savetxt(out / "demo.csv", data, delimiter=",", fmt="%.9g", header=HEADER, comments="")
    return out


def _demo_settings(folder: Path, **changes):
    problem = load_problem(folder)
    return problem, dataclasses.replace(problem.demonstration, **changes)


def _tilt_deg(rotations: np.ndarray) -> np.ndarray:
    """Angle between the tool z axis and straight down [deg]."""
    return np.degrees(np.arccos(np.clip(-rotations[:, 2, 2], -1.0, 1.0)))


def test_a_radian_csv_read_as_degrees_stops_naming_rad(line, tmp_path):
    folder = _rewrite(line, tmp_path / "rad", radians=True)
    problem, demo = _demo_settings(folder)
    with pytest.raises(InputError) as e:
        solve_problem(problem)
    msg = str(e.value)
    assert 'angle_units = "rad"' in msg and "radians" in msg, msg
    assert "demo.csv" in msg and "200 mm" in msg, msg  # the bead is 200 mm long


def test_a_radian_csv_with_angle_units_rad_gives_the_demonstrated_tilt(line, tmp_path):
    folder = _rewrite(line, tmp_path / "rad", radians=True)
    toml = (folder / "problem.toml").read_text()
    (folder / "problem.toml").write_text(toml.replace('format = "csv"', 'format = "csv"\nangle_units = "rad"'))
    problem = load_problem(folder)
    assert problem.demonstration.angle_units == "rad"
    result = solve_problem(problem)
    assert result.refinement.status == "ok"
    tilt = _tilt_deg(result.fused.rotations)
    assert tilt[0] == pytest.approx(0.0, abs=1.0)  # the generator tilts from 0 ...
    assert tilt[-1] == pytest.approx(TILT_DEG, abs=1.0)  # ... to 15 deg


def test_degrees_read_as_radians_stop_naming_deg(line):
    _, demo = _demo_settings(line, angle_units="rad")
    with pytest.raises(InputError) as e:
        read_tracker_log(demo)
    msg = str(e.value)
    assert 'angle_units = "deg"' in msg and "beyond ±2π" in msg, msg


def test_small_angles_in_degrees_read_as_radians_stop_on_the_turning_rate(tmp_path):
    """Angles within ±2π deg (a sensor nearly aligned with the receiver), read as radians: the
    0.15 deg noise of 240 Hz samples becomes a turning of thousands of deg/s."""
    rng = np.random.default_rng(3)
    t = np.arange(480) / 240.0
    angles = np.column_stack([2.0 * np.sin(t), np.full_like(t, 1.0), np.full_like(t, 3.0)])
    angles += rng.normal(scale=0.15, size=angles.shape)
    xyz = np.column_stack([0.5 + 0.1 * t, np.zeros_like(t), np.full_like(t, 0.2)])
    f = tmp_path / "small.csv"
    np.savetxt(f, np.column_stack([t, xyz, angles]), delimiter=",", fmt="%.9g", header=HEADER, comments="")
    assert read_demo_csv(f, units="m", angle_units="deg").t[-1] == pytest.approx(479 / 240)
    with pytest.raises(InputError) as e:
        read_demo_csv(f, units="m", angle_units="rad")
    msg = str(e.value)
    assert "turning rate" in msg and 'angle_units = "deg"' in msg, msg


def test_a_csv_in_metres_read_as_millimetres_asks_about_the_units(line):
    _, demo = _demo_settings(line, units="mm")
    with pytest.raises(InputError) as e:
        read_tracker_log(demo)
    msg = str(e.value)
    assert "are the units right?" in msg and 'units = "m"' in msg, msg
    assert "no motion found" not in msg
    assert "0.2 mm" in msg, msg  # the 200 mm bead read in mm of a metre file


def test_a_csv_in_millimetres_read_as_metres_asks_about_the_units(line, tmp_path):
    folder = _rewrite(line, tmp_path / "mm", position_scale=1000.0)
    _, demo = _demo_settings(folder)  # the file says units = "m"
    with pytest.raises(InputError) as e:
        read_tracker_log(demo)
    msg = str(e.value)
    assert "are the units right?" in msg and 'units = "mm"' in msg, msg


def test_the_right_units_read_without_complaint(line, tmp_path):
    folder = _rewrite(line, tmp_path / "mm", position_scale=1000.0)
    _, demo = _demo_settings(folder, units="mm")
    log = read_tracker_log(demo)
    assert np.ptp(log.positions[:, 1]) == pytest.approx(0.2, abs=0.002)  # the bead runs 200 mm along y


def test_degrees_that_stay_small_are_read_when_stated(tmp_path):
    """A tool that keeps within 3 deg of the receiver axes: stopped when the unit is not stated,
    read as degrees when ``angle_units = "deg"`` says so."""
    t = np.arange(300) / 100.0
    xyz = np.column_stack([0.5 + 0.05 * t, np.zeros_like(t), np.full_like(t, 0.2)])
    angles = np.column_stack([np.zeros_like(t), 2.0 * t / t[-1], np.zeros_like(t)])
    f = tmp_path / "aligned.csv"
    np.savetxt(f, np.column_stack([t, xyz, angles]), delimiter=",", fmt="%.9g", header=HEADER, comments="")
    with pytest.raises(InputError, match="look like radians"):
        read_demo_csv(f, units="m")
    log = read_demo_csv(f, units="m", angle_units="deg")
    assert _tilt_deg(np.diag([1.0, -1.0, -1.0]) @ log.rotations[-1:]) == pytest.approx(2.0, abs=1e-6)
