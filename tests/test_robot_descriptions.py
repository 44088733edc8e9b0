"""Robot descriptions as published: ROS-Industrial xacros, ROS packages, the reach, the registry import.

The expectations come from outside the code under test: forward kinematics composed here from the
joint origins written in the support packages' macro files (read with ElementTree), the makers'
data-sheet reach (FANUC M-20iA 1811 mm, Yaskawa Motoman GP12 1440 mm) and its arm-length formula,
and the packages' own collision meshes (read with trimesh from the package folders) for the
shapes' coverage, measured as ``tests/test_robot_shapes.py`` measures it.
"""

import math
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

import refine
from refine.cli import main
from refine.robot.registry import load_robot
from refine.synthetic import write_line_problem

ROOT = Path(__file__).resolve().parents[1]
DESCRIPTIONS = ROOT.parent / "shared" / "robot-descriptions"
M20IA = DESCRIPTIONS / "fanuc_m20ia_support"
GP12 = DESCRIPTIONS / "motoman_gp12_support"

pytestmark = pytest.mark.skipif(not M20IA.is_dir(), reason=f"support packages not found at {DESCRIPTIONS}")


def macro_chain(macro: Path):
    """(parent, child, type, origin 4x4, axis) of every joint of a macro file, ``${prefix}`` empty.

    The only expressions in these files' joint origins are ``${pi}`` and ``${-pi/2.0}``.
    """
    text = macro.read_text().replace("${prefix}", "")
    text = text.replace("${pi}", repr(math.pi)).replace("${-pi/2.0}", repr(-math.pi / 2.0))
    root = ET.fromstring(text)
    out = []
    for j in root.iter("joint"):
        org = j.find("origin")
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", [float(v) for v in org.get("rpy").split()]).as_matrix()
        T[:3, 3] = [float(v) for v in org.get("xyz").split()]
        axis = j.find("axis")
        w = np.array([float(v) for v in axis.get("xyz").split()]) if axis is not None else np.zeros(3)
        out.append((j.find("parent").get("link"), j.find("child").get("link"), j.get("type"), T, w))
    return out


def composed_fk(chain, q, target: str) -> np.ndarray:
    """The pose of link ``target`` in the root link: origins and axis rotations composed in order."""
    by_child = {c: (p, kind, T, w) for p, c, kind, T, w in chain}
    movable = [c for _, c, kind, _, _ in chain if kind != "fixed"]
    path = []
    link = target
    while link in by_child:
        path.append(link)
        link = by_child[link][0]
    T_out = np.eye(4)
    for child in reversed(path):
        _, kind, T, w = by_child[child]
        R = np.eye(4)
        if kind != "fixed":
            R[:3, :3] = Rotation.from_rotvec(w * q[movable.index(child)]).as_matrix()
        T_out = T_out @ T @ R
    return T_out


@pytest.mark.parametrize(
    ("xacro", "macro", "controller", "tool0_at_zero"),
    [
        # FANUC M-20iA: x = 0.150 + 0.835 + 0.100, z = 0.525 + 0.790 + 0.250 [m]
        (M20IA / "urdf" / "m20ia.xacro", M20IA / "urdf" / "m20ia_macro.xacro", "fanuc", (1.085, 0.0, 1.565)),
        # Motoman GP12: x = 0.155 + 0.640 + 0.100, z = 0.450 + 0.614 + 0.200 [m]
        (GP12 / "urdf" / "gp12.xacro", GP12 / "urdf" / "gp12_macro.xacro", "yaskawa", (0.895, 0.0, 1.264)),
    ],
)
def test_a_published_xacro_loads_unchanged_and_its_kinematics_are_the_macros(
    xacro, macro, controller, tool0_at_zero
):
    robot = refine.Robot.from_urdf(xacro, controller=controller)
    assert robot.nq == 6 and robot.spec.controller == controller
    assert len(robot.collision_shapes()) == 7  # one convex hull per link's collision STL
    chain = macro_chain(macro)
    np.testing.assert_allclose(robot.fk(np.zeros(6))[:3, 3], tool0_at_zero, atol=1e-9)
    # the flange's z (tool0) points along the arm at zero, as ROS-Industrial's tool0 convention says
    np.testing.assert_allclose(robot.fk(np.zeros(6))[:3, 2], [1.0, 0.0, 0.0], atol=1e-6)
    rng = np.random.default_rng(5)
    for _ in range(5):
        q = rng.uniform(robot.spec.lower, robot.spec.upper)
        np.testing.assert_allclose(robot.fk(q), composed_fk(chain, q, "tool0"), atol=1e-6)
    limits = [
        (float(j.find("limit").get("lower")), float(j.find("limit").get("upper")))
        for j in ET.fromstring(macro.read_text().replace("${prefix}", "")).iter("joint")
        if j.get("type") == "revolute"
    ]
    np.testing.assert_allclose(robot.spec.lower, [lo for lo, _ in limits])
    np.testing.assert_allclose(robot.spec.upper, [hi for _, hi in limits])


