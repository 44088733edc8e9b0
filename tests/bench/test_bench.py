"""refine bench: suites from data, one CSV row per problem and contender, the report from the CSV."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from refine.bench import contenders as contenders_module
from refine.bench.contenders import Answer, Unavailable, verify
from refine.bench.outcomes import score
from refine.bench.report import write_report
from refine.bench.runner import COLUMNS, run_suites, run_turns
from refine.bench.suites import generated_problem, growth_exponent, load_suites, problems
from refine.cli import main
from refine.errors import InputError

WAVE_BOX = """boxes = [{ name = "post", centre_m = [1.5, 0.0, 0.55], size_m = [0.1, 0.1, 0.3] }]\n"""
"""The post beside the wave of the ``wave_box`` family (its other keys: the wave's)."""


@pytest.fixture
def suites_file(tmp_path, tiny_wave_with, wave_family):
    """The wave and the wave beside a post, 20 and 40 waypoints each."""
    path = tmp_path / "suites.toml"
    path.write_text(tiny_wave_with(["wave", "wave_box"], [20, 40], wave_family("wave_box", WAVE_BOX)))
    return path


def test_suites_are_data_and_build_their_problems(suites_file):
    data = load_suites(suites_file)
    built = list(problems(data, "tiny"))
    assert [p.name for p in built] == ["wave-20", "wave-40", "wave_box-20", "wave_box-40"]
    assert [p.n_waypoints for p in built] == [20, 40, 20, 40]
    assert not built[0].sources and built[2].sources  # the boxes become a clearance check
    with pytest.raises(InputError, match="no suite 'huge'"):
        list(problems(data, "huge"))


def test_the_repository_suites_name_existing_problems():
    data = load_suites()
    assert {"bundled", "scaling", "unreachable", "quick", "glass", "growth"} <= set(data["suite"])
    assert data["suite"]["scaling"]["sizes"][0] == 100 and data["suite"]["scaling"]["sizes"][-1] == 10000
    from refine.bench.suites import ROOT

    for suite in data["suite"].values():
        for folder in suite.get("problems", []):
            assert (ROOT / folder / "problem.toml").exists(), folder


def test_run_writes_one_row_per_problem_and_contender_and_the_report_reads_the_csv_alone(
    suites_file, tmp_path, monkeypatch
):
    def missing(problem):
        raise Unavailable("not installed here")

    monkeypatch.setitem(contenders_module.CONTENDERS, "drake-ik", missing)
    messages = []
    out = tmp_path / "bench.csv"
    rows = run_suites(
        ["tiny"], ["refine", "greedy-ik", "drake-ik"], out, suites_file=suites_file, echo=messages.append
    )
    # 4 problems x 3 contenders; the missing one is skipped with a message and leaves rows that say so
    assert len(rows) == 12
    assert any("skipping drake-ik: not installed here" in m for m in messages)
    with out.open() as f:
        table = list(csv.DictReader(f))
    assert list(table[0]) == COLUMNS and len(table) == 12
    missing_rows = [r for r in table if r["contender"] == "drake-ik"]
    assert len(missing_rows) == 4 and {r["status"] for r in missing_rows} == {"unavailable"}
    assert all(r["note"] == "not installed here" and r["success"] == "False" for r in missing_rows)
    table = [r for r in table if r["contender"] != "drake-ik"]
    for row in table:
        assert row["verified"] == "True" and row["success"] == "True", row
        assert float(row["total_s"]) > 0 and float(row["cpu_s"]) > 0 and row["casadi"]
        assert float(row["max_position_error_m"]) <= 1e-6
    refine_rows = [r for r in table if r["contender"] == "refine"]
    assert all(int(r["iterations"]) > 0 for r in refine_rows)
    # quality and provenance: IPOPT's own status and options, the shared residuals, versions, threads
    for row in refine_rows:
        assert row["solver_status"] == "Solve_Succeeded" and row["verified_runs"] == row["repeats"]
        assert json.loads(row["solver_options"])["options"]["ipopt.tol"] > 0
        assert float(row["primal_residual"]) < 1e-6 and float(row["dual_residual"]) < 1e-4
        assert float(row["objective"]) > 0
    for row in table:
        assert "ipopt 3." in row["solver_versions"] and row["blas_threads"]
        assert set(part.split()[1] for part in row["blas_threads"].split("; ")) == {"1"}
    assert all(float(r["max_orientation_deviation_deg"]) <= 3.0 for r in refine_rows)
    assert all(r["min_clearance_m"] for r in table if r["obstacles"] == "True")

    report = write_report(out, tmp_path / "report")
    text = report.read_text()
    assert "| tiny | refine | 4 | 4/4 |" in text and "| tiny | greedy-ik | 4 | 4/4 |" in text
    assert "growth exponent" in text and "- machine:" in text and "| tiny | drake-ik |" not in text
    assert "- not run here: drake-ik on 4 problem(s), not installed here" in text
    assert (tmp_path / "report" / "tiny-wave.png").stat().st_size > 1000
    # the suite's performance profile beside the report, as PNG and SVG, and linked from it
    assert (tmp_path / "report" / "tiny-profile.png").stat().st_size > 1000
    assert (tmp_path / "report" / "tiny-profile.svg").read_text().lstrip().startswith("<?xml")
    assert "(tiny-profile.png)" in text and "(tiny-profile.svg)" in text


def test_contenders_take_turns_after_their_untimed_warm_up_runs(suites_file):
    """Warm-up runs first, each contender alike; then the timed runs alternate; a contender missing
    here is left out with a message and the others still get their rows."""
    problem = next(problems(load_suites(suites_file), "tiny"))
    calls = []

    def contender(name):
        def run(p):
            calls.append(name)
            return Answer(
                "ok", contenders_module.greedy_ik(p).q, {"solve": 0.01 * len(calls)}, 0.001 * len(calls)
            )

        return run

    def missing(p):
        raise Unavailable("not here")

    messages = []
    rows = run_turns(
        problem,
        {"a": contender("a"), "gone": missing, "b": contender("b")},
        3,
        2,
        echo=messages.append,
        isolate=False,  # the calls are counted in this process
    )
    assert calls == ["a", "a", "b", "b", "a", "b", "a", "b", "a", "b"]
    assert set(rows) == {"a", "b"} and messages == ["skipping gone: not here"]
    a = rows["a"]
    assert (a["repeats"], a["warmup"]) == (3, 2)
    # the timed runs of "a" were calls 5, 7 and 9: medians and minima of those alone
    assert a["total_s"] == pytest.approx(0.07) and a["min_total_s"] == pytest.approx(0.05)
    assert a["cpu_s"] == pytest.approx(0.007) and a["min_cpu_s"] == pytest.approx(0.005)
    assert a["verified"] and a["load_1min"].count("-") >= 1


def test_success_rules_per_expected_outcome(suites_file):
    """Success needs a claimed, verified answer; saying infeasible is never one (it may be a detection)."""
    problem = next(problems(load_suites(suites_file), "tiny"))
    q = np.zeros((20, 6))

    def judge(status, verified, repaired):
        return score(
            problem.expected, problem.expected_s_range_m, status, q, 20, verified, repaired, [], False
        )

    assert judge("ok", True, False).success and not judge("ok", False, False).success
    problem.expected = "infeasible"
    assert not judge("infeasible", False, False).success and not judge("ok", False, False).success
    problem.expected = "repaired"
    assert judge("repaired", False, True).success and not judge("repaired", False, False).success
    assert judge("ok", True, False).success


def test_verification_rejects_an_answer_off_the_path(suites_file):
    data = load_suites(suites_file)
    problem = generated_problem("tiny", "wave", data["generated"]["wave"], 20)
    answer = contenders_module.greedy_ik(problem)
    assert verify(problem, answer.q).verified
    moved = answer.q.copy()
    moved[5, 1] += 0.01  # 10 mrad on the shoulder moves the TCP by centimetres
    verdict = verify(problem, moved)
    assert not verdict.verified and verdict.max_position_error_m > 1e-3 and "position" in verdict.reason
    assert not verify(problem, None).verified


def test_growth_exponent_of_a_power_law():
    n = np.array([100.0, 400.0, 1600.0, 6400.0])
    assert growth_exponent(n, 3e-4 * n**1.2) == pytest.approx(1.2, abs=1e-9)
    assert growth_exponent(n, np.full(4, 2.0)) == pytest.approx(0.0, abs=1e-9)


def test_bench_command_lists_suites_and_rejects_unknown_contenders(capsys, tmp_path, suites_file):
    assert main(["bench", "list", "--suites-file", str(suites_file)]) == 0
    assert "tiny" in capsys.readouterr().out
    code = main(
        [
            "bench",
            "run",
            "--suite",
            "tiny",
            "--contender",
            "nope",
            "--csv",
            str(tmp_path / "x.csv"),
            "--suites-file",
            str(suites_file),
        ]
    )
    assert code == 2 and "unknown contender" in capsys.readouterr().err


def test_drake_chains_its_ik_on_a_plant_made_once_per_problem(suites_file):
    """Drake's answer passes the shared verification; its plant is kept on the problem and reused,
    and its stage times are the programs' making and SNOPT's solving."""
    pytest.importorskip("pydrake")
    problem = generated_problem("tiny", "wave", load_suites(suites_file)["generated"]["wave"], 20)
    first = contenders_module.drake_chained_ik(problem)
    plant = problem.extra["drake_plant"]
    second = contenders_module.drake_chained_ik(problem)
    assert problem.extra["drake_plant"] is plant
    for answer in (first, second):
        assert answer.status == "ok", answer.note
        assert verify(problem, answer.q).verified
        assert answer.times_s["build"] > 0 and answer.times_s["solve"] > 0 and answer.times_s["seed"] == 0
        # SNOPT's result counted over the 20 waypoints, and its settings
        assert answer.solver_status == "kSolutionFound x20" and "SNOPT" in answer.solver_options["solver"]
    np.testing.assert_allclose(first.q, second.q, atol=1e-9)


def test_the_fatrop_contender_is_verified_as_the_others_and_refuses_long_paths(suites_file):
    from refine.optimise.stagewise import MAX_FATROP_WAYPOINTS

    data = load_suites(suites_file)
    problem = generated_problem("tiny", "wave", data["generated"]["wave"], 30)
    answer = contenders_module.refine_fatrop(problem)
    assert answer.status == "ok" and answer.iterations > 0 and answer.cpu_s > 0
    assert verify(problem, answer.q).verified
    reference = contenders_module.refine_assembled(problem)
    np.testing.assert_allclose(answer.q, reference.q, atol=1e-6)
    long = generated_problem("tiny", "wave", data["generated"]["wave"], MAX_FATROP_WAYPOINTS + 1)
    with pytest.raises(contenders_module.NotPosed) as refused:
        contenders_module.refine_fatrop(long)
    assert f"at most {MAX_FATROP_WAYPOINTS} waypoints, the path has {MAX_FATROP_WAYPOINTS + 1}" in str(
        refused.value
    )


def test_generated_problems_carry_the_weights_refine_run_gives_their_robot(suites_file):
    from refine.optimise.problem import Weights

    data = load_suites()
    # refine run: no mid-range cost for a six-axis arm, 2.0 for the seven-axis LBR iiwa (problem-file.md)
    assert generated_problem("t", "irb4600", data["generated"]["irb4600"], 20).weights == Weights()
    assert generated_problem("t", "iiwa", data["generated"]["iiwa"], 20).weights == Weights(mid_range=2.0)


def test_each_refine_run_pays_for_its_own_clearance_checks(suites_file, monkeypatch):
    """A repeated run of the same problem reuses no dense check of an earlier one (as a fresh
    ``refine run`` could not), so every timed run does the same work."""
    import refine.optimise.clearance as clearance_module

    data = load_suites()
    problem = generated_problem("t", "irb4600_obstacles", data["generated"]["irb4600_obstacles"], 40)
    assert problem.sources
    calls = []
    real = clearance_module.check_path_clearance
    monkeypatch.setattr(
        clearance_module, "check_path_clearance", lambda *a, **k: calls.append(1) or real(*a, **k)
    )
    counts = []
    for _ in range(3):
        before = len(calls)
        assert contenders_module.refine_assembled(problem).status == "ok"
        counts.append(len(calls) - before)
    assert counts[0] > 0 and counts == [counts[0]] * 3
