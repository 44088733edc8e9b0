"""``refine robots import``: a registry folder made from a ROS-Industrial support package as published.

:func:`import_support_package` expands the package's xacro (:mod:`refine.robot.description`), covers
each link's collision mesh with convex pieces (:func:`refine.robot.shapes.make_link_shapes`, the code
of ``robots/make_shapes.py``), samples the self-collision matrix as ``robots/make_self_collision.py``
does (the package's own meshes stand for the maker's), and writes the folder the bundled robots have:
``robot.urdf``, ``collision/``, ``self_collision.toml``, ``robot.toml`` (controller, program, reach
as the makers quote it) and a ``README.md`` with the sources, the licence and the shapes' fit.
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from lxml import etree

from refine.errors import InputError
from refine.frames import make_transform, matrix_from_fixed_xyz
from refine.lazy import lean_imports, on_first_use
from refine.robot.coupling import JOINT_COUPLINGS
from refine.robot.description import package_name, resolve_description
from refine.robot.geometry import read_mesh
from refine.robot.reach import wrist_centre_reach
from refine.robot.self_collision import (
    NEVER_M,
    PairStats,
    maker_contacts,
    sample_matrix,
    with_maker,
    write_matrix,
)
from refine.robot.shapes import LinkShapes, make_link_shapes, rewrite_urdf, shapes_table
from refine.robot.spec import CONTROLLERS, DEFAULT_PROGRAM, PROGRAMS, SELF_COLLISION_FILE, build_model

with lean_imports():
    import pinocchio as pin
if TYPE_CHECKING:
    import trimesh
else:
    trimesh = on_first_use("trimesh")  # the first mesh call imports it

MAKERS = {
    "abb": "ABB",
    "kuka": "KUKA",
    "ur": "Universal Robots",
    "fanuc": "FANUC",
    "yaskawa": "Yaskawa Motoman",
}
"""The maker written to ``robot.toml`` for each controller family unless ``maker`` names another."""
ACCELERATION_RULE = "2x the joint speed limit per second"
"""The registry's rule for industrial arms without acceleration figures: full speed from rest in 0.5 s."""


COUPLING_CHOICES = ("auto", "none", *JOINT_COUPLINGS)
"""``--joint-coupling``: ``auto`` decides from the package (:func:`detect_joint_coupling`)."""


@dataclass(frozen=True)
class Coupling:
    """The joint coupling an import writes, and how it was decided.

    Attributes:
        name: one of :data:`refine.robot.coupling.JOINT_COUPLINGS`, or ``""`` for none.
        reason: one sentence on the evidence (for the import's output and the README).
    """

    name: str
    reason: str


@dataclass(frozen=True)
class ImportResult:
    """What an import wrote.

    Attributes:
        folder: the registry folder written.
        description: the description file expanded.
        shapes: each link's convex pieces and their fit to its mesh.
        reach_m: the reach written to ``robot.toml`` [m].
        pairs: the sampled self-collision matrix.
        reach_given: the reach given to the import [m]; None when it is the wrist centre's.
    """

    folder: Path
    description: Path
    shapes: list[LinkShapes]
    reach_m: float
    pairs: list[PairStats]
    reach_given: float | None = None
    coupling: Coupling = Coupling("", "")


def driver_j23_factors(package: Path, stem: str) -> list[tuple[str, int]]:
    """The ``J23_factor`` defaults the package's launch files give the ROS-Industrial FANUC driver.

    Only the launch files whose name holds the description's file stem (``m20ia`` for
    ``m20ia.xacro``) count when any does (a package may describe several variants).

    Returns:
        (launch file name, factor) of every ``<arg name="J23_factor" default="n">`` found.
    """
    found = []
    for path in sorted(package.glob("launch/*.launch")) + sorted(package.glob("launch/*.launch.xml")):
        try:
            root = etree.parse(str(path)).getroot()
        except (OSError, etree.XMLSyntaxError):
            continue
        for arg in root.iter("arg"):
            value = arg.get("default", arg.get("value"))
            if (
                arg.get("name") == "J23_factor"
                and value is not None
                and re.fullmatch(r"-?\d+", value.strip())
            ):
                found.append((path.name, int(value)))
    own = [(n, f) for n, f in found if re.search(rf"(^|_){re.escape(stem)}(\.|$)", n)]
    return own or found


