"""Behaviour of refine.problem.load_problem on the bundled glass_adhesive problem and on edited copies.

Every error case starts from a copy of the bundled problem and changes one thing in its TOML text, so
the error seen can only come from that change.
"""

from __future__ import annotations

import dataclasses
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from refine.errors import InputError
from refine.frames import transform_from_xyz_rpy
from refine.problem import load_problem

BUNDLED = Path(__file__).resolve().parents[1] / "problems" / "glass_adhesive"

# the keys docs/problem-file.md allows in each table (written out, not read from the dataclasses)
ALLOWED = {
    "": [
        "cad",
        "demonstration",
        "description",
        "frames",
        "name",
        "output",
        "process",
        "robot",
        "tolerances",
        "tool",
    ],
    "robot": ["base_in_world", "home_deg", "joint_acceleration_deg_s2", "model", "velocity_scale"],
    "tool": ["axisymmetric", "cog_in_flange_m", "mass_kg", "name", "sensor_in_tcp", "tcp_in_flange"],
    "frames": ["cad_in_world", "source_in_world"],
    "cad": ["file", "format", "layer", "reverse", "spacing_m", "units"],
    "demonstration": [
        "file",
        "format",
        "hampel_sigmas",
        "hampel_window",
        "pause_speed_m_s",
        "rate_hz",
        "smoothing_s",
        "station",
        "truth",
        "units",
    ],
    "tolerances": ["joint_margin_deg", "orientation_deg", "position_m", "singularity_margin"],
    "process": ["kind", "output", "parameters"],
    "process.parameters": ["name", "unit", "value"],
    "output": ["programs"],
}


@pytest.fixture
def problem_toml(tmp_path):
    """problem.toml of a private copy of the bundled problem (safe to edit)."""
    folder = tmp_path / "glass_adhesive"
    shutil.copytree(BUNDLED, folder, ignore=shutil.ignore_patterns("__pycache__"))
    return folder / "problem.toml"


def edit(toml: Path, old: str, new: str) -> None:
    """Replace exactly one occurrence of ``old`` in the file."""
    text = toml.read_text(encoding="utf-8")
    assert text.count(old) == 1, f"{old!r} occurs {text.count(old)} times"
    toml.write_text(text.replace(old, new), encoding="utf-8")


def add_key(toml: Path, table: str, line: str) -> None:
    """Add ``line`` as the first key of ``[table]`` (of the first ``[[table]]``); '' is the top level."""
    text = toml.read_text(encoding="utf-8")
    if not table:
        toml.write_text(f"{line}\n{text}", encoding="utf-8")
        return
    header = f"[[{table}]]\n" if table == "process.parameters" else f"[{table}]\n"
    assert header in text
    toml.write_text(text.replace(header, f"{header}{line}\n", 1), encoding="utf-8")


def remove_table(toml: Path, table: str) -> None:
    """Delete ``[table]`` and its keys, and its sub-tables such as ``[[table.collision]]``."""
    lines = toml.read_text(encoding="utf-8").splitlines(keepends=True)
    kept, dropping = [], False
    for line in lines:
        if line.startswith("["):
            name = line.strip().strip("[]")
            dropping = name == table or name.startswith(table + ".")
        if not dropping:
            kept.append(line)
    assert len(kept) < len(lines), f"no table [{table}]"
    toml.write_text("".join(kept), encoding="utf-8")


def remove_line(toml: Path, prefix: str) -> None:
    lines = toml.read_text(encoding="utf-8").splitlines(keepends=True)
    kept = [ln for ln in lines if not ln.startswith(prefix)]
    assert len(kept) == len(lines) - 1, f"no single line starts with {prefix!r}"
    toml.write_text("".join(kept), encoding="utf-8")


def load_error(path: Path) -> str:
    with pytest.raises(InputError) as info:
        load_problem(path)
    return str(info.value)


# ---- the bundled problem ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def bundled():
    return load_problem(BUNDLED)


