"""Sample the registry robots' self-collision matrices and write ``robots/<robot>/self_collision.toml``.

    python3 robots/make_self_collision.py [--robots ur10e ...] [--samples 20000] [--seed 1]
        [--meshes ../shared/robot-meshes]

Run it again whenever a robot's shapes change (``robots/make_shapes.py``). Prints every pair's
reason, least distance and share of samples in contact. A pair the sample leaves checked is disabled
as ``"maker"`` when the maker's own collision meshes (the reference description, when present) are
in contact at :data:`MAKER_FRACTION` of ``--samples // 10`` random configurations or more: there the
meshes overlap where the real parts pass each other.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import fcl
import numpy as np
import pinocchio as pin
import trimesh
from make_shapes import joint_links

from refine.robot.registry import available_robots, load_robot, robots_dir
from refine.robot.self_collision import NEVER_M, sample_matrix, write_matrix
from refine.robot.spec import SELF_COLLISION_FILE

HERE = Path(__file__).resolve().parent
MAKER_FRACTION = 0.2
"""Share of samples in contact on the maker's meshes from which a pair is disabled as ``"maker"``."""


def maker_contacts(robot, folder: Path, samples: int, seed: int) -> dict[frozenset[str], float]:  # noqa: ANN001
    """Per pair of the project's links, the share of random configurations where the maker's meshes touch.

    The maker's meshes are those of ``folder/reference.urdf``; its joints are in the project's order.
    """
    ref, geometry, _ = pin.buildModelsFromUrdf(str(folder / "reference.urdf"), package_dirs=[str(folder)])
    links = joint_links(Path(robot.spec.urdf))
    link_of = {k: links[robot.model.names[g.parentJoint]] for k, g in enumerate(geometry.geometryObjects)}
    models = []
    for g in geometry.geometryObjects:
        mesh = trimesh.load(g.meshPath, force="mesh")
        bvh = fcl.BVHModel()
        bvh.beginModel(len(mesh.vertices), len(mesh.faces))
        bvh.addSubModel(np.asarray(mesh.vertices) * np.asarray(g.meshScale), np.asarray(mesh.faces))
        bvh.endModel()
        models.append(bvh)
    data, gdata = ref.createData(), geometry.createData()
    count: dict[frozenset[str], int] = {}
    for q in np.random.default_rng(seed).uniform(
        robot.spec.lower, robot.spec.upper, size=(samples, robot.nq)
    ):
        pin.forwardKinematics(ref, data, q)
        pin.updateGeometryPlacements(ref, data, geometry, gdata)
        objects = [
            fcl.CollisionObject(m, fcl.Transform(gdata.oMg[k].rotation, gdata.oMg[k].translation))
            for k, m in enumerate(models)
        ]
        for a in range(len(models)):
            for b in range(a + 1, len(models)):
                if link_of[a] != link_of[b] and fcl.collide(
                    objects[a], objects[b], fcl.CollisionRequest(), fcl.CollisionResult()
                ):
                    pair = frozenset((link_of[a], link_of[b]))
                    count[pair] = count.get(pair, 0) + 1
    return {pair: n / samples for pair, n in count.items()}


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
            maker = maker_contacts(robot, args.meshes / name, args.samples // 10, args.seed)
        stats = [
            dataclasses.replace(s, reason="maker")
            if not s.reason and maker.get(frozenset(s.links), 0.0) >= MAKER_FRACTION
            else s
            for s in stats
        ]
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
