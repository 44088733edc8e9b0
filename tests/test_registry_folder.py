"""The robot of a problem's ``[robot]`` table comes from the registry folder in force when it is asked for."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from refine.robot.registry import robot_for
from refine.settings.inputs import RobotSettings

ROOT = Path(__file__).resolve().parents[1]
NAME = "abb_irb4600_60_205"


def test_a_robot_of_another_registry_folder_is_not_the_cached_one(tmp_path, monkeypatch):
    settings = RobotSettings(model=NAME, base_in_world=np.eye(4))
    monkeypatch.delenv("REFINE_ROBOTS_DIR", raising=False)
    default = robot_for(settings)
    assert default.spec.reach_m == 2.05  # robots/abb_irb4600_60_205/robot.toml

    shutil.copytree(ROOT / "robots" / NAME, tmp_path / NAME)
    toml = tmp_path / NAME / "robot.toml"
    toml.write_text(toml.read_text().replace("reach_m = 2.05", "reach_m = 2.5"))
    monkeypatch.setenv("REFINE_ROBOTS_DIR", str(tmp_path))
    assert robot_for(settings).spec.reach_m == 2.5

    monkeypatch.delenv("REFINE_ROBOTS_DIR")
    assert robot_for(settings).spec.reach_m == 2.05