def test_bundled_problem_loads_with_the_values_written_in_its_file(bundled):
    p = bundled
    assert p.name == "glass_adhesive"
    assert p.root == BUNDLED and p.root.is_absolute()
    assert p.description.startswith("Rear side window")
    assert p.robot.model == "abb_irb4600_60_205"
    assert p.robot.velocity_scale == 1.0
    assert p.tool.name == "caulk_gun" and p.tool.mass_kg == 6.5 and p.tool.axisymmetric is False
    assert (p.cad.format, p.cad.units, p.cad.spacing_m, p.cad.layer, p.cad.reverse) == (
        "dxf",
        "mm",
        0.005,
        "BEAD",
        False,
    )
    d = p.demonstration
    assert (d.format, d.units, d.station, d.rate_hz) == ("liberty_ascii", "in", 1, 240)
    assert (p.tolerances.orientation_deg, p.tolerances.joint_margin_deg, p.tolerances.singularity_margin) == (
        3.0,
        2.0,
        0.02,
    )
    assert p.tolerances.position_m == 1e-6  # not in the file: the default
    assert (p.process.kind, p.process.output) == ("glue", "doGlueGun")
    assert [(q.name, q.value, q.unit) for q in p.process.parameters] == [
        ("glue_flow_rate", 4.0, "ml/s"),
        ("bead_width", 8.0, "mm"),
        ("gun_pressure", 5.5, "bar"),
    ]
    assert p.output.programs == ("rapid",)


def test_bundled_problem_files_are_absolute_existing_paths_beside_the_toml(bundled):
    for f, name in (
        (bundled.cad.file, "bead.dxf"),
        (bundled.demonstration.file, "demo.liberty"),
        (bundled.demonstration.truth, "truth.csv"),
    ):
        assert isinstance(f, Path) and f.is_absolute() and f.is_file()
        assert f == BUNDLED / name


def test_bundled_poses_are_rigid_4x4_transforms_from_xyz_and_fixed_xyz_degrees(bundled):
    poses = {
        "robot.base_in_world": bundled.robot.base_in_world,
        "tool.tcp_in_flange": bundled.tool.tcp_in_flange,
        "tool.sensor_in_tcp": bundled.tool.sensor_in_tcp,
        "frames.source_in_world": bundled.frames.source_in_world,
        "frames.cad_in_world": bundled.frames.cad_in_world,
    }
    for name, T in poses.items():
        assert T.shape == (4, 4), name
        np.testing.assert_array_equal(T[3], [0, 0, 0, 1], err_msg=name)
        np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12, err_msg=name)
    np.testing.assert_allclose(
        bundled.tool.sensor_in_tcp,
        transform_from_xyz_rpy([-0.03, 0.0, -0.25], [180.0, 0.0, 30.0]),
        atol=1e-15,
    )
    # by hand: rpy_deg [0, 0, 90] turns the receiver's x onto world y, its y onto world -x
    expected = np.array([[0, -1, 0, 1.30], [1, 0, 0, -0.82], [0, 0, 1, 0.72], [0, 0, 0, 1.0]])
    np.testing.assert_allclose(bundled.frames.source_in_world, expected, atol=1e-15)
    np.testing.assert_allclose(bundled.tool.tcp_in_flange[:3, 3], [0.0, 0.0, 0.35])
    np.testing.assert_allclose(bundled.robot.base_in_world, np.eye(4))


def test_loaded_problem_is_frozen(bundled):
    with pytest.raises(dataclasses.FrozenInstanceError):
        bundled.name = "other"  # type: ignore[misc]


def test_folder_path_and_problem_toml_path_load_the_same_problem(problem_toml):
    folder = problem_toml.parent
    from_folder, from_file, from_str = (
        load_problem(folder),
        load_problem(problem_toml),
        load_problem(str(folder)),
    )
    for p in (from_file, from_str):
        assert p.root == from_folder.root == folder.resolve()
        assert p.cad.file == from_folder.cad.file == folder.resolve() / "bead.dxf"
        np.testing.assert_array_equal(p.tool.sensor_in_tcp, from_folder.tool.sensor_in_tcp)


