"""Compute the registry robots' collision shapes from their makers' reference collision meshes.

For every link, the reference mesh (``../shared/robot-meshes/<robot>/``, loaded with Pinocchio from
its ``reference.urdf``) is carried into the frame of the same link of ``robots/<robot>/robot.urdf``
(the two descriptions agree kinematically but lay out their link frames differently; the mesh is
moved through the world at the zero configuration, and the shapes test checks the match at random
configurations), covered by a few convex polytopes and written as
``robots/<robot>/collision/<link>_<k>.obj`` by :func:`refine.robot.shapes.make_link_shapes` (the code
``refine robots import`` uses, with its settings :data:`refine.robot.shapes.SETTINGS`). The
``<collision>`` and ``<visual>`` elements of the robot's URDF are rewritten to name these files;
nothing else in the URDF changes.

    python3 robots/make_shapes.py [--robots ur10e ...] [--meshes ../shared/robot-meshes]

Needs ``rtree`` for the overshoot measurement. Prints, per link, the pieces, their faces, how far
the reference mesh lies outside them and how far they reach beyond it.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
import pinocchio as pin
import trimesh

from refine.robot.shapes import joint_links, make_link_shapes, rewrite_urdf

HERE = Path(__file__).resolve().parent
ROBOTS = ("abb_irb4600_60_205", "kuka_iiwa14_r820", "kuka_kr8_r1440_2_arc_hw", "ur10e")
REFERENCE_FLANGE = {"kuka_iiwa14_r820": "lbr_link_ee"}
"""The reference's flange frame where it is not ``tool0``."""
ROBOT_SETTINGS = {
    "kuka_iiwa14_r820": {"max_overshoot_m": 0.010, "tolerance_m": 0.005},
    "kuka_kr8_r1440_2_arc_hw": {"max_pieces": 5, "tolerance_m": 0.004, "mixed": True, "cuts": 8},
}
"""Tighter for the iiwa, whose round housings leave hulls loose in the waist between them. The KR 8's
reference meshes are coarse (faces up to tens of mm, many separate shells), which the fast overshoot
estimate handles poorly: its cuts are ranked by the exact measure and may differ in direction."""


def reference_meshes(robot: str, meshes: Path) -> dict[str, trimesh.Trimesh]:
    """Each reference collision mesh in the frame of the project's link moved by the same joint [m]."""
    folder = meshes / robot
    ref, ref_geometry, _ = pin.buildModelsFromUrdf(str(folder / "reference.urdf"), package_dirs=[str(folder)])
    urdf = HERE / robot / "robot.urdf"
    own = pin.buildModelFromUrdf(str(urdf))
    if ref.nq != own.nq:
        raise SystemExit(f"{robot}: the reference has {ref.nq} joints, the project's model {own.nq}")
    links = joint_links(urdf)
    ref_data, own_data = ref.createData(), own.createData()
    pin.forwardKinematics(ref, ref_data, pin.neutral(ref))
    pin.forwardKinematics(own, own_data, pin.neutral(own))
    pin.updateFramePlacements(own, own_data)
    pin.updateFramePlacements(ref, ref_data)
    # the references' world may differ from the project's base (UR: ROS base_link is the controller's
    # Base turned 180 deg about z); the flanges agree, so they give the one from the other
    T_own_ref = own_data.oMf[own.getFrameId("tool0")].homogeneous @ np.linalg.inv(
        ref_data.oMf[ref.getFrameId(REFERENCE_FLANGE.get(robot, "tool0"))].homogeneous
    )
    out: dict[str, trimesh.Trimesh] = {}
    for g in ref_geometry.geometryObjects:
        own_joint = own.names[g.parentJoint]  # joints in the same order in both descriptions
        link = links[own_joint]
        T_world_link = own_data.oMf[own.getFrameId(link)].homogeneous
        T_world_mesh = T_own_ref @ ref_data.oMi[g.parentJoint].homogeneous @ g.placement.homogeneous
        mesh = trimesh.load(g.meshPath, force="mesh")
        mesh.vertices = mesh.vertices * np.asarray(g.meshScale)
        mesh.apply_transform(np.linalg.inv(T_world_link) @ T_world_mesh)
        if link in out:
            out[link] = trimesh.util.concatenate([out[link], mesh])
        else:
            out[link] = mesh
    return out


def make(robot: str, meshes: Path) -> None:
    """Write one robot's shapes and rewrite its URDF; print what they are."""
    print(f"{robot}:")
    shapes = make_link_shapes(
        reference_meshes(robot, meshes),
        HERE / robot,
        robot,
        "the reference collision mesh by robots/make_shapes.py",
        **ROBOT_SETTINGS.get(robot, {}),
    )
    for s in shapes:
        faces = ", ".join(f"{p.plane_count} faces/{len(p.faces)} triangles" for p in s.pieces)
        print(
            f"  {s.link:12} {len(s.pieces)} piece(s): {faces}; {max(s.outside_m, 0.0) * 1e3:.1f} mm of the "
            f"mesh outside, {s.overshoot_m * 1e3:.1f} mm beyond the mesh at most"
        )
    rewrite_urdf(HERE / robot / "robot.urdf", {s.link: s.files for s in shapes})


def main() -> None:
    """Make the chosen robots' shapes."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS))
    parser.add_argument("--meshes", type=Path, default=HERE.parent.parent / "shared" / "robot-meshes")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    for robot in args.robots:
        make(robot, args.meshes)


if __name__ == "__main__":
    main()
