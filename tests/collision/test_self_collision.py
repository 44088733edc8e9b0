"""The registry robots' sampled self-collision matrices, checked against a fresh sample."""

from __future__ import annotations

import itertools
from pathlib import Path

import fcl
import numpy as np
import pinocchio as pin
import pytest
import trimesh
from lxml import etree

from refine.collision import CollisionModel
from refine.errors import InputError
from refine.robot.registry import available_robots, load_robot
from refine.robot.self_collision import read_matrix
from refine.robot.spec import SELF_COLLISION_FILE

NAMES = available_robots()


def _links_with_shapes(robot):
    return list(dict.fromkeys(s.link for s in robot.collision_shapes()))


def _urdf_neighbours(robot):
    """Link pairs joined by one URDF joint, or by a chain of fixed joints plus at most one moving one."""
    root = etree.parse(str(robot.spec.urdf)).getroot()
    parent = {
        j.find("child").get("link"): (j.find("parent").get("link"), j.get("type")) for j in root.iter("joint")
    }

    def body(link):  # the link's rigid body: climb fixed joints
        while link in parent and parent[link][1] == "fixed":
            link = parent[link][0]
        return link

    def parent_body(link):
        b = body(link)
        return body(parent[b][0]) if b in parent else None

    links = _links_with_shapes(robot)
    return {
        frozenset((a, b))
        for a, b in itertools.combinations(links, 2)
        if body(a) == body(b) or parent_body(a) == body(b) or parent_body(b) == body(a)
    }


@pytest.mark.parametrize("name", NAMES)
def test_the_matrix_names_every_pair_of_links_once_and_adjacent_means_joint_neighbours(name):
    robot = load_robot(name)
    path = robot.spec.urdf.parent / SELF_COLLISION_FILE
    text = path.read_text()
    links = _links_with_shapes(robot)
    assert text.count("[[pair]]") == len(links) * (len(links) - 1) // 2
    matrix = read_matrix(path)
    adjacent = {pair for pair, why in matrix.items() if why == "adjacent"}
    assert adjacent == _urdf_neighbours(robot)


@pytest.mark.parametrize("name", NAMES)
def test_a_fresh_sample_agrees_with_the_matrix(name):
    """'never' pairs stay apart and 'always' pairs stay in contact at 1,500 new random configurations."""
    robot = load_robot(name)
    matrix = robot.self_collision()
    shapes = robot.collision_shapes()
    rng = np.random.default_rng(2024)
    never = [tuple(sorted(p)) for p, why in matrix.items() if why == "never"]
    always = [tuple(sorted(p)) for p, why in matrix.items() if why == "always"]
    assert never, "a 6- or 7-axis arm has links that can never meet"
    for q in rng.uniform(robot.spec.lower, robot.spec.upper, size=(1500, robot.nq)):
        poses = robot.link_poses(q)
        objects = {}
        for s in shapes:
            objects.setdefault(s.link, []).append(s.collision_object(poses[s.link]))

        def touching(a, b, objects=objects):
            return any(
                fcl.collide(x, y, fcl.CollisionRequest(), fcl.CollisionResult())
                for x in objects[a]
                for y in objects[b]
            )

        for a, b in never:
            assert not touching(a, b), f"{name}: 'never' pair {a}, {b} in contact at q = {q}"
        for a, b in always:
            assert touching(a, b), f"{name}: 'always' pair {a}, {b} apart at q = {q}"


MESHES = Path(__file__).resolve().parents[2].parent / "shared" / "robot-meshes"


