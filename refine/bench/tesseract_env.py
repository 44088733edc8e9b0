"""Tesseract's environment of a benchmark problem, made from refine's own files (the ``peers`` extra).

One environment per problem (:func:`tesseract_environment`, kept in ``problem.extra``): the
robot's URDF with the world, the TCP, the tool shapes and the cell added (:func:`compose_urdf`),
its joint limits narrowed by the problem's joint margin, an SRDF that disables every link pair the
problem's collision model does not check, KDL's IK and Bullet's contact managers from the
``tesseract-robotics`` wheel. A problem that brings Tesseract's own workcell files
(``problem.extra["tesseract_files"]``: the puzzle piece as Tesseract poses it) is loaded from them.
"""

from __future__ import annotations

import glob
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from refine.bench.contenders import Unavailable
from refine.bench.suites import BenchProblem
from refine.types import Array

KDL_EPS = 1e-10
"""The KDL IK's stopping tolerance on its pose error [m and rad] (KDL's default 1e-5 leaves
micrometres: refine's verifier holds the position to 1 µm)."""

WORLD, TCP = "refine_world", "refine_tcp"
"""The links the composed environment adds: the world (the root) and the TCP on the flange."""


def _import_tesseract() -> dict[str, Any]:
    os.environ.setdefault("TRAJOPT_LOG_THRESH", "ERROR")  # TrajOpt's own log, read when it loads
    try:
        import tesseract_robotics
        from tesseract_robotics import tesseract_command_language as cl
        from tesseract_robotics import tesseract_common as common
        from tesseract_robotics import tesseract_environment as environment
        from tesseract_robotics import tesseract_motion_planners as planners
        from tesseract_robotics import tesseract_motion_planners_descartes as descartes_
        from tesseract_robotics import tesseract_motion_planners_trajopt as trajopt_
    except ImportError as e:
        raise Unavailable(f"tesseract-robotics is not installed ({e}); pip install '.[peers]'") from e
    return {
        "root": Path(tesseract_robotics.__file__).resolve().parent,
        "cl": cl,
        "common": common,
        "environment": environment,
        "planners": planners,
        "descartes": descartes_,
        "trajopt": trajopt_,
    }


def _plugin_library(libs: Path, stem: str) -> str:
    """The name a plugin loader takes for ``lib<stem>*.so`` in the wheel's library folder."""
    found = sorted(glob.glob(str(libs / f"lib{stem}*.so")))
    if not found:
        raise Unavailable(f"tesseract-robotics has no {stem} library in {libs}")
    return Path(found[0]).name[3:-3]


def _origin(T: Array) -> dict[str, str]:
    from scipy.spatial.transform import Rotation

    rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")
    return {"xyz": " ".join(f"{v:.12g}" for v in T[:3, 3]), "rpy": " ".join(f"{v:.12g}" for v in rpy)}


def _geometry(body: Any, folder: Path) -> ET.Element:
    """The URDF geometry of one body of refine's collision model, as refine measures it.

    Primitives as they are; a convex piece and a mesh as a mesh file of the vertices refine uses
    (written into ``folder``), in the body's shape frame [m].
    """
    import trimesh

    geometry = ET.Element("geometry")
    kind = body.kind_params[0]
    if kind == "box":
        ET.SubElement(geometry, "box", size=" ".join(f"{2.0 * v:.12g}" for v in body.kind_params[1]))
    elif kind == "cylinder":
        _, radius, half = body.kind_params
        ET.SubElement(geometry, "cylinder", radius=f"{radius:.12g}", length=f"{2.0 * half:.12g}")
    elif kind == "sphere":
        ET.SubElement(geometry, "sphere", radius=f"{body.kind_params[1]:.12g}")
    else:
        if kind == "convex":
            mesh = trimesh.convex.convex_hull(np.asarray(body.kind_params[1], dtype=float))
        else:
            mesh = trimesh.Trimesh(np.asarray(body.vertices), np.asarray(body.faces), process=False)
        path = folder / f"{body.label.replace('/', '_').replace(':', '_')}.stl"
        mesh.export(path)
        ET.SubElement(geometry, "mesh", filename=str(path))
    return geometry


def _add_link(
    root: ET.Element,
    name: str,
    parent: str,
    T_parent_link: Array,
    body: Any = None,
    folder: Path | None = None,
) -> None:
    link = ET.SubElement(root, "link", name=name)
    if body is not None and folder is not None:
        collision = ET.SubElement(link, "collision")
        ET.SubElement(collision, "origin", _origin(np.eye(4)))
        collision.append(_geometry(body, folder))
    joint = ET.SubElement(root, "joint", name=f"{parent}-{name}", type="fixed")
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=name)
    ET.SubElement(joint, "origin", _origin(T_parent_link))


