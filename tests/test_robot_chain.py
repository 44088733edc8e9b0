"""A workcell URDF: the arm's chain named by its base link and flange, every other joint locked."""

from __future__ import annotations

import numpy as np
import pytest

from refine.errors import InputError
from refine.problem import load_problem
from refine.robot.model import robot_from_urdf
from refine.robot.registry import robot_for

# world -> table (0.5 m up) -> base_link -> j1 (about z) -> j2 (about y, 0.3 m up) -> tool0 (0.2 m up);
# world -> turntable joint (about z, 1 m along x) -> fixture, with a box on the fixture
WORKCELL = """<robot name="cell">
  <link name="world"/>
  <link name="table"/>
  <joint name="world-table" type="fixed"><parent link="world"/><child link="table"/>
    <origin xyz="0 0 0.5"/></joint>
  <link name="base_link"/>
  <joint name="table-base" type="fixed"><parent link="table"/><child link="base_link"/></joint>
  <link name="l1"/>
  <joint name="j1" type="revolute"><parent link="base_link"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" velocity="2" effort="0"/></joint>
  <link name="l2"/>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.3"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" velocity="2" effort="0"/></joint>
  <link name="tool0"/>
  <joint name="l2-tool0" type="fixed"><parent link="l2"/><child link="tool0"/><origin xyz="0 0 0.2"/></joint>
  <link name="fixture"><collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision></link>
  <joint name="turntable" type="revolute"><parent link="world"/><child link="fixture"/>
    <origin xyz="1 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" velocity="1" effort="0"/></joint>
</robot>
"""


@pytest.fixture
def workcell(tmp_path):
    path = tmp_path / "cell.urdf"
    path.write_text(WORKCELL)
    return path


def test_an_unlocked_joint_off_the_chain_is_named(workcell):
    with pytest.raises(InputError, match=r"turntable do not carry the flange 'tool0'.*locked_joints_deg"):
        robot_from_urdf(workcell, controller="abb")
    with pytest.raises(InputError, match=r"names \['spindle'\], not joints"):
        robot_from_urdf(workcell, controller="abb", locked_joints_deg={"turntable": 0.0, "spindle": 0.0})


def test_the_chain_from_its_base_link_with_the_rest_locked(workcell):
    robot = robot_from_urdf(
        workcell, controller="abb", base_link="base_link", locked_joints_deg={"turntable": 30.0}
    )
    assert robot.spec.joint_names == ("j1", "j2")
    # by hand: in base_link's frame, tool0 is 0.3 + 0.2 m up at zero; j2 = 90 deg swings the 0.2 m to +x
    assert robot.fk(np.zeros(2))[:3, 3] == pytest.approx([0.0, 0.0, 0.5])
    assert robot.fk(np.array([0.0, np.pi / 2]))[:3, 3] == pytest.approx([0.2, 0.0, 0.3])
    assert robot.fk(np.array([np.pi / 2, np.pi / 2]))[:3, 3] == pytest.approx([0.0, 0.2, 0.3])
    # the fixture stays with the old root: 1 m along x and 0.5 m below the base, turned 30 deg
    fixture = robot.model.frames[robot.model.getFrameId("fixture")].placement
    assert fixture.translation == pytest.approx([1.0, 0.0, -0.5])
    assert np.degrees(np.arctan2(fixture.rotation[1, 0], fixture.rotation[0, 0])) == pytest.approx(30.0)
    # without base_link the URDF's root is the base: tool0 is 0.5 m higher
    rooted = robot_from_urdf(workcell, controller="abb", locked_joints_deg={"turntable": 0.0})
    assert rooted.fk(np.zeros(2))[:3, 3] == pytest.approx([0.0, 0.0, 1.0])


def test_a_locked_joint_on_the_chain_and_a_moving_base_link(workcell):
    robot = robot_from_urdf(
        workcell, controller="abb", reach_m=0.5, locked_joints_deg={"turntable": 0.0, "j2": 90.0}
    )
    assert robot.spec.joint_names == ("j1",)
    assert robot.fk(np.zeros(1))[:3, 3] == pytest.approx([0.2, 0.0, 0.8])
    with pytest.raises(InputError, match=r"base_link 'l2' is moved by joint 'j2'"):
        robot_from_urdf(workcell, controller="abb", base_link="l2", locked_joints_deg={"turntable": 0.0})


def test_the_problem_file_names_the_chain(workcell):
    folder = workcell.parent
    (folder / "problem.toml").write_text(
        'name = "cell"\n[robot]\nurdf = "cell.urdf"\ncontroller = "abb"\nbase_link = "base_link"\n'
        "locked_joints_deg = { turntable = 0.0 }\n"
        '[tool]\nname = "t"\ntcp_in_flange = { xyz = [0, 0, 0.1] }\n'
        '[cad]\nfile = "p.csv"\n[demonstration]\nfile = "d.csv"\n'
    )
    (folder / "p.csv").write_text("x,y,z\n0.1,0,0.5\n0.12,0,0.5\n")
    (folder / "d.csv").write_text("t,x,y,z,qw,qx,qy,qz\n0,0.1,0,0.5,1,0,0,0\n")
    problem = load_problem(folder)
    assert problem.robot.base_link == "base_link"
    assert problem.robot.locked_joints_deg == (("turntable", 0.0),)
    assert robot_for(problem.robot).spec.joint_names == ("j1", "j2")
    text = (folder / "problem.toml").read_text()
    (folder / "problem.toml").write_text(
        text.replace("locked_joints_deg = { turntable = 0.0 }", "locked_joints_deg = 3")
    )
    with pytest.raises(InputError, match="locked_joints_deg must be a table of joint = value"):
        load_problem(folder)
