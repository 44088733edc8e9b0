"""Plug-in contenders (a file, an entry point), the runner's clock, and solver options passed through."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from refine.bench import contenders as module
from refine.bench.contenders import (
    CONTENDERS,
    Answer,
    Unavailable,
    load_contender_file,
    load_entry_points,
    parse_solver_option,
    refine_assembled,
    refine_options,
    register_contender,
    timed_call,
)
from refine.bench.runner import run_suites
from refine.bench.suites import generated_problem, load_suites
from refine.cli import main
from refine.errors import InputError
from refine.optimise.rounds import RoundLoop
from refine.stopwatch import StageTimes

PLUGIN = '''
"""Two contenders outside refine: one follows the demonstration by IK, one answers the robot's zero pose."""
import numpy as np

from refine.bench.contenders import Answer, greedy_ik


def follow(problem):
    answer = greedy_ik(problem)
    return Answer("ok", answer.q, {"solve": 0.01}, 0.01, 0, "plug-in")


def zeros(problem):
    return Answer("ok", np.zeros((problem.n_waypoints, problem.robot.nq)), {"solve": 0.0})
'''


@pytest.fixture
def suites_file(tmp_path, tiny_wave):
    path = tmp_path / "suites.toml"
    path.write_text(tiny_wave)
    return path


@pytest.fixture
def wave(suites_file):
    return generated_problem("tiny", "wave", load_suites(suites_file)["generated"]["wave"], 20)


def test_a_contender_from_a_file_runs_and_is_verified_as_the_others(registry, suites_file, tmp_path):
    plugin = tmp_path / "my_contenders.py"
    plugin.write_text(PLUGIN)
    out = tmp_path / "bench.csv"
    argv = [
        "bench",
        "run",
        "--suite",
        "tiny",
        "--suites-file",
        str(suites_file),
        "--csv",
        str(out),
        "--warmup",
        "0",
    ]
    argv += ["--contender-file", f"{plugin}:follow", "--contender-file", f"{plugin}:zeros"]
    assert main([*argv, "--contender", "follow", "--contender", "zeros"]) == 0
    rows = {r["contender"]: r for r in csv.DictReader(out.open())}
    assert set(rows) == {"follow", "zeros"}
    # the demonstrated poses by IK keep every tolerance of the wave; the zero pose is nowhere near it
    assert rows["follow"]["verified"] == "True" and rows["follow"]["success"] == "True"
    assert rows["zeros"]["verified"] == "False" and rows["zeros"]["success"] == "False"
    assert float(rows["zeros"]["max_position_error_m"]) > 0.5


def test_contender_files_and_names_are_checked(registry, tmp_path):
    plugin = tmp_path / "plug.py"
    plugin.write_text(PLUGIN)
    with pytest.raises(InputError, match="expected FILE.py:NAME"):
        load_contender_file(str(plugin))
    with pytest.raises(InputError, match="no file"):
        load_contender_file(f"{tmp_path / 'none.py'}:follow")
    with pytest.raises(InputError, match="defines no 'lead'; its callables: .*follow.*zeros"):
        load_contender_file(f"{plugin}:lead")
    broken = tmp_path / "broken.py"
    broken.write_text("import not_a_module_anywhere\n")
    with pytest.raises(InputError, match="failed to import: ModuleNotFoundError"):
        load_contender_file(f"{broken}:x")
    with pytest.raises(InputError, match="a contender named 'refine' exists already"):
        register_contender("refine", lambda problem: None)
    with pytest.raises(InputError, match="without spaces"):
        register_contender("my contender", lambda problem: None)
    with pytest.raises(InputError, match="not a callable"):
        register_contender("number", 3)


def test_an_installed_entry_point_is_a_contender(registry, tmp_path, monkeypatch):
    (tmp_path / "outside_solver.py").write_text(PLUGIN)
    info = tmp_path / "outside_solver-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: outside-solver\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[refine.bench.contenders]\noutside = outside_solver:follow\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert "outside" in load_entry_points()
    assert CONTENDERS["outside"].__name__ == "follow"
    assert list(CONTENDERS).index("outside") > list(CONTENDERS).index("drake-ik")  # after the built-in ones


def test_the_runners_clock_turns_a_crash_or_a_wrong_answer_into_an_error(wave):
    def crash(problem):
        raise RuntimeError("boom")

    answer, wall = timed_call(wave, "crash", crash)
    assert answer.status == "error" and "RuntimeError: boom" in answer.note and wall >= 0.0
    answer, _ = timed_call(wave, "text", lambda problem: "ok")
    assert answer.status == "error" and "not an Answer" in answer.note

    def absent(problem):
        raise Unavailable("not installed")

    with pytest.raises(Unavailable):
        timed_call(wave, "absent", absent)


def test_solver_options_are_typed():
    assert parse_solver_option("max_iter=100") == ("ipopt.max_iter", 100)
    assert parse_solver_option("ipopt.tol = 1e-8") == ("ipopt.tol", 1e-8)
    assert parse_solver_option("mu_strategy=monotone") == ("ipopt.mu_strategy", "monotone")
    assert parse_solver_option("fatrop.mu_init=0.1") == ("fatrop.mu_init", 0.1)
    assert isinstance(parse_solver_option("max_iter=100")[1], int)
    for bad in ("max_iter", "=3", "tol="):
        with pytest.raises(InputError, match="expected key=value"):
            parse_solver_option(bad)


def test_a_solver_option_reaches_ipopt_and_is_recorded(wave, suites_file, tmp_path):
    # one IPOPT iteration cannot converge the wave from its seed: IPOPT says so
    wave.solver_options = {"ipopt.max_iter": 1}
    answer = refine_assembled(wave)
    assert "Maximum_Iterations_Exceeded" in answer.note
    assert answer.solver_options["options"]["ipopt.max_iter"] == 1
    assert answer.solver_options["given"] == ["ipopt.max_iter"]
    # through the runner: every problem gets them, and the row says what was used
    rows = run_suites(
        ["tiny"], ["refine"], tmp_path / "b.csv", suites_file=suites_file, echo=lambda s: None,
        solver_options={"ipopt.max_iter": 1},
    )  # fmt: skip
    used = json.loads(rows[0]["solver_options"])
    assert used["options"]["ipopt.max_iter"] == 1 and rows[0]["iterations"] <= 2


def test_a_given_option_is_not_overridden_by_later_rounds_or_the_repair(wave):
    # refine's own choices, as docs/bench.md states them: mu_init 1e-4 when a round starts from the
    # last answer, the monotone barrier for the elastic repair
    plain = RoundLoop(wave.refinement("assembled"), StageTimes())
    plain.rebuild(warm=True, elastic_deg=2.0)
    assert plain.problem.solver_options["ipopt.mu_init"] == 1e-4
    assert plain.problem.solver_options["ipopt.mu_strategy"] == "monotone"
    plain.rebuild(warm=False)  # a cold round after a warm one: the warm round's option is gone
    assert "ipopt.mu_init" not in plain.problem.solver_options and plain.problem.given_options == {}
    given = {"ipopt.mu_init": 0.5, "ipopt.mu_strategy": "adaptive"}
    loop = RoundLoop(wave.refinement("assembled", solver_options=given), StageTimes())
    loop.rebuild(warm=True, elastic_deg=2.0)
    loop.rebuild(warm=True, elastic_deg=2.0)  # and again, from the rebuilt problem
    assert loop.problem.solver_options["ipopt.mu_init"] == 0.5
    assert loop.problem.solver_options["ipopt.mu_strategy"] == "adaptive"
    recorded = refine_options(wave.refinement("assembled", solver_options={"ipopt.mu_init": 0.5}))
    assert recorded["later_rounds"] == {} and recorded["repair"] == {"ipopt.mu_strategy": "monotone"}
    assert np.isclose(refine_options(wave.refinement("assembled"))["later_rounds"]["ipopt.mu_init"], 1e-4)


def test_the_module_documents_its_interface():
    assert module.ENTRY_POINT_GROUP == "refine.bench.contenders"
    assert Answer("ok", None).solver_options == {}


def test_fatrop_gets_its_own_options_and_records_them_with_its_defaults(wave):
    from refine.bench.contenders import refine_fatrop

    wave.solver_options = {"fatrop.max_iter": 50, "ipopt.max_iter": 1}
    answer = refine_fatrop(wave)
    used = answer.solver_options
    assert answer.status == "ok" and used["given"] == ["fatrop.max_iter"]
    assert used["options"]["fatrop.max_iter"] == 50 and "fatrop.tol" in used["options"]
    assert not any(k.startswith("ipopt.") for k in used["options"])  # IPOPT's are not fatrop's