def test_the_reach_is_the_data_sheets_wrist_centre_distance_from_axis_1():
    m20ia = refine.Robot.from_urdf(M20IA / "urdf" / "m20ia.xacro", controller="fanuc")
    gp12 = refine.Robot.from_urdf(GP12 / "urdf" / "gp12.xacro", controller="yaskawa")
    # the data sheets: M-20iA 1811 mm, GP12 1440 mm (to the millimetre they quote)
    assert m20ia.spec.reach_m == pytest.approx(1.811, abs=0.001)
    assert gp12.spec.reach_m == pytest.approx(1.440, abs=0.001)
    # the arm lengths of the macros: a1 + a2 + hypot(a3, d4), the forearm stretched horizontally
    assert m20ia.spec.reach_m == pytest.approx(0.150 + 0.790 + math.hypot(0.835, 0.250), abs=1e-6)
    assert gp12.spec.reach_m == pytest.approx(0.155 + 0.614 + math.hypot(0.640, 0.200), abs=1e-6)
    # ABB's IRB 4600-60/2.05 from its URDF: 2.05 m on the data sheet
    abb = refine.Robot.from_urdf(ROOT / "robots" / "abb_irb4600_60_205" / "robot.urdf", controller="abb")
    assert abb.spec.reach_m == pytest.approx(0.175 + 0.900 + math.hypot(0.960, 0.175), abs=1e-6)


def test_a_missing_package_is_named_with_where_it_was_looked_for(tmp_path):
    shutil.copytree(M20IA, tmp_path / "alone" / "fanuc_m20ia_support")
    xacro = tmp_path / "alone" / "fanuc_m20ia_support" / "urdf" / "m20ia.xacro"
    with pytest.raises(
        refine.InputError, match=r"package 'fanuc_resources' not found.*alone.*\[robot\] packages"
    ):
        refine.Robot.from_urdf(xacro, controller="fanuc")
    robot = refine.Robot.from_urdf(
        xacro, controller="fanuc", packages={"fanuc_resources": DESCRIPTIONS / "fanuc_resources"}
    )
    assert robot.nq == 6


def box_package(folder: Path) -> Path:
    """A ROS package ``boxarm`` with one revolute joint and a 0.2 x 0.1 x 0.4 m box mesh by package:// URL."""
    (folder / "boxarm" / "meshes").mkdir(parents=True)
    (folder / "boxarm" / "urdf").mkdir()
    (folder / "boxarm" / "package.xml").write_text(
        '<?xml version="1.0"?><package format="2"><name>boxarm</name><version>1.0.0</version>'
        "<license>MIT</license></package>"
    )
    trimesh.creation.box(extents=(0.2, 0.1, 0.4)).export(folder / "boxarm" / "meshes" / "box.stl")
    urdf = folder / "boxarm" / "urdf" / "boxarm.urdf"
    urdf.write_text(
        """<?xml version="1.0"?>
<robot name="boxarm">
  <link name="base_link"/>
  <link name="arm">
    <collision><origin xyz="0 0 0.3" rpy="0 0 0"/>
      <geometry><mesh filename="package://boxarm/meshes/box.stl"/></geometry></collision>
  </link>
  <link name="tool0"/>
  <joint name="j1" type="revolute"><parent link="base_link"/><child link="arm"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="2"/></joint>
  <joint name="j1-tool0" type="fixed"><parent link="arm"/><child link="tool0"/><origin xyz="0 0 0.5"/></joint>
</robot>
"""
    )
    return urdf


