"""The kernel cache under a bound: its folder's size after many different base placements.

Each base placement is a new set of compiled per-waypoint kernels (``refine.optimise.compiled``):
a shared library and its ``.names`` file in the cache folder. With ``REFINE_CACHE_MAX_MB`` set,
the least recently used are removed after each new library. This script builds the kernels of
``--placements`` different bases (the UR10e's base moved 1 mm further each time) into a fresh cache
folder with the bound in force, and prints the folder's size and file count as it goes, the
in-process caches' sizes, and the size the folder would have had without eviction.

    PYTHONPATH=. python3 benchmarks/cache_bound.py [--placements 200] [--max-mb 1]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path


def _size(folder: Path) -> tuple[int, int]:
    files = [p for p in folder.iterdir() if p.is_file()]
    return sum(p.stat().st_size for p in files), len(files)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--placements", type=int, default=200)
    ap.add_argument("--max-mb", type=float, default=1.0)
    ap.add_argument("--robot", default="ur10e")
    args = ap.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="refine-cache-"))
    os.environ["REFINE_CACHE_DIR"] = str(folder)
    os.environ["REFINE_CACHE_MAX_MB"] = str(args.max_mb)

    import numpy as np

    from refine.optimise import compiled, derivatives
    from refine.robot.registry import load_robot

    print(f"load average {open('/proc/loadavg').read().split()[:3]}; cache {folder}, bound {args.max_mb} MB")
    robot = load_robot(args.robot)
    largest, library_bytes, t0, c0 = 0, [], time.perf_counter(), time.process_time()
    for k in range(args.placements):
        base = np.eye(4)
        base[0, 3] = 1e-3 * k
        before = {p.name for p in folder.glob("*.so")}
        derivatives.waypoint_kernels(robot, base, np.eye(4), False)
        new = [p for p in folder.glob("*.so") if p.name not in before]
        library_bytes += [p.stat().st_size + p.with_suffix(".names").stat().st_size for p in new]
        size, count = _size(folder)
        largest = max(largest, size)
        if (k + 1) % 20 == 0 or k == 0:
            print(
                f"after {k + 1:3d} placements: folder {size / 1e6:.3f} MB in {count} files; "
                f"in process {len(derivatives._kernel_cache)} kernel sets, {len(compiled._loaded)} libraries loaded"
            )
    size, count = _size(folder)
    print(
        f"{args.placements} placements, {len(library_bytes)} libraries compiled "
        f"({sum(library_bytes) / 1e6:.2f} MB had none been removed); folder at the end {size / 1e6:.3f} MB "
        f"in {count} files, largest {largest / 1e6:.3f} MB, bound {args.max_mb} MB; "
        f"{time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU (this process; cc runs apart)"
    )
    print(f"load average {open('/proc/loadavg').read().split()[:3]}")
    return 0 if largest <= args.max_mb * 1e6 else 1


if __name__ == "__main__":
    sys.exit(main())
