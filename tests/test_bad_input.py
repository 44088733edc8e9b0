"""Bad input is refused before anything is solved or written: exit 2, the file and key named.

Each case edits a copy of a bundled problem the way a careless user might and runs both
``refine check`` and ``refine run``: both must exit 2 with a message naming the problem file (or
the option) and the key, print no traceback, and leave the output folder uncreated.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from refine.cli import main

ROOT = Path(__file__).resolve().parents[1]
GLASS = ROOT / "problems" / "glass_adhesive"
SEALING = ROOT / "problems" / "ur10e_sealing"


def _sub(old: str, new: str):
    def edit(text: str) -> str:
        assert old in text, old
        return text.replace(old, new, 1)

    return edit


# (case id, edit of problem.toml text, words the message must contain)
TOML_CASES = [
    (
        "nan-in-pose",
        _sub("xyz = [1.30, -0.82, 0.72]", "xyz = [nan, -0.82, 0.72]"),
        ["source_in_world", "finite"],
    ),
    (
        "inf-in-rpy",
        _sub("rpy_deg = [180.0, 0.0, 30.0]", "rpy_deg = [180.0, inf, 30.0]"),
        ["sensor_in_tcp", "finite"],
    ),
    ("huge-pose", _sub("xyz = [0.0, 0.0, 0.35]", "xyz = [0.0, 0.0, 1e300]"), ["tcp_in_flange", "100 m"]),
    ("nan-mass", _sub("mass_kg = 6.5", "mass_kg = nan"), ["mass_kg", "finite"]),
    (
        "nan-home",
        _sub('model = "abb_irb4600_60_205"', 'model = "abb_irb4600_60_205"\nhome_deg = [0, 0, 0, 0, nan, 0]'),
        ["home_deg", "finite"],
    ),
    (
        "short-home",
        _sub('model = "abb_irb4600_60_205"', 'model = "abb_irb4600_60_205"\nhome_deg = [0, 10, 20]'),
        ["home_deg", "3 values", "6 joints"],
    ),
    (
        "short-accel",
        _sub(
            'model = "abb_irb4600_60_205"',
            'model = "abb_irb4600_60_205"\njoint_acceleration_deg_s2 = [100, 100]',
        ),
        ["joint_acceleration_deg_s2", "2 values"],
    ),
    (
        "nan-velocity-scale",
        _sub('model = "abb_irb4600_60_205"', 'model = "abb_irb4600_60_205"\nvelocity_scale = nan'),
        ["velocity_scale"],
    ),
    (
        "unknown-robot",
        _sub('model = "abb_irb4600_60_205"', 'model = "abb_irb9999"'),
        ["robot.model", "available"],
    ),
    (
        "parameters-not-tables",
        _sub('output = "doGlueGun"', 'output = "doGlueGun"\nparameters = [1, 2]'),
        ["process.parameters[0]", "table"],
    ),
    ("nan-parameter", _sub("value = 4.0", "value = nan"), ["process.parameters[0].value", "finite"]),
    ("tiny-spacing", _sub("spacing_m = 0.005", "spacing_m = 1e-7"), ["cad.spacing_m", "0.0001"]),
    (
        "huge-hampel",
        _sub("smoothing_s = 0.03", "smoothing_s = 0.03\nhampel_window = 100000000"),
        ["hampel_window", "samples"],
    ),
    ("huge-smoothing", _sub("smoothing_s = 0.03", "smoothing_s = 1e6"), ["smoothing_s", " s"]),
    (
        "tiny-check-step",
        _sub("self_margin_m = 0.005", "self_margin_m = 0.005\ncheck_step_m = 1e-7"),
        ["check_step_m"],
    ),
    ("tiny-cone", _sub("orientation_deg = 3.0", "orientation_deg = 1e-4"), ["orientation_deg", "0.01"]),
    ("empty-name", _sub('name = "glass_adhesive"', 'name = ""'), ["name"]),
    ("name-not-string", _sub('name = "glass_adhesive"', "name = 5"), ["name", "string"]),
    ("tool-name-newline", _sub('name = "caulk_gun"', 'name = "gun\\nPROC x()"'), ["tool.name", "printable"]),
    ("output-newline", _sub('output = "doGlueGun"', 'output = "do\\nSetDO x, 1;"'), ["process.output"]),
    (
        "bad-rapid-signal",
        _sub('output = "doGlueGun"', 'output = "do glue!"'),
        ["process.output", "RAPID signal"],
    ),
    ("krl-on-abb", _sub('programs = ["rapid"]', 'programs = ["krl"]'), ["krl", "abb"]),
    ("unknown-language", _sub('programs = ["rapid"]', 'programs = ["gcode"]'), ["gcode", "rapid"]),
    (
        "passwd",
        _sub('file = "bead.dxf"', 'file = "../../../../../../../etc/passwd"'),
        ["cad.file", "outside the problem folder"],
    ),
    ("absolute", _sub('file = "demo.liberty"', 'file = "/etc/hostname"'), ["demonstration.file", "outside"]),
    ("missing-file", _sub('file = "bead.dxf"', 'file = "nope.dxf"'), ["cad.file", "nope.dxf"]),
    ("dev-zero", _sub('file = "demo.liberty"', 'file = "/dev/zero"'), ["demonstration.file"]),
    (
        "description-table",
        _sub('name = "glass_adhesive"', 'name = "glass_adhesive"\n[description]\nx = 1'),
        ["description"],
    ),
    ("bad-toml", _sub("[robot]", "[robot"), ["not valid TOML", "line"]),
]


def _copy(src: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "problem"
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("generate.py", "README.md"))
    return dst


def _expect_refused(command: list[str], out: Path, capsys, words: list[str]) -> str:
    assert main(command) == 2
    captured = capsys.readouterr()
    err = captured.err
    assert "Traceback" not in err + captured.out
    for word in words:
        assert word in err, (word, err)
    assert not out.exists(), sorted(p.name for p in out.iterdir())
    return err


@pytest.mark.parametrize("command", ["check", "run"])
@pytest.mark.parametrize("case", TOML_CASES, ids=[c[0] for c in TOML_CASES])
def test_bad_problem_file_is_refused_before_anything_is_written(tmp_path, capsys, command, case):
    _, edit, words = case
    problem = _copy(GLASS, tmp_path)
    toml = problem / "problem.toml"
    text = edit(toml.read_text())
    if "parameters = [1, 2]" in text:  # the inline list and the [[tables]] cannot both be given
        text = text.split("[[process.parameters]]")[0] + "[output]" + text.split("[output]")[1]
    toml.write_text(text)
    out = tmp_path / "out"
    extra = ["--out", str(out)]
    err = _expect_refused([command, str(problem), *extra], out, capsys, words)
    assert "problem.toml" in err or "--out" in err or "--programs" in err
    assert "root:" not in err  # nothing of a foreign file is echoed


@pytest.mark.parametrize("command", ["check", "run"])
def test_non_utf8_and_binary_problem_files_name_the_line(tmp_path, capsys, command):
    problem = _copy(GLASS, tmp_path)
    toml = problem / "problem.toml"
    toml.write_bytes(toml.read_bytes().replace(b'"caulk_gun"', b'"caulk_\xe9gun"'))
    err = _expect_refused(
        [command, str(problem), "--out", str(tmp_path / "o")], tmp_path / "o", capsys, ["UTF-8"]
    )
    line = (
        toml.read_bytes().split(b"\n").index(next(x for x in toml.read_bytes().split(b"\n") if b"\xe9" in x))
        + 1
    )
    assert f"problem.toml:{line}:" in err
    toml.write_bytes(os.urandom(4096))
    _expect_refused(
        [command, str(problem), "--out", str(tmp_path / "o")], tmp_path / "o", capsys, ["problem.toml"]
    )


@pytest.mark.parametrize("command", ["check", "run"])
def test_out_that_is_a_file_is_refused_before_solving(tmp_path, capsys, command):
    target = tmp_path / "out.txt"
    target.write_text("keep me")
    assert main([command, str(GLASS), "--out", str(target)]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "is a file" in err and "Traceback" not in err
    assert target.read_text() == "keep me"


@pytest.mark.parametrize("command", ["check", "run"])
def test_programs_option_for_another_controller_is_refused(tmp_path, capsys, command):
    out = tmp_path / "o"
    _expect_refused(
        [command, str(GLASS), "--out", str(out), "--programs", "urscript"], out, capsys, ["urscript", "abb"]
    )
    _expect_refused(
        [command, str(GLASS), "--out", str(out), "--programs", "gcode"], out, capsys, ["--programs", "gcode"]
    )
    _expect_refused(
        [command, str(SEALING), "--out", str(out), "--programs", "rapid"], out, capsys, ["rapid", "ur10e"]
    )


@pytest.mark.parametrize("command", ["check", "run"])
def test_a_link_out_of_the_problem_folder_is_refused_unless_allowed(tmp_path, capsys, command):
    problem = _copy(GLASS, tmp_path)
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (problem / "bead.dxf").rename(outside / "bead.dxf")
    (problem / "bead.dxf").symlink_to(outside / "bead.dxf")
    out = tmp_path / "o"
    _expect_refused([command, str(problem), "--out", str(out)], out, capsys, ["cad.file", "--allow-outside"])
    if command == "check":
        assert main([command, str(problem), "--allow-outside"]) == 0


@pytest.mark.parametrize("command", ["check", "run"])
def test_outputs_never_replace_an_input(tmp_path, capsys, command):
    problem = _copy(GLASS, tmp_path)
    (problem / "bead.dxf").rename(problem / "glass_adhesive.aml")
    toml = problem / "problem.toml"
    toml.write_text(toml.read_text().replace('file = "bead.dxf"', 'file = "glass_adhesive.aml"'))
    before = (problem / "glass_adhesive.aml").read_bytes()
    assert main([command, str(problem), "--out", str(problem)]) == 2
    err = capsys.readouterr().err
    assert "glass_adhesive.aml" in err and "replace" in err
    assert (problem / "glass_adhesive.aml").read_bytes() == before


@pytest.mark.parametrize("command", ["check", "run"])
def test_a_garbage_dxf_fails_check_as_it_fails_run(tmp_path, capsys, command):
    problem = _copy(GLASS, tmp_path)
    (problem / "bead.dxf").write_bytes(b"0\nSECTION\n2\nENTITIES\n0\nGARBAGE\n" + os.urandom(300))
    out = tmp_path / "o"
    _expect_refused([command, str(problem), "--out", str(out)], out, capsys, ["bead.dxf"])


TIG = ROOT / "problems" / "tig_weld"
KR8 = ROOT / "problems" / "kr8_arc_weld"


@pytest.mark.parametrize("command", ["check", "run"])
def test_a_program_the_arms_own_controller_does_not_run_is_refused(tmp_path, capsys, command):
    # the LBR iiwa's Sunrise cabinet runs Sunrise Java only; the KR 8's KR C5 runs KRL only
    out = tmp_path / "o"
    err = _expect_refused(
        [command, str(TIG), "--out", str(out), "--programs", "krl"],
        out,
        capsys,
        ["--programs", "'krl'", "kuka_iiwa14_r820", "kuka controller", "sunrise only"],
    )
    assert "krl only" not in err
    problem = _copy(KR8, tmp_path)
    toml = problem / "problem.toml"
    toml.write_text(_sub('programs = ["krl"]', 'programs = ["sunrise"]')(toml.read_text()))
    _expect_refused(
        [command, str(problem), "--out", str(out)],
        out,
        capsys,
        ["problem.toml", "'sunrise'", "kuka_kr8_r1440_2_arc_hw", "kuka controller", "krl only"],
    )
