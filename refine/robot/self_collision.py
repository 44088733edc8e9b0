"""A robot's self-collision matrix: which pairs of its links are never checked against each other.

As robot set-up tools do, the matrix comes from sampling: at many random configurations within the
joint limits every pair of links is measured, and a pair is disabled when it is

* ``"adjacent"``: the two links are moved by the same joint or by a joint and its parent (they meet
  at that joint, and their collision meshes overlap there by design);
* ``"always"``: in contact at every sample (a housing around a joint that is not adjacent in the
  tree, e.g. a wrist's first and last links; no motion can separate them);
* ``"never"``: never closer than ``never_m`` at any sample;
* ``"maker"``: in contact on the maker's own collision meshes at a sizeable share of the samples
  (``robots/make_self_collision.py`` measures it on the reference meshes): the meshes overlap where
  the real parts pass each other (a hollow wrist's flange beside the A4 housing), so a contact
  between them says nothing.

Every other pair is checked. The matrix is written per robot as ``self_collision.toml`` next to its
URDF (:func:`write_matrix`) by ``robots/make_self_collision.py``, and read by
:meth:`refine.robot.model.Robot.self_collision`.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, replace
from pathlib import Path

import fcl
import numpy as np
import pinocchio as pin

from refine.errors import InputError

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

log = logging.getLogger(__name__)

REASONS = ("adjacent", "always", "never", "maker")
NEVER_M = 0.01
"""A pair is disabled as ``"never"`` when no sample brings it closer than this [m]."""
MAKER_FRACTION = 0.2
"""Share of samples in contact on the maker's meshes from which a pair is disabled as ``"maker"``."""


@dataclass(frozen=True)
class PairStats:
    """What the samples showed of one link pair.

    Attributes:
        links: the two link names, sorted.
        reason: why the pair is disabled (one of :data:`REASONS`), or ``""`` when it is checked.
        min_distance_m: the least distance over the samples [m] (negative: in contact).
        contact_fraction: share of the samples with the two in contact.
    """

    links: tuple[str, str]
    reason: str
    min_distance_m: float
    contact_fraction: float


def adjacent(model: pin.Model, joint_a: int, joint_b: int) -> bool:
    """Whether two bodies' joints are the same or one is the other's parent."""
    return joint_a == joint_b or model.parents[joint_a] == joint_b or model.parents[joint_b] == joint_a


def sample_matrix(robot, samples: int, seed: int, never_m: float = NEVER_M) -> list[PairStats]:  # noqa: ANN001
    """Measure every pair of the robot's links at ``samples`` random configurations.

    Args:
        robot: a :class:`refine.robot.model.Robot` with collision shapes.
        samples: random configurations, uniform within the joint limits.
        seed: seed of the random generator.
        never_m: the distance a pair must always keep to be disabled as ``"never"`` [m].

    Returns:
        One entry per pair of links with shapes, in link order.
    """
    if samples < 1:
        raise InputError(f"self-collision matrix: samples must be >= 1, got {samples}")
    shapes = robot.collision_shapes()
    links = list(dict.fromkeys(s.link for s in shapes))
    joint = {link: int(robot.model.frames[robot.frame_id(link)].parentJoint) for link in links}
    objects = {
        link: [(s, fcl.CollisionObject(s.geometry)) for s in shapes if s.link == link] for link in links
    }
    pairs = [
        (a, b) for a, b in itertools.combinations(links, 2) if not adjacent(robot.model, joint[a], joint[b])
    ]
    least = dict.fromkeys(pairs, np.inf)
    contacts = dict.fromkeys(pairs, 0)
    rng = np.random.default_rng(seed)
    request = fcl.CollisionRequest()
    for q in rng.uniform(robot.spec.lower, robot.spec.upper, size=(samples, robot.nq)):
        poses = robot.link_poses(q)
        for link, items in objects.items():
            for s, obj in items:
                T = poses[link] @ s.link_T_shape
                obj.setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))
        for a, b in pairs:
            touching = any(
                fcl.collide(oa, ob, request, fcl.CollisionResult())
                for _, oa in objects[a]
                for _, ob in objects[b]
            )
            if touching:
                contacts[(a, b)] += 1
                least[(a, b)] = min(least[(a, b)], 0.0)
            elif least[(a, b)] > never_m:  # only a pair that may still be "never" needs its distance
                d = min(
                    fcl.distance(oa, ob, fcl.DistanceRequest(), fcl.DistanceResult())
                    for _, oa in objects[a]
                    for _, ob in objects[b]
                )
                least[(a, b)] = min(least[(a, b)], float(d))
    out = []
    for a, b in itertools.combinations(links, 2):
        if (a, b) not in least:
            out.append(PairStats((a, b), "adjacent", -np.inf, 1.0))
            continue
        fraction = contacts[(a, b)] / samples
        reason = "always" if contacts[(a, b)] == samples else "never" if least[(a, b)] > never_m else ""
        out.append(PairStats((a, b), reason, float(least[(a, b)]), fraction))
    return out