@pytest.mark.parametrize("name", NAMES)
def test_maker_pairs_touch_on_the_makers_own_meshes(name):
    """A pair disabled as 'maker' is in contact on the maker's reference meshes at >= 20 % of 300
    fresh random configurations (the link of a reference mesh: the one its joint moves)."""
    robot = load_robot(name)
    maker = [tuple(sorted(p)) for p, why in robot.self_collision().items() if why == "maker"]
    if not maker:
        return
    folder = MESHES / name
    if not (folder / "reference.urdf").is_file():
        pytest.skip(f"reference meshes not found at {folder}")
    ref, geometry, _ = pin.buildModelsFromUrdf(str(folder / "reference.urdf"), package_dirs=[str(folder)])
    link_of_joint = {
        int(robot.model.frames[robot.frame_id(s.link)].parentJoint): s.link for s in robot.collision_shapes()
    }
    bodies = {}
    for k, g in enumerate(geometry.geometryObjects):
        mesh = trimesh.load(g.meshPath, force="mesh")
        bvh = fcl.BVHModel()
        bvh.beginModel(len(mesh.vertices), len(mesh.faces))
        bvh.addSubModel(np.asarray(mesh.vertices), np.asarray(mesh.faces))
        bvh.endModel()
        bodies[link_of_joint[g.parentJoint]] = (k, bvh)
    data, gdata = ref.createData(), geometry.createData()
    hits = dict.fromkeys(maker, 0)
    for q in np.random.default_rng(99).uniform(robot.spec.lower, robot.spec.upper, size=(300, robot.nq)):
        pin.forwardKinematics(ref, data, q)
        pin.updateGeometryPlacements(ref, data, geometry, gdata)

        def placed(link, gdata=gdata):
            k, bvh = bodies[link]
            return fcl.CollisionObject(bvh, fcl.Transform(gdata.oMg[k].rotation, gdata.oMg[k].translation))

        for a, b in maker:
            hits[(a, b)] += fcl.collide(placed(a), placed(b), fcl.CollisionRequest(), fcl.CollisionResult())
    for pair, n in hits.items():
        assert n >= 60, (
            f"{name}: 'maker' pair {pair} touches on the maker's meshes at only {n} of 300 samples"
        )


def test_the_model_checks_exactly_the_pairs_the_matrix_enables():
    robot = load_robot("abb_irb4600_60_205")
    model = CollisionModel(robot, np.eye(4), np.eye(4), (), (), margin_m=0.01, self_margin_m=0.005)
    matrix = robot.self_collision()
    checked = {frozenset(label.split("/")[0] for label in pair) for pair in model.pairs}
    links = _links_with_shapes(robot)
    enabled = {frozenset(p) for p in itertools.combinations(links, 2) if frozenset(p) not in matrix}
    assert checked == enabled
    reasons = {why for *_, why in model.excluded}
    assert reasons <= {"same body", "matrix: adjacent", "matrix: always", "matrix: never", "matrix: maker"}


@pytest.mark.parametrize("a6_deg", [115.0, -115.0])
def test_the_iiwa_bends_its_wrist_to_115_deg_without_self_contact(a6_deg):
    """On the makers' meshes link 5 and link 7 stay >= 31 mm apart up to A6 = 119 deg. The shapes
    (measured directly, whatever the matrix checks) keep them apart too, and the model reports no
    contact among the wrist links (other joints sampled within their limits)."""
    robot = load_robot("kuka_iiwa14_r820")
    model = CollisionModel(robot, np.eye(4), np.eye(4), (), (), margin_m=0.01, self_margin_m=0.005)
    shapes = robot.collision_shapes()
    rng = np.random.default_rng(11)
    wrist = {"link_5", "link_6", "link_7"}
    for q in rng.uniform(robot.spec.lower, robot.spec.upper, size=(300, robot.nq)):
        q[5] = np.radians(a6_deg)
        poses = robot.link_poses(q)
        five = [s.collision_object(poses[s.link]) for s in shapes if s.link == "link_5"]
        seven = [s.collision_object(poses[s.link]) for s in shapes if s.link == "link_7"]
        gap = min(
            fcl.distance(x, y, fcl.DistanceRequest(), fcl.DistanceResult()) for x in five for y in seven
        )
        assert gap > 0.01, f"link_5 and link_7 only {gap * 1e3:.1f} mm apart at q = {q}"
        for c in model.contacts(q, 0.0):
            assert not ({c.body, c.other} <= wrist), f"{c.body} vs {c.other} at {c.distance_m * 1e3:.1f} mm"


def test_a_bad_reason_is_an_input_error(tmp_path):
    path = tmp_path / SELF_COLLISION_FILE
    path.write_text('[[pair]]\nlinks = ["a", "b"]\nreason = "sometimes"\n')
    with pytest.raises(InputError, match="reason 'sometimes' is not one of adjacent, always, never, maker"):
        read_matrix(path)
