"""The time limit interrupts a run: the watchdog kills a contender past it, survives one that dies,
and refine's contenders get the limit and stop there themselves."""

from __future__ import annotations

import ctypes
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


def pauses_in_libc(problem):
    """Block in C until a signal comes (libc ``pause``), as a solver's loop that never returns to Python."""
    (problem.extra["pid_file"]).write_text(str(os.getpid()))
    ctypes.CDLL(None).pause()
    return contenders_module.Answer("ok", None)


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


def test_a_contender_blocked_in_libc_is_killed_at_the_limit_and_its_run_is_a_timeout(problem, tmp_path):
    problem.extra["pid_file"] = tmp_path / "pid"
    t0 = time.perf_counter()
    answer, wall = run_limited(problem, "pauses", pauses_in_libc, 1.0)
    elapsed = time.perf_counter() - t0
    problem.extra.pop("pid_file")
    assert answer.status == "timeout" and answer.q is None
    assert answer.note == "stopped by the watchdog at the time limit of 1 s"
    # the limit (1 s) and the grace (0.5 s) passed before the kill; the call came back soon after
    assert 1.5 <= wall <= elapsed < 30.0 and answer.times_s["solve"] == wall and math.isnan(answer.cpu_s)
    # the worker that blocked is gone (killed and reaped), not left behind
    pid = int((tmp_path / "pid").read_text())
    assert pid != os.getpid()
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


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


SETUP_CPU_S, SOLVE_CPU_S, FIRST_CALL_CPU_S = 0.6, 0.2, 0.4
"""CPU seconds the fake contender burns in its declared set-up, in each solve, and once per process."""

_first_call_done = False  # a process-wide one-off, as a library's lazy initialisation or fresh pages


def _burn(seconds: float) -> None:
    t0 = time.process_time()
    while time.process_time() - t0 < seconds:
        pass


def _make_setup(problem) -> None:
    if "fake_setup" not in problem.extra:  # made by the contender itself when nobody made it before
        _burn(SETUP_CPU_S)
        problem.extra["fake_setup"] = True


def set_up_then_solve(problem):
    """A contender timing its whole call on the process clock: its set-up (if not made), a one-off, its solve."""
    global _first_call_done
    c0, w0 = time.process_time(), time.perf_counter()
    _make_setup(problem)
    if not _first_call_done:
        _burn(FIRST_CALL_CPU_S)
        _first_call_done = True
    _burn(SOLVE_CPU_S)
    return contenders_module.Answer("ok", None, {"solve": time.perf_counter() - w0}, time.process_time() - c0)


set_up_then_solve.setup = _make_setup


@pytest.mark.parametrize("isolate", [True, False])
def test_the_timed_window_holds_the_solve_and_not_the_declared_set_up(
    tmp_path, monkeypatch, tiny_wave, isolate
):
    suites = tmp_path / "suites.toml"
    suites.write_text(tiny_wave)
    monkeypatch.setitem(contenders_module.CONTENDERS, "greedy-ik", set_up_then_solve)
    (row,) = run_suites(
        ["tiny"], ["greedy-ik"], tmp_path / "b.csv", suites_file=suites, warmup=1, repeat=3,
        echo=lambda _: None, isolate=isolate,
    )  # fmt: skip
    # the set-up was made once, before the runs, in the runner's process, and measured apart
    assert row["setup_cpu_s"] >= SETUP_CPU_S and row["setup_s"] > 0.0
    # every timed run holds its solve only: neither the set-up nor the one-off of the warm-up run
    # (the worker that made the warm-up run makes the timed ones too)
    assert SOLVE_CPU_S <= row["min_cpu_s"] <= row["max_cpu_s"] < SOLVE_CPU_S + 0.5 * FIRST_CALL_CPU_S
    assert row["max_total_s"] >= 0.5 * SOLVE_CPU_S  # wall: the solve was inside the window


def test_without_a_declared_set_up_the_warm_up_run_pays_it_for_the_timed_runs(
    tmp_path, monkeypatch, tiny_wave
):
    suites = tmp_path / "suites.toml"
    suites.write_text(tiny_wave)

    def solve_only(problem):
        return set_up_then_solve(problem)

    monkeypatch.setitem(contenders_module.CONTENDERS, "greedy-ik", solve_only)
    (row,) = run_suites(
        ["tiny"], ["greedy-ik"], tmp_path / "b.csv", suites_file=suites, warmup=1, repeat=2,
        echo=lambda _: None,
    )  # fmt: skip
    assert row["setup_s"] == 0.0 and row["setup_cpu_s"] == 0.0
    # what the warm-up run cached in problem.extra is kept in the worker for the timed runs
    assert row["max_cpu_s"] < SOLVE_CPU_S + 0.5 * FIRST_CALL_CPU_S