def _turn_axes(model: pin.Model) -> tuple[np.ndarray, np.ndarray]:
    """The world directions joints 2 and 3 turn about at zero, unit vectors (3,)."""
    data = model.createData()
    q = pin.neutral(model)
    pin.computeJointJacobians(model, data, q)
    axes = []
    for j in (2, 3):
        J = pin.getJointJacobian(model, data, j, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        w = J[3:, model.joints[j].idx_v]
        axes.append(w / max(float(np.linalg.norm(w)), 1e-12))
    return axes[0], axes[1]


def detect_joint_coupling(
    package: Path, source: Path, model: pin.Model, controller: str, requested: str = "auto"
) -> Coupling:
    """The joint coupling of an imported arm: ``requested``, or with ``"auto"`` what the package says.

    ``auto``: only a ``fanuc`` controller counts joints otherwise than the URDF. Its support
    package's driver launch files state ``J23_factor`` (:func:`driver_j23_factors`): the
    ROS-Industrial ``fanuc_driver`` adds ``J23_factor · J2`` to the controller's J3 to get the
    URDF's, so a factor 1 is ``"fanuc_j2_j3"`` and 0 none; without the argument, none. The joint
    axes are checked against it: with factor 1, J2 and J3 must turn about opposite directions
    (the ROS-Industrial FANUC descriptions: +y and -y), as they do when J3 is counted from the
    horizontal through a parallel link.

    Raises:
        InputError: an unknown ``requested``; a coupling for a six-joint-less arm; a factor other
            than 0 and 1, launch files that disagree, or axes that contradict the factor.
    """
    if requested not in COUPLING_CHOICES:
        raise InputError(f"--joint-coupling {requested!r} is not one of {', '.join(COUPLING_CHOICES)}")
    if requested == "none":
        return Coupling("", "none: --joint-coupling none")
    if requested != "auto":
        if model.nq < 3:
            raise InputError(f"--joint-coupling {requested}: needs at least 3 joints, the arm has {model.nq}")
        return Coupling(requested, f"{requested}: --joint-coupling {requested}")
    if controller != "fanuc":
        return Coupling("", f"none: a {controller} controller counts the joints as the URDF does")
    factors = driver_j23_factors(package, source.name.split(".")[0])
    if not factors:
        return Coupling(
            "",
            "none: the package's launch files give the FANUC driver no J23_factor "
            "(pass --joint-coupling fanuc_j2_j3 for an arm with a parallel link)",
        )
    values = sorted({f for _, f in factors})
    files = ", ".join(f"{n} ({f})" for n, f in factors)
    if len(values) > 1 or values[0] not in (0, 1):
        raise InputError(
            f"J23_factor in the launch files: {files}; refine models 0 and 1 only: choose with --joint-coupling"
        )
    if values[0] == 0:
        return Coupling("", f"none: J23_factor = 0 in {files}")
    a2, a3 = _turn_axes(model)
    if float(np.dot(a2, a3)) > -0.999:
        raise InputError(
            f"J23_factor = 1 in {files}, but joints 2 and 3 turn about {np.round(a2, 3).tolist()} and "
            f"{np.round(a3, 3).tolist()}, not opposite directions: choose with --joint-coupling"
        )
    return Coupling(
        "fanuc_j2_j3",
        f"fanuc_j2_j3: J23_factor = 1 in {files}, and joints 2 and 3 turn about opposite directions "
        f"({np.round(a2, 3).tolist()}, {np.round(a3, 3).tolist()})",
    )


def find_description(package: Path, xacro: str | None) -> Path:
    """The description file of a support package: ``xacro`` (relative to the package), or its only top file.

    The top files are the ``urdf/*.xacro`` and ``urdf/*.urdf`` files whose ``<robot>`` has a name
    (macro files have none).

    Raises:
        InputError: the file is missing, or the package holds none or several (listed).
    """
    if xacro is not None:
        path = Path(xacro) if Path(xacro).is_absolute() else package / xacro
        if not path.is_file():
            raise InputError(f"--xacro {xacro}: no such file in {package}")
        return path.resolve()
    tops = []
    for path in sorted([*package.glob("urdf/*.xacro"), *package.glob("urdf/*.urdf")]):
        try:
            root = etree.parse(str(path)).getroot()
        except (OSError, etree.XMLSyntaxError):
            continue
        if root.tag == "robot" and root.get("name"):
            tops.append(path)
    if len(tops) != 1:
        found = ", ".join(str(p.relative_to(package)) for p in tops) or "none"
        raise InputError(
            f"support package {package}: {len(tops)} robot descriptions in urdf/ ({found}); name one with --xacro"
        )
    return tops[0].resolve()


def link_meshes(urdf: Path) -> dict[str, trimesh.Trimesh]:
    """Each link's ``<collision>`` geometry as one mesh in the link frame [m] (links without none left out)."""
    root = etree.parse(str(urdf)).getroot()
    out: dict[str, trimesh.Trimesh] = {}
    for link in root.iter("link"):
        parts = []
        for k, col in enumerate(link.findall("collision")):
            where = f"{urdf.name}: link {link.get('name')!r}, collision {k + 1}"
            parts.append(_collision_mesh(col, where, urdf.parent))
        if parts:
            out[str(link.get("name"))] = trimesh.util.concatenate(parts)
    return out


def _numbers(element: etree._Element | None, key: str, default: list[float]) -> list[float]:
    text = None if element is None else element.get(key)
    return default if text is None else [float(v) for v in text.split()]


def _collision_mesh(col: etree._Element, where: str, folder: Path) -> trimesh.Trimesh:
    geometry = col.find("geometry")
    shape = None if geometry is None else next((c for c in geometry if isinstance(c.tag, str)), None)
    if shape is None:
        raise InputError(f"{where}: <collision> has no geometry")
    if shape.tag == "mesh":
        mesh = read_mesh(folder / str(shape.get("filename")), where).copy()
        mesh.vertices = np.asarray(mesh.vertices) * np.asarray(_numbers(shape, "scale", [1.0] * 3))
    elif shape.tag == "box":
        mesh = trimesh.creation.box(extents=_numbers(shape, "size", []))
    elif shape.tag == "cylinder":
        radius, length = _numbers(shape, "radius", []), _numbers(shape, "length", [])
        mesh = trimesh.creation.cylinder(radius=radius[0], height=length[0], sections=32)
    elif shape.tag == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=_numbers(shape, "radius", [])[0])
    else:
        raise InputError(
            f"{where}: collision geometry <{shape.tag}> is not supported (mesh, box, cylinder, sphere)"
        )
    origin = col.find("origin")
    T = make_transform(
        matrix_from_fixed_xyz(_numbers(origin, "rpy", [0.0] * 3), degrees=False),
        _numbers(origin, "xyz", [0.0] * 3),
    )
    return mesh.apply_transform(T)


