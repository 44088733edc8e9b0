"""The settings the app may change: applied to the TOML document, checked as the problem file is."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import tomlkit

from refine.errors import InputError
from refine.serve.edits import apply_changes, edit_data, edit_document

ROOT = Path(__file__).resolve().parents[2]
GLASS = ROOT / "problems" / "glass_adhesive" / "problem.toml"


@pytest.fixture(scope="module")
def base():
    return tomlkit.parse(GLASS.read_text(encoding="utf-8"))


def test_a_workpiece_move_turns_the_cad_frame_receiver_and_glass_about_the_cad_origin(base):
    # by hand: the CAD origin (1.30, 0, 0.60) shifts by (0.1, 0.2, 0); the receiver at (1.30, -0.82,
    # 0.72) is (0, -0.82, 0.12) from it, turned 90 deg about z that is (0.82, 0, 0.12)
    move = {"xyz": [0.1, 0.2, 0.0], "rpy_deg": [0.0, 0.0, 90.0]}
    doc, problem = apply_changes(base, {"move": move}, GLASS)
    f = problem.frames
    np.testing.assert_allclose(f.cad_in_world[:3, 3], [1.4, 0.2, 0.6], atol=1e-9)
    np.testing.assert_allclose(f.source_in_world[:3, 3], [2.22, 0.2, 0.72], atol=1e-9)
    yaw = math.degrees(math.atan2(f.cad_in_world[1, 0], f.cad_in_world[0, 0]))
    assert abs(abs(yaw) - 180.0) < 1e-6  # 90 + 90
    glass = next(o for o in problem.cell if o.name == "glass")
    table = next(o for o in problem.cell if o.name == "table")
    np.testing.assert_allclose(glass.pose[:3, 3], [1.4, 0.2, 0.625], atol=1e-9)
    np.testing.assert_allclose(table.pose[:3, 3], [1.30, 0.0, 0.425], atol=1e-12)  # not the workpiece
    text = tomlkit.dumps(doc)
    assert "# the window's CAD frame: origin at the lowest point of the glass" in text  # comments kept
    assert "cad_in_world = { xyz = [1.30, 0.0, 0.60]" in tomlkit.dumps(base)  # the base is left as it was


def test_a_move_with_a_new_cad_frame_moves_about_the_frame_as_set_and_the_file_saved_is_the_problem(base):
    # by hand: the CAD frame set to (1.20, 0.10, 0.60), then shifted by 0.05 m along x and turned
    # 90 deg about z about that origin: the CAD origin goes to (1.25, 0.10, 0.60); the receiver
    # (1.30, -0.82, 0.72) is (0.10, -0.92, 0.12) from the set origin, turned (0.92, 0.10, 0.12)
    changes = {
        "frames.cad_in_world": {"xyz": [1.2, 0.1, 0.6], "rpy_deg": [0.0, 0.0, 0.0]},
        "tolerances.orientation_deg": 2.5,
        "move": {"xyz": [0.05, 0.0, 0.0], "rpy_deg": [0.0, 0.0, 90.0]},
    }
    data, problem = edit_data(base.unwrap(), changes, GLASS)
    f = problem.frames
    np.testing.assert_allclose(f.cad_in_world[:3, 3], [1.25, 0.1, 0.6], atol=1e-9)
    np.testing.assert_allclose(f.source_in_world[:3, 3], [1.25 + 0.92, 0.2, 0.72], atol=1e-9)
    assert problem.tolerances.orientation_deg == 2.5
    doc = edit_document(base, changes, GLASS)
    assert doc.unwrap() == data  # the file written holds the problem solved
    assert "# the window's CAD frame: origin at the lowest point of the glass" in tomlkit.dumps(doc)
    assert base.unwrap()["frames"]["cad_in_world"]["xyz"] == [1.30, 0.0, 0.60]  # the base as it was


def test_a_zero_move_leaves_the_file_as_written(base):
    doc, _ = apply_changes(base, {"move": {"xyz": [0, 0, 0], "rpy_deg": [0, 0, 0]}}, GLASS)
    assert tomlkit.dumps(doc) == GLASS.read_text(encoding="utf-8")


def test_a_scalar_change_is_written_in_place_and_read_back(base):
    doc, problem = apply_changes(base, {"tolerances.orientation_deg": 1.5, "collision.margin_m": 0.02}, GLASS)
    assert problem.tolerances.orientation_deg == 1.5 and problem.collision.margin_m == 0.02
    lines = tomlkit.dumps(doc).splitlines()
    assert lines.index("orientation_deg = 1.5") == lines.index("[tolerances]") + 1  # order kept


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        ({"tolerances.orientation_deg": -1}, ["tolerances.orientation_deg", "deg", "-1"]),
        ({"tolerances.orientation_deg": "abc"}, ["tolerances.orientation_deg", "[deg]", "'abc'"]),
        ({"tolerances.orientation_deg": True}, ["tolerances.orientation_deg", "[deg]"]),
        ({"collision.margin_m": 5.0}, ["collision.margin_m", " m", "5"]),
        ({"robot.velocity_scale": 3}, ["robot.velocity_scale", "(0, 1]"]),
        ({"frames.cad_in_world": {"xyz": [1, 2], "rpy_deg": [0, 0, 0]}}, ["cad_in_world.xyz", "3 numbers"]),
        ({"move": {"xyz": [9.0, 0, 0]}}, ["move.xyz", "m"]),
        ({"move": {"xyz": [0, 0, 0], "rpy_deg": [0, 0, 400]}}, ["move.rpy_deg", "deg"]),
        ({"cad.file": "/etc/passwd"}, ["'cad.file'", "not a setting"]),
        ({"demonstration.file": "../../secret.liberty"}, ["not a setting"]),
    ],
)
def test_a_bad_value_is_refused_with_its_key_and_unit(base, changes, words):
    with pytest.raises(InputError) as e:
        apply_changes(base, changes, GLASS)
    for w in words:
        assert w in str(e.value), str(e.value)


def test_the_loader_gives_the_same_message_as_for_the_file(base, tmp_path):
    from refine.problem import load_problem

    bad = tmp_path / "problem.toml"
    text = GLASS.read_text(encoding="utf-8").replace("orientation_deg = 3.0", "orientation_deg = 200")
    bad.write_text(text, encoding="utf-8")
    for name in ("bead.dxf", "demo.liberty", "truth.csv"):
        (tmp_path / name).symlink_to(GLASS.parent / name)
    with pytest.raises(InputError) as from_file:
        load_problem(bad, allow_outside=True)
    with pytest.raises(InputError) as from_app:
        apply_changes(base, {"tolerances.orientation_deg": 200}, GLASS)
    tail = "tolerances.orientation_deg must be a finite number in [0.01, 89] deg, got 200"
    assert str(from_file.value).endswith(tail) and str(from_app.value).endswith(tail)


@pytest.mark.parametrize("key", ["frames.cad_in_world", "frames.source_in_world"])
@pytest.mark.parametrize(
    "bad, says",
    [
        ({"rpy_deg": [0.0, 0.0, 1000.0]}, "within ±720 deg"),
        ({"xyz": [True, 0.0, 0.0]}, "must be a number"),
        ({"xyz": [1.3, 0.0, 0.6], "scale": 2}, "unknown key(s) 'scale'"),
    ],
)
def test_a_frame_the_loader_refuses_is_refused_with_a_move_too(base, key, bad, says):
    # the move rewrites the frame as a pose table: the value as set is read by the loader first
    with pytest.raises(InputError, match=re.escape(f"{key}")) as caught:
        edit_data(base.unwrap(), {key: bad, "move": {"xyz": [0.01, 0.0, 0.0]}}, GLASS)
    assert says in str(caught.value)
