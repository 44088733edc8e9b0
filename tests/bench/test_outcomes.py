"""Honest outcomes of refine bench: what counts as a success and as a detection, the time penalty,
one schema per file, and a report built from the rows of one run only."""

from __future__ import annotations

import csv
import time

import pytest

from refine.bench import contenders as contenders_module
from refine.bench import watchdog
from refine.bench.contenders import Answer
from refine.bench.outcomes import score
from refine.bench.report import write_report
from refine.bench.runner import run_suites
from refine.bench.table import COLUMNS, SCHEMA_VERSION
from refine.cli import main
from refine.errors import InputError

# the 37 columns the benchmark wrote before run ids and outcome columns (schema 1)
OLD_COLUMNS = [
    "suite", "problem", "robot", "n_waypoints", "obstacles", "expected", "contender", "status", "verified",
    "success", "max_position_error_m", "max_orientation_deviation_deg", "min_clearance_m", "build_s", "seed_s",
    "solve_s", "total_s", "min_total_s", "cpu_s", "min_cpu_s", "iterations", "repeats", "warmup", "load_1min",
    "peak_rss_mb", "rss_growth_mb", "reason", "note", "date", "machine", "cpu", "cores", "python", "refine",
    "casadi", "pinocchio", "drake",
]  # fmt: skip

# benchmarks/suites.toml's unreachable suite: 7 problem folders, of which the problem files of
# joint_wrap_infeasible, elbow_through_table and out_of_reach state [expected] status = "infeasible"
UNREACHABLE = 7
STATED_INFEASIBLE = 3


def always_raises(problem):
    raise RuntimeError("this contender always crashes")


def always_infeasible_without_joints(problem):
    return Answer("infeasible", None, {"solve": 0.001}, 0.001)


def always_infeasible_with_joints(problem):
    """Says infeasible whatever it found: the greedy chain's joints, which pass on some problems."""
    answer = contenders_module.greedy_ik(problem)
    return Answer("infeasible", answer.q, answer.times_s, answer.cpu_s)


def test_contenders_that_raise_or_always_say_infeasible_score_nothing_on_the_unreachable_suite(
    tmp_path, monkeypatch
):
    fakes = {
        "refine": always_raises,
        "refine-casadi-ad": always_infeasible_without_joints,
        "greedy-ik": always_infeasible_with_joints,
    }
    for name, function in fakes.items():
        monkeypatch.setitem(contenders_module.CONTENDERS, name, function)
    out = tmp_path / "bench.csv"
    t0 = time.perf_counter()
    run_suites(["unreachable"], list(fakes), out, time_limit_s=60.0, echo=lambda _: None)
    seconds = time.perf_counter() - t0
    with out.open() as f:
        table = list(csv.DictReader(f))
    assert len(table) == UNREACHABLE * len(fakes), seconds
    assert sum(r["expected"] == "infeasible" for r in table) == STATED_INFEASIBLE * len(fakes)
    by = {name: [r for r in table if r["contender"] == name] for name in fakes}
    for name, rows in by.items():
        assert sum(r["success"] == "True" for r in rows) == 0, name
    raising = by["refine"]
    assert sum(r["detected_infeasible"] == "True" for r in raising) == 0
    assert {r["status"] for r in raising} == {"error"}
    assert all("always crashes" in r["note"] for r in raising)
    # a failed row counts as the 60 s limit in time summaries, not as the 0 s it reported
    assert all(float(r["total_s"]) == 0.0 and float(r["penalised_total_s"]) == 60.0 for r in raising)
    assert all(float(r["penalised_cpu_s"]) == 60.0 for r in raising)
    # "infeasible" with no joints is no attempt: no detection either
    assert sum(r["detected_infeasible"] == "True" for r in by["refine-casadi-ad"]) == 0
    assert all(float(r["penalised_total_s"]) == 60.0 for r in by["refine-casadi-ad"])
    # detections only ever on problems stated infeasible
    assert all(r["expected"] == "infeasible" for r in table if r["detected_infeasible"] == "True")


