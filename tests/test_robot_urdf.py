"""Robots outside the registry, from their URDF: limits, collision meshes, problem files, end to end."""

import json
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import refine
from refine.cli import main
from refine.problem import load_problem
from refine.robot.registry import available_robots
from refine.synthetic import write_line_problem

ROOT = Path(__file__).resolve().parents[1]
KR8 = ROOT / ".." / "shared" / "robot-meshes" / "kuka_kr8_r1440_2_arc_hw"
URDF = KR8 / "reference.urdf"

pytestmark = pytest.mark.skipif(not URDF.is_file(), reason="needs ../shared/robot-meshes")


def urdf_joints():
    """(name, lower, upper, velocity, origin 4x4, axis) of each movable joint, read with ElementTree."""
    out = []
    for j in ET.parse(URDF).getroot().iter("joint"):
        if j.get("type") == "fixed":
            continue
        lim, org = j.find("limit"), j.find("origin")
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", [float(v) for v in org.get("rpy").split()]).as_matrix()
        T[:3, 3] = [float(v) for v in org.get("xyz").split()]
        axis = np.array([float(v) for v in j.find("axis").get("xyz").split()])
        out.append(
            (
                j.get("name"),
                float(lim.get("lower")),
                float(lim.get("upper")),
                float(lim.get("velocity")),
                T,
                axis,
            )
        )
    return out


def test_the_reference_robot_is_not_in_the_registry_by_this_name():
    assert "kr8_r1440_2_arc_hw" not in available_robots()


def test_from_urdf_takes_limits_speeds_and_collision_meshes_from_the_file():
    robot = refine.Robot.from_urdf(URDF, controller="kuka", flange_frame="tool0")
    joints = urdf_joints()
    assert robot.spec.name == "kr8_r1440_2_arc_hw" and robot.nq == len(joints) == 6
    assert np.allclose(robot.spec.lower, [j[1] for j in joints])
    assert np.allclose(robot.spec.upper, [j[2] for j in joints])
    assert np.allclose(robot.spec.velocity, [j[3] for j in joints])
    assert np.allclose(robot.spec.acceleration, robot.spec.velocity / 1.0)  # full speed in 1 s
    assert robot.spec.controller == "kuka"
    # one shape per <collision>, each a mesh made convex
    n_collision = len(list(ET.parse(URDF).getroot().iter("collision")))
    shapes = robot.collision_shapes()
    assert len(shapes) == n_collision == 7
    assert {type(s.geometry).__name__ for s in shapes} == {"Convex"}


def test_forward_kinematics_composes_the_urdf_joint_origins():
    robot = refine.Robot.from_urdf(URDF, controller="kuka")
    rng = np.random.default_rng(3)
    tool0 = next(j for j in ET.parse(URDF).getroot().iter("joint") if j.find("child").get("link") == "tool0")
    T_tool = np.eye(4)
    org = tool0.find("origin")
    T_tool[:3, :3] = Rotation.from_euler("xyz", [float(v) for v in org.get("rpy").split()]).as_matrix()
    T_tool[:3, 3] = [float(v) for v in org.get("xyz").split()]
    for _ in range(5):
        q = rng.uniform(-1.0, 1.0, 6)
        T = np.eye(4)
        for (_, *_limits, origin, axis), qi in zip(urdf_joints(), q, strict=True):
            R = np.eye(4)
            R[:3, :3] = Rotation.from_rotvec(axis * qi).as_matrix()
            T = T @ origin @ R
        assert np.allclose(robot.fk(q), T @ T_tool, atol=1e-12)


def test_overrides_and_bad_values_name_the_key_and_unit():
    robot = refine.Robot.from_urdf(
        URDF,
        controller="kuka",
        joint_lower_deg=[-90, -120, -100, -150, -110, -300],
        joint_velocity_deg_s=[100, 100, 100, 200, 200, 300],
        joint_acceleration_deg_s2=[200] * 6,
        reach_m=1.44,
    )
    assert np.allclose(np.degrees(robot.spec.lower), [-90, -120, -100, -150, -110, -300])
    assert np.allclose(np.degrees(robot.spec.velocity), [100, 100, 100, 200, 200, 300])
    assert np.allclose(np.degrees(robot.spec.acceleration), 200)
    assert robot.spec.reach_m == 1.44
    with pytest.raises(refine.InputError, match=r"joint_upper_deg: expected 6 finite values \[deg\]"):
        refine.Robot.from_urdf(URDF, controller="kuka", joint_upper_deg=[10, 20])
    with pytest.raises(refine.InputError, match="no frame 'flange_tip'.*tool0"):
        refine.Robot.from_urdf(URDF, controller="kuka", flange_frame="flange_tip")
    with pytest.raises(refine.InputError, match="controller 'staubli' is not one of"):
        refine.Robot.from_urdf(URDF, controller="staubli")


