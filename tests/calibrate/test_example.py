"""The glass_calibrated example: its frames are what `refine calibrate` gives on its measurements."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from refine.calibrate.files import update_problem
from refine.cli import main
from refine.frames import invert_transform, rotation_angle_deg, transform_from_xyz_rpy
from refine.problem import load_problem

PROBLEMS = Path(__file__).resolve().parents[2] / "problems"
EXAMPLE = PROBLEMS / "glass_calibrated"
FRAMES = (
    ("tool", "sensor_in_tcp"),
    ("tool", "tcp_in_flange"),
    ("frames", "source_in_world"),
    ("frames", "cad_in_world"),
)


def _frame(problem, table, key):
    return getattr(problem.tool if table == "tool" else problem.frames, key)


@pytest.fixture(scope="module")
def recalibrated(tmp_path_factory):
    """A copy of the example with drawing frames, calibrated again from the committed files."""
    copy = tmp_path_factory.mktemp("example") / "glass_calibrated"
    shutil.copytree(EXAMPLE, copy)
    for table, key in FRAMES:  # start from frames centimetres and degrees off
        T = _frame(load_problem(copy), table, key) @ transform_from_xyz_rpy(
            [0.01, -0.02, 0.01], [1.0, 0.0, -2.0]
        )
        update_problem(copy, table, key, T)
    m, p = str(copy / "measurements"), str(copy)
    for args in (
        ["pivot", f"{m}/pivot.liberty", "--rate-hz", "60", "--write", p],
        ["tcp", f"{m}/tcp.csv", "--six-point", "--problem", p, "--write", p],
        [
            "receiver",
            f"{m}/touch.liberty",
            f"{m}/fixture_points.csv",
            "--rate-hz",
            "60",
            "--problem",
            p,
            "--write",
            p,
        ],
        ["workpiece", f"{m}/workpiece.csv", f"{m}/glass_points.csv", "--problem", p, "--write", p],
    ):
        assert main(["calibrate", *args]) == 0
    return load_problem(copy)


@pytest.mark.parametrize("table,key", FRAMES)
def test_the_committed_frames_come_from_the_committed_measurements(recalibrated, table, key):
    committed = _frame(load_problem(EXAMPLE), table, key)
    again = _frame(recalibrated, table, key)
    if key == "sensor_in_tcp":  # the pivot measures the tip; the orientation is the problem's (here off)
        tip, tip_again = invert_transform(committed)[:3, 3], invert_transform(again)[:3, 3]
        np.testing.assert_allclose(tip_again, tip, atol=2e-6)
        return
    np.testing.assert_allclose(again[:3, 3], committed[:3, 3], atol=2e-6)
    assert rotation_angle_deg(again[:3, :3], committed[:3, :3]) < 2e-4


@pytest.mark.parametrize("table,key", FRAMES)
def test_the_calibrated_frames_are_close_to_the_simulation_truth(table, key):
    truth = _frame(load_problem(PROBLEMS / "glass_adhesive"), table, key)
    measured = _frame(load_problem(EXAMPLE), table, key)
    assert np.linalg.norm(measured[:3, 3] - truth[:3, 3]) < 0.5e-3
    assert rotation_angle_deg(measured[:3, :3], truth[:3, :3]) < 0.1
