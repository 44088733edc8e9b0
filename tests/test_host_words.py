"""Errors raised through the library speak its words (keywords, arguments), not the command line's."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import refine


def test_an_unknown_registry_robot_carries_its_key_and_value():
    positions = np.column_stack([np.full(5, 0.6), np.linspace(-0.1, 0.1, 5), np.full(5, 0.3)])
    R = np.repeat(np.diag([1.0, -1.0, -1.0])[None], 5, axis=0)
    with pytest.raises(refine.InputError) as e:
        refine.refine_path("ur1e", positions, R, speeds=0.1)
    assert (e.value.key, e.value.value) == ("robot", "ur1e")
    assert "ur10e" in e.value.expected and "unknown robot 'ur1e'" in str(e.value)


def test_an_unknown_robot_of_a_problem_file_names_the_setting(tmp_path):
    shutil.copytree("problems/tig_weld", tmp_path / "p")
    toml = tmp_path / "p" / "problem.toml"
    text = toml.read_text()
    model = text.split('model = "', 1)[1].split('"', 1)[0]
    toml.write_text(text.replace(f'model = "{model}"', 'model = "no_such_arm"', 1))
    with pytest.raises(refine.InputError) as e:
        refine.solve(tmp_path / "p")
    assert (e.value.key, e.value.value) == ("robot.model", "no_such_arm")


def _turned_frame(deg: float) -> refine.Problem:
    problem = refine.load_problem("problems/tig_weld")
    T = np.array(problem.frames.source_in_world, dtype=float)
    T[:3, :3] = Rotation.from_euler("z", deg, degrees=True).as_matrix() @ T[:3, :3]  # the receiver turned
    return dataclasses.replace(problem, frames=dataclasses.replace(problem.frames, source_in_world=T))


def test_a_wrong_tracker_frame_through_the_api_names_the_keyword_not_the_flag():
    problem = _turned_frame(10.0)
    with pytest.raises(refine.InputError) as e:
        refine.solve(problem, time_limit_s=600)
    msg = str(e.value)
    assert "accept_frame_error=True" in msg and "--accept-frame-error" not in msg
    assert e.value.key == "frames.source_in_world"
    assert 8.0 < e.value.value < 12.0  # the 10 deg turn, as the path shows it [deg]


# the command line's own wording of the same stop (its --accept-frame-error flag) is tested in
# tests/demo/test_frame_distortion.py


def test_a_data_file_outside_the_folder_through_load_problem_names_its_keyword(tmp_path):
    shutil.copytree("problems/tig_weld", tmp_path / "p")
    toml = tmp_path / "p" / "problem.toml"
    text = toml.read_text()
    cad = text.split("[cad]", 1)[1].split('file = "', 1)[1].split('"', 1)[0]
    shutil.move(tmp_path / "p" / cad, tmp_path / cad)  # the CAD file one folder up
    toml.write_text(text.replace(f'file = "{cad}"', f'file = "../{cad}"', 1))
    with pytest.raises(refine.InputError) as e:
        refine.load_problem(tmp_path / "p")
    msg = str(e.value)
    assert "allow_outside=True" in msg and "--allow-outside" not in msg
    assert e.value.key == "cad.file" and e.value.value == f"../{cad}"
    assert refine.load_problem(tmp_path / "p", allow_outside=True).cad is not None