def kr8_problem(folder: Path) -> Path:
    """A straight bead in front of the KR 8 over a table, its URDF and meshes copied beside it."""
    problem = write_line_problem(
        folder, start=(0.9, -0.1, 0.4), end=(0.9, 0.1, 0.4), tilt_deg=8.0, program="krl"
    )
    (folder / "robot").mkdir()
    for f in KR8.iterdir():
        if f.suffix in (".urdf", ".stl"):
            shutil.copy(f, folder / "robot" / f.name)
    # accelerations from the description's joint_limits.yaml [rad/s^2], in deg/s^2
    accel = [
        12.76953344640725,
        9.928064409333242,
        6.969378109575402,
        47.68925519016255,
        48.953076912202526,
        214.93590012478643,
    ]
    text = problem.read_text().replace(
        '[robot]\nmodel = "ur10e"\n',
        '[robot]\nurdf = "robot/reference.urdf"\nflange_frame = "tool0"\ncontroller = "kuka"\n'
        f"joint_acceleration_deg_s2 = {[round(float(np.degrees(a)), 3) for a in accel]}\n",
    )
    text += """
[[tool.collision]]
name = "torch"
shape = "cylinder"
radius_m = 0.02
length_m = 0.12
pose = { xyz = [0.0, 0.0, 0.07], rpy_deg = [0.0, 0.0, 0.0] }

[[cell.objects]]
name = "table"
shape = "box"
size_m = [0.6, 1.0, 0.1]
pose = { xyz = [0.95, 0.0, 0.15], rpy_deg = [0.0, 0.0, 0.0] }

[collision]
margin_m = 0.01
# the links' convex hulls are fuller than the links: the wrist's (link 4 and link 6) come within
# a few millimetres of each other
self_margin_m = 0.002
"""
    problem.write_text(text)
    return problem


def test_a_problem_file_names_a_urdf_robot_and_its_overrides(tmp_path):
    problem = load_problem(kr8_problem(tmp_path / "kr8"))
    assert problem.robot.urdf == (tmp_path / "kr8" / "robot" / "reference.urdf").resolve()
    assert problem.robot.model == "kr8_r1440_2_arc_hw" and problem.robot.controller == "kuka"
    toml = tmp_path / "kr8" / "problem.toml"
    text = toml.read_text()
    toml.write_text(text.replace('controller = "kuka"\n', ""))
    with pytest.raises(refine.InputError, match="needs controller"):
        load_problem(toml)
    toml.write_text(text.replace('urdf = "robot/reference.urdf"\n', 'model = "ur10e"\n'))
    with pytest.raises(refine.InputError, match="go with urdf"):
        load_problem(toml)


@pytest.mark.slow
def test_a_robot_outside_the_registry_is_refined_end_to_end_with_collision(tmp_path):
    folder = tmp_path / "kr8"
    kr8_problem(folder)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--out", str(out), "--no-report"]) == 0
    doc = json.loads((out / "result.json").read_text())
    assert doc["status"] == "ok"
    assert doc["robot"]["model"] == "kr8_r1440_2_arc_hw"
    assert doc["metrics"]["min_clearance_m"] >= 0.002 - 1e-4  # the self margin, the smaller one
    assert doc["metrics"]["max_position_error_m"] < 1e-6
    assert {"krl_src", "krl_dat"} <= set(doc["outputs"])
    # the planned joints, through the URDF's own kinematics composed by hand, put the TCP on the line
    table = np.genfromtxt(out / "trajectory.csv", delimiter=",", names=True)
    q = np.column_stack([table[f"q{j}"] for j in range(1, 7)])
    robot = refine.Robot.from_urdf(folder / "robot" / "reference.urdf", controller="kuka")
    tcp = np.array([robot.fk(qk) @ [0.0, 0.0, 0.15, 1.0] for qk in q])[:, :3]
    assert np.abs(tcp[:, 0] - 0.9).max() < 1e-6 and np.abs(tcp[:, 2] - 0.4).max() < 1e-6
    assert tcp[0, 1] == pytest.approx(-0.1, abs=1e-6) and tcp[-1, 1] == pytest.approx(0.1, abs=1e-6)