def test_the_scoring_rules_by_hand():
    """The rules of refine.bench.outcomes on hand-made verdicts (20 waypoints, stated stretch 0.10-0.20 m)."""
    joints = [[0.0] * 6] * 20
    stated = ("infeasible", (0.10, 0.20))

    def rule(expected, status, q, verified=False, repaired=False, broken=(), timed_out=False):
        return score(*expected, status, q, 20, verified, repaired, list(broken), timed_out)

    # a verified answer is a success; an unverified one or one past the time limit is not
    assert rule(("", None), "ok", joints, verified=True).success
    assert not rule(("", None), "ok", joints).success
    assert not rule(("", None), "ok", joints, verified=True, timed_out=True).success
    # a repaired answer verified with its slack, on a problem built to be repaired
    assert rule(("repaired", None), "repaired", joints, repaired=True).success
    assert not rule(("", None), "repaired", joints, repaired=True).success
    # infeasible: with joints broken inside the stated stretch
    assert rule(stated, "infeasible", joints, broken=[(0.15, 0.30)]).detected_infeasible
    assert not rule(stated, "infeasible", joints, broken=[(0.25, 0.30)]).detected_infeasible  # elsewhere
    assert not rule(stated, "infeasible", None, broken=[(0.15, 0.30)]).detected_infeasible  # no joints
    assert not rule(stated, "infeasible", joints[:19], broken=[(0.15, 0.3)]).detected_infeasible  # 19 of 20
    assert not rule(stated, "infeasible", joints, verified=True).detected_infeasible  # its answer passes
    assert not rule(stated, "error", joints, broken=[(0.15, 0.3)]).detected_infeasible
    assert not rule(stated, "infeasible", joints, broken=[(0.15, 0.3)], timed_out=True).detected_infeasible
    assert not rule(("infeasible", None), "infeasible", joints, broken=[(0.15, 0.3)]).detected_infeasible
    assert not rule(("repaired", (0.1, 0.2)), "infeasible", joints, broken=[(0.15, 0.3)]).detected_infeasible
    # a solver that stopped without converging gives no success, however its answer verifies
    assert rule(("", None), "ok", joints, verified=True).success  # no solver status: none to judge
    assert score("", None, "ok", joints, 20, True, False, [], False, "Solve_Succeeded").success
    assert score("", None, "ok", joints, 20, True, False, [], False, "Solved_To_Acceptable_Level").success
    assert not score(
        "", None, "ok", joints, 20, True, False, [], False, "Maximum_Iterations_Exceeded"
    ).success
    assert not score("", None, "ok", joints, 20, True, False, [], False, "Maximum_CpuTime_Exceeded").success
    assert not score("", None, "ok", joints, 20, True, False, [], False, "not solved (return flag 2)").success
    assert not score(
        "repaired", None, "repaired", joints, 20, False, True, [], False, "Restoration_Failed"
    ).success
    # never both; and saying infeasible is never a success
    assert not rule(stated, "infeasible", joints, broken=[(0.15, 0.30)]).success
    assert rule(stated, "infeasible", joints, broken=[(0.15, 0.30)]).failed is False
    assert rule(stated, "infeasible", None).failed


def test_a_run_over_the_time_limit_is_a_timeout_whatever_its_answer(tmp_path, monkeypatch, tiny_wave):
    suites = tmp_path / "suites.toml"
    suites.write_text(tiny_wave)

    def slow(problem):
        answer = contenders_module.greedy_ik(problem)
        time.sleep(0.3)
        return answer

    monkeypatch.setitem(contenders_module.CONTENDERS, "greedy-ik", slow)
    # the answer must come back before the watchdog's kill, however loaded the machine: it waits
    # past the limit for as long as the grace allows
    monkeypatch.setattr(watchdog, "GRACE_S", 60.0)
    out = tmp_path / "bench.csv"
    (row,) = run_suites(
        ["tiny"], ["greedy-ik"], out, suites_file=suites, time_limit_s=0.1, echo=lambda _: None
    )
    assert row["timed_out"] and row["status"] == "timeout"
    # a late answer claims no path (its status is timeout); its joints are checked for the record
    assert row["verified"] == "" and row["claimed_runs"] == 0 and row["strict_runs"] == 1
    assert not row["success"] and row["penalised_total_s"] == 0.1


