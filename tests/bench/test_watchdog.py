"""The time limit interrupts a run: the watchdog kills a contender past it, survives one that dies,
and refine's contenders get the limit and stop there themselves."""

from __future__ import annotations

import math
import os
import time

import pytest

from refine.bench import contenders as contenders_module
from refine.bench.runner import run_suites
from refine.bench.suites import load_suites, problems
from refine.bench.watchdog import can_fork, keeps_time_limit, run_limited

pytestmark = pytest.mark.skipif(not can_fork(), reason="the watchdog forks")


@pytest.fixture(scope="module")
def problem(tmp_path_factory, tiny_wave):
    path = tmp_path_factory.mktemp("suites") / "suites.toml"
    path.write_text(tiny_wave)
    return next(problems(load_suites(path), "tiny"))


def sleeps_forever(problem):
    time.sleep(60.0)


def dies(problem):
    os.abort()  # as a C++ solver's uncaught exception does


def test_a_contender_past_the_limit_is_killed_and_fails_at_the_limit(tmp_path, monkeypatch, tiny_wave):
    suites = tmp_path / "suites.toml"
    suites.write_text(tiny_wave)
    monkeypatch.setitem(contenders_module.CONTENDERS, "greedy-ik", sleeps_forever)
    t0 = time.perf_counter()
    (row,) = run_suites(
        ["tiny"], ["greedy-ik"], tmp_path / "b.csv", suites_file=suites, time_limit_s=0.5, echo=lambda _: None
    )
    # the contender would sleep 60 s: the run ends at the limit (0.5 s) plus the grace (0.5 s)
    assert time.perf_counter() - t0 < 20.0
    assert row["status"] == "timeout" and row["timed_out"] and not row["success"]
    assert not row["verified"] and "watchdog" in row["note"]
    # the time it ran until stopped, not 0 s; its CPU time is not known
    assert 0.5 <= row["total_s"] < 20.0 and math.isnan(row["cpu_s"])
    assert row["penalised_total_s"] == 0.5 and row["penalised_cpu_s"] == 0.5


def test_a_contender_that_kills_its_process_is_an_error_and_the_runner_goes_on(problem):
    answer, _ = run_limited(problem, "dies", dies, 30.0)
    assert answer.status == "error" and answer.q is None and "SIGABRT" in answer.note
    # the next run in the same process still works, and its answer comes back from the child
    answer, wall = run_limited(problem, "greedy-ik", contenders_module.greedy_ik, 30.0)
    assert answer.status == "ok" and answer.q.shape == (problem.n_waypoints, 6) and wall > 0.0


def test_refines_contenders_keep_the_limit_themselves(problem):
    for name in ("refine", "refine-casadi-ad", "refine-fatrop"):
        assert keeps_time_limit(contenders_module.CONTENDERS[name])
    for name in ("greedy-ik", "drake-ik"):
        assert not keeps_time_limit(contenders_module.CONTENDERS[name])
    # a limit shorter than any solve: refine stops at it and says so, in this process
    answer, _ = run_limited(problem, "refine", contenders_module.CONTENDERS["refine"], 1e-4)
    assert answer.status == "timeout"
    assert answer.solver_options["options"]["ipopt.max_wall_time"] == pytest.approx(1e-4)


def test_each_run_leaves_its_log_with_the_solvers_iterations(tmp_path, tiny_wave):
    suites = tmp_path / "suites.toml"
    suites.write_text(tiny_wave)
    rows = run_suites(
        ["tiny"], ["refine", "greedy-ik"], tmp_path / "b.csv", suites_file=suites, warmup=1,
        repeat=2, log_dir=tmp_path / "logs", echo=lambda _: None,
    )  # fmt: skip
    folder = tmp_path / "logs" / rows[0]["run_id"] / "tiny" / "wave-20"
    names = sorted(p.name for p in folder.iterdir())
    assert names == [f"{c}{kind}-{k}.log" for c in ("greedy-ik", "refine") for kind, k in
                     (("", 1), ("", 2), ("-warmup", 1))]  # fmt: skip
    text = (folder / "refine-1.log").read_text()
    # IPOPT's own iteration table (its header and one line per iteration), as IPOPT prints it
    assert "iter    objective    inf_pr" in text and "EXIT: Optimal Solution Found." in text
    by = {r["contender"]: r for r in rows}
    assert by["refine"]["success"] and '"ipopt.print_level": 5' in by["refine"]["solver_options"]
    assert (
        '"compiled": true' in by["refine"]["solver_options"]
        or '"compiled": false' in by["refine"]["solver_options"]
    )
