"""The rounds' controller-line check of a re-solve's answer, started cold and from the previous line.

On the glass cell's arrays (``benchmarks/warm_resolve.py``'s set-up and its ``part`` and ``cone``
changes), the warm re-solve's last line check (:class:`refine.optimise.controller_line.ControllerLineSource`)
is taken and made again on the same joints ``--repeat`` times each way, in turns: with today's start
(the one-step Newton start at every sample) and from the previous answer's line
(``previous=``, :mod:`refine.optimise.line_start`). Printed per change: the median CPU time of
each, and how far apart the two checks' figures are (line joints, IK residuals, singularity
measures, violations).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python3 benchmarks/warm_line.py [--repeat 15]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from warm_resolve import ROBOT, glass_setup  # the same cell, first answer and changes

import refine
from refine.optimise import controller_line as cl


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    args = parser.parse_args()
    seen: list = []
    check = cl.ControllerLineSource._check

    def spy(self, q):  # noqa: ANN001, ANN202 - the source's own method, recorded
        seen.append((self, np.array(q, dtype=float)))
        return check(self, q)

    cl.ControllerLineSource._check = spy
    f, common, changes = glass_setup()
    first = refine.refine_path(ROBOT, f.positions, f.rotations, **common)
    for name in ("part", "cone"):
        change = {"positions": f.positions, "orientations": f.rotations, **common, **changes[name]}
        positions, orientations = change.pop("positions"), change.pop("orientations")
        seen.clear()
        refine.refine_path(ROBOT, positions, orientations, **change, previous=first)
        source, q = seen[-1]
        s = np.arange(len(q), dtype=float)
        wrist = np.asarray(source.wrist(q), dtype=bool) if source.wrist else np.zeros(len(q) - 1, dtype=bool)
        starts = {"cold": None, "previous": source.previous}
        lines = {
            k: cl.check_controller_lines(source.kin, q, s, source.tolerances, wrist=wrist, previous=v)
            for k, v in starts.items()
        }
        times: dict[str, list[float]] = {k: [] for k in starts}
        for _ in range(args.repeat):
            for way, previous in starts.items():
                c0 = time.process_time()
                cl.check_controller_lines(source.kin, q, s, source.tolerances, wrist=wrist, previous=previous)
                times[way].append(time.process_time() - c0)
        a, b = lines["cold"], lines["previous"]
        print(
            f"{name}: {len(a.t)} samples; median CPU {statistics.median(times['cold']) * 1e3:.2f} ms cold start, "
            f"{statistics.median(times['previous']) * 1e3:.2f} ms from the previous line; "
            f"max |q_line difference| {np.abs(a.q - b.q).max():.1e} rad, max IK residual "
            f"{a.ik_error.max():.1e} / {b.ik_error.max():.1e} m+rad, max |singularity difference| "
            f"{np.abs(a.singularity - b.singularity).max():.1e}, same violations {a.violations == b.violations}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
