"""The time limit of one benchmark run: kept by the contender itself, or enforced by a watchdog.

A contender that keeps the limit itself says so with the attribute ``keeps_time_limit = True``
(refine's contenders: they give ``problem.time_limit_s`` to the refinement, which stops its solves
there and answers ``timeout``); it runs in the runner's process, as before.

Every other contender (Drake, the Tesseract peers, greedy IK, plug-ins) runs under
:func:`run_limited`: in a child process forked from the runner, so it starts with everything the
runner has loaded and cached (the problem, its robot, Drake's plant, Tesseract's environment).
The child times the call on its own clock (:func:`refine.bench.contenders.timed_call`) and sends
back the answer and its wall time. When the child has not answered by the time limit it is
killed (SIGKILL, so a C++ solver that never returns to Python stops too) and the run is a
``timeout`` answer: no joints, a failure, counted at the time limit; its ``solve`` time is the
runner's wall time until the kill and its CPU time unknown (NaN, an empty cell). A child that dies without
answering (a C++ ``abort``, a segmentation fault) gives an ``error`` answer naming the signal; the
benchmark goes on. What the child caches in ``problem.extra`` stays in the child: a contender
that caches its set-up there (Drake's plant, Tesseract's environment) makes it again in every
run, outside its own stage times (its ``times_s`` stay as it measures them).

Where ``fork`` is not available (not Linux or macOS) or with ``isolate=False``, the contender runs
in the runner's process and the limit is only applied afterwards: a run over it is a ``timeout``
failure, but it is not interrupted.
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing
import os
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from refine.bench.contenders import Answer, Contender, Unavailable, timed_call
from refine.bench.suites import BenchProblem

GRACE_S = 0.5
"""Extra wall time [s] the watchdog waits past the limit for an answer already on its way."""


def keeps_time_limit(function: Contender) -> bool:
    """Whether ``function`` stops at ``problem.time_limit_s`` itself (``keeps_time_limit = True``)."""
    return bool(getattr(function, "keeps_time_limit", False))


def can_fork() -> bool:
    """Whether this platform starts a child process by ``fork`` (Linux, macOS)."""
    return "fork" in multiprocessing.get_all_start_methods()


def run_limited(
    problem: BenchProblem,
    name: str,
    function: Contender,
    time_limit_s: float,
    isolate: bool = True,
    log: Path | None = None,
) -> tuple[Answer, float]:
    """One run of ``function`` on ``problem`` held to ``time_limit_s`` [s]; the answer and its wall time [s].

    See the module's rules. :class:`Unavailable` raised by the contender reaches the caller in
    either way of running. ``log``: a file that receives everything the run prints to the
    process's standard output and error, the solvers' own iteration logs included (:func:`captured`).
    """
    problem.time_limit_s = time_limit_s
    if keeps_time_limit(function) or not isolate or not can_fork():
        with captured(log):
            answer, wall = timed_call(problem, name, function)
        if wall > time_limit_s and answer.status != "timeout":
            answer = _over(
                answer, f"ran {wall:.3g} s, over the time limit of {time_limit_s:g} s (not interrupted)"
            )
        return answer, wall
    context = multiprocessing.get_context("fork")
    receive, send = context.Pipe(duplex=False)
    child = context.Process(target=_child, args=(send, problem, name, function, log), daemon=True)
    t0 = time.perf_counter()
    child.start()
    send.close()
    try:
        if receive.poll(time_limit_s + GRACE_S):
            try:
                kind, payload = receive.recv()
            except EOFError:  # the child died before answering
                kind, payload = "died", None
        else:
            kind, payload = "timeout", None
    finally:
        wall = time.perf_counter() - t0
        if child.is_alive():
            child.kill()
        child.join()
        receive.close()
    if kind == "answer":
        answer, own_wall = payload
        if own_wall > time_limit_s and answer.status != "timeout":
            answer = _over(answer, f"ran {own_wall:.3g} s, over the time limit of {time_limit_s:g} s")
        return answer, own_wall
    if kind == "unavailable":
        raise Unavailable(payload)
    # no answer: the stage time is the runner's wall time until then, the child's CPU time unknown
    if kind == "timeout":
        note = f"stopped by the watchdog at the time limit of {time_limit_s:g} s"
        return Answer("timeout", None, {"solve": wall}, math.nan, note=note), wall
    code = child.exitcode
    how = f"signal {signal.Signals(-code).name}" if code is not None and code < 0 else f"exit code {code}"
    note = f"the contender's process died without an answer ({how})"
    return Answer("error", None, {"solve": wall}, math.nan, note=note), wall


def _over(answer: Answer, note: str) -> Answer:
    """``answer`` marked as over the time limit: status ``timeout``, its joints kept for the record."""
    answer.status = "timeout"
    answer.note = f"{note}; {answer.note}"[:160] if answer.note else note
    return answer


@contextlib.contextmanager
def captured(log: Path | None) -> Iterator[None]:
    """Send the process's standard output and error to the file ``log`` while the block runs.

    Python's ``sys.stdout`` and ``sys.stderr`` (where CasADi sends IPOPT's log) and file
    descriptors 1 and 2 (where other C and C++ libraries print) are redirected; nothing changes
    for None.
    """
    if log is None:
        yield
        return
    log.parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with log.open("a", buffering=1) as f:
        os.dup2(f.fileno(), 1)
        os.dup2(f.fileno(), 2)
        try:
            with contextlib.redirect_stdout(f), contextlib.redirect_stderr(f):
                yield
        finally:
            f.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)


def _child(send: Any, problem: BenchProblem, name: str, function: Contender, log: Path | None) -> None:
    """The watchdog's child: one timed call, its answer sent back."""
    try:
        with captured(log):
            message = ("answer", timed_call(problem, name, function))
    except Unavailable as e:
        message = ("unavailable", str(e))
    try:
        send.send(message)
    except Exception as e:  # an answer that cannot be pickled is an error of the contender
        send.send(("answer", (Answer("error", None, note=f"its answer cannot be sent back: {e}"[:160]), 0.0)))
    send.close()