def test_relative_file_paths_resolve_against_the_problem_folder_not_the_working_directory(
    problem_toml, tmp_path, monkeypatch
):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    p = load_problem(Path("..") / "glass_adhesive" / "problem.toml")
    assert p.root == problem_toml.parent.resolve()
    assert p.cad.file == problem_toml.parent.resolve() / "bead.dxf"


def test_a_missing_problem_file_is_named(tmp_path):
    message = load_error(tmp_path / "nowhere")
    assert str(tmp_path / "nowhere") in message


# ---- defaults -----------------------------------------------------------------------------------


def test_defaults_apply_when_optional_tables_are_absent(problem_toml):
    for table in ("tolerances", "output", "frames"):
        remove_table(problem_toml, table)
    p = load_problem(problem_toml)
    t = p.tolerances
    assert (t.position_m, t.orientation_deg, t.joint_margin_deg, t.singularity_margin) == (
        1e-6,
        3.0,
        2.0,
        0.02,
    )
    assert p.output.programs is None  # the robot's own language, chosen at preflight
    np.testing.assert_array_equal(p.frames.source_in_world, np.eye(4))
    np.testing.assert_array_equal(p.frames.cad_in_world, np.eye(4))


def test_process_defaults_and_name_from_the_folder_apply_when_absent(problem_toml):
    folder = problem_toml.parent.rename(problem_toml.parent.with_name("renamed_cell"))
    toml = folder / "problem.toml"
    text = toml.read_text(encoding="utf-8")
    toml.write_text(text[: text.index("[process]")] + text[text.index("[output]") :], encoding="utf-8")
    remove_line(toml, 'name = "glass_adhesive"')
    p = load_problem(toml)
    assert p.name == "renamed_cell"
    assert (p.process.kind, p.process.output, p.process.parameters) == ("other", "doProcess", ())


def test_cad_format_comes_from_the_extension_when_not_given(problem_toml):
    remove_line(problem_toml, 'format = "dxf"')
    assert load_problem(problem_toml).cad.format == "dxf"


# ---- unknown and missing keys ---------------------------------------------------------------------


@pytest.mark.parametrize("table", list(ALLOWED))
def test_an_unknown_key_is_named_and_the_allowed_keys_listed(problem_toml, table):
    add_key(problem_toml, table, "colour = 1")
    message = load_error(problem_toml)
    assert "'colour'" in message
    assert str(problem_toml) in message
    allowed = message.split("allowed", 1)[1]
    for key in ALLOWED[table]:
        assert re.search(rf"\b{re.escape(key)}\b", allowed), f"allowed key {key!r} not listed in: {message}"
    if table:
        assert f"[{table}" in message


def test_a_misspelt_key_is_reported_not_ignored(problem_toml):
    edit(problem_toml, "mass_kg = 6.5", "mass_kilograms = 6.5")
    assert "'mass_kilograms'" in load_error(problem_toml)


@pytest.mark.parametrize("table", ["robot", "tool", "cad", "demonstration"])
def test_a_missing_required_table_is_named(problem_toml, table):
    remove_table(problem_toml, table)
    message = load_error(problem_toml)
    assert f"missing required table [{table}]" in message
    assert str(problem_toml) in message


@pytest.mark.parametrize(
    ("line", "table", "key"),
    [
        ("tcp_in_flange = ", "tool", "tcp_in_flange"),
        ('name = "caulk_gun"', "tool", "name"),
        ("model = ", "robot", "model"),
        ('file = "bead.dxf"', "cad", "file"),
        ('file = "demo.liberty"', "demonstration", "file"),
    ],
)
def test_a_missing_required_key_is_named_with_its_table(problem_toml, line, table, key):
    remove_line(problem_toml, line)
    message = load_error(problem_toml)
    assert re.search(rf"\[{table}\] missing required key '{key}'", message), message


@pytest.mark.parametrize(
    ("data_file", "key"),
    [("bead.dxf", "cad.file"), ("demo.liberty", "demonstration.file"), ("truth.csv", "demonstration.truth")],
)
def test_a_missing_data_file_names_the_key_and_the_path_looked_at(problem_toml, data_file, key):
    missing = problem_toml.parent / data_file
    missing.unlink()
    message = load_error(problem_toml)
    assert key in message
    assert str(missing.resolve()) in message


