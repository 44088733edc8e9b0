"""The batched NumPy kinematics (refine.robot.chain) against Pinocchio's row-by-row evaluation."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from refine.frames import make_transform
from refine.robot.chain import MIN_ROWS, BatchChain, axis_frame
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import available_robots, load_robot

ROWS = max(MIN_ROWS, 150)

# a tree with every joint kind the chain takes: unaligned and negative axes, prismatic joints,
# a branch off the first link (its joint moves no frame of the other branch)
TREE = """<robot name="tree">
  <link name="base"/>
  <link name="a"/><link name="b"/><link name="c"/><link name="d"/><link name="e"/><link name="side"/>
  <link name="tip"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 -1"/>
    <origin xyz="0.1 0 0.2" rpy="0.1 -0.2 0.3"/><limit lower="-3" upper="3" velocity="1" effort="0"/></joint>
  <joint name="branch" type="prismatic"><parent link="a"/><child link="side"/><axis xyz="1 0 0"/>
    <origin xyz="0 0.3 0"/><limit lower="-1" upper="1" velocity="1" effort="0"/></joint>
  <joint name="j2" type="prismatic"><parent link="a"/><child link="b"/><axis xyz="0.3 -0.4 0.866"/>
    <origin xyz="0 0 0.4" rpy="0.5 0 0"/><limit lower="-1" upper="1" velocity="1" effort="0"/></joint>
  <joint name="j3" type="revolute"><parent link="b"/><child link="c"/><axis xyz="0.6 0 0.8"/>
    <origin xyz="0.2 0.1 0" rpy="0 0.7 -0.4"/><limit lower="-3" upper="3" velocity="1" effort="0"/></joint>
  <joint name="j4" type="revolute"><parent link="c"/><child link="d"/><axis xyz="0 -1 0"/>
    <origin xyz="0 0 0.3"/><limit lower="-3" upper="3" velocity="1" effort="0"/></joint>
  <joint name="j5" type="prismatic"><parent link="d"/><child link="e"/><axis xyz="0 1 0"/>
    <origin xyz="0.05 0 0" rpy="1.2 0.3 0.2"/><limit lower="-1" upper="1" velocity="1" effort="0"/></joint>
  <joint name="e-tip" type="fixed"><parent link="e"/><child link="tip"/><origin xyz="0 0.1 0.25" rpy="0.3 0.2 0.1"/></joint>
