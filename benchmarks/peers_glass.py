"""refine against Tesseract's TrajOpt and Descartes on the glass cell, in turns, with the CPU time of each.

The contenders of ``refine bench`` (``refine/bench/contenders.py``, ``refine/bench/peers.py``) on a
suite's problems (default ``glass``: 618 waypoints, collision on), each timed from outside its
call, so every figure covers the same span: refine's build, seed, solve and its own verification
of every round (``refine bench`` leaves the verification out of refine's time); TrajOpt's chained
IK seed, program and solve; Descartes' program and solve. The peers' environments are made before
the timed runs (as ``refine bench`` does). Contenders take turns within each repeat, so load
changes reach them alike; printed per contender: the median and least CPU time, the median wall
time, the answer's status and whether refine's verifier accepts it, and the ratio of each median
CPU time to refine's, and the median of the CPU time the contender reports for its own stages
(``Answer.cpu_s``, the ``cpu_s`` of a ``refine bench`` row: the same as the outside figure for the
peers, refine's without its verification); then the 1-minute load average over the runs. A
contender that cannot run here (``Unavailable``) or does not pose a problem (``NotPosed``, e.g.
Drake on a stationary tool) gets one line saying so and is left out there.

    python3 benchmarks/peers_glass.py [--repeat 7] [--suite glass] [--contenders refine,trajopt,descartes]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import refine.bench.peers  # noqa: F401  (the peers join the contenders)
from refine.bench.contenders import CONTENDERS, NotPosed, Unavailable, verify
from refine.bench.suites import load_suites, problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--suite", default="glass")
    parser.add_argument("--contenders", default="refine,trajopt,descartes")
    args = parser.parse_args()
    available = args.contenders.split(",")
    for problem in problems(load_suites(), args.suite):
        names = list(available)  # less those that do not pose this problem
        times: dict[str, list[tuple[float, float]]] = {name: [] for name in names}
        verdicts: dict[str, str] = {}
        loads = []
        for name in list(names):  # the untimed warm-up: environments, compiled kernels
            try:
                CONTENDERS[name](problem)
            except Unavailable as e:
                print(f"  {name}: unavailable ({e})")
                names.remove(name)
                available.remove(name)
            except NotPosed as e:
                print(f"  {name}: not posed on {problem.name} ({e})")
                names.remove(name)
        if not names:
            continue
        for _ in range(args.repeat):
            for name in names:
                w0, c0 = time.perf_counter(), time.process_time()
                answer = CONTENDERS[name](problem)
                times[name].append((time.process_time() - c0, time.perf_counter() - w0, answer.cpu_s))
                verdict = verify(problem, answer.q) if answer.q is not None else None
                verdicts[name] = f"{answer.status}, " + (
                    "no answer"
                    if verdict is None
                    else "verified"
                    if verdict.verified
                    else f"not verified: {verdict.reason[:70]}"
                )
            loads.append(os.getloadavg()[0])
        print(
            f"{problem.name}, {problem.n_waypoints} waypoints, {args.repeat} runs each, contenders in turns"
        )
        base = statistics.median(t[0] for t in times[names[0]])
        for name in names:
            cpu = statistics.median(t[0] for t in times[name])
            print(
                f"  {name:10s} CPU median {cpu * 1e3:8.1f} ms, least {min(t[0] for t in times[name]) * 1e3:8.1f} ms; "
                f"wall median {statistics.median(t[1] for t in times[name]) * 1e3:8.1f} ms; "
                f"{cpu / base:5.2f}x {names[0]}'s CPU; own CPU (refine bench's cpu_s) median "
                f"{statistics.median(t[2] for t in times[name]) * 1e3:8.1f} ms; {verdicts[name]}"
            )
        print(f"  load (1 min) {min(loads):.1f}-{max(loads):.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
