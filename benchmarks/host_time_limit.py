"""A 1 s ``time_limit_s`` on a whole library call: ``timeout`` within about a second, never a verdict.

Calls ``refine.solve(problem, time_limit_s=LIMIT)`` twice in one process (cold: the first call,
with the pipeline's imports; warm: the second) and prints each call's status, the stage that
stopped it, the wall time from the call to its return and the CPU time, with the load average.

    PYTHONPATH=. python3 benchmarks/host_time_limit.py [problems/tig_weld problems/glass_adhesive] [--limit 1]
"""

from __future__ import annotations

import argparse
import time

import refine


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("problems", nargs="*", default=["problems/tig_weld", "problems/glass_adhesive"])
    ap.add_argument("--limit", type=float, default=1.0, help="the calls' time_limit_s [s]")
    args = ap.parse_args()
    print(f"load average {open('/proc/loadavg').read().split()[:3]}")
    verdicts = 0
    for problem in args.problems:
        for call in ("cold", "warm"):
            t0, c0 = time.perf_counter(), time.process_time()
            result = refine.solve(problem, time_limit_s=args.limit)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            doc = result.to_dict()
            verdicts += result.status != "timeout"
            print(
                f"{problem} {call}: {result.status}, stopped at {doc.get('stopped_stage')}, "
                f"{wall:.2f} s wall to return, {cpu:.2f} s CPU; {doc['reason']}"
            )
    print(f"load average {open('/proc/loadavg').read().split()[:3]}")
    return 1 if verdicts else 0


if __name__ == "__main__":
    raise SystemExit(main())
