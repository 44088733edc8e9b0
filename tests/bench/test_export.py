"""refine bench export: one fixed refinement NLP in files any NLP solver can read."""

from __future__ import annotations

import importlib.util
import json
import math

import casadi as ca
import numpy as np
import pytest

from refine.bench.export import export_instance, find_problem, load_instance, solve_instance
from refine.bench.suites import ROOT, load_suites
from refine.cli import main
from refine.errors import InputError

WAVE_BOX = """
# 2 cm from the tool where the wave is farthest out: the seed brings clearance rows
boxes = [{ name = "post", centre_m = [1.41, 0.125, 0.65], size_m = [0.06, 0.06, 0.2] }]

[instances.pair]
problems = ["tiny/wave-20", "tiny/wave_box-20"]
"""


TOLERANCES = {"ipopt.tol": 1e-9, "ipopt.constr_viol_tol": 1e-10}
"""refine's convergence tolerances, written out (IPOPT's defaults are 1e-8 and 1e-4)."""


@pytest.fixture(scope="module")
def suites(tmp_path_factory, tiny_wave_with, wave_family):
    path = tmp_path_factory.mktemp("suites") / "suites.toml"
    path.write_text(tiny_wave_with(["wave", "wave_box"], [20], wave_family("wave_box", WAVE_BOX)))
    return path


@pytest.fixture(scope="module")
def exported(suites, tmp_path_factory):
    """The wave of 20 waypoints exported once for the tests of this module."""
    problem = find_problem(load_suites(suites), "tiny/wave-20")
    folder = tmp_path_factory.mktemp("wave")
    return problem, export_instance(problem, folder)


def test_the_files_hold_the_nlp_its_bounds_and_what_it_is(exported):
    problem, done = exported
    assert sorted(p.name for p in done.folder.iterdir()) == ["bounds.json", "instance.json", "nlp.casadi"]
    raw = json.loads((done.folder / "bounds.json").read_text())
    assert set(raw) == {"x0", "lbx", "ubx", "lbg", "ubg", "p"}
    N, n = 20, 6
    function, b, info = load_instance(done.folder)
    assert function.name_in() == ["x", "p"] and function.name_out() == ["f", "g"]
    assert function.size1_in(0) == N * n == len(b["x0"]) and len(b["p"]) == 12 * N
    # joint limits of the IRB 4600 from its registry spec (degrees), less the 5 deg default margin
    spec = problem.robot.spec
    lower = np.degrees(spec.lower) + problem.tolerances.joint_margin_deg
    assert np.allclose(np.degrees(b["lbx"][:n]), lower) and np.allclose(np.degrees(b["lbx"][-n:]), lower)
    # p: the CAD points waypoint by waypoint, then the demonstrated rotations
    assert np.allclose(b["p"][: 3 * N].reshape(N, 3), problem.fused.positions)
    assert np.allclose(b["p"][3 * N :].reshape(N, 3, 3).transpose(0, 2, 1), problem.fused.rotations)
    assert info["round"] == done.round >= 1 and info["n_x"] == N * n and info["refine"]["status"] == "ok"


def test_refines_answer_is_feasible_for_the_exported_nlp_and_its_objective_is_recorded(exported):
    _, done = exported
    function, b, info = load_instance(done.folder)
    x = np.array(info["refine"]["x"])
    f, g = (np.asarray(v).ravel() for v in function(x, b["p"]))
    assert f[0] == pytest.approx(info["refine"]["objective"], rel=1e-12) == pytest.approx(done.objective)
    assert np.all(g >= b["lbg"] - 1e-8) and np.all(g <= b["ubg"] + 1e-8)
    assert np.all(x >= b["lbx"]) and np.all(x <= b["ubx"])


def test_exact_second_derivatives_are_available_and_match_finite_differences(exported):
    _, done = exported
    function, b, _ = load_instance(done.folder)
    x = ca.MX.sym("x", function.size1_in(0))
    f, _ = function(x, b["p"])
    hessian, gradient = ca.hessian(f, x)
    H = ca.Function("H", [x], [hessian])
    G = ca.Function("G", [x], [gradient])
    x0 = b["x0"]
    direction = np.random.default_rng(0).normal(size=len(x0))
    step = 1e-5
    fd = (np.asarray(G(x0 + step * direction)) - np.asarray(G(x0 - step * direction))).ravel() / (2 * step)
    exact = (np.asarray(H(x0)) @ direction).ravel()
    assert np.allclose(exact, fd, rtol=1e-4, atol=1e-6 * np.abs(exact).max())


def test_plain_ipopt_from_x0_reaches_refines_objective(exported):
    _, done = exported
    plain = solve_instance(done.folder, TOLERANCES)
    assert plain["status"] == "Solve_Succeeded" and plain["max_violation"] < 1e-7
    assert math.isclose(plain["objective"], done.objective, rel_tol=1e-6)


def test_the_bench_rows_objective_is_plain_ipopts_on_the_exported_instance(exported, tiny_wave, tmp_path):
    """The CSV's ``objective`` (the shared evaluator at refine's answer in a bench run) and plain
    IPOPT's optimum of the exported instance, solved outside refine: the same within 1e-6."""
    import csv

    from refine.bench.runner import run_suites

    _, done = exported
    out, suites = tmp_path / "bench.csv", tmp_path / "suites.toml"
    suites.write_text(tiny_wave)  # the exported wave alone
    run_suites(["tiny"], ["refine"], out, suites_file=suites, echo=lambda _: None)
    (row,) = [r for r in csv.DictReader(out.open()) if r["problem"] == "wave-20"]
    plain = solve_instance(done.folder, TOLERANCES)
    assert plain["status"] == "Solve_Succeeded"
    assert math.isclose(float(row["objective"]), plain["objective"], rel_tol=1e-6)


