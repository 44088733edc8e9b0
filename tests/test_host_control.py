"""A host's control over a library call: progress, cancel, a time limit, Ctrl-C inside IPOPT.

None of these may ever come back as a verdict: a cancel raises ``refine.Cancelled``, Ctrl-C raises
``KeyboardInterrupt``, an exhausted time limit is the status ``timeout``.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import refine
from refine.control import after_solve, controlled

STAGES = {"load", "cad", "demo", "fuse", "build", "verify", "refine", "timing", "line_check", "arc_check", "motions", "solve"}
"""The stage names docs/api.md gives for ``Progress.stage``."""


def _line(n: int = 16) -> tuple[np.ndarray, np.ndarray]:
    positions = np.column_stack([np.full(n, 0.6), np.linspace(-0.15, 0.15, n), np.full(n, 0.3)])
    down = Rotation.from_euler("x", 180.0, degrees=True).as_matrix()  # tool z pointing down
    return positions, np.repeat(down[None], n, axis=0)


def test_progress_reports_each_stage_and_each_solver_iteration():
    positions, R = _line()
    seen: list[refine.Progress] = []
    result = refine.refine_path("ur10e", positions, R, speeds=0.1, progress=seen.append)
    assert result.status == "ok"
    stages = [p.stage for p in seen]
    assert set(stages) <= STAGES, set(stages) - STAGES
    assert stages[-1] == "motions" and "verify" in stages
    iterations = [p.iteration for p in seen if p.stage == "solve"]
    assert iterations and iterations[0] == 1
    # within one solve the iterations count up by one; a new solve starts again at 1
    assert all(b == a + 1 or b == 1 for a, b in zip(iterations, iterations[1:], strict=False))
    assert sum(1 for i in iterations if i == 1) == result.run.first.refinement.outer_iterations
    assert all(p.round >= 1 for p in seen if p.stage == "solve")


def test_a_cancel_inside_ipopt_stops_it_and_raises_cancelled():
    positions, R = _line()
    stop = threading.Event()
    after: list[int] = []

    def progress(p: refine.Progress) -> None:
        if stop.is_set():
            after.append(p.iteration)
        if p.stage == "solve" and p.iteration == 2:
            stop.set()

    with pytest.raises(refine.Cancelled, match="inside the solver"):
        refine.refine_path("ur10e", positions, R, speeds=0.1, progress=progress, cancel=stop)
    assert after == []  # IPOPT stopped at the iteration that saw the cancel: no iteration after it


def test_a_cancel_before_the_call_stops_it_at_its_first_stage():
    positions, R = _line()
    with pytest.raises(refine.Cancelled, match="stage"):
        refine.refine_path("ur10e", positions, R, speeds=0.1, cancel=lambda: True)
    with pytest.raises(TypeError, match="threading.Event or a callable"):
        refine.refine_path("ur10e", positions, R, speeds=0.1, cancel=True)


def test_an_exhausted_time_limit_is_the_status_timeout_never_infeasible(tmp_path):
    positions, R = _line()

    def slow_host(p: refine.Progress) -> None:  # the host's callback eats the budget in the first solve
        if p.stage == "solve" and p.iteration == 1:
            time.sleep(0.15)

    result = refine.refine_path("ur10e", positions, R, speeds=0.1, time_limit_s=0.1, progress=slow_host)
    assert result.status == "timeout"
    assert "time limit of 0.1 s" in result.run.first.refinement.reason
    files = result.write(tmp_path, report=False)
    doc = json.loads(files["result"].read_text())
    assert doc["status"] == "timeout" and doc["solver"]["time_limit_reached"] is True
    assert not any(p.suffix in {".mod", ".src", ".script", ".java"} for p in tmp_path.rglob("*"))


def test_ctrl_c_inside_ipopt_is_a_keyboard_interrupt_not_a_verdict():
    positions, R = _line()

    def progress(p: refine.Progress) -> None:
        if p.stage == "solve" and p.iteration == 2:
            signal.raise_signal(signal.SIGINT)  # Ctrl-C while IPOPT runs (its callback is Python)

    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with pytest.raises(KeyboardInterrupt):
        refine.refine_path("ur10e", positions, R, speeds=0.1, progress=progress)


def test_ipopt_stopped_by_an_exception_of_casadi_is_an_interrupt():
    # CasADi catches a KeyboardInterrupt between evaluations and IPOPT then returns this status
    with pytest.raises(KeyboardInterrupt):
        after_solve("NonIpopt_Exception_Thrown")
    after_solve("Solve_Succeeded")  # nothing happens


def test_ctrl_c_from_another_thread_during_a_solve_interrupts_the_call():
    positions, R = _line(60)
    fired, sent = threading.Event(), threading.Event()

    def interrupt() -> None:
        os.kill(os.getpid(), signal.SIGINT)
        sent.set()

    def progress(p: refine.Progress) -> None:
        if p.stage == "solve" and p.iteration == 1 and not fired.is_set():
            fired.set()
            threading.Timer(0.002, interrupt).start()
            sent.wait(10.0)  # the solve goes on only once the other thread has sent Ctrl-C, however loaded

    with pytest.raises(KeyboardInterrupt):
        result = refine.refine_path("ur10e", positions, R, speeds=0.1, progress=progress)
        # the signal may land after the last solve, in plain Python: then it raises there
        raise AssertionError(f"returned {result.status} after Ctrl-C")  # pragma: no cover


def test_a_ctrl_c_inside_a_compiled_call_reaches_the_host_as_keyboard_interrupt():
    # CPython's own wording when a handler raises while a C function returns: the interrupt is the cause
    def compiled_call_interrupted() -> None:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise SystemError("<function DM.__array__> returned a result with an exception set") from e

    with pytest.raises(KeyboardInterrupt), controlled():
        compiled_call_interrupted()
    with pytest.raises(SystemError), controlled():  # any other SystemError is left as it is
        raise SystemError("something else")
