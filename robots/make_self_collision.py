"""Sample the registry robots' self-collision matrices and write ``robots/<robot>/self_collision.toml``.

    python3 robots/make_self_collision.py [--robots ur10e ...] [--samples 20000] [--seed 1]
        [--meshes ../shared/robot-meshes]

Run it again whenever a robot's shapes change (``robots/make_shapes.py``). Prints every pair's
reason, least distance and share of samples in contact. A pair the sample leaves checked is disabled
as ``"maker"`` when the maker's own collision meshes (the reference description, when present) are
in contact at :data:`refine.robot.self_collision.MAKER_FRACTION` of ``--samples // 10`` random
configurations or more: there the meshes overlap where the real parts pass each other.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from refine.robot.registry import available_robots, load_robot, robots_dir
from refine.robot.self_collision import NEVER_M, maker_contacts, sample_matrix, with_maker, write_matrix
from refine.robot.spec import SELF_COLLISION_FILE

HERE = Path(__file__).resolve().parent


def main() -> None:
    """Sample and write the matrices of the chosen robots."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=available_robots())
    parser.add_argument("--samples", type=int, default=20000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--meshes", type=Path, default=HERE.parent.parent / "shared" / "robot-meshes")
    args = parser.parse_args()
    for name in args.robots:
        robot = load_robot(name)
        t0 = time.perf_counter()
        stats = sample_matrix(robot, args.samples, args.seed, NEVER_M)
        maker = {}
        if (args.meshes / name / "reference.urdf").is_file():
            folder = args.meshes / name
            maker = maker_contacts(
                robot, folder / "reference.urdf", args.samples // 10, args.seed, package_dirs=(str(folder),)
            )
        stats = with_maker(stats, maker)
        write_matrix(
            robots_dir() / name / SELF_COLLISION_FILE,
            stats,
            samples=args.samples,
            seed=args.seed,
            never_m=NEVER_M,
        )
        print(f"{name}: {args.samples} samples in {time.perf_counter() - t0:.0f} s")
        for s in stats:
            share = maker.get(frozenset(s.links))
            print(
                f"  {s.links[0]:10} {s.links[1]:10} {s.reason or 'checked':9} "
                f"least {s.min_distance_m * 1e3:8.1f} mm  in contact {s.contact_fraction:7.2%}"
                + (f"  (maker's meshes {share:.1%})" if share is not None else "")
            )


if __name__ == "__main__":
    main()
