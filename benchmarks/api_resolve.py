"""What solving again after a small change saves: cold vs warm start vs reusing the built problem.

On the glass cell's arrays (618 waypoints, collision on) and on the same path without the cell, it
times three ways of refining after the orientation tolerance went from 3 to 2.5 deg:

* cold: ``refine_path`` from scratch (build, IK seed, solve, verify, time);
* warm: ``initial_joints=`` the first answer (build, solve, verify, time; no IK seed);
* reuse: ``previous=`` the first answer (no build, no IK seed).

Each is repeated ``--repeat`` times and the minimum wall time printed, with the stage times of that run.

    python3 benchmarks/api_resolve.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import refine
from refine.run.stages import fused_path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    p = refine.load_problem(ROOT / "problems" / "glass_adhesive")
    f = fused_path(p)
    for label, cell in (("with the cell", True), ("without collision", False)):
        common = {
            "speeds": f.speed,
            "arc_length": f.s,
            "tcp_in_flange": p.tool.tcp_in_flange,
            "base_in_world": p.robot.base_in_world,
            "cell": p.cell if cell else (),
            "tool_shapes": p.tool.collision if cell else (),
            "collision": p.collision,
        }
        first = refine.refine_path("abb_irb4600_60_205", f.positions, f.rotations, **common)
        changed = {**common, "tolerances": {"orientation_deg": 2.5}}
        ways = {
            "cold": {},
            "warm": {"initial_joints": first.joints},
            "reuse": {"previous": first},
        }
        print(f"glass cell, {len(f)} waypoints, {label}: orientation tolerance 3 -> 2.5 deg")
        answers = {}
        for way, extra in ways.items():
            best, stages = float("inf"), {}
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                r = refine.refine_path("abb_irb4600_60_205", f.positions, f.rotations, **changed, **extra)
                wall = time.perf_counter() - t0
                if wall < best:
                    best, stages, answers[way] = wall, dict(r.run.timings_s), r
            print(
                f"  {way:6s} {best:6.2f} s  status {answers[way].status}  "
                + ", ".join(f"{k} {v:.3f}" for k, v in stages.items())
            )
        dq = max(np.abs(answers[w].joints - answers["cold"].joints).max() for w in ("warm", "reuse"))
        print(f"  largest joint difference from cold: {dq:.1e} rad")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
