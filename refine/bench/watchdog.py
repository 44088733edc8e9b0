"""The time limit of one benchmark run: kept by the contender itself, or enforced by a watchdog.

A contender that keeps the limit itself says so with the attribute ``keeps_time_limit = True``
(refine's contenders: they give ``problem.time_limit_s`` to the refinement, which stops its solves
there and answers ``timeout``); it runs in the runner's process, as before.

Every other contender (Drake, the Tesseract peers, greedy IK, plug-ins) runs under a watchdog, in
a worker: a child process forked from the runner once per problem and contender (:class:`Workers`),
so it starts with everything the runner has loaded and cached (the problem, its robot, the
contender's declared set-up), and which then makes every run of that contender on that problem,
the untimed warm-up runs and the timed ones, as refine's contenders make theirs in the runner's
process. So what a first call in a process pays once (lazy libraries, the allocator's first pages:
Tesseract's Bullet contact managers fault in some hundred megabytes on a planner's first solve in a
process) falls in the warm-up for every contender alike, and what a contender caches in
``problem.extra`` during its warm-up is kept for its timed runs. The worker times each call on its
own clock (:func:`refine.bench.contenders.timed_call`) and sends back the answer and its wall time.
When it has not answered by the time limit it is killed (SIGKILL, so a C++ solver that never
returns to Python stops too) and the run is a ``timeout`` answer: no joints, a failure, counted at
the time limit; its ``solve`` time is the runner's wall time until the kill and its CPU time
unknown (NaN, an empty cell); the next run of the contender starts a new worker. A worker that dies
without answering (a C++ ``abort``, a segmentation fault) gives an ``error`` answer naming the
signal; the benchmark goes on.

A contender may declare a set-up (:func:`setup_of`: the attribute ``setup``, a callable taking the
problem), work a user does once per problem and not per query: loading its model of the robot and
cell (Drake's plant, Tesseract's environment) into ``problem.extra``. :func:`prepare` makes it once
per problem in the runner's process, before the worker is forked and outside every timed window
and time limit, and measures its wall and CPU time apart.

Where ``fork`` is not available (not Linux or macOS) or with ``isolate=False``, the contender runs
in the runner's process and the limit is only applied afterwards: a run over it is a ``timeout``
failure, but it is not interrupted.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import math
import multiprocessing
import os
import re
import signal
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from refine.bench.contenders import Answer, Contender, NotPosed, Unavailable, timed_call
from refine.bench.suites import BenchProblem

log = logging.getLogger(__name__)

GRACE_S = 0.5
"""Extra wall time [s] the watchdog waits past the limit for an answer already on its way."""


def keeps_time_limit(function: Contender) -> bool:
    """Whether ``function`` stops at ``problem.time_limit_s`` itself (``keeps_time_limit = True``)."""
    return bool(getattr(function, "keeps_time_limit", False))


def can_fork() -> bool:
    """Whether this platform starts a child process by ``fork`` (Linux, macOS)."""
    return "fork" in multiprocessing.get_all_start_methods()


def setup_of(function: Contender) -> Callable[[BenchProblem], Any] | None:
    """The set-up ``function`` declares (its attribute ``setup``: a callable taking the problem), or None."""
    setup = getattr(function, "setup", None)
    return setup if callable(setup) else None


def prepare(problem: BenchProblem, function: Contender) -> tuple[float, float]:
    """Make ``function``'s declared set-up for ``problem`` in this process; its wall and CPU time [s].

    Nothing for a contender without one (0, 0). :class:`Unavailable` and :class:`NotPosed` reach the
    caller; any other
    exception is logged and left to the contender's own calls, which then make the set-up themselves
    (and fail as they fail).
    """
    setup = setup_of(function)
    if setup is None:
        return 0.0, 0.0
    w0, c0 = time.perf_counter(), time.process_time()
    try:
        setup(problem)
    except (Unavailable, NotPosed):
        raise
    except Exception as e:  # the contender's call meets it again, as an error answer
        log.warning("the set-up of a contender on %s failed: %s", problem.name, e)
    return time.perf_counter() - w0, time.process_time() - c0


def run_limited(
    problem: BenchProblem,
    name: str,
    function: Contender,
    time_limit_s: float,
    isolate: bool = True,
    log: Path | None = None,
) -> tuple[Answer, float]:
    """One run of ``function`` on ``problem`` held to ``time_limit_s`` [s], in a worker of its own.

    As :meth:`Workers.run` with a worker made for this run alone.
    """
    with Workers() as workers:
        return workers.run(problem, name, function, time_limit_s, isolate, log)


class Workers:
    """The watchdog's workers of one problem: one forked child per contender, kept between its runs.

    Use as a context manager; leaving it stops every worker. See the module's rules.
    """

    def __init__(self) -> None:
        self._live: dict[str, tuple[Any, Any, Any]] = {}  # name -> (process, requests, answers)

    def __enter__(self) -> Workers:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop every worker (asked to end, killed when it does not within a second)."""
        for name in list(self._live):
            process, requests, answers = self._live.pop(name)
            with contextlib.suppress(OSError):
                requests.send(None)
            process.join(1.0)
            _stop(process, requests, answers)

    def run(
        self,
        problem: BenchProblem,
        name: str,
        function: Contender,
        time_limit_s: float,
        isolate: bool = True,
        log: Path | None = None,
    ) -> tuple[Answer, float]:
        """One run of ``function`` on ``problem`` held to ``time_limit_s`` [s]; the answer and its wall time [s].

        In the contender's worker (made on its first run, or after a kill), or in this process for
        a contender that keeps the limit itself, with ``isolate`` False or without ``fork``.
        :class:`Unavailable` and :class:`NotPosed` raised by the contender reach the caller in either
        way of running.
        ``log``: a file that receives everything the run prints to the process's standard output
        and error, the solvers' own iteration logs included (:func:`captured`).
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
        if name not in self._live:
            self._live[name] = _start(problem, name, function)
        process, requests, answers = self._live[name]
        t0 = time.perf_counter()
        try:
            requests.send(("run", log))
            if answers.poll(time_limit_s + GRACE_S):
                kind, payload = answers.recv()
            else:
                kind, payload = "timeout", None
        except (EOFError, OSError):  # the worker died before answering
            kind, payload = "died", None
        wall = time.perf_counter() - t0
        if kind in ("timeout", "died"):
            del self._live[name]
            _stop(process, requests, answers)
        if kind == "answer":
            answer, own_wall = payload
            if own_wall > time_limit_s and answer.status != "timeout":
                answer = _over(answer, f"ran {own_wall:.3g} s, over the time limit of {time_limit_s:g} s")
            return answer, own_wall
        if kind == "unavailable":
            raise Unavailable(payload)
        if kind == "not_posed":
            raise NotPosed(payload)
        # no answer: the stage time is the runner's wall time until then, the worker's CPU time unknown
        if kind == "timeout":
            note = f"stopped by the watchdog at the time limit of {time_limit_s:g} s"
            return Answer("timeout", None, {"solve": wall}, math.nan, note=note), wall
        code = process.exitcode
        how = f"signal {signal.Signals(-code).name}" if code is not None and code < 0 else f"exit code {code}"
        note = f"the contender's process died without an answer ({how})"
        return Answer("error", None, {"solve": wall}, math.nan, note=note), wall


def _start(problem: BenchProblem, name: str, function: Contender) -> tuple[Any, Any, Any]:
    """Fork a worker for ``function`` on ``problem``: the process and the ends of its two pipes."""
    context = multiprocessing.get_context("fork")
    requests_in, requests = context.Pipe(duplex=False)
    answers, answers_out = context.Pipe(duplex=False)
    process = context.Process(
        target=_serve, args=(requests_in, answers_out, problem, name, function), daemon=True
    )
    process.start()
    requests_in.close()
    answers_out.close()
    return process, requests, answers


def _stop(process: Any, requests: Any, answers: Any) -> None:
    if process.is_alive():
        process.kill()
    process.join()
    requests.close()
    answers.close()


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
    _flush_c_streams()  # what the C library buffered before the block stays where it was going
    saved = [os.dup(1), os.dup(2)]
    with log.open("a", buffering=1) as f:
        os.dup2(f.fileno(), 1)
        os.dup2(f.fileno(), 2)
        try:
            with contextlib.redirect_stdout(f), contextlib.redirect_stderr(f):
                yield
        finally:
            f.flush()
            _flush_c_streams()  # and what it buffered inside goes to the log, not after it
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)


def _flush_c_streams() -> None:
    """Flush the C library's ``stdout`` and ``stderr`` (``fflush(NULL)``).

    C and C++ libraries print through them, fully buffered when file descriptor 1 is a file or a pipe.
    """
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).fflush(None)


_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
_ERROR_LIKE = re.compile(r"error|fail|fatal|abort|exception|terminat", re.IGNORECASE)
_WARNING_LIKE = re.compile(r"warn|leak", re.IGNORECASE)


def output_summary(logs: list[Path], name: str) -> str | None:
    """A line saying what ``name``'s runs printed to the files ``logs`` (:func:`captured`), or None.

    How many lines there were and the last error-like one (else the last warning-like one, else the
    last line), its colour codes removed; None when the runs printed nothing.
    """
    lines: list[str] = []
    for path in logs:
        if path.is_file():
            text = path.read_text(errors="replace")
            lines += [" ".join(_ANSI.sub("", line).split()) for line in text.splitlines()]
    if not lines:
        return None
    said = [line for line in lines if line]
    last = next((line for line in reversed(said) if _ERROR_LIKE.search(line)), None)
    last = last or next((line for line in reversed(said) if _WARNING_LIKE.search(line)), None)
    last = last or (said[-1] if said else "")
    if len(last) > 100:
        last = last[:97] + "..."
    return f'{name} printed {len(lines)} line(s) (last: "{last}"); --log-dir DIR keeps them'


def _serve(requests: Any, answers: Any, problem: BenchProblem, name: str, function: Contender) -> None:
    """The worker: for each request (``("run", log file or None)``), one timed call, its answer sent back.

    It ends on the request ``None`` or when the runner's end of the pipe closes.
    """
    while True:
        try:
            request = requests.recv()
        except EOFError:
            break
        if request is None:
            break
        log_file = request[1]
        try:
            with captured(log_file):
                message = ("answer", timed_call(problem, name, function))
        except Unavailable as e:
            message = ("unavailable", str(e))
        except NotPosed as e:
            message = ("not_posed", str(e))
        try:
            answers.send(message)
        except Exception as e:  # an answer that cannot be pickled is an error of the contender
            note = f"its answer cannot be sent back: {e}"[:160]
            answers.send(("answer", (Answer("error", None, note=note), 0.0)))
    answers.close()