def maker_contacts(
    robot,  # noqa: ANN001 - Robot
    reference_urdf: str | Path,
    samples: int,
    seed: int,
    package_dirs: tuple[str, ...] = (),
) -> dict[frozenset[str], float]:
    """Per pair of the robot's links, the share of random configurations where the maker's meshes touch.

    The maker's meshes are the ``<collision>`` meshes of ``reference_urdf`` (loaded with Pinocchio,
    relative names found in ``package_dirs``), whose joints are in the robot's order.
    """
    import trimesh

    from refine.robot.shapes import joint_links

    ref, geometry, _ = pin.buildModelsFromUrdf(str(reference_urdf), package_dirs=list(package_dirs))
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


def with_maker(
    stats: list[PairStats], maker: dict[frozenset[str], float], fraction: float = MAKER_FRACTION
) -> list[PairStats]:
    """``stats`` with each checked pair disabled as ``"maker"`` whose maker's meshes touch often.

    Often: at ``fraction`` of the samples of :func:`maker_contacts` or more.
    """
    return [
        replace(s, reason="maker") if not s.reason and maker.get(frozenset(s.links), 0.0) >= fraction else s
        for s in stats
    ]


def write_matrix(
    path: str | Path, stats: list[PairStats], *, samples: int, seed: int, never_m: float
) -> None:
    """Write the matrix as TOML: the sampling settings and one ``[[pair]]`` per pair of links."""
    lines = [
        "# Self-collision matrix: which link pairs are checked. Written by robots/make_self_collision.py",
        "# from random configurations within the joint limits; see refine/robot/self_collision.py.",
        "# reason: adjacent (joint neighbours), always (in contact at every sample), never (never closer",
        "# than never_m), maker (in contact on the maker's own meshes at a sizeable share of samples),",
        '# or "" (checked).',
        f"samples = {samples}",
        f"seed = {seed}",
        f"never_m = {never_m}",
        "",
    ]
    for s in stats:
        lines += [
            "[[pair]]",
            f'links = ["{s.links[0]}", "{s.links[1]}"]',
            f'reason = "{s.reason}"',
        ]
        if np.isfinite(s.min_distance_m):
            lines += [
                f"min_distance_mm = {s.min_distance_m * 1e3:.1f}",
                f"contact_fraction = {s.contact_fraction:.4f}",
            ]
        lines.append("")
    Path(path).write_text("\n".join(lines), encoding="utf-8")


def read_matrix(path: str | Path) -> dict[frozenset[str], str]:
    """The disabled pairs of a matrix file: ``{frozenset({link_a, link_b}): reason}``.

    Raises:
        InputError: naming the file if it cannot be read or a pair is malformed.
    """
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise InputError(f"cannot read self-collision matrix {path}: {e}") from e
    disabled: dict[frozenset[str], str] = {}
    for k, pair in enumerate(data.get("pair", [])):
        links, reason = pair.get("links"), pair.get("reason")
        if not (isinstance(links, list) and len(links) == 2 and all(isinstance(x, str) for x in links)):
            raise InputError(f"{path}: pair {k + 1}: links must be two link names, got {links!r}")
        if reason not in (*REASONS, ""):
            raise InputError(
                f'{path}: pair {k + 1}: reason {reason!r} is not one of {", ".join(REASONS)} or ""'
            )
        if reason:
            disabled[frozenset(links)] = reason
    return disabled