def test_the_standalone_script_agrees(exported, capsys):
    _, done = exported
    spec = importlib.util.spec_from_file_location("solve_exported", ROOT / "benchmarks" / "solve_exported.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.main([str(done.folder)]) == 0
    assert "worst relative objective difference" in capsys.readouterr().out


def test_the_command_exports_a_problem_and_a_named_test_set(suites, tmp_path, capsys):
    assert (
        main(["bench", "export", "tiny/wave_box-20", str(tmp_path / "one"), "--suites-file", str(suites)])
        == 0
    )
    assert "round" in capsys.readouterr().out
    info = json.loads((tmp_path / "one" / "instance.json").read_text())
    assert info["problem"] == "wave_box-20" and info["rows"]["linear"] >= 1  # the post's clearance rows
    # a clearance row has no upper bound: written as null and read back as an infinite bound
    raw = json.loads((tmp_path / "one" / "bounds.json").read_text())
    assert raw["ubg"][-1] is None and load_instance(tmp_path / "one")[1]["ubg"][-1] == math.inf
    plain = solve_instance(tmp_path / "one", TOLERANCES)
    assert math.isclose(plain["objective"], info["refine"]["objective"], rel_tol=1e-6)
    tight = ["--solver-option", "tol=1e-10", "--suites-file", str(suites)]
    assert main(["bench", "export", "tiny/wave-20", str(tmp_path / "tight"), *tight]) == 0
    used = json.loads((tmp_path / "tight" / "instance.json").read_text())["refine"]["ipopt_options"]
    assert used["ipopt.tol"] == 1e-10
    assert (
        main(["bench", "export", "--set", "pair", str(tmp_path / "set"), "--suites-file", str(suites)]) == 0
    )
    index = json.loads((tmp_path / "set" / "index.json").read_text())
    assert [i["folder"] for i in index["instances"]] == ["wave-20", "wave_box-20"]
    assert (tmp_path / "set" / "wave-20" / "nlp.casadi").is_file()


def test_unknown_problems_sets_and_keys_are_errors(suites, tmp_path, capsys):
    data = load_suites(suites)
    with pytest.raises(InputError, match="has no problem 'wave-30'; it has wave-20, wave_box-20"):
        find_problem(data, "tiny/wave-30")
    with pytest.raises(InputError, match="neither a problem folder nor SUITE/NAME"):
        find_problem(data, "nowhere")
    assert main(["bench", "export", "--set", "none", str(tmp_path), "--suites-file", str(suites)]) != 0
    assert "no test set 'none' of exported instances; sets: pair" in capsys.readouterr().err
    assert main(["bench", "export", str(tmp_path), "--suites-file", str(suites)]) != 0
    assert "needs PROBLEM and DIR" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text(suites.read_text() + '\n[instances.odd]\nproblems = []\nsolver = "x"\n')
    with pytest.raises(InputError, match=r"\[instances.odd\] takes one key"):
        load_suites(bad)
    bad.write_text(suites.read_text() + "\n[instance.typo]\nproblems = []\n")
    with pytest.raises(InputError, match=r"unknown table\(s\) \['instance'\]"):
        load_suites(bad)
    with pytest.raises(InputError, match="missing"):
        load_instance(tmp_path)


def test_bench_list_names_the_test_sets(suites, capsys):
    assert main(["bench", "list", "--suites-file", str(suites)]) == 0
    assert "pair           2 exported instances (bench export --set pair)" in capsys.readouterr().out


def test_the_repository_test_set_names_problems_of_its_suites():
    data = load_suites()
    for reference in data["instances"]["refinement"]["problems"]:
        suite, name = reference.split("/")
        spec = data["suite"][suite]
        folders = [f.rsplit("/", 1)[-1] for f in spec.get("problems", [])]
        generated = [f"{g}-{n}" for g in spec.get("generated", []) for n in spec.get("sizes", [])]
        assert name in folders + generated, reference


def test_a_repaired_problem_exports_its_elastic_last_round(suites, tmp_path):
    from dataclasses import replace

    # the post 2 cm from the wave's crest, with a 1 deg cone: the strict problem has no answer, the
    # repair leans the tool up to 5 deg more
    problem = find_problem(load_suites(suites), "tiny/wave_box-20")
    tight = replace(problem.tolerances, orientation_deg=1.0)
    done = export_instance(replace(problem, tolerances=tight, repair_max_slack_deg=5.0), tmp_path)
    function, b, info = load_instance(tmp_path)
    assert done.status == "repaired" and info["elastic"] and info["round"] >= 2
    N, n = 20, 6
    assert info["n_x"] == N * n + N and len(b["x0"]) == N * n + N and not any(b["x0"][N * n :])
    x = np.array(info["refine"]["x"])
    slack = x[N * n :]
    # the slacks are what the cone rows need at refine's joints: some waypoints need slack, and every
    # cone row is met
    g = np.asarray(function(x, b["p"])[1]).ravel()
    assert slack.max() > 1e-5 and np.all(g[3 : 4 * N : 4] >= math.cos(math.radians(1.0)) - 1e-12)
    plain = solve_instance(tmp_path, TOLERANCES)
    assert math.isclose(plain["objective"], done.objective, rel_tol=1e-6)
