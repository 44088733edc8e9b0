"""The peers of ``refine bench``: Tesseract's TrajOpt and Descartes (the ``peers`` extra).

Each is posed as a careful user of Tesseract would pose the problem (``tesseract-robotics`` on
PyPI, 0.5): one environment of the robot, its tool and the cell, made from refine's own files
(:func:`tesseract_environment`), and one Cartesian waypoint per path point, the TCP's target pose
in the world.

- TrajOpt (:func:`trajopt`): every waypoint seeded by refine's chained IK of the demonstrated pose
  (the greedy-IK contender, timed as the seed); the position held exactly and the orientation
  inside a tolerance box that lies inside the cone (each rotation-vector component within
  cone/sqrt(3), or within cone/sqrt(2) about x and y and free about the tool axis for an
  axisymmetric tool); collision as a constraint with the problem's cell margin; the joints inside
  their limits less the problem's joint margin; smooth velocities as TrajOpt's default cost.
- Descartes (:func:`descartes`): the same waypoints, sampled about the tool axis (the whole turn
  for an axisymmetric tool in :data:`DESCARTES_SAMPLE_DEG` steps, else three turns within half the
  cone), joint solutions a whole turn apart where a joint's range allows them, the
  numerical IK of every sample (KDL, the only IK the wheel ships for any arm), the collision of
  every vertex with the cell margin, the shortest joint path through the ladder graph. The
  wheel's Python profile samples about one axis only: a grid of tilts within the cone cannot be
  given to it, so a non-axisymmetric tool keeps its tilt as demonstrated. On a stationary TCP
  (the puzzle piece as Tesseract poses it) the wheel's Descartes aborts the process (an uncaught
  std::out_of_range), so it answers `failed` there without being called.

Rules neither keeps (the shared verification still checks them, so an answer that breaks one is
not verified): refine's joint-step bound between waypoints, its singularity margin, the
self-collision margin where it differs from the cell margin, and the dense clearance check between
waypoints (TrajOpt checks its continuous collision between waypoints; Descartes only at them).
The environment is made once per problem and kept, as Drake's plant and refine's robot are, and
is not timed.
"""

from __future__ import annotations

import glob
import math
import os
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from refine.bench.contenders import CONTENDERS, Answer, Unavailable, greedy_ik
from refine.bench.suites import BenchProblem
from refine.types import Array

TRAJOPT_NAMESPACE = "TrajOptMotionPlannerTask"
DESCARTES_NAMESPACE = "DescartesMotionPlannerTask"
PROFILE = "REFINE_BENCH"

DESCARTES_SAMPLE_DEG = 10.0
"""Step of Descartes' samples about the tool axis [deg] (36 samples over a whole turn)."""

CONE_BACKOFF_DEG = 1e-3
"""How much narrower than the problem's cone the peers' orientation tolerance is [deg]."""

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


def _cell_model(problem: BenchProblem) -> Any:
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
    model = _cell_model(problem)
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


def _isometry(t: dict[str, Any], T: Array) -> Any:
    iso = t["common"].Isometry3d()
    iso.setMatrix(np.ascontiguousarray(T, dtype=float))
    return iso


def _program(
    t: dict[str, Any],
    problem: BenchProblem,
    manip: Any,
    names: list[str],
    seed: Array | None = None,
    tolerance: Array | None = None,
) -> Any:
    """One linear move per path point to its Cartesian waypoint (the TCP's target in the world).

    ``seed``: joints per waypoint [rad] (N, n) given as each waypoint's seed; ``tolerance``: the
    waypoints' symmetric tolerance box (position [m], rotation vector [rad]) (6,).
    """
    cl = t["cl"]
    program = cl.CompositeInstruction(PROFILE)
    program.setManipulatorInfo(manip)
    fused = problem.fused
    for k in range(problem.n_waypoints):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = fused.rotations[k], fused.positions[k]
        waypoint = cl.CartesianWaypoint(_isometry(t, T))
        if tolerance is not None:
            waypoint.setLowerTolerance(-np.asarray(tolerance, dtype=float))
            waypoint.setUpperTolerance(np.asarray(tolerance, dtype=float))
        if seed is not None:
            waypoint.setSeed(t["common"].JointState(names, np.asarray(seed[k], dtype=float)))
        move = cl.MoveInstruction(
            cl.CartesianWaypointPoly_wrap_CartesianWaypoint(waypoint),
            cl.MoveInstructionType_LINEAR,
            PROFILE,
            manip,
        )
        program.appendMoveInstruction(cl.MoveInstructionPoly_wrap_MoveInstruction(move))
    return program