def test_a_plain_urdf_with_package_urls_finds_its_meshes(tmp_path):
    robot = refine.Robot.from_urdf(box_package(tmp_path), controller="abb", reach_m=0.5)
    (shape,) = robot.collision_shapes()
    corners = shape.convex.vertices @ shape.link_T_shape[:3, :3].T + shape.link_T_shape[:3, 3]
    np.testing.assert_allclose(corners.min(axis=0), [-0.1, -0.05, 0.1], atol=1e-9)
    np.testing.assert_allclose(corners.max(axis=0), [0.1, 0.05, 0.5], atol=1e-9)


def robot_table(problem: Path, table: str) -> None:
    text = problem.read_text()
    problem.write_text(text.replace('[robot]\nmodel = "ur10e"\n', table))


def test_refine_check_takes_every_form_of_robot(tmp_path, capsys):
    """A registry name, a URDF beside the problem, and a published xacro whose packages lie elsewhere."""
    registry = write_line_problem(tmp_path / "registry", program="urscript")
    assert main(["check", str(registry)]) == 0
    urdf = write_line_problem(tmp_path / "urdf", start=(0.9, -0.1, 0.4), end=(0.9, 0.1, 0.4), program="krl")
    shutil.copytree(ROOT / "robots" / "kuka_kr8_r1440_2_arc_hw", tmp_path / "urdf" / "kr8")
    robot_table(urdf, '[robot]\nurdf = "kr8/robot.urdf"\ncontroller = "kuka"\n')
    assert main(["check", str(urdf)]) == 0
    xacro = write_line_problem(tmp_path / "xacro", start=(1.2, -0.1, 0.6), end=(1.2, 0.1, 0.6), program="tp")
    shutil.copytree(M20IA, tmp_path / "xacro" / "descriptions" / "fanuc_m20ia_support")
    shutil.copytree(DESCRIPTIONS / "fanuc_resources", tmp_path / "elsewhere" / "fanuc_resources")
    robot_table(
        xacro,
        '[robot]\nurdf = "descriptions/fanuc_m20ia_support/urdf/m20ia.xacro"\ncontroller = "fanuc"\n'
        'packages = { fanuc_resources = "../elsewhere/fanuc_resources" }\n',
    )
    assert main(["check", str(xacro)]) == 0
    out = capsys.readouterr().out
    assert "robot ur10e" in out and "robot kuka_kr8_r1440_2_arc_hw" in out and "robot fanuc_m20ia" in out
    robot_table_text = xacro.read_text().replace("../elsewhere/fanuc_resources", "../nowhere")
    xacro.write_text(robot_table_text)
    assert main(["check", str(xacro)]) == 2
    assert "robot.packages.fanuc_resources = '../nowhere': not a folder" in capsys.readouterr().err


def outside(points, corner_sets):
    """Per point, the least over shapes of the largest face-plane excess (<= 0 inside a shape)."""
    best = np.full(len(points), np.inf)
    for corners in corner_sets:
        eq = ConvexHull(corners).equations
        best = np.minimum(best, np.max(points @ eq[:, :3].T + eq[:, 3], axis=1))
    return best


def package_meshes(macro: Path, package: Path) -> dict[str, trimesh.Trimesh]:
    """Each link's collision STL named in the macro, read from the package (collision origins are zero)."""
    root = ET.fromstring(macro.read_text().replace("${prefix}", ""))
    out = {}
    for link in root.iter("link"):
        for col in link.findall("collision"):
            assert col.find("origin") is None or col.find("origin").get("xyz") == "0 0 0"
            name = col.find("geometry/mesh").get("filename").split("/", 3)[3]
            out[link.get("name")] = trimesh.load(package / name, force="mesh")
    return out


