"""Ctrl-C during a library solve: always ``KeyboardInterrupt`` (or ``refine.Cancelled``), never a verdict.

A host process (a child of this script) imports refine, says it is ready and calls
``refine.solve(problem)``. One uninterrupted call measures the solve's duration T; then each of
``--tries`` calls is sent SIGINT at a moment drawn uniformly over ``--window`` (fractions of T,
default [0.02, 0.9]) after the call started, so the signal lands in every stage (load, seed, build,
inside IPOPT, verify, timing). T is calibrated on the runs themselves: a call that ends before its
signal (the machine's load changed its length) sets T to that call's own length, and the try is
drawn again (at most ``--redraws`` times; the count is reported), so every try's signal falls
inside a solve. The host prints
what ended its call: ``KeyboardInterrupt``, ``Cancelled`` or a status (a verdict). The latency is
the time from the signal to the exception reaching the host (both sides read CLOCK_MONOTONIC).

A verdict returned after the signal was sent counts as a failure, unless the host then received
the signal itself (it waits 2 s after its call returns, ready to catch it): the call had ended
before the signal arrived (on a loaded machine the signal can leave this script a little after
the moment it was meant for). The script exits 1 if any failed.
Then one call with ``time_limit_s=1`` reports its status (``timeout`` expected when the call
needs longer than 1 s), the stage that stopped and its wall time to return.

    PYTHONPATH=. python3 benchmarks/host_interrupt.py [--problem problems/tig_weld] [--tries 20]
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import statistics
import subprocess
import sys
import time

HOST = r"""
import signal, sys, time
signal.signal(signal.SIGINT, signal.default_int_handler)  # Ctrl-C as in a terminal (a shell's
# background job starts with SIGINT ignored, and Python then keeps it ignored)
import refine
import refine.run.solve  # the heavy imports happen before "ready"
problem, limit = sys.argv[1], (float(sys.argv[2]) if len(sys.argv) > 2 else None)
t0 = time.monotonic()
print("ready", t0, flush=True)
try:
    r = refine.solve(problem, time_limit_s=limit)
    d = r.to_dict()
    print("done", time.monotonic(), r.status, d["solver"].get("status"), d.get("stopped_stage"), flush=True)
    try:  # a signal that comes after the verdict lands here
        time.sleep(2.0)
    except KeyboardInterrupt:
        print("after", time.monotonic(), "KeyboardInterrupt after the verdict", flush=True)
except KeyboardInterrupt:
    print("interrupted", time.monotonic(), "KeyboardInterrupt", flush=True)
except refine.Cancelled:
    print("interrupted", time.monotonic(), "Cancelled", flush=True)
"""


def _start(problem: str, *extra: str) -> tuple[subprocess.Popen, float]:
    proc = subprocess.Popen(
        [sys.executable, "-c", HOST, problem, *extra], stdout=subprocess.PIPE, text=True, env=os.environ
    )
    assert proc.stdout is not None
    line = proc.stdout.readline().split()
    assert line and line[0] == "ready", line
    return proc, float(line[1])


def _finish(proc: subprocess.Popen) -> list[str]:
    out, _ = proc.communicate(timeout=600)
    lines = [ln.split() for ln in out.splitlines() if ln.strip()]
    if len(lines) >= 2 and lines[-1][0] == "after" and lines[-2][0] == "done":
        return ["late", *lines[-2][1:]]  # the signal reached the host after its call had returned
    _finish.other = [" ".join(ln) for ln in lines[:-1]]  # what else the host printed (CasADi's warnings)
    return lines[-1] if lines else ["exit", str(time.monotonic()), f"code {proc.returncode}"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--problem", default="problems/tig_weld")
    ap.add_argument("--tries", type=int, default=20)
    ap.add_argument("--seed", type=int, default=27)
    ap.add_argument(
        "--window",
        type=float,
        nargs=2,
        default=(0.02, 0.9),
        help="fractions of the solve the moments are drawn from",
    )
    ap.add_argument("--redraws", type=int, default=5, help="new moments for a try whose call ended first")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    print(f"load average {open('/proc/loadavg').read().split()[:3]}")

    proc, t0 = _start(args.problem)
    end = _finish(proc)
    duration = float(end[1]) - t0
    print(f"uninterrupted: {' '.join(end[2:])}, solve {duration:.2f} s wall")

    latencies, kinds, failures, late = [], {}, 0, 0
    for k in range(args.tries):
        for _ in range(1 + args.redraws):
            proc, t0 = _start(args.problem)
            delay = rng.uniform(args.window[0] * duration, args.window[1] * duration)
            time.sleep(max(0.0, t0 + delay - time.monotonic()))
            sent = time.monotonic()
            proc.send_signal(signal.SIGINT)
            end = _finish(proc)
            when = float(end[1])
            if end[0] != "late" and not (end[0] == "done" and when < sent):
                break
            late += 1
            duration = min(duration, when - t0)  # this run was shorter: draw within its length
            print(
                f"try {k + 1:2d}: SIGINT at {delay:6.2f} s came after the call ended; T now {duration:.2f} s"
            )
        if end[0] == "interrupted":
            latencies.append(when - sent)
            kinds[end[2]] = kinds.get(end[2], 0) + 1
            what = f"{end[2]} after {when - sent:.3f} s"
        elif end[0] == "late" or (end[0] == "done" and when < sent):
            what = f"finished before the signal ({' '.join(end[2:])}), {args.redraws} redraws used"
        else:
            failures += 1
            what = f"FAILED: {' '.join(end)}; the host also printed: {_finish.other[-5:]}"
        print(f"try {k + 1:2d}: SIGINT at {delay:6.2f} s: {what}")
    if latencies:
        print(
            f"{len(latencies)} of {args.tries} interrupted ({kinds}); latency median "
            f"{statistics.median(latencies) * 1e3:.0f} ms, worst {max(latencies) * 1e3:.0f} ms; "
            f"{late} redrawn (the call had ended before the signal); {failures} verdicts after a signal"
        )

    proc, t0 = _start(args.problem, "1.0")
    end = _finish(proc)
    print(
        f"time_limit_s=1: {' '.join(end[2:])} (status, solver, stopped stage) after {float(end[1]) - t0:.2f} s wall"
    )
    print(f"load average {open('/proc/loadavg').read().split()[:3]}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