def import_support_package(
    package: str | Path,
    name: str,
    registry: str | Path,
    *,
    controller: str,
    xacro: str | None = None,
    program: str | None = None,
    maker: str | None = None,
    model: str | None = None,
    flange_frame: str = "tool0",
    reach_m: float | None = None,
    packages: Mapping[str, str | Path] | None = None,
    licence: str | Path | None = None,
    samples: int = 20000,
    seed: int = 1,
    replace: bool = False,
    joint_coupling: str = "auto",
    say: Callable[[str], None] = print,
) -> ImportResult:
    """Write ``registry/name`` from a support package; ``say`` reports each step (the shapes' fit).

    Args:
        package: the support package's folder (its ``package.xml`` names it).
        name: the registry name (lower-case letters, digits, ``_``).
        registry: the registry folder to write into (``robots/``).
        controller: the controller family, one of :data:`refine.robot.spec.CONTROLLERS`.
        xacro: the description file, relative to the package; None for its only top file.
        program: the program format, one of the family's :data:`refine.robot.spec.PROGRAMS`; None
            for the family's default.
        maker: the manufacturer; None for the controller family's (:data:`MAKERS`).
        model: the maker's designation; None for the description's ``<robot name>``.
        flange_frame: the frame the tool is mounted on.
        reach_m: the reach [m]; None for the wrist centre's largest distance from axis 1
            (:func:`refine.robot.reach.wrist_centre_reach`).
        packages: package name -> folder, for packages not found beside the description.
        licence: a licence file copied to ``collision/LICENSE``; None for the package's own
            ``LICENSE`` file if it has one (the README quotes the ``package.xml`` licence anyway).
        samples: random configurations for the self-collision matrix (a tenth for the maker's meshes).
        seed: seed of the samples.
        replace: write over an existing folder.
        joint_coupling: ``"auto"`` (decided from the package, :func:`detect_joint_coupling`),
            ``"none"`` or one of :data:`refine.robot.coupling.JOINT_COUPLINGS`.
        say: where progress lines go.

    Raises:
        InputError: a bad name, controller or program, an existing folder, or a description that
            cannot be read (missing package, mesh, frame).
    """
    package = Path(package).resolve()
    pkg = package_name(package)
    if pkg is None:
        raise InputError(
            f"{package}: no package.xml naming a ROS package (is it a support package's folder?)"
        )
    if not re.fullmatch(r"[a-z0-9_]{1,64}", name):
        raise InputError(f"--name {name!r}: a registry name is 1 to 64 lower-case letters, digits or '_'")
    if controller not in CONTROLLERS:
        raise InputError(f"--controller {controller!r} is not one of {', '.join(CONTROLLERS)}")
    program = program or DEFAULT_PROGRAM[controller]
    if program not in PROGRAMS[controller]:
        raise InputError(
            f"--program {program!r} does not run on a {controller} controller: {', '.join(PROGRAMS[controller])}"
        )
    folder = Path(registry).resolve() / name
    if folder.exists() and not replace:
        raise InputError(f"{folder} exists; choose another --name or pass --replace")
    source = find_description(package, xacro)
    expanded = resolve_description(source, packages)
    pin_model = build_model(expanded)
    if not pin_model.existFrame(flange_frame):
        raise InputError(f"{source.name}: no frame {flange_frame!r} for the flange")
    if reach_m is not None and not reach_m > 0.0:
        raise InputError(f"--reach-m {reach_m}: the reach must be positive [m]")
    reach = float(reach_m) if reach_m is not None else wrist_centre_reach(pin_model, flange_frame)
    coupling = detect_joint_coupling(package, source, pin_model, controller, joint_coupling)
    say(f"{pkg}/{source.relative_to(package)} expanded: {pin_model.nq} joints, reach {reach * 1e3:.1f} mm")
    say(f"  joint coupling {coupling.reason}")
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    label = model or str(etree.parse(str(expanded)).getroot().get("name") or name)
    maker_name = maker or MAKERS[controller]
    shapes = make_link_shapes(link_meshes(expanded), folder, label, f"the collision meshes of {pkg}")
    for s in shapes:
        faces = "/".join(str(p.plane_count) for p in s.pieces)
        say(
            f"  {s.link:14} {len(s.pieces)} piece(s), {faces} faces: mesh {max(s.outside_m, 0.0) * 1e3:.1f} mm "
            f"outside, pieces {s.overshoot_m * 1e3:.1f} mm beyond the mesh at most"
        )
    urdf = folder / "robot.urdf"
    shutil.copyfile(expanded, urdf)
    rewrite_urdf(urdf, {s.link: s.files for s in shapes})
    text = urdf.read_text(encoding="utf-8")
    note = (
        f"<!-- Expanded from {pkg}/{source.relative_to(package)} by refine robots import; its <collision> and "
        "<visual> name the convex pieces in collision/ (see README.md). -->\n"
    )
    urdf.write_text(text.replace("<robot", note + "<robot", 1), encoding="utf-8")
    _write_licence(folder, package, licence)

    from refine.robot.model import robot_from_urdf

    robot = robot_from_urdf(
        urdf,
        controller=controller,
        flange_frame=flange_frame,
        name=name,
        maker=maker_name,
        model=label,
        reach_m=reach,
    )
    pairs = sample_matrix(robot, samples, seed, NEVER_M)
    pairs = with_maker(pairs, maker_contacts(robot, expanded, max(samples // 10, 1), seed))
    write_matrix(folder / SELF_COLLISION_FILE, pairs, samples=samples, seed=seed, never_m=NEVER_M)
    counts = {r: sum(p.reason == r for p in pairs) for r in ("adjacent", "always", "never", "maker", "")}
    say(
        f"  self-collision: {samples} samples, {counts['']} pairs checked, "
        + ", ".join(f"{n} {r}" for r, n in counts.items() if r and n)
    )
    speeds = np.degrees(robot.spec.velocity)
    (folder / "robot.toml").write_text(
        "\n".join(
            [
                "# Registry entry for refine, written by refine robots import. See README.md.",
                f'maker = "{maker_name}"',
                f'model = "{label}"',
                'urdf = "robot.urdf"',
                f'flange_frame = "{flange_frame}"',
                f"reach_m = {reach:.4f}",
                f'controller = "{controller}"',
                f'program = "{program}"',
                "",
                "# Not in the description. Rule for the industrial arms: 2x the speed limit per second",
                "# (each joint reaches full speed from rest in 0.5 s). Speeds "
                + ", ".join(f"{v:.0f}" for v in speeds)
                + " deg/s.",
                f'acceleration_rule = "{ACCELERATION_RULE}"',
                f"joint_acceleration_deg_s2 = [{', '.join(f'{2.0 * v:.1f}' for v in speeds)}]",
                *_controller_lines(pin_model, controller, coupling, robot.spec),
                "",
            ]
        ),
        encoding="utf-8",
    )
    result = ImportResult(folder, source, shapes, reach, pairs, reach_m, coupling)
    (folder / "README.md").write_text(
        readme(result, package, pkg, robot, program, samples, seed), encoding="utf-8"
    )
    say(f"wrote {folder}")
    return result


CONTROLLER_FRAME = "base"
"""ROS-Industrial's frame of the maker's own coordinates, fixed to ``base_link``."""


def _controller_lines(model: pin.Model, controller: str, coupling: Coupling, spec) -> list[str]:  # noqa: ANN001
    """``robot.toml``'s controller conventions: the position frame, the joint coupling and the J3 row.

    * ``controller_frame = "base"`` for a FANUC or Yaskawa arm whose description has a ``base``
      frame fixed to the root (ROS-Industrial: the maker's world / robot coordinates); the TP and
      INFORM writers measure positions in it.
    * ``joint_coupling`` as decided (:func:`detect_joint_coupling`); with ``fanuc_j2_j3``, the
      description's joint 3 range as a ``joint_interaction`` row on the controller's J3 (the
      descriptions copy FANUC's motion ranges, which are the controller's).
    """
    lines = []
    fixed = (
        model.existFrame(CONTROLLER_FRAME)
        and model.frames[model.getFrameId(CONTROLLER_FRAME)].parentJoint == 0
    )
    if controller in ("fanuc", "yaskawa") and fixed:
        lines += [
            "",
            f"# Positions in the controller's frame, the description's `{CONTROLLER_FRAME}`.",
            f'controller_frame = "{CONTROLLER_FRAME}"',
        ]
    if coupling.name:
        lo, hi = np.degrees(spec.lower[2]), np.degrees(spec.upper[2])
        lines += [
            "",
            f"# Joint coupling {coupling.reason}.",
            f'joint_coupling = "{coupling.name}"',
            "# The description's joint 3 range, kept on the J3 the controller shows (from the horizontal).",
            "joint_interaction = [",
            f"    {{ joints = [3], coefficients = [1.0], lower_deg = {lo:.1f}, upper_deg = {hi:.1f}, "
            'label = "J3 from the horizontal" },',
            "]",
        ]
    return lines


def _write_licence(folder: Path, package: Path, licence: str | Path | None) -> None:
    """Copy the licence file to ``collision/LICENSE``: the one given, else the package's own if any."""
    candidates = (
        [Path(licence)]
        if licence is not None
        else [package / n for n in ("LICENSE", "LICENSE.txt", "LICENSE.md")]
    )
    for path in candidates:
        if path.is_file():
            shutil.copyfile(path, folder / "collision" / "LICENSE")
            return
    if licence is not None:
        raise InputError(f"--licence {licence}: no such file")


def _manifest(package: Path) -> dict[str, str]:
    root = etree.parse(str(package / "package.xml")).getroot()
    return {
        key: " ".join((root.findtext(key) or "").split())
        for key in ("name", "version", "license", "maintainer", "url")
    }


def readme(
    result: ImportResult, package: Path, pkg: str, robot, program: str, samples: int, seed: int
) -> str:  # noqa: ANN001 - Robot
    """The README of an imported robot: sources, licence, kinematics, shapes and matrix."""
    info = _manifest(package)
    spec = robot.spec
    licence_file = (result.folder / "collision" / "LICENSE").is_file()
    lines = [
        f"# {spec.maker} {spec.model}",
        "",
        f"Imported by `refine robots import` from the ROS-Industrial support package `{pkg}` "
        f"{info['version']}, unchanged. Controller family `{spec.controller}`, program `{program}`. "
        f"Registry name: `{result.folder.name}`.",
        "",
        "## Sources and licence",
        f"- Description: `{pkg}/{result.description.relative_to(package)}`, expanded with xacrodoc "
        "(`$(find ...)` and `package://` resolved to the packages beside it).",
        f"- Licence: `{info['license'] or 'not stated'}` (its `package.xml`)"
        + (
            "; the licence text is in `collision/LICENSE`."
            if licence_file
            else "; no licence file in the package."
        ),
        f"- Maintainer: {info['maintainer'] or 'not stated'}" + (f"; {info['url']}" if info["url"] else ""),
        "",
        "## Files",
        "- `robot.urdf`: the expanded description; kinematics and limits unchanged, its `<collision>` and "
        "`<visual>` elements name the convex pieces in `collision/`.",
        "- `robot.toml`: registry metadata (maker, model, reach, controller, program, accelerations).",
        f"- `{SELF_COLLISION_FILE}`: the sampled self-collision matrix.",
        "",
        "## Kinematics and limits, as the description gives them",
        "| joint | lower [deg] | upper [deg] | speed [deg/s] |",
        "|---|---|---|---|",
    ]
    for k, joint in enumerate(spec.joint_names):
        lines.append(
            f"| `{joint}` | {np.degrees(spec.lower[k]):.1f} | {np.degrees(spec.upper[k]):.1f} | "
            f"{np.degrees(spec.velocity[k]):.1f} |"
        )
    lines += [
        "",
        f"Reach: {result.reach_m * 1e3:.1f} mm"
        + (
            ", the wrist centre's largest distance from axis 1 over the joint ranges "
            "(`refine.robot.reach.wrist_centre_reach`), the figure the data sheets quote."
            if result.reach_given is None
            else ", as given to the import (`--reach-m`)."
        ),
        "Accelerations: not in the description; the registry's rule for industrial arms, "
        f"{ACCELERATION_RULE}.",
        "",
        "## The controller's joints",
        f"Joint coupling {result.coupling.reason}."
        + (
            " J3_controller = J3_urdf - J2_urdf: `home_deg`, the program's joints, `trajectory.csv` and the "
            "report hold the controller's joints, and the description's joint 3 range is kept on the "
            "controller's J3 (`joint_interaction` in `robot.toml`). FANUC's J2/J3 interference area "
            "(the J3 range as a function of J2) is not in the package and not modelled."
            if result.coupling.name == "fanuc_j2_j3"
            else " The controller's joints are the URDF's."
        ),
        "",
        "## Collision shapes",
        "Each link's collision mesh is covered by convex pieces (`refine.robot.shapes.make_link_shapes`, the code "
        "of `robots/make_shapes.py`). Measured as the shape tests do: how far any mesh vertex lies outside "
        "every piece (face planes), and how far the pieces reach beyond the mesh (corners and 1,500 surface "
        "samples per piece, trimesh's signed distance).",
        "",
        *shapes_table(result.shapes),
        "",
        "## Self-collision matrix",
        f"Sampled at {samples} random configurations (seed {seed}); pairs disabled: "
        + ", ".join(
            f"{sum(p.reason == r for p in result.pairs)} {r}"
            for r in ("adjacent", "always", "never", "maker")
        )
        + f"; {sum(not p.reason for p in result.pairs)} checked (see `refine/robot/self_collision.py`).",
        "",
        "## Checked against the data sheet",
        "Not by the import: compare the reach, the axis ranges and the speeds above with the maker's data "
        "sheet before use.",
        "",
    ]
    return "\n".join(lines)