def _joints(t: dict[str, Any], results: Any, n: int, nq: int) -> Array | None:
    cl = t["cl"]
    rows = []
    flat = results.flatten()  # kept: its items refer into it
    for i in range(len(flat)):
        instruction = flat[i]
        if not instruction.isMoveInstruction():
            continue
        move = cl.InstructionPoly_as_MoveInstructionPoly(instruction)  # kept: the waypoint refers into it
        waypoint = move.getWaypoint()
        if waypoint.isStateWaypoint():
            rows.append(np.asarray(cl.WaypointPoly_as_StateWaypointPoly(waypoint).getPosition(), dtype=float))
        elif waypoint.isJointWaypoint():
            rows.append(np.asarray(cl.WaypointPoly_as_JointWaypointPoly(waypoint).getPosition(), dtype=float))
    q = np.array(rows).reshape(len(rows), -1)
    if q.shape != (n, nq):
        return None
    return q


def _cone_rad(problem: BenchProblem) -> float:
    return math.radians(problem.tolerances.orientation_deg - CONE_BACKOFF_DEG)


def trajopt(problem: BenchProblem) -> Answer:
    """TrajOpt over the whole path, seeded by chained IK, the cone as its orientation tolerance.

    Timed: the chained IK (``seed``), making the program and profiles (``build``) and TrajOpt's
    solve, which builds its own problem (``solve``). Raises :class:`Unavailable` without the extra.
    """
    if problem.tool_in_world is not None and "tesseract_files" not in problem.extra:
        return Answer(
            "failed",
            None,
            note="not run: a problem file's stationary tool is not composed into a Tesseract workcell",
        )
    t, env, manip, _, names, _ = tesseract_environment(problem)
    T = t["trajopt"]
    c0 = time.process_time()
    w0 = time.perf_counter()
    seed = greedy_ik(problem).q
    w1 = time.perf_counter()
    cone = _cone_rad(problem)
    if problem.axisymmetric:
        box = np.array([0.0, 0.0, 0.0, cone / math.sqrt(2.0), cone / math.sqrt(2.0), math.pi])
    else:
        box = np.array([0.0, 0.0, 0.0] + [cone / math.sqrt(3.0)] * 3)
    plan = T.TrajOptDefaultPlanProfile()  # the Cartesian waypoints as constraints, with their tolerances
    composite = T.TrajOptDefaultCompositeProfile()
    model = _cell_model(problem)
    composite.collision_cost_config.enabled = False
    composite.collision_constraint_config.enabled = model is not None
    if model is not None:
        composite.collision_constraint_config.safety_margin = float(model.margin_m)
    profiles = t["cl"].ProfileDictionary()
    profiles.addProfile(TRAJOPT_NAMESPACE, PROFILE, plan)
    profiles.addProfile(TRAJOPT_NAMESPACE, PROFILE, composite)
    request = t["planners"].PlannerRequest()
    request.instructions = _program(t, problem, manip, names, seed, box)
    request.env = env
    request.profiles = profiles
    planner = T.TrajOptMotionPlanner(TRAJOPT_NAMESPACE)
    w2 = time.perf_counter()
    response = planner.solve(request)
    w3 = time.perf_counter()
    q = _joints(t, response.results, problem.n_waypoints, problem.robot.nq) if response.successful else None
    note = "" if response.successful else f"TrajOpt: {response.message}"[:80]
    options = {
        "sqp": _settings(T.BasicTrustRegionSQPParameters(), SQP_SETTINGS),  # no solver profile: its defaults
        "orientation_box_rad": [float(v) for v in box[3:]],
        **_settings(composite, COMPOSITE_SETTINGS),
        "collision_constraint": bool(composite.collision_constraint_config.enabled),
        "safety_margin_m": float(model.margin_m) if model is not None else None,
    }
    return Answer(
        "ok" if q is not None else "failed",
        q,
        {"build": w2 - w1, "seed": w1 - w0, "solve": w3 - w2},
        time.process_time() - c0,
        0,
        note,
        solver_status=_status(response),
        solver_options=options,
    )