</robot>"""


def _random_rows(model: pin.Model, rows: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(-3.5, 3.5, (rows, model.nq))  # past the limits too: the kinematics does not care


def _compare(model: pin.Model, frame_ids: list[int], seed: int) -> None:
    chain = BatchChain.from_model(model)
    assert chain is not None
    data = model.createData()
    qs = _random_rows(model, 40, seed)
    oMi = chain.joint_placements(qs)
    for fid in frame_ids:
        T, J = chain.frame(qs, fid)
        for k, q in enumerate(qs):
            J_pin = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)
            pin.framesForwardKinematics(model, data, q)
            np.testing.assert_allclose(T[k], data.oMf[fid].homogeneous, rtol=0, atol=1e-12)
            np.testing.assert_allclose(J[k], J_pin, rtol=0, atol=1e-12)
            for i in range(model.njoints):
                np.testing.assert_allclose(oMi[k, i], data.oMi[i].homogeneous, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", available_robots())
def test_the_chain_agrees_with_pinocchio_on_every_registry_robot(name: str) -> None:
    robot = load_robot(name)
    _compare(robot.model, [robot.flange_id], seed=hash(name) % 1000)


def test_the_chain_agrees_with_pinocchio_on_a_tree_of_prismatic_and_unaligned_joints() -> None:
    model = pin.buildModelFromXML(TREE)
    kinds = {model.joints[i].shortname() for i in range(1, model.njoints)}
    assert {"JointModelPrismaticUnaligned", "JointModelRevoluteUnaligned", "JointModelPX"} <= kinds
    frames = [model.getFrameId(n) for n in ("tip", "side", "base", "c")]
    _compare(model, frames, seed=7)
    T, J = BatchChain.from_model(model).frame(np.zeros((3, model.nq)), model.getFrameId("tip"))
    assert np.all(J[:, :, model.joints[model.getJointId("branch")].idx_v] == 0.0)


def test_a_continuous_joint_gives_no_chain_and_the_robot_keeps_pinocchio() -> None:
    model = pin.buildModelFromXML(TREE.replace('name="j4" type="revolute"', 'name="j4" type="continuous"'))
    assert model.nq == model.nv + 1  # a continuous joint's two variables
    assert BatchChain.from_model(model) is None


@pytest.mark.parametrize("axis", [[1, 0, 0], [0, -1, 0], [0, 0, -1], [0.3, -0.4, 0.866], [-1e-9, 1, 0]])
def test_an_axis_frame_is_a_rotation_onto_the_axis(axis: list[float]) -> None:
    A = axis_frame(axis)
    np.testing.assert_allclose(A.T @ A, np.eye(3), atol=1e-15)
    assert np.linalg.det(A) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(A[:, 2], np.asarray(axis) / np.linalg.norm(axis), atol=1e-15)


def _pose(p: list[float], xyz_deg: list[float]) -> np.ndarray:
    return make_transform(Rotation.from_euler("xyz", xyz_deg, degrees=True).as_matrix(), p)


BASE = _pose([0.2, -0.1, 0.05], [1.0, -2.0, 30.0])
TCP = _pose([0.01, 0.02, 0.25], [0.0, 20.0, 5.0])
TOOL_IN_WORLD = _pose([1.4, 0.3, 0.9], [180.0, 0.0, 10.0])


@pytest.mark.parametrize("name", ["abb_irb4600_60_205", "kuka_iiwa14_r820"])
@pytest.mark.parametrize("stationary", [False, True])
def test_a_batch_of_many_rows_equals_pinocchios_pose_and_jacobian_row_by_row(
    name: str, stationary: bool
) -> None:
    robot = load_robot(name)
    kin = TcpKinematics(robot, BASE, TCP, TOOL_IN_WORLD if stationary else None)
    qs = np.random.default_rng(3).uniform(robot.spec.lower, robot.spec.upper, (ROWS, robot.nq))
    p, R, J = kin.batch(qs)
    poses = kin.poses(qs)
    T_both, J_both = kin.poses_jacobians(qs)
    assert np.array_equal(T_both, poses) and np.array_equal(J_both, J)  # the same products, the same bits
    for k, q in enumerate(qs):
        T_pin, J_pin = kin.pose_jacobian(q)  # one pass of Pinocchio
        np.testing.assert_allclose(p[k], T_pin[:3, 3], rtol=0, atol=1e-12)
        np.testing.assert_allclose(R[k], T_pin[:3, :3], rtol=0, atol=1e-12)
        np.testing.assert_allclose(J[k], J_pin, rtol=0, atol=1e-12)
        np.testing.assert_allclose(poses[k], T_pin, rtol=0, atol=1e-12)


def test_the_collision_models_moving_poses_of_many_rows_equal_its_row_by_row_ones() -> None:
    from refine.collision.model import CollisionModel

    robot = load_robot("kuka_iiwa14_r820")
    model = CollisionModel(robot, BASE, TCP, (), (), margin_m=0.01, self_margin_m=0.005)
    qs = np.random.default_rng(5).uniform(robot.spec.lower, robot.spec.upper, (ROWS, robot.nq))
    many = model.moving_poses(qs)
    one_by_one = np.concatenate([model.moving_poses(q[None]) for q in qs])  # one row: Pinocchio's loop
    assert many.shape == one_by_one.shape and many.shape[1] > 5
    np.testing.assert_allclose(many, one_by_one, rtol=0, atol=1e-12)
