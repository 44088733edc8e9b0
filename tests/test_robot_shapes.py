"""The registry robots' collision shapes against their makers' reference collision meshes.

The references (``../shared/robot-meshes/<robot>/reference.urdf`` and its STL files) are loaded with
Pinocchio, independently of the project's model; a link's reference mesh and the project's shapes
of that link are matched by the joint that moves them (same order in both descriptions).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import trimesh
from scipy.spatial import ConvexHull

from refine.robot.registry import load_robot

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "robot-meshes"
NAMES = ["abb_irb4600_60_205", "kuka_iiwa14_r820", "kuka_kr8_r1440_2_arc_hw", "ur10e"]
REFERENCE_FLANGE = {"kuka_iiwa14_r820": "lbr_link_ee"}
TOLERANCE_M = 1e-6
OVERSHOOT_M = 0.025
CONCAVE_OVERSHOOT_M = {
    ("kuka_kr8_r1440_2_arc_hw", 1): 0.038,
    ("kuka_kr8_r1440_2_arc_hw", 2): 0.027,
    ("kuka_kr8_r1440_2_arc_hw", 3): 0.033,
}
"""(robot, joint): links whose concavity a handful of convex pieces cannot follow to 25 mm (see the
robot's README): the KR 8's column, where the A2 drive stands out sideways above the narrower
turntable, its lower arm, a tube between two wider joint housings, and its forearm, the A3 housing
offset from the hollow wrist's tube."""

pytestmark = pytest.mark.skipif(not MESHES.is_dir(), reason=f"reference meshes not found at {MESHES}")


def _reference(name):
    folder = MESHES / name
    model, geometry, _ = pin.buildModelsFromUrdf(str(folder / "reference.urdf"), package_dirs=[str(folder)])
    meshes = [trimesh.load(g.meshPath, force="mesh") for g in geometry.geometryObjects]
    for mesh, g in zip(meshes, geometry.geometryObjects, strict=True):
        mesh.vertices = mesh.vertices * np.asarray(g.meshScale)
    return model, geometry, meshes


def _placed(name, q):
    """Per joint: the reference meshes and the corners of the project's shapes, in the project's base."""
    robot = load_robot(name)
    model, geometry, meshes = _reference(name)
    data, gdata = model.createData(), geometry.createData()
    pin.forwardKinematics(model, data, q)
    pin.updateGeometryPlacements(model, data, geometry, gdata)
    # the reference's world is not always the project's base (UR: turned 180 deg about z); the
    # flanges agree, so the flange pose at zero gives it (random poses then test it)
    T_ref_flange = pin.updateFramePlacement(
        model, data, model.getFrameId(REFERENCE_FLANGE.get(name, "tool0"))
    )
    zero = model.createData()
    pin.forwardKinematics(model, zero, np.zeros(model.nq))
    T_own_ref = robot.fk(np.zeros(robot.nq)) @ np.linalg.inv(
        pin.updateFramePlacement(
            model, zero, model.getFrameId(REFERENCE_FLANGE.get(name, "tool0"))
        ).homogeneous
    )
    np.testing.assert_allclose(T_own_ref @ T_ref_flange.homogeneous, robot.fk(q), atol=1e-9)
    reference: dict[int, list[trimesh.Trimesh]] = {}
    for k, g in enumerate(geometry.geometryObjects):
        placed = meshes[k].copy().apply_transform(T_own_ref @ gdata.oMg[k].homogeneous)
        reference.setdefault(g.parentJoint, []).append(placed)
    poses = robot.link_poses(q)
    shapes: dict[int, list[np.ndarray]] = {}
    for s in robot.collision_shapes():
        joint = robot.model.frames[robot.frame_id(s.link)].parentJoint
        T = poses[s.link] @ s.link_T_shape
        corners = s.convex.vertices @ T[:3, :3].T + T[:3, 3]
        shapes.setdefault(joint, []).append(corners)
    return robot, reference, shapes


def _outside(points, corner_sets):
    """Per point, the least over shapes of the largest face-plane excess (<= 0 inside a shape)."""
    best = np.full(len(points), np.inf)
    for corners in corner_sets:
        eq = ConvexHull(corners).equations  # unit outward normals and offsets: n . x + c <= 0 inside
        best = np.minimum(best, np.max(points @ eq[:, :3].T + eq[:, 3], axis=1))
    return best


def _configurations(robot, count, seed):
    rng = np.random.default_rng(seed)
    lo, hi = robot.spec.lower, robot.spec.upper
    return [np.zeros(robot.nq)] + [rng.uniform(lo, hi) for _ in range(count)]


@pytest.mark.parametrize("name", NAMES)
def test_every_reference_vertex_is_inside_its_links_shapes_at_zero_and_random_poses(name):
    robot = load_robot(name)
    for q in _configurations(robot, 10, seed=7):
        _, reference, shapes = _placed(name, q)
        assert set(reference) <= set(shapes), "a reference link has no shape of the project"
        for joint, meshes in reference.items():
            vertices = np.vstack([m.vertices for m in meshes])
            excess = _outside(vertices, shapes[joint])
            worst = int(np.argmax(excess))
            assert excess[worst] <= TOLERANCE_M, (
                f"{name} joint {robot.model.names[joint]} at q={np.round(q, 3)}: vertex {vertices[worst]} "
                f"is {excess[worst] * 1e3:.2f} mm outside every shape"
            )


@pytest.mark.parametrize("name", NAMES)
def test_no_shape_reaches_more_than_25_mm_beyond_its_reference_mesh(name):
    _, reference, shapes = _placed(name, np.zeros(load_robot(name).nq))
    for joint, corner_sets in shapes.items():
        if joint not in reference:
            continue
        solid = trimesh.util.concatenate(reference[joint])
        for k, corners in enumerate(corner_sets):
            hull = trimesh.convex.convex_hull(corners)
            points = np.vstack([hull.vertices, trimesh.sample.sample_surface(hull, 1500, seed=k)[0]])
            depth = trimesh.proximity.signed_distance(solid, points)  # positive inside the mesh
            limit = CONCAVE_OVERSHOOT_M.get((name, joint), OVERSHOOT_M)
            assert -depth.min() <= limit, f"{name} joint {joint} piece {k}: {-depth.min() * 1e3:.1f} mm"


def test_a_slightly_thinned_shape_fails_the_coverage_check():
    """The forearm's shape shrunk by 3 % about its centre uncovers reference vertices by millimetres."""
    _, reference, shapes = _placed("ur10e", np.zeros(6))
    joint = 3  # the forearm
    vertices = np.vstack([m.vertices for m in reference[joint]])
    corners = shapes[joint][0]
    centre = corners.mean(axis=0)
    thinned = centre + 0.97 * (corners - centre)
    assert _outside(vertices, [corners]).max() <= TOLERANCE_M
    assert _outside(vertices, [thinned]).max() > 0.001
