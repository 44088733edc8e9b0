"""Re-solving from the previous answer through the public API, against a cold solve of the same change.

On the glass cell's arrays (618 waypoints, collision on), a first answer is refined, then each
change below is refined twice: cold (``refine_path`` from scratch: build, IK seed, solve, verify,
time) and warm (``refine_path(..., previous=first)``: the previous joints moved onto the new poses,
the last problem, active set and multipliers kept, the dense check starting from the previous
check's bounds; :mod:`refine.optimise.warm`). The changes:

* ``part``: the glass, its path and its demonstrated orientations moved rigidly by 2 mm along
  world x and turned 0.3 deg about the vertical through the pane's centre (the cell's glass box
  moved with it);
* ``cone``: the orientation tolerance from 3 to 2.5 deg;
* ``tool``: the TCP 1 mm further along the flange z axis (the problem is rebuilt, the seed warm);
* ``base``: the robot base 1 mm along world y.

Each is repeated ``--repeat`` times, cold and warm alternating; printed per change: the median wall
and CPU time of the whole call, the median CPU time of the warm call's stages, the status, the
largest joint difference between the warm and the cold answer, and the 1-minute load average.
``--stages`` also prints the median CPU time of each top-level stage of the whole call, cold and
warm: the refinement (seed, solve, verify), the controller line's final check, TOPP-RA, the planned
motions and the collision model (each function wrapped in a CPU stopwatch).

    python3 benchmarks/warm_resolve.py [--repeat 7] [--changes part,cone] [--stages]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import refine
import refine.run.solve
import refine.run.stages
from refine.frames import make_transform
from refine.run.stages import fused_path

ROOT = Path(__file__).resolve().parents[1]
ROBOT = "abb_irb4600_60_205"


STAGE_CPU: dict[str, float] = {}
"""CPU seconds per top-level stage of the call being timed (``--stages``)."""


def _timed(name: str, fn):  # noqa: ANN001, ANN202 - any callable
    def wrapper(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        c0 = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            STAGE_CPU[name] = STAGE_CPU.get(name, 0.0) + time.process_time() - c0

    return wrapper


def time_stages() -> None:
    """Wrap the pipeline's top-level stages in CPU stopwatches (into :data:`STAGE_CPU`)."""
    stages = refine.run.stages
    refinement = stages.solve_refinement
    stages.solve_refinement = _timed("refinement", refinement)
    stages.controller_line_check = _timed("line", stages.controller_line_check)
    stages.time_parameterise = _timed("toppra", stages.time_parameterise)
    stages.plan_motions = _timed("motions", stages.plan_motions)
    refine.run.solve.constraint_sources = _timed("collision model", stages.constraint_sources)


def glass_setup() -> tuple[object, dict, dict[str, dict]]:
    """The glass cell's fused path, the arguments every call shares, and each change's own (module notes)."""
    p = refine.load_problem(ROOT / "problems" / "glass_adhesive")
    f = fused_path(p)
    common = {
        "speeds": f.speed,
        "arc_length": f.s,
        "tcp_in_flange": p.tool.tcp_in_flange,
        "base_in_world": p.robot.base_in_world,
        "cell": p.cell,
        "tool_shapes": p.tool.collision,
        "collision": p.collision,
    }
    centre = np.array([1.30, 0.0, 0.60])  # the pane's centre [m]
    R = Rotation.from_rotvec(np.radians(0.3) * np.array([0.0, 0.0, 1.0])).as_matrix()
    move = make_transform(p=centre - R @ centre + np.array([0.002, 0.0, 0.0]))
    move[:3, :3] = R
    part = {
        "positions": f.positions @ R.T + move[:3, 3],
        "orientations": np.einsum("ij,njk->nik", R, f.rotations),
        "cell": tuple(dataclasses.replace(o, pose=move @ o.pose) if o.workpiece else o for o in p.cell),
    }
    tcp = p.tool.tcp_in_flange @ make_transform(p=[0.0, 0.0, 0.001])
    base = make_transform(p=[0.0, 0.001, 0.0]) @ p.robot.base_in_world
    changes = {
        "part": part,
        "cone": {"tolerances": {"orientation_deg": 2.5}},
        "tool": {"tcp_in_flange": tcp},
        "base": {"base_in_world": base},
    }
    return f, common, changes


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--changes", default="part,cone,tool,base")
    parser.add_argument("--stages", action="store_true", help="time the top-level stages in CPU too")
    args = parser.parse_args()
    if args.stages:
        time_stages()
    f, common, changes = glass_setup()
    first = refine.refine_path(ROBOT, f.positions, f.rotations, **common)
    print(f"glass cell, {len(f)} waypoints, collision on; first answer {first.status}")
    for name in args.changes.split(","):
        change = {"positions": f.positions, "orientations": f.rotations, **common, **changes[name]}
        positions, orientations = change.pop("positions"), change.pop("orientations")
        times: dict[str, list[tuple[float, float]]] = {"cold": [], "warm": []}
        stages: list[dict[str, float]] = []
        top: dict[str, list[dict[str, float]]] = {"cold": [], "warm": []}
        answers = {}
        loads = []
        for _ in range(args.repeat):
            for way in ("cold", "warm"):
                extra = {"previous": first} if way == "warm" else {}
                STAGE_CPU.clear()
                w0, c0 = time.perf_counter(), time.process_time()
                r = refine.refine_path(ROBOT, positions, orientations, **change, **extra)
                times[way].append((time.perf_counter() - w0, time.process_time() - c0))
                top[way].append(dict(STAGE_CPU))
                answers[way] = r
                if way == "warm":
                    stages.append(dict(r.run.first.refinement.timings_s.cpu))
            loads.append(os.getloadavg()[0])
        dq = float(np.abs(answers["warm"].joints - answers["cold"].joints).max())
        line = [f"  {name:5s}"]
        for way in ("cold", "warm"):
            wall = statistics.median(t[0] for t in times[way]) * 1e3
            cpu = statistics.median(t[1] for t in times[way]) * 1e3
            line.append(f"{way} {wall:7.1f} ms wall {cpu:7.1f} ms CPU ({answers[way].status})")
        print(", ".join(line) + f"; max |q_warm - q_cold| {dq:.1e} rad; load {min(loads):.1f}-{max(loads):.1f}")
        keys = sorted({k for s in stages for k in s})
        print(
            "        warm stages, median CPU [ms]: "
            + ", ".join(f"{k} {statistics.median(s.get(k, 0.0) for s in stages) * 1e3:.1f}" for k in keys)
        )
        if args.stages:
            for way in ("cold", "warm"):
                names = list(top[way][0])
                print(
                    f"        {way} top-level stages, median CPU [ms]: "
                    + ", ".join(f"{k} {statistics.median(d[k] for d in top[way]) * 1e3:.1f}" for k in names)
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