def descartes(problem: BenchProblem) -> Answer:
    """Descartes over the whole path: samples about the tool axis, IK of each, the shortest joint path.

    Timed: making the program and profile (``build``) and Descartes' solve (sampling, IK, vertex
    collision, the ladder graph's search: ``solve``). Raises :class:`Unavailable` without the extra.
    """
    if problem.tool_in_world is not None:
        # measured: the wheel's Descartes aborts the process (std::out_of_range, uncaught in C++)
        # on the puzzle piece's stationary TCP, so it is not called there
        return Answer(
            "failed", None, note="not run: Descartes of tesseract-robotics 0.5.1 aborts on a stationary TCP"
        )
    t, env, manip, _, names, _ = tesseract_environment(problem)
    D = t["descartes"]
    c0 = time.process_time()
    w0 = time.perf_counter()
    profile = D.DescartesDefaultPlanProfileD()
    profile.target_pose_fixed = False
    profile.target_pose_sample_axis = np.array([0.0, 0.0, 1.0])
    if problem.axisymmetric:
        profile.target_pose_sample_min, profile.target_pose_sample_max = -math.pi, math.pi
        profile.target_pose_sample_resolution = math.radians(DESCARTES_SAMPLE_DEG)
    else:  # three turns about the tool axis, inside the cone by half of it (room for the IK's tolerance)
        half = 0.5 * _cone_rad(problem)
        profile.target_pose_sample_min, profile.target_pose_sample_max = -half, half
        profile.target_pose_sample_resolution = half
    model = _cell_model(problem)
    profile.enable_collision = model is not None
    profile.allow_collision = model is None  # without a cell nothing is checked, as for refine
    if model is not None:
        _set_margin(t, profile.vertex_collision_check_config, float(model.margin_m))
    profile.enable_edge_collision = False
    profile.use_redundant_joint_solutions = True  # whole turns of a joint whose range spans more
    profiles = t["cl"].ProfileDictionary()
    profiles.addProfile(DESCARTES_NAMESPACE, PROFILE, D.cast_DescartesPlanProfileD(profile))
    request = t["planners"].PlannerRequest()
    request.instructions = _program(t, problem, manip, names, None)
    request.env = env
    request.profiles = profiles
    planner = D.DescartesMotionPlannerD(DESCARTES_NAMESPACE)
    w1 = time.perf_counter()
    response = planner.solve(request)
    w2 = time.perf_counter()
    q = _joints(t, response.results, problem.n_waypoints, problem.robot.nq) if response.successful else None
    note = "" if response.successful else f"Descartes: {response.message}"[:80]
    options = _settings(profile, DESCARTES_SETTINGS)
    options["target_pose_sample_axis"] = [float(v) for v in np.ravel(profile.target_pose_sample_axis)]
    options["collision_margin_m"] = float(model.margin_m) if model is not None else None
    return Answer(
        "ok" if q is not None else "failed",
        q,
        {"build": w1 - w0, "seed": 0.0, "solve": w2 - w1},
        time.process_time() - c0,
        0,
        note,
        solver_status=_status(response),
        solver_options=options,
    )


SQP_SETTINGS = (
    "max_iter", "max_time", "cnt_tolerance", "min_approx_improve", "min_trust_box_size", "trust_box_size",
    "improve_ratio_threshold", "trust_shrink_ratio", "trust_expand_ratio", "max_merit_coeff_increases",
    "merit_coeff_increase_ratio", "initial_merit_error_coeff",
)  # fmt: skip
"""TrajOpt's trust-region SQP settings recorded in a row's ``solver_options`` (``sqp``)."""

COMPOSITE_SETTINGS = ("smooth_velocities", "velocity_coeff", "smooth_accelerations", "smooth_jerks",
                      "avoid_singularity", "longest_valid_segment_length")  # fmt: skip
"""TrajOpt's composite-profile settings recorded in a row's ``solver_options``."""

DESCARTES_SETTINGS = (
    "target_pose_fixed", "target_pose_sample_min", "target_pose_sample_max", "target_pose_sample_resolution",
    "enable_collision", "allow_collision", "enable_edge_collision", "use_redundant_joint_solutions",
)  # fmt: skip
"""Descartes' plan-profile settings recorded in a row's ``solver_options``."""


def _settings(source: Any, names: tuple[str, ...]) -> dict[str, Any]:
    """The named attributes of a Tesseract profile or parameter set, as JSON-ready numbers and flags."""
    found = {}
    for name in names:
        value = getattr(source, name)
        if isinstance(value, float) and not math.isfinite(value):
            value = str(value)  # TrajOpt's "no limit" is the largest double
        elif isinstance(value, float) and abs(value) > 1e300:
            value = "unlimited"
        elif hasattr(value, "tolist"):
            value = np.asarray(value).tolist()
        found[name] = value
    return found


def _status(response: Any) -> str:
    """The planner's own word on its solve: ``successful`` or its message (Tesseract has no status code)."""
    return "successful" if response.successful else str(response.message)[:80]


def _set_margin(t: dict[str, Any], config: Any, margin_m: float) -> None:
    """Give a collision check config the cell margin as its default margin [m]."""
    manager = config.contact_manager_config
    manager.margin_data = t["common"].CollisionMarginData(margin_m)
    manager.margin_data_override_type = t["common"].CollisionMarginOverrideType_OVERRIDE_DEFAULT_MARGIN


for _peer in (trajopt, descartes):
    _peer.setup = tesseract_environment  # made once per problem, before the runs (refine.bench.watchdog)

PEERS = {"trajopt": trajopt, "descartes": descartes}
"""The peers by name; they join :data:`refine.bench.contenders.CONTENDERS` when this module is imported."""

CONTENDERS.update(PEERS)
