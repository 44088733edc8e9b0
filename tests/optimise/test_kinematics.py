"""CasADi kinematics of refine.optimise.kinematics against Pinocchio and finite differences."""

from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from refine.errors import InputError
from refine.frames import make_transform, matrix_from_fixed_xyz
from refine.optimise.kinematics import fk_function, jacobian_function
from refine.robot.model import Robot
from refine.robot.registry import load_robot
from refine.robot.spec import RobotSpec

NAMES = ["abb_irb4600_60_205", "kuka_iiwa14_r820", "ur10e"]

# a tilted, shifted base and a tool that is neither short nor aligned with the flange
BASE_IN_WORLD = make_transform(matrix_from_fixed_xyz([10.0, -20.0, 35.0]), [0.4, -0.3, 0.6])
TCP_IN_FLANGE = make_transform(matrix_from_fixed_xyz([5.0, 40.0, -60.0]), [0.02, -0.03, 0.25])


@pytest.fixture(scope="session")
def robots() -> dict[str, Robot]:
    return {name: load_robot(name) for name in NAMES}


@pytest.fixture(scope="session")
def functions(robots) -> dict[str, tuple[ca.Function, ca.Function]]:
    return {
        name: (
            fk_function(r, BASE_IN_WORLD, TCP_IN_FLANGE),
            jacobian_function(r, BASE_IN_WORLD, TCP_IN_FLANGE),
        )
        for name, r in robots.items()
    }


def _configurations(robot: Robot, n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(robot.spec.lower, robot.spec.upper, (n, robot.nq))


def _tcp_jacobian_pinocchio(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Pinocchio's own Jacobian at a TCP frame added to a copy of the model, in world axes."""
    model = pin.Model(robot.model)
    flange = model.frames[robot.flange_id]
    tcp = model.addFrame(
        pin.Frame(
            "tcp",
            flange.parentJoint,
            robot.flange_id,
            flange.placement * pin.SE3(TCP_IN_FLANGE),
            pin.OP_FRAME,
        )
    )
    J = pin.computeFrameJacobian(model, model.createData(), q, tcp, pin.LOCAL_WORLD_ALIGNED)
    R = BASE_IN_WORLD[:3, :3]
    return np.vstack([R @ J[:3], R @ J[3:]])


@pytest.mark.parametrize("name", NAMES)
def test_fk_matches_pinocchio_on_50_random_configurations(robots, functions, name):
    robot, (fk, _) = robots[name], functions[name]
    for q in _configurations(robot, 50, seed=1):
        T = BASE_IN_WORLD @ robot.fk(q) @ TCP_IN_FLANGE
        p, R = fk(q)
        np.testing.assert_allclose(np.asarray(p).ravel(), T[:3, 3], rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.asarray(R), T[:3, :3], rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_jacobian_matches_pinocchio_frame_jacobian(robots, functions, name):
    robot, (_, jac) = robots[name], functions[name]
    for q in _configurations(robot, 20, seed=2):
        np.testing.assert_allclose(np.asarray(jac(q)), _tcp_jacobian_pinocchio(robot, q), rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_jacobian_matches_finite_differences_of_the_casadi_fk(robots, functions, name):
    robot, (fk, jac) = robots[name], functions[name]
    h = 1e-6
    for q in _configurations(robot, 5, seed=3):
        J = np.asarray(jac(q))
        R0 = np.asarray(fk(q)[1])
        for k in range(robot.nq):
            dq = np.zeros(robot.nq)
            dq[k] = h
            (pp, Rp), (pm, Rm) = fk(q + dq), fk(q - dq)
            v = np.asarray(pp - pm).ravel() / (2 * h)
            W = np.asarray(Rp - Rm) / (2 * h) @ R0.T  # skew matrix of the angular velocity
            np.testing.assert_allclose(J[:3, k], v, atol=1e-8)
            np.testing.assert_allclose(J[3:, k], [W[2, 1], W[0, 2], W[1, 0]], atol=1e-8)


@pytest.mark.parametrize("name", NAMES)
def test_each_joint_angle_is_put_through_sin_and_cos_once(robots, functions, name):
    for f in functions[name]:
        ops = [f.instruction_id(k) for k in range(f.n_instructions())]
        assert ops.count(ca.OP_SIN) == ops.count(ca.OP_COS) == robots[name].nq


def test_functions_are_named_and_map_over_waypoints(functions):
    fk, jac = functions["ur10e"]
    assert (fk.name(), fk.name_in(), fk.name_out()) == ("fk", ["q"], ["p", "R"])
    assert (jac.name(), jac.name_in(), jac.name_out()) == ("jacobian", ["q"], ["J"])
    qs = np.random.default_rng(4).uniform(-1.0, 1.0, (6, 8))
    p_all = np.asarray(fk.map(8)(qs)[0])
    assert p_all.shape == (3, 8)
    np.testing.assert_allclose(p_all[:, 3], np.asarray(fk(qs[:, 3])[0]).ravel(), atol=1e-15)


def _toy_robot(joint_models: list) -> Robot:
    """A chain of the given Pinocchio joints with offset placements and a tool0 frame."""
    model = pin.Model()
    rng = np.random.default_rng(9)
    parent = 0
    for k, joint in enumerate(joint_models):
        placement = pin.SE3(matrix_from_fixed_xyz(rng.uniform(-90, 90, 3)), rng.uniform(-1, 1, 3))
        parent = model.addJoint(parent, joint, placement, f"j{k}")
    model.addFrame(pin.Frame("tool0", parent, 0, pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.1])), pin.OP_FRAME))
    n = model.nq
    spec = RobotSpec(
        "toy",
        "none",
        Path("toy.urdf"),
        "tool0",
        tuple(f"j{k}" for k in range(n)),
        -np.pi * np.ones(n),
        np.pi * np.ones(n),
        np.ones(n),
        np.ones(n),
        1.0,
        "ur",
    )
    return Robot(spec, model)


def test_unaligned_axes_and_rotated_placements_match_pinocchio():
    axes = np.random.default_rng(10).normal(size=(4, 3))
    joints = [pin.JointModelRevoluteUnaligned(a / np.linalg.norm(a)) for a in axes]
    robot = _toy_robot([pin.JointModelRX(), *joints, pin.JointModelRY()])
    fk = fk_function(robot, BASE_IN_WORLD, TCP_IN_FLANGE)
    jac = jacobian_function(robot, BASE_IN_WORLD, TCP_IN_FLANGE)
    for q in _configurations(robot, 10, seed=12):
        T = BASE_IN_WORLD @ robot.fk(q) @ TCP_IN_FLANGE
        p, R = fk(q)
        np.testing.assert_allclose(np.asarray(p).ravel(), T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(np.asarray(R), T[:3, :3], atol=1e-12)
        np.testing.assert_allclose(np.asarray(jac(q)), _tcp_jacobian_pinocchio(robot, q), atol=1e-12)


def test_unsupported_joint_type_is_named():
    robot = _toy_robot([pin.JointModelRZ(), pin.JointModelPX()])
    with pytest.raises(InputError, match="joint 'j1' is a JointModelPX; supported joint types"):
        fk_function(robot, np.eye(4), np.eye(4))


def test_non_rigid_transforms_are_rejected(robots):
    with pytest.raises(InputError, match="base_in_world"):
        fk_function(robots["ur10e"], 2.0 * np.eye(4), np.eye(4))
    with pytest.raises(InputError, match="tcp_in_flange"):
        jacobian_function(robots["ur10e"], np.eye(4), np.eye(3))