@pytest.mark.parametrize(
    ("name", "macro", "package"),
    [
        ("fanuc_m20ia", M20IA / "urdf" / "m20ia_macro.xacro", M20IA),
        ("motoman_gp12", GP12 / "urdf" / "gp12_macro.xacro", GP12),
    ],
)
def test_the_imported_arms_cover_their_packages_meshes(name, macro, package):
    robot = load_robot(name)
    chain = macro_chain(macro)
    rng = np.random.default_rng(11)
    for q in [np.zeros(6), *rng.uniform(robot.spec.lower, robot.spec.upper, size=(3, 6))]:
        np.testing.assert_allclose(robot.fk(q), composed_fk(chain, q, "tool0"), atol=1e-6)
    assert {"robot.urdf", "robot.toml", "README.md", "self_collision.toml"} <= {
        p.name for p in (ROOT / "robots" / name).iterdir()
    }
    pieces: dict[str, list[np.ndarray]] = {}
    for s in robot.collision_shapes():
        # closed convex pieces of a few dozen planes (48 asked; a sliver triangle of qhull's may
        # count as a plane of its own)
        assert s.convex.mesh.is_watertight and s.convex.plane_count <= 50, f"{name} {s.name}"
        pieces.setdefault(s.link, []).append(
            s.convex.vertices @ s.link_T_shape[:3, :3].T + s.link_T_shape[:3, 3]
        )
    meshes = package_meshes(macro, package)
    assert set(meshes) == set(pieces)
    for link, mesh in meshes.items():
        assert outside(np.asarray(mesh.vertices), pieces[link]).max() <= 1e-6, f"{name} {link}: not covered"
        for k, corners in enumerate(pieces[link]):
            hull = trimesh.convex.convex_hull(corners)
            points = np.vstack([hull.vertices, trimesh.sample.sample_surface(hull, 500, seed=k)[0]])
            assert -trimesh.proximity.signed_distance(mesh, points).min() <= 0.025, f"{name} {link} piece {k}"
    assert robot.spec.reach_m == pytest.approx({"fanuc_m20ia": 1.811, "motoman_gp12": 1.440}[name], abs=0.001)
    assert robot.spec.default_program == {"fanuc_m20ia": "tp", "motoman_gp12": "inform"}[name]


def test_import_writes_a_registry_folder_that_loads_and_covers_its_mesh(tmp_path, capsys, monkeypatch):
    box_package(tmp_path / "src")
    registry = tmp_path / "registry"
    status = main(
        [
            "robots",
            "import",
            str(tmp_path / "src" / "boxarm"),
            "--name",
            "boxarm",
            "--controller",
            "yaskawa",
            "--samples",
            "20",
            "--reach-m",
            "0.6",
            "--registry",
            str(registry),
        ]
    )
    assert status == 0
    out = capsys.readouterr().out
    assert "arm" in out and "mesh 0.0 mm outside" in out
    folder = registry / "boxarm"
    for f in ("robot.urdf", "robot.toml", "self_collision.toml", "README.md", "collision/arm_0.obj"):
        assert (folder / f).is_file(), f
    monkeypatch.setenv("REFINE_ROBOTS_DIR", str(registry))
    robot = load_robot("boxarm")
    assert robot.spec.controller == "yaskawa" and robot.spec.default_program == "inform"
    assert "MIT" in (folder / "README.md").read_text()
    (shape,) = robot.collision_shapes()
    box = trimesh.creation.box(extents=(0.2, 0.1, 0.4))
    box.apply_translation([0.0, 0.0, 0.3])
    corners = shape.convex.vertices @ shape.link_T_shape[:3, :3].T + shape.link_T_shape[:3, 3]
    assert outside(np.asarray(box.vertices), [corners]).max() <= 1e-6
    # a box is its own hull: the piece is the box, up to the padding of its planes
    np.testing.assert_allclose(corners.min(axis=0), [-0.1, -0.05, 0.1], atol=1e-5)
    np.testing.assert_allclose(corners.max(axis=0), [0.1, 0.05, 0.5], atol=1e-5)
    assert (
        main(
            [
                "robots",
                "import",
                str(tmp_path / "src" / "boxarm"),
                "--name",
                "boxarm",
                "--controller",
                "yaskawa",
                "--registry",
                str(registry),
            ]
        )
        == 2
    )
    assert "exists" in capsys.readouterr().err