def test_invalid_toml_is_reported_with_the_file_path(problem_toml):
    edit(problem_toml, "mass_kg = 6.5", "mass_kg = = 6.5")
    message = load_error(problem_toml)
    assert message.startswith(str(problem_toml))
    assert "TOML" in message


def test_a_table_given_as_a_plain_value_is_rejected(problem_toml):
    add_key(problem_toml, "", "tolerances = 3")
    remove_table(problem_toml, "tolerances")
    assert "[tolerances] must be a table" in load_error(problem_toml)


def test_a_process_parameter_without_a_unit_is_rejected(problem_toml):
    remove_line(problem_toml, 'unit = "ml/s"')
    message = load_error(problem_toml)
    assert "process.parameters" in message and "unit" in message


# ---- bad values -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("old", "new", "field", "value"),
    [
        ("orientation_deg = 3.0", "orientation_deg = 120", "tolerances.orientation_deg", "120"),
        ("orientation_deg = 3.0", "orientation_deg = 0", "tolerances.orientation_deg", "0"),
        ("singularity_margin = 0.02", "singularity_margin = -0.1", "tolerances.singularity_margin", "-0.1"),
        ("spacing_m = 0.005", "spacing_m = -1", "cad.spacing_m", "-1"),
        (
            'model = "abb_irb4600_60_205"',
            'model = "abb_irb4600_60_205"\nvelocity_scale = 0',
            "robot.velocity_scale",
            "0",
        ),
        (
            'model = "abb_irb4600_60_205"',
            'model = "abb_irb4600_60_205"\nvelocity_scale = 1.5',
            "robot.velocity_scale",
            "1.5",
        ),
        ('units = "mm"', 'units = "ft"', "cad.units", "'ft'"),
        ('format = "dxf"', 'format = "step"', "cad.format", "'step'"),
        ('units = "in"', 'units = "furlong"', "demonstration.units", "'furlong'"),
        ("rate_hz = 240", "rate_hz = -240", "demonstration.rate_hz", "-240"),
        ("mass_kg = 6.5", "mass_kg = 0", "tool.mass_kg", "0"),
        ('kind = "glue"', 'kind = "paint"', "process.kind", "'paint'"),
        ('programs = ["rapid"]', 'programs = ["gcode"]', "output.programs", "'gcode'"),
    ],
)
def test_a_bad_value_is_rejected_naming_the_field_and_the_value(problem_toml, old, new, field, value):
    edit(problem_toml, old, new)
    message = load_error(problem_toml)
    assert str(problem_toml) in message
    assert field in message, message
    assert re.search(rf"(got|=) {re.escape(value)}(\.0)?(?![\d.])", message), message


@pytest.mark.parametrize(
    "new",
    [
        pytest.param("xyz = [0.0, 0.35]", id="xyz-2-values"),
        pytest.param(
            "xyz = [0.0, 0.0, 0.35], rpy_deg = [0.0, 0.0] }  # ",
            id="rpy-2-values",
        ),
    ],
)
def test_a_pose_with_two_values_is_rejected_naming_the_field(problem_toml, new):
    edit(problem_toml, "xyz = [0.0, 0.0, 0.35]", new)
    message = load_error(problem_toml)
    assert "tool.tcp_in_flange" in message, message


def test_a_pose_with_two_values_is_rejected_naming_what_is_wrong(problem_toml):
    edit(problem_toml, "xyz = [0.0, 0.0, 0.35]", "xyz = [0.0, 0.35]")
    message = load_error(problem_toml)
    assert "list of 3 numbers" in message and "[0.0, 0.35]" in message


def test_a_pose_with_an_unknown_key_is_rejected_naming_the_field_and_the_allowed_form(problem_toml):
    edit(
        problem_toml, "rpy_deg = [180.0, 0.0, 30.0] }", "rpy_deg = [180.0, 0.0, 30.0], quat = [1, 0, 0, 0] }"
    )
    message = load_error(problem_toml)
    assert "tool.sensor_in_tcp" in message
    assert "xyz" in message and "rpy_deg" in message


