"""Sample the registry robots' self-collision matrices and write ``robots/<robot>/self_collision.toml``.

    python3 robots/make_self_collision.py [--robots ur10e ...] [--samples 20000] [--seed 1]

Run it again whenever a robot's shapes change (``robots/make_shapes.py``). Prints every pair's
reason, least distance and share of samples in contact.
"""

from __future__ import annotations

import argparse
import time

from refine.collision.self_collision import NEVER_M, sample_matrix, write_matrix
from refine.robot import SELF_COLLISION_FILE, available_robots, load_robot, robots_dir


def main() -> None:
    """Sample and write the matrices of the chosen robots."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=available_robots())
    parser.add_argument("--samples", type=int, default=20000)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    for name in args.robots:
        robot = load_robot(name)
        t0 = time.perf_counter()
        stats = sample_matrix(robot, args.samples, args.seed, NEVER_M)
        write_matrix(robots_dir() / name / SELF_COLLISION_FILE, stats, samples=args.samples, seed=args.seed,
                     never_m=NEVER_M)
        print(f"{name}: {args.samples} samples in {time.perf_counter() - t0:.0f} s")
        for s in stats:
            print(f"  {s.links[0]:10} {s.links[1]:10} {s.reason or 'checked':9} "
                  f"least {s.min_distance_m * 1e3:8.1f} mm  in contact {s.contact_fraction:7.2%}")


if __name__ == "__main__":
    main()