def test_a_csv_with_another_header_is_refused_before_anything_runs(tmp_path, monkeypatch, tiny_wave):
    suites = tmp_path / "suites.toml"
    suites.write_text(tiny_wave)
    calls = []
    monkeypatch.setitem(contenders_module.CONTENDERS, "greedy-ik", lambda p: calls.append(p))
    old = tmp_path / "old.csv"
    with old.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(OLD_COLUMNS)
        writer.writerow(["quick", "glass_adhesive"] + ["1"] * (len(OLD_COLUMNS) - 2))
    before = old.read_bytes()
    with pytest.raises(InputError) as caught:
        run_suites(["tiny"], ["greedy-ik"], old, suites_file=suites, echo=lambda _: None)
    message = str(caught.value)
    assert str(old) in message and "37 columns" in message and f"{len(COLUMNS)} (schema" in message
    assert old.read_bytes() == before and calls == []
    # the command line says the same and exits with an error
    code = main(["bench", "run", "--suite", "tiny", "--contender", "greedy-ik", "--csv", str(old),
                 "--suites-file", str(suites)])  # fmt: skip
    assert code != 0 and old.read_bytes() == before and calls == []
    # a thread count below 1 is refused before anything runs, too
    new = tmp_path / "new.csv"
    with pytest.raises(InputError, match="BLAS threads must be >= 1, got 0"):
        run_suites(["tiny"], ["greedy-ik"], new, suites_file=suites, blas_threads=0, echo=lambda _: None)
    assert not new.exists() and calls == []
    # and the report refuses it too rather than reading shifted columns
    with pytest.raises(InputError, match="37 columns"):
        write_report(old, tmp_path / "report")


def _row(run_id, suite, problem, contender, n, total, cpu, success=True, penalised=None):
    row = dict.fromkeys(COLUMNS, "")
    row.update(
        schema=SCHEMA_VERSION, run_id=run_id, suite=suite, problem=problem, robot="abb_irb4600_60_205",
        n_waypoints=str(n), obstacles="False", expected="", contender=contender, status="ok",
        verified=str(success), success=str(success), detected_infeasible="False", timed_out="False",
        time_limit_s="300", total_s=str(total), cpu_s=str(cpu), min_total_s=str(total), min_cpu_s=str(cpu),
        penalised_total_s=str(total if penalised is None else penalised),
        penalised_cpu_s=str(cpu if penalised is None else penalised), date=f"{run_id[:8]}", machine="m",
        max_orientation_deviation_deg="1.0", repeats="1",
    )  # fmt: skip
    return row


def test_the_report_uses_the_rows_of_one_run_and_pairs_rows_within_a_suite(tmp_path, write_rows):
    a, b = "20260101T000000Z-aaaaaa", "20260102T000000Z-bbbbbb"
    rows = [
        # run a: refine 2 s, greedy 1 s on the glass cell: ratio 2.00; growth t = n / 100: exponent 1.00
        _row(a, "glass", "glass_adhesive", "refine", 300, 2.0, 2.0),
        _row(a, "glass", "glass_adhesive", "greedy-ik", 300, 1.0, 1.0),
        _row(a, "growth", "irb4600-100", "refine", 100, 1.0, 1.0),
        _row(a, "growth", "irb4600-400", "refine", 400, 4.0, 4.0),
        # the same family in another suite of the same run: a 100-waypoint row at 50 s must not enter
        _row(a, "quick", "irb4600-100", "refine", 100, 50.0, 50.0),
        # run b, later: refine 3 s, greedy 12 s: ratio 0.25; growth t = (n / 100)^2: exponent 2.00
        _row(b, "glass", "glass_adhesive", "refine", 300, 3.0, 3.0),
        _row(b, "glass", "glass_adhesive", "greedy-ik", 300, 12.0, 12.0),
        _row(b, "growth", "irb4600-100", "refine", 100, 1.0, 1.0),
        _row(b, "growth", "irb4600-400", "refine", 400, 16.0, 16.0),
        # a failed row of b counts as its 300 s limit: median of 1, 16, 300 is 16
        _row(b, "growth", "irb4600-1600", "refine", 1600, 0.0, 0.0, success=False, penalised=300.0),
    ]
    path = write_rows(tmp_path / "bench.csv", rows)

    latest = write_report(path, tmp_path / "latest").read_text()
    assert f"Run `{b}`" in latest and a not in latest
    assert "ratio refine / greedy-ik 0.25 (wall)" in latest
    assert "irb4600 (suite `growth`): growth exponent of build + seed + solve" in latest
    growth_line = next(line for line in latest.splitlines() if "suite `growth`): growth" in line)
    assert "solve 2.00 (wall)" in growth_line and "2 successful rows, 100-400 waypoints" in growth_line
    # success per profile: 2 of 3 verified, none within a KKT profile (no residuals), 1 failed
    assert "| growth | refine | 3 | 2/3 | 0/3 | 0/3 | 0/0 | 1 | 0 |" in latest
    # shifted geometric mean of the penalised 1, 16, 300 s with shift 0.1 s:
    # (1.1 * 16.1 * 300.1)^(1/3) - 0.1 = 17.351 s; the median 16 s
    assert "| growth | refine | 3 | 17.351 | 1.00 | 17.351 | 16.000 |" in latest
    assert "| glass | greedy-ik | 1 | 1/1 |" in latest and "| quick |" not in latest

    assert main(["bench", "report", str(path), "--run-id", a, "--out", str(tmp_path / "first")]) == 0
    first = (tmp_path / "first" / "report.md").read_text()
    assert f"Run `{a}`" in first and b not in first
    assert "ratio refine / greedy-ik 2.00 (wall)" in first
    growth_a = next(line for line in first.splitlines() if "suite `growth`): growth" in line)
    assert "solve 1.00 (wall)" in growth_a and "2 successful rows, 100-400 waypoints" in growth_a
    assert "| quick | refine | 1 | 1/1 |" in first  # the quick suite's row stays in its own suite
    # two runs asked for: a section each, each with its own ratio, none pairing rows across runs
    assert main(["bench", "report", str(path), "--run", a, "--run", b, "--out", str(tmp_path / "both")]) == 0
    both = (tmp_path / "both" / "report.md").read_text()
    section_a, section_b = both.split(f"## Run `{a}`")[1].split(f"## Run `{b}`")
    assert "ratio refine / greedy-ik 2.00 (wall)" in section_a and "greedy-ik 0.25" not in section_a
    assert "ratio refine / greedy-ik 0.25 (wall)" in section_b and "greedy-ik 2.00" not in section_b
    with pytest.raises(InputError, match="no run nope"):
        write_report(path, tmp_path / "x", "nope")


