"""A host program's timer, signal handlers and signal mask survive refine's library calls.

The host sets a 30 s ``ITIMER_REAL`` and handlers of its own for SIGINT, SIGTERM and SIGALRM, then
solves a short line and writes its files, in the main thread and in another one.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import numpy as np
from scipy.spatial.transform import Rotation

import refine

HOST_TIMER_S = 30.0
SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGALRM)


def _line(n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    positions = np.column_stack([np.full(n, 0.6), np.linspace(-0.1, 0.1, n), np.full(n, 0.3)])
    down = Rotation.from_euler("x", 180.0, degrees=True).as_matrix()  # tool z pointing down
    return positions, np.repeat(down[None], n, axis=0)


def _solve_and_write(out) -> dict:
    positions, R = _line()
    result = refine.refine_path("ur10e", positions, R, speeds=0.1, name="line")
    return result.write(out, report=False)


def _host_handler(signum: int, frame: object) -> None:  # the host's own; never called here
    raise AssertionError(f"host handler called for signal {signum}")


def test_library_calls_leave_the_hosts_timer_handlers_and_mask_alone(tmp_path, monkeypatch):
    old = {sig: signal.getsignal(sig) for sig in SIGNALS}
    handlers = {sig: (lambda signum, frame, sig=sig: _host_handler(signum, frame)) for sig in SIGNALS}
    mask_before = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    # while the files move into place, the host's handlers stay installed and nothing is blocked
    during_moves: list[bool] = []
    replace = os.replace

    def watched_replace(src, dst) -> None:  # noqa: ANN001 - as os.replace
        if threading.current_thread() is threading.main_thread():
            during_moves.append(
                all(signal.getsignal(sig) is h for sig, h in handlers.items())
                and signal.pthread_sigmask(signal.SIG_BLOCK, []) == mask_before
            )
        replace(src, dst)

    monkeypatch.setattr(os, "replace", watched_replace)
    try:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        signal.setitimer(signal.ITIMER_REAL, HOST_TIMER_S)
        t0 = time.monotonic()

        files = _solve_and_write(tmp_path / "main")
        assert json.loads(files["result"].read_text())["status"] == "ok"
        assert len(during_moves) >= len(files) and all(during_moves), during_moves

        left, interval = signal.getitimer(signal.ITIMER_REAL)
        elapsed = time.monotonic() - t0
        # the timer ran on undisturbed: 30 s less the time the calls took (10 ms of slack for timer
        # granularity), never cancelled (0.0) nor re-armed
        assert HOST_TIMER_S - elapsed - 0.01 <= left <= HOST_TIMER_S - elapsed + 0.01, (left, elapsed)
        assert interval == 0.0
        for sig, handler in handlers.items():
            assert signal.getsignal(sig) is handler, signal.Signals(sig).name
        assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == mask_before

        # from another thread, which may not set signal handlers at all, the write works
        caught: list[BaseException] = []
        written: dict = {}

        def work() -> None:
            try:
                written.update(_solve_and_write(tmp_path / "thread"))
            except BaseException as e:  # noqa: BLE001 - reported by the assertion below
                caught.append(e)

        worker = threading.Thread(target=work)
        worker.start()
        worker.join(timeout=300)
        assert not worker.is_alive()
        assert caught == []
        assert sorted(p.name for p in (tmp_path / "thread").iterdir()) == sorted(
            p.name for p in written.values()
        )
        assert json.loads(written["result"].read_text())["status"] == "ok"
        left, _ = signal.getitimer(signal.ITIMER_REAL)
        elapsed = time.monotonic() - t0
        assert HOST_TIMER_S - elapsed - 0.01 <= left <= HOST_TIMER_S - elapsed + 0.01, (left, elapsed)
        for sig, handler in handlers.items():
            assert signal.getsignal(sig) is handler, signal.Signals(sig).name
        assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == mask_before
        print(f"timer left {left:.3f} s after {elapsed:.3f} s of {HOST_TIMER_S} s")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        for sig, handler in old.items():
            signal.signal(sig, handler)


def test_a_host_that_opts_in_has_its_sigint_held_back_until_the_files_are_moved(tmp_path, monkeypatch):
    from refine.interrupt import guarded

    positions, R = _line()
    result = refine.refine_path("ur10e", positions, R, speeds=0.1, name="line")
    old = {sig: signal.getsignal(sig) for sig in SIGNALS}
    received: list[tuple[int, bool]] = []  # (signal, result.json in place when the handler ran)
    out = tmp_path / "out"

    def host_sigint(signum: int, frame: object) -> None:
        received.append((signum, (out / "result.json").is_file()))

    replace = os.replace
    moves: list[str] = []

    def replace_and_interrupt(src, dst) -> None:  # noqa: ANN001 - as os.replace
        if os.path.dirname(dst) == str(out):  # a move into the output folder (not in staging)
            moves.append(os.path.basename(dst))
            if len(moves) == 1:
                signal.raise_signal(signal.SIGINT)  # Ctrl-C at the first move
        replace(src, dst)

    monkeypatch.setattr(os, "replace", replace_and_interrupt)
    try:
        signal.signal(signal.SIGINT, host_sigint)
        signal.signal(signal.SIGALRM, _host_handler)
        signal.setitimer(signal.ITIMER_REAL, HOST_TIMER_S)
        t0 = time.monotonic()
        with guarded():
            files = result.write(out, report=False)
        left, _ = signal.getitimer(signal.ITIMER_REAL)
        elapsed = time.monotonic() - t0
        assert moves[-1] == "result.json" and len(moves) == len(files)
        # delivered once, after the last move: result.json was already in place
        assert received == [(signal.SIGINT, True)]
        assert signal.getsignal(signal.SIGINT) is host_sigint
        assert signal.getsignal(signal.SIGALRM) is _host_handler
        assert HOST_TIMER_S - elapsed - 0.01 <= left <= HOST_TIMER_S - elapsed + 0.01, (left, elapsed)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        for sig, handler in old.items():
            signal.signal(sig, handler)