def _narrow_limits(problem: BenchProblem, root: ET.Element) -> None:
    """Narrow the limits of the robot's revolute joints in a URDF tree by the problem's joint margin."""
    margin = math.radians(problem.tolerances.joint_margin_deg)
    joints = set(problem.robot.spec.joint_names)
    for joint in root.iter("joint"):
        limit = joint.find("limit")
        if joint.get("name") in joints and limit is not None and joint.get("type") == "revolute":
            limit.set("lower", f"{float(limit.get('lower')) + margin:.12g}")
            limit.set("upper", f"{float(limit.get('upper')) - margin:.12g}")


def _narrowed(problem: BenchProblem, urdf_text: str) -> str:
    root = ET.fromstring(urdf_text)
    _narrow_limits(problem, root)
    return ET.tostring(root, encoding="unicode")


def cell_model(problem: BenchProblem) -> Any:
    """The problem's collision model (of its clearance source), or None without a cell."""
    for source in problem.sources:
        model = getattr(source, "model", None)
        if model is not None:
            return model
    return None


def compose_urdf(problem: BenchProblem, folder: Path) -> tuple[str, list[tuple[str, str]]]:
    """The robot's URDF with the world, the TCP, the tool shapes and the cell added, and the link pairs to check.

    The robot's own collision geometry is the URDF's (mesh paths made absolute); its joint limits
    are narrowed by the problem's joint margin, so every peer keeps the margin the verification
    checks. Tool shapes become links fixed to the flange, cell objects links fixed to the world,
    each with the geometry refine's collision model measures (:func:`_geometry`).

    Returns:
        the URDF text and the link pairs the problem's collision model checks (every other pair of
        links is disabled in the SRDF, so the peers check what refine checks).
    """
    robot = problem.robot
    urdf = Path(robot.spec.urdf)
    tree = ET.parse(urdf)
    root = tree.getroot()
    for mesh in root.iter("mesh"):
        name = mesh.get("filename", "")
        if not name.startswith(("/", "package://", "file://")):
            mesh.set("filename", str((urdf.parent / name).resolve()))
    _narrow_limits(problem, root)
    children = {c.get("link") for c in root.iter("child")}
    (base,) = [link.get("name") for link in root.findall("link") if link.get("name") not in children]
    flange = robot.spec.flange_frame
    _add_link(root, WORLD, WORLD, np.eye(4))  # placeholder joint removed below
    root.remove(root.findall("joint")[-1])
    joint = ET.SubElement(root, "joint", name=f"{WORLD}-{base}", type="fixed")
    ET.SubElement(joint, "parent", link=WORLD)
    ET.SubElement(joint, "child", link=base)
    ET.SubElement(joint, "origin", _origin(problem.base_in_world))
    _add_link(root, TCP, flange, problem.tcp_in_flange)
    pairs: list[tuple[str, str]] = []
    model = cell_model(problem)
    if model is not None:
        link_of: dict[str, str] = {}
        for body in model.bodies:
            if body.kind == "link":
                link_of[body.label] = body.link
            elif body.kind == "tool":
                name = f"tool_{body.name.split(':', 1)[-1]}"
                link_of[body.label] = name
                _add_link(root, name, flange, body.link_T_shape, body, folder)
            else:
                name = f"cell_{body.name}"
                link_of[body.label] = name
                _add_link(root, name, WORLD, body.link_T_shape, body, folder)
        pairs = sorted({tuple(sorted((link_of[a], link_of[b]))) for a, b in model.pairs})
    return ET.tostring(root, encoding="unicode"), pairs


def _srdf(problem: BenchProblem, urdf_text: str, pairs: list[tuple[str, str]], folder: Path) -> str:
    root = ET.fromstring(urdf_text)
    links = sorted(link.get("name") for link in root.findall("link"))
    children = {c.get("link") for c in root.iter("child")}
    base = next(
        j.find("child").get("link") for j in root.findall("joint") if j.find("parent").get("link") == WORLD
    )
    del children
    srdf = ET.Element("robot", name=root.get("name", "robot"))
    group = ET.SubElement(srdf, "group", name="manipulator")
    ET.SubElement(group, "chain", base_link=base, tip_link=TCP)
    ET.SubElement(srdf, "kinematics_plugin_config", filename=str(folder / "kinematics.yaml"))
    ET.SubElement(srdf, "contact_managers_plugin_config", filename=str(folder / "contact_managers.yaml"))
    checked = set(pairs)
    for i, a in enumerate(links):
        for b in links[i + 1 :]:
            if (a, b) not in checked:
                ET.SubElement(srdf, "disable_collisions", link1=a, link2=b, reason="Never")
    return ET.tostring(srdf, encoding="unicode")


