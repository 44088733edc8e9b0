"""A host's timer, signal handlers and signal mask across ``refine.solve`` and ``Result.write``.

The host arms ``ITIMER_REAL`` (60 s, with its own SIGALRM handler), installs its own SIGINT,
SIGTERM and SIGALRM handlers and blocks nothing; then it solves a problem and writes the result
(with the report and programs), reading the timer, the handlers and the signal mask before, during
(from the ``progress`` hook, at every stage and IPOPT iteration) and after each call. The timer
must keep running down (its remaining time falls by the wall time elapsed, within 50 ms), the
handlers must be the host's own objects and the mask empty, throughout. Also run in a second
thread (where CPython cannot change handlers at all) to show the calls work there.

    PYTHONPATH=. python3 benchmarks/host_side_effects.py [--problem problems/glass_adhesive]
"""

from __future__ import annotations

import argparse
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGALRM)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--problem", default="problems/glass_adhesive")
    args = ap.parse_args()
    import refine

    def host_handler(signum, frame):  # noqa: ANN001 - a host's own handler
        print(f"host handler ran for signal {signum}")

    for s in SIGNALS:
        signal.signal(s, host_handler)
    signal.setitimer(signal.ITIMER_REAL, 60.0)
    armed_at = time.monotonic()
    problems: list[str] = []
    checks = 0

    def check(where: str) -> None:
        nonlocal checks
        checks += 1
        left = signal.getitimer(signal.ITIMER_REAL)[0]
        expected = 60.0 - (time.monotonic() - armed_at)
        if abs(left - expected) > 0.05:
            problems.append(f"{where}: ITIMER_REAL {left:.3f} s left, expected {expected:.3f} s")
        for s in SIGNALS:
            if signal.getsignal(s) is not host_handler:
                problems.append(f"{where}: handler of {signal.Signals(s).name} is {signal.getsignal(s)!r}")
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, [])
        if blocked:
            problems.append(f"{where}: signals blocked {sorted(blocked)}")

    print(f"load average {open('/proc/loadavg').read().split()[:3]}")
    check("before solve")
    t0 = time.perf_counter()
    result = refine.solve(args.problem, progress=lambda p: check(f"during solve ({p.stage})"))
    solve_s = time.perf_counter() - t0
    check("after solve")
    out = Path(tempfile.mkdtemp()) / "out"
    t0 = time.perf_counter()
    files = result.write(out)
    write_s = time.perf_counter() - t0
    check("after write")
    left = signal.getitimer(signal.ITIMER_REAL)[0]
    print(
        f"solve {result.status} in {solve_s:.2f} s, write of {len(files)} files in {write_s:.2f} s; "
        f"ITIMER_REAL {left:.2f} s left after {time.monotonic() - armed_at:.2f} s of its 60 s; "
        f"{checks} checks of the timer, the SIGINT/SIGTERM/SIGALRM handlers and the mask: "
        f"{len(problems)} changes"
    )
    for line in problems[:10]:
        print("  ", line)

    errors: list[BaseException] = []

    def in_thread() -> None:
        try:
            r = refine.solve(args.problem)
            r.write(Path(tempfile.mkdtemp()) / "out", report=False)
        except BaseException as e:  # noqa: BLE001 - reported
            errors.append(e)

    t = threading.Thread(target=in_thread)
    t.start()
    t.join()
    check("after a solve and write in another thread")
    print(f"solve and write in a second thread: {'ok' if not errors else errors[0]!r}; changes {len(problems)}")
    signal.setitimer(signal.ITIMER_REAL, 0.0)
    return 1 if problems or errors else 0


if __name__ == "__main__":
    sys.exit(main())