def test_every_timed_run_is_verified_and_an_unconverged_solver_is_no_success(
    tmp_path, monkeypatch, tiny_wave
):
    suites = tmp_path / "suites.toml"
    suites.write_text(tiny_wave)
    calls = []

    def flaky(problem):
        """Right on its first call, 0.1 rad off on every joint on the second."""
        calls.append(1)
        answer = contenders_module.greedy_ik(problem)
        q = answer.q if len(calls) == 1 else answer.q + 0.1
        return Answer("ok", q, answer.times_s, answer.cpu_s)

    def out_of_iterations(problem):
        answer = contenders_module.greedy_ik(problem)
        return Answer(
            "ok", answer.q, answer.times_s, answer.cpu_s, solver_status="Maximum_Iterations_Exceeded"
        )

    monkeypatch.setitem(contenders_module.CONTENDERS, "greedy-ik", flaky)
    monkeypatch.setitem(contenders_module.CONTENDERS, "drake-ik", out_of_iterations)
    rows = run_suites(
        ["tiny"], ["greedy-ik", "drake-ik"], tmp_path / "b.csv", suites_file=suites, repeat=2,
        time_limit_s=50.0, echo=lambda _: None, isolate=False,  # flaky counts its calls here
    )  # fmt: skip
    by = {r["contender"]: r for r in rows}
    # the last answer alone would not verify, the first did: 1 of 2, no success, the limit counted
    assert by["greedy-ik"]["verified_runs"] == 1 and not by["greedy-ik"]["verified"]
    assert not by["greedy-ik"]["success"] and by["greedy-ik"]["penalised_cpu_s"] == 50.0
    # verified in both runs, but its solver ran out of iterations
    out = by["drake-ik"]
    assert (
        out["verified_runs"] == 2
        and out["verified"]
        and out["solver_status"] == "Maximum_Iterations_Exceeded"
    )
    assert not out["success"] and out["penalised_total_s"] == 50.0


def test_ipopt_out_of_iterations_on_the_glass_cell_is_no_success(tmp_path):
    """A real ``Maximum_Iterations_Exceeded``: refine's IPOPT held to 2 iterations on the glass cell
    (refine needs 3 there). The path may still verify; the row is no success all the same."""
    out = tmp_path / "bench.csv"
    code = main(["bench", "run", "--suite", "glass", "--contender", "refine", "--solver-option",
                 "max_iter=2", "--warmup", "0", "--csv", str(out)])  # fmt: skip
    assert code == 0
    (row,) = csv.DictReader(out.open())
    assert row["solver_status"] == "Maximum_Iterations_Exceeded"
    assert row["success"] == "False" and row["penalised_total_s"] == row["time_limit_s"]
    assert '"ipopt.max_iter": 2' in row["solver_options"]