def test_a_pose_with_an_unknown_key_names_that_key(problem_toml):
    edit(
        problem_toml, "rpy_deg = [180.0, 0.0, 30.0] }", "rpy_deg = [180.0, 0.0, 30.0], quat = [1, 0, 0, 0] }"
    )
    assert "quat" in load_error(problem_toml)


def test_a_pose_given_as_a_list_is_rejected_naming_the_field(problem_toml):
    edit(
        problem_toml,
        "cad_in_world = { xyz = [1.30, 0.0, 0.60], rpy_deg = [0.0, 0.0, 90.0] }",
        "cad_in_world = [1.30, 0.0, 0.60, 0.0, 0.0, 90.0]",
    )
    assert "frames.cad_in_world" in load_error(problem_toml)


# ---- values of the wrong type -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        pytest.param(
            'model = "abb_irb4600_60_205"',
            'model = "abb_irb4600_60_205"\nvelocity_scale = "fast"',
            "robot.velocity_scale",
            id="velocity_scale-string",
        ),
        pytest.param(
            'model = "abb_irb4600_60_205"',
            'model = "abb_irb4600_60_205"\nhome_deg = [0, "up", 0, 0, 0, 0]',
            "robot.home_deg",
            id="home_deg-string",
        ),
        pytest.param(
            "value = 4.0",
            'value = "lots"',
            "process.parameters",
            id="parameter-value-string",
        ),
        pytest.param(
            "xyz = [0.0, 0.0, 0.35]",
            'xyz = ["a", 0.0, 0.35]',
            "tool.tcp_in_flange",
            id="pose-string",
        ),
        pytest.param(
            "station = 1",
            'station = "one"',
            "demonstration.station",
            id="station-string",
        ),
        pytest.param(
            "station = 1",
            "station = 1\nhampel_window = 2.5",
            "demonstration.hampel_window",
            id="hampel_window-fraction",
        ),
        pytest.param(
            "axisymmetric = false",
            'axisymmetric = "no"',
            "tool.axisymmetric",
            id="axisymmetric-string",
        ),
        pytest.param(
            "spacing_m = 0.005",
            "spacing_m = true",
            "cad.spacing_m",
            id="spacing_m-bool",
        ),
        ("mass_kg = 6.5", 'mass_kg = "6.5"', "tool.mass_kg"),
        ("orientation_deg = 3.0", "orientation_deg = nan", "tolerances.orientation_deg"),
    ],
)
def test_a_value_of_the_wrong_type_is_an_input_error_naming_the_field(problem_toml, old, new, field):
    edit(problem_toml, old, new)
    assert field in load_error(problem_toml)


def test_programs_given_as_a_string_is_reported_with_the_value_written(problem_toml):
    edit(problem_toml, 'programs = ["rapid"]', 'programs = "rapid"')
    message = load_error(problem_toml)
    assert "output.programs" in message and "'rapid'" in message


# The language each arm's controller runs, from the makers' documentation: ABB IRC5 runs RAPID, the
# KUKA KR C4 runs KRL, the LBR iiwa's Sunrise cabinet runs Sunrise Java, a UR e-Series runs URScript,
# a FANUC R-30iB runs TP, a Yaskawa YRC1000 runs INFORM.
@pytest.mark.parametrize(
    ("bundled", "language"),
    [
        ("glass_adhesive", "rapid"),
        ("kr8_arc_weld", "krl"),
        ("tig_weld", "sunrise"),
        ("ur10e_sealing", "urscript"),
        ("m20ia_arc_weld", "tp"),
        ("gp12_arc_weld", "inform"),
    ],
)
def test_without_an_output_table_the_robot_gets_the_program_its_controller_runs(tmp_path, bundled, language):
    from refine.run.preflight import preflight

    folder = tmp_path / bundled
    shutil.copytree(BUNDLED.parent / bundled, folder, ignore=shutil.ignore_patterns("__pycache__"))
    remove_table(folder / "problem.toml", "output")
    problem = load_problem(folder / "problem.toml")
    assert preflight(problem, tmp_path / "out", report=False).programs == (language,)