def tesseract_environment(problem: BenchProblem) -> Any:
    """Tesseract's environment of the problem (robot, TCP, tool shapes, cell), made once and kept.

    Raises:
        Unavailable: without tesseract-robotics, or when its environment does not load.
    """
    if "tesseract_env" in problem.extra:
        return problem.extra["tesseract_env"]
    t = _import_tesseract()
    libs = t["root"].parent / "tesseract_robotics.libs"
    folder = Path(tempfile.mkdtemp(prefix="refine-peers-"))
    given = problem.extra.get("tesseract_files")
    tcp_frame, working_frame, tip = TCP, WORLD, TCP
    if given is not None:  # the peers' own workcell (a stationary tool): its URDF and SRDF as they stand
        urdf_text = _narrowed(problem, Path(given["urdf"]).read_text())
        pairs = None
        tcp_frame, working_frame, tip = given["tcp_frame"], given["working_frame"], given["tip_link"]
        srdf_text = Path(given["srdf"]).read_text()
        srdf_root = ET.fromstring(srdf_text)
        group = srdf_root.find("group[@name='manipulator']/chain")
        base = group.get("base_link")
        for old in list(srdf_root):
            if old.tag in ("contact_managers_plugin_config", "kinematics_plugin_config"):
                srdf_root.remove(old)
        ET.SubElement(srdf_root, "kinematics_plugin_config", filename=str(folder / "kinematics.yaml"))
        ET.SubElement(
            srdf_root, "contact_managers_plugin_config", filename=str(folder / "contact_managers.yaml")
        )
        srdf_text = ET.tostring(srdf_root, encoding="unicode")
    else:
        base = None
        urdf_text, pairs = compose_urdf(problem, folder)
        for j in ET.fromstring(urdf_text).findall("joint"):
            if j.find("parent").get("link") == WORLD:
                base = j.find("child").get("link")
        srdf_text = None
    (folder / "kinematics.yaml").write_text(
        "kinematic_plugins:\n"
        f"  search_paths: [{libs}]\n"
        f"  search_libraries: [{_plugin_library(libs, 'tesseract_kinematics_kdl_factories')}]\n"
        "  inv_kin_plugins:\n"
        "    manipulator:\n"
        "      default: KDLInvKinChainLMA\n"
        "      plugins:\n"
        "        KDLInvKinChainLMA:\n"
        "          class: KDLInvKinChainLMAFactory\n"
        f"          config: {{base_link: {base}, tip_link: {tip}, eps: {KDL_EPS}}}\n"
    )
    (folder / "contact_managers.yaml").write_text(
        "contact_manager_plugins:\n"
        f"  search_paths: [{libs}]\n"
        f"  search_libraries: [{_plugin_library(libs, 'tesseract_collision_bullet_factories')}]\n"
        "  discrete_plugins:\n"
        "    default: BulletDiscreteBVHManager\n"
        "    plugins:\n"
        "      BulletDiscreteBVHManager: {class: BulletDiscreteBVHManagerFactory}\n"
        "  continuous_plugins:\n"
        "    default: BulletCastBVHManager\n"
        "    plugins:\n"
        "      BulletCastBVHManager: {class: BulletCastBVHManagerFactory}\n"
    )
    (folder / "cell.urdf").write_text(urdf_text)
    (folder / "cell.srdf").write_text(srdf_text or _srdf(problem, urdf_text, pairs or [], folder))
    env = t["environment"].Environment()
    locator = t["common"].GeneralResourceLocator()
    if not env.init(
        t["common"].FilesystemPath(str(folder / "cell.urdf")),
        t["common"].FilesystemPath(str(folder / "cell.srdf")),
        locator,
    ):
        raise Unavailable(f"Tesseract's environment of {problem.name} did not load (files in {folder})")
    names = list(env.getJointGroup("manipulator").getJointNames())
    if names != list(problem.robot.spec.joint_names):
        raise Unavailable(
            f"Tesseract's joint group {names} is not refine's {list(problem.robot.spec.joint_names)}"
        )
    manip = t["common"].ManipulatorInfo()
    manip.manipulator = "manipulator"
    manip.tcp_frame = tcp_frame
    manip.working_frame = working_frame
    manip.manipulator_ik_solver = "KDLInvKinChainLMA"
    problem.extra["tesseract_env"] = (t, env, manip, locator, names, folder)
    return problem.extra["tesseract_env"]
