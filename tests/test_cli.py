import json
import os
import shutil
import time
from pathlib import Path

import pytest

from refine.cli import main

ROOT = Path(__file__).resolve().parents[1]
GLASS = ROOT / "problems" / "glass_adhesive"


def test_robots_lists_every_registered_robot(capsys):
    assert main(["robots"]) == 0
    out = capsys.readouterr().out
    for name in ("abb_irb4600_60_205", "kuka_iiwa14_r820", "ur10e"):
        assert name in out


def test_check_accepts_the_bundled_problem(capsys):
    assert main(["check", str(GLASS)]) == 0
    assert "problem file OK" in capsys.readouterr().out


def test_bad_problem_file_exits_2_with_the_key_named(tmp_path, capsys):
    problem = tmp_path / "glass"
    shutil.copytree(GLASS, problem)
    toml = problem / "problem.toml"
    toml.write_text(toml.read_text().replace("[tolerances]", "[tolerances]\ncone_deg = 3"))
    assert main(["check", str(problem)]) == 2
    err = capsys.readouterr().err
    assert "cone_deg" in err and "orientation_deg" in err


def test_missing_problem_exits_2(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nowhere")]) == 2
    assert "problem file not found" in capsys.readouterr().err


@pytest.mark.slow
def test_run_writes_every_output_and_a_result_with_the_documented_keys(tmp_path, capsys):
    out = tmp_path / "out"
    start = time.perf_counter()
    assert main(["run", str(GLASS), "--out", str(out)]) == 0
    wall_s = time.perf_counter() - start
    assert "status       ok" in capsys.readouterr().out
    names = {p.name for p in out.iterdir()}
    assert {"result.json", "trajectory.csv", "glass_adhesive.aml", "glass_adhesive.mod"} <= names
    doc = json.loads((out / "result.json").read_text())
    for key in (
        "status",
        "problem",
        "n_waypoints",
        "dof",
        "robot",
        "tool",
        "tolerances",
        "metrics",
        "timings_s",
        "repairs",
        "outputs",
    ):
        assert key in doc
    assert set(doc["robot"]) >= {"urdf", "flange_frame", "base_in_world"}
    assert set(doc["tool"]) >= {"tcp_in_flange", "axisymmetric"}
    for key in (
        "max_position_error_m",
        "max_orientation_deviation_deg",
        "min_joint_margin_rad",
        "min_singularity_measure",
        "min_clearance_m",
        "cycle_time_s",
        "speed_tracking_error_rel",
    ):
        assert key in doc["metrics"]
    stages = ("cad", "demo", "fuse", "build", "seed", "solve", "verify", "timing", "export")
    times = doc["timings_s"]
    assert all(times[stage] >= 0.0 for stage in stages)
    # the stages run one after the other inside the run, the run inside the process and inside the
    # wall time measured here: a stage counted twice or in the wrong unit breaks this chain
    assert sum(times[stage] for stage in stages) <= times["run"] + 1e-5 * len(stages)
    assert times["run"] <= times["total"] + 1e-6
    assert times["run"] <= wall_s
    assert (ROOT / doc["robot"]["urdf"]).is_file()
    assert set(doc["outputs"].values()) <= names


def test_ctrl_c_while_the_command_line_is_read_exits_130_without_a_traceback(monkeypatch, capsys):
    import refine.cli

    def interrupted(*_args, **_kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(refine.cli, "_parser", interrupted)
    assert refine.cli.main(["robots"]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err


def _line_problems(tmp_path: Path) -> tuple[Path, Path]:
    """The same straight bead on the registry's UR10e and on the UR10e from its URDF file.

    The URDF's robot is renamed ``cell_ur10e``, a name the registry does not have.
    """
    from refine.synthetic import write_line_problem

    registry = write_line_problem(tmp_path / "registry" / "line").parent
    urdf = write_line_problem(tmp_path / "urdf" / "line").parent
    shutil.copytree(ROOT / "robots" / "ur10e", urdf / "robot")
    description = urdf / "robot" / "robot.urdf"
    xml = description.read_text()
    assert xml.count('<robot name="ur10e">') == 1
    description.write_text(xml.replace('<robot name="ur10e">', '<robot name="cell_ur10e">'))
    toml = urdf / "problem.toml"
    text = toml.read_text()
    assert '[robot]\nmodel = "ur10e"\n' in text
    toml.write_text(
        text.replace('[robot]\nmodel = "ur10e"\n', '[robot]\nurdf = "robot/robot.urdf"\ncontroller = "ur"\n')
    )
    return registry, urdf


def test_check_takes_a_robot_from_a_urdf_as_run_does(tmp_path, capsys):
    import xml.etree.ElementTree as ET

    registry, urdf = _line_problems(tmp_path)
    assert main(["check", str(registry)]) == 0
    from_registry = capsys.readouterr().out
    assert main(["check", str(urdf)]) == 0
    from_urdf = capsys.readouterr().out
    # the URDF's robot is named after its <robot name="...">; every other finding is the same
    urdf_name = ET.parse(urdf / "robot" / "robot.urdf").getroot().get("name")
    assert urdf_name == "cell_ur10e" and main(["robots"]) == 0 and urdf_name not in capsys.readouterr().out
    assert "(robot ur10e," in from_registry and "(robot cell_ur10e," in from_urdf
    assert from_urdf.replace("(robot cell_ur10e,", "(robot ur10e,") == from_registry
    assert "problem file OK" in from_urdf and "programs urscript" in from_urdf


def test_check_of_a_urdf_robot_still_reports_what_is_wrong(tmp_path, capsys):
    _, urdf = _line_problems(tmp_path)
    toml = urdf / "problem.toml"
    text = toml.read_text()
    toml.write_text(text.replace('controller = "ur"\n', 'controller = "ur"\nhome_deg = [0.0, -90.0, 90.0]\n'))
    assert main(["check", str(urdf)]) == 2
    err = capsys.readouterr().err
    assert "home_deg" in err and "6" in err and "Traceback" not in err  # the UR10e has six joints
    toml.write_text(text.replace('programs = ["urscript"]', 'programs = ["rapid"]'))
    assert main(["check", str(urdf)]) == 2
    err = capsys.readouterr().err
    assert "'rapid'" in err and "ur controller" in err and "urscript only" in err


def test_help_lists_every_command_as_the_full_parser_does_without_importing_the_heavy_ones():
    """``refine --help`` (in a fresh interpreter) prints what the parser with every command's module
    imported prints, and leaves the benchmark's and the calibration's modules unimported; a lazy
    command still gets its own full parser."""
    import subprocess
    import sys

    from refine import cli

    code = (
        "import sys, contextlib, io\n"
        "from refine import cli\n"
        "out = io.StringIO()\n"
        "with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):\n"
        "    cli._parser(['--help']).parse_args(['--help'])\n"
        "print(out.getvalue(), end='')\n"
        "print([m for m in ('refine.bench.cli', 'refine.calibrate.cli', 'scipy') if m in sys.modules])\n"
    )
    env = {**os.environ, "COLUMNS": "100"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    *lines, loaded = done.stdout.splitlines()
    assert loaded == "[]"
    full = subprocess.run(
        [sys.executable, "-c", code.replace("cli._parser(['--help'])", "cli._parser(every=True)")],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    ).stdout.splitlines()[:-1]
    assert lines == full and any(line.strip().startswith("bench") for line in lines)
    args = cli._parser(["bench", "list"]).parse_args(["bench", "list"])
    assert args.command == "bench" and args.bench_command == "list"
    commands = next(a for a in cli._parser(["-v", "calibrate"])._actions if a.dest == "command").choices
    kinds = next(a for a in commands["calibrate"]._actions if a.dest == "kind").choices
    assert {"pivot", "receiver"} <= set(kinds)
