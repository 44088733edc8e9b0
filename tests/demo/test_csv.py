"""Behaviour of the demonstration CSV reader (refine.demo.csv_)."""

import numpy as np
import pytest

from refine.demo import read_tracker_log
from refine.demo.csv_ import read_demo_csv
from refine.errors import InputError
from refine.frames import matrix_from_tracker_angles
from refine.problem import DemoSettings


def test_columns_are_read_in_any_order_and_time_starts_at_zero(tmp_path):
    f = tmp_path / "demo.csv"
    f.write_text(
        "# from the lab\n Roll, T, x, y, z, Azimuth, elevation\n"
        "30, 5.0, 1, 2, 3, 10, 20\n30, 5.1, 4, 5, 6, 10, 20\n"
    )
    log = read_demo_csv(f, units="mm")
    np.testing.assert_allclose(log.t, [0.0, 0.1])
    np.testing.assert_allclose(log.positions, [[0.001, 0.002, 0.003], [0.004, 0.005, 0.006]])
    np.testing.assert_allclose(log.rotations[1], matrix_from_tracker_angles(10.0, 20.0, 30.0))


def test_missing_column_is_named(tmp_path):
    f = tmp_path / "demo.csv"
    f.write_text("t,x,y,z,azimuth,elevation\n0,0,0,0,0,0\n")
    with pytest.raises(InputError, match=r"demo\.csv:1.*lacks column\(s\) roll"):
        read_demo_csv(f)


def test_malformed_line_and_time_going_back_name_the_line(tmp_path):
    f = tmp_path / "demo.csv"
    f.write_text("t,x,y,z,azimuth,elevation,roll\n0,0,0,0,0,0,0\n0.1,0,0,0,0,0,oops\n")
    with pytest.raises(InputError, match=r"demo\.csv:3: not a number"):
        read_demo_csv(f)
    f.write_text("t,x,y,z,azimuth,elevation,roll\n0,0,0,0,0,0,0\n0.1,0,0,0,0,0,0\n0.1,0,0,0,0,0,0\n")
    with pytest.raises(InputError, match=r"demo\.csv:4: t = 0.1 s does not increase"):
        read_demo_csv(f)


def test_read_tracker_log_dispatches_csv_with_units(tmp_path):
    f = tmp_path / "demo.csv"
    f.write_text("t,x,y,z,azimuth,elevation,roll\n0,1,0,0,0,0,0\n0.1,2,0,0,0,0,0\n")
    log = read_tracker_log(DemoSettings(file=f, format="csv", units="mm"))
    np.testing.assert_allclose(log.positions[:, 0], [0.001, 0.002])
