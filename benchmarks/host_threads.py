"""Two threads calling ``refine.refine_path`` on one Robot at once: same answers, no slower than in turn.

A host holds one ``refine.Robot`` and refines two different short paths (the UR10e, lines at two
heights). Each round solves both one after the other in the main thread, then both at once in two
threads (started together), and compares: the joints of each path (largest difference [rad]), the
wall time of the pair and the process's CPU time. The kernels are compiled and the robot loaded
before the first round.

    PYTHONPATH=. python3 benchmarks/host_threads.py [--rounds 5] [--waypoints 41]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--waypoints", type=int, default=41)
    args = ap.parse_args()
    import refine
    from refine.robot.registry import load_robot

    n = args.waypoints
    down = np.diag([1.0, -1.0, -1.0])
    R = np.repeat(down[None], n, axis=0)
    paths = [np.column_stack([np.full(n, 0.6), np.linspace(-0.2, 0.2, n), np.full(n, z)]) for z in (0.3, 0.4)]
    robot = load_robot("ur10e")

    def one(k: int, out: dict[int, np.ndarray]) -> None:
        out[k] = refine.refine_path(robot, paths[k], R, speeds=0.1, name=f"line{k}").joints

    reference: dict[int, np.ndarray] = {}
    for k in (0, 1):
        one(k, reference)  # warm: kernels compiled, robot loaded
    print(f"load average {open('/proc/loadavg').read().split()[:3]}; {n} waypoints, UR10e, one Robot")
    serial_wall, serial_cpu, both_wall, both_cpu, worst = [], [], [], [], 0.0
    for r in range(args.rounds):
        out: dict[int, np.ndarray] = {}
        t0, c0 = time.perf_counter(), time.process_time()
        one(0, out)
        one(1, out)
        serial_wall.append(time.perf_counter() - t0)
        serial_cpu.append(time.process_time() - c0)
        worst = max(worst, *(float(np.abs(out[k] - reference[k]).max()) for k in (0, 1)))

        out = {}
        threads = [threading.Thread(target=one, args=(k, out)) for k in (0, 1)]
        t0, c0 = time.perf_counter(), time.process_time()
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        both_wall.append(time.perf_counter() - t0)
        both_cpu.append(time.process_time() - c0)
        worst = max(worst, *(float(np.abs(out[k] - reference[k]).max()) for k in (0, 1)))
        print(
            f"round {r + 1}: in turn {serial_wall[-1]:.3f} s wall, {serial_cpu[-1]:.3f} s CPU; "
            f"two threads {both_wall[-1]:.3f} s wall, {both_cpu[-1]:.3f} s CPU"
        )
    med = statistics.median
    print(
        f"median of {args.rounds}: in turn {med(serial_wall):.3f} s wall / {med(serial_cpu):.3f} s CPU, "
        f"two threads {med(both_wall):.3f} s wall / {med(both_cpu):.3f} s CPU "
        f"(ratio {med(both_wall) / med(serial_wall):.2f} wall, {med(both_cpu) / med(serial_cpu):.2f} CPU); "
        f"largest joint difference from the first answers {worst:.1e} rad"
    )
    print(f"load average {open('/proc/loadavg').read().split()[:3]}")
    return 0 if worst <= 1e-9 else 1


if __name__ == "__main__":
    sys.exit(main())
