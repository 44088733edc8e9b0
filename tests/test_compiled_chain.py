"""The compiled batch kinematics (refine.robot.compiled_chain) against Pinocchio's row-by-row evaluation."""

from __future__ import annotations

import logging
import pickle
import threading

import numpy as np
import pinocchio as pin
import pytest

from refine.robot import compiled_chain as compiled_module
from refine.robot.chain import MIN_ROWS, BatchChain
from refine.robot.compiled_chain import COMPILED_MIN_ROWS, CompiledChain
from refine.robot.registry import available_robots, load_robot
from tests.test_batch_chain import TREE

pytestmark = pytest.mark.skipif(compiled_module.compiler() is None, reason="no C compiler")


def _fresh(model: pin.Model, flange_id: int) -> CompiledChain:
    chain = CompiledChain.from_model(model, flange_id)
    assert chain is not None
    return chain


def _assert_pinocchio(model: pin.Model, chain: CompiledChain, fid: int, qs: np.ndarray) -> None:
    """Flange placements, Jacobians (with and without) and every joint's oMi against Pinocchio, 1e-12."""
    data = model.createData()
    T, J = chain.frame(qs, fid)
    T_alone, none = chain.frame(qs, fid, jacobian=False)
    oMi = chain.joint_placements(qs)
    assert none is None and T.shape == (len(qs), 4, 4) and J.shape == (len(qs), 6, model.nv)
    assert oMi.shape == (len(qs), model.njoints, 4, 4)
    for k, q in enumerate(qs):
        pin.forwardKinematics(model, data, q)  # every joint (the Jacobian's pass: only the frame's support)
        oMi_pin = [data.oMi[i].homogeneous.copy() for i in range(model.njoints)]
        J_pin = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)
        T_pin = pin.updateFramePlacement(model, data, fid).homogeneous
        np.testing.assert_allclose(T[k], T_pin, rtol=0, atol=1e-12)
        np.testing.assert_allclose(T_alone[k], T_pin, rtol=0, atol=1e-12)
        np.testing.assert_allclose(J[k], J_pin, rtol=0, atol=1e-12)
        for i in range(model.njoints):
            np.testing.assert_allclose(oMi[k, i], oMi_pin[i], rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", available_robots())
def test_the_compiled_chain_agrees_with_pinocchio_on_every_registry_robot(name: str, chain_cache) -> None:
    robot = load_robot(name)
    chain = _fresh(robot.model, robot.flange_id)
    assert chain.compiled and chain.min_rows == COMPILED_MIN_ROWS
    rng = np.random.default_rng(sum(map(ord, name)))
    qs = rng.uniform(robot.spec.lower, robot.spec.upper, (37, robot.nq))  # 37: no round number of rows
    _assert_pinocchio(robot.model, chain, robot.flange_id, qs)
    _assert_tcp(robot.model, chain, robot.flange_id, qs)


BASE = pin.SE3(pin.exp3(np.array([0.02, -0.03, 0.5])), np.array([0.2, -0.1, 0.05])).homogeneous
TCP = pin.SE3(pin.exp3(np.array([0.0, 0.35, 0.1])), np.array([0.01, 0.02, 0.25])).homogeneous


def _assert_tcp(model: pin.Model, chain: CompiledChain, fid: int, qs: np.ndarray) -> None:
    """The TCP's world pose and Jacobian against Pinocchio's frame of a TCP added to the model, 1e-12.

    The model with a frame at ``TCP`` on the flange and ``BASE`` applied by hand: ``oMf`` of the
    new frame, its ``LOCAL_WORLD_ALIGNED`` Jacobian turned into world axes by ``R(BASE)``.
    """
    with_tcp = model.copy()
    flange = model.frames[fid]
    placement = flange.placement * pin.SE3(TCP)
    tcp_id = with_tcp.addFrame(pin.Frame("tcp", flange.parentJoint, fid, placement, pin.FrameType.OP_FRAME))
    data = with_tcp.createData()
    T, J = chain.tcp_frames(qs, BASE, TCP)
    T_alone, none = chain.tcp_frames(qs, BASE, TCP, jacobian=False)
    assert none is None
    R = BASE[:3, :3]
    for k, q in enumerate(qs):
        J_pin = pin.computeFrameJacobian(with_tcp, data, q, tcp_id, pin.LOCAL_WORLD_ALIGNED)
        T_pin = BASE @ pin.updateFramePlacement(with_tcp, data, tcp_id).homogeneous
        np.testing.assert_allclose(T[k], T_pin, rtol=0, atol=1e-12)
        np.testing.assert_allclose(T_alone[k], T_pin, rtol=0, atol=1e-12)
        np.testing.assert_allclose(J[k], np.vstack([R @ J_pin[:3], R @ J_pin[3:]]), rtol=0, atol=1e-12)


def test_the_compiled_chain_agrees_with_pinocchio_on_a_tree_of_prismatic_and_unaligned_joints(chain_cache) -> None:
    model = pin.buildModelFromXML(TREE)
    chain = _fresh(model, model.getFrameId("tip"))
    assert chain.compiled
    qs = np.random.default_rng(11).uniform(-3.5, 3.5, (23, model.nq))
    _assert_pinocchio(model, chain, model.getFrameId("tip"), qs)
    _assert_tcp(model, chain, model.getFrameId("tip"), qs)
    # another frame than the flange, and a subset of the joints: the NumPy chain's answers
    side = model.getFrameId("side")
    T_side, J_side = chain.frame(qs, side)
    T_np, J_np = BatchChain.from_model(model).frame(qs, side)
    assert np.array_equal(T_side, T_np) and np.array_equal(J_side, J_np)
    np.testing.assert_allclose(
        chain.joint_placements(qs, [3, 1]), chain.joint_placements(qs)[:, [3, 1]], rtol=0, atol=0
    )


def test_one_row_and_no_rows_are_evaluated_too(chain_cache) -> None:
    robot = load_robot("kuka_iiwa14_r820")
    chain = _fresh(robot.model, robot.flange_id)
    q = np.random.default_rng(2).uniform(robot.spec.lower, robot.spec.upper, (1, robot.nq))
    _assert_pinocchio(robot.model, chain, robot.flange_id, q)
    _assert_tcp(robot.model, chain, robot.flange_id, q)
    T, J = chain.tcp_frames(np.zeros((0, robot.nq)), BASE, TCP)
    assert T.shape == (0, 4, 4) and J.shape == (0, 6, robot.nq)
    T, J = chain.frame(np.zeros((0, robot.nq)), robot.flange_id)
    assert T.shape == (0, 4, 4) and J.shape == (0, 6, robot.nq)
    assert chain.joint_placements(np.zeros((0, robot.nq))).shape == (0, robot.model.njoints, 4, 4)
    with pytest.raises(ValueError, match="expected shape"):
        chain.frame(np.zeros((3, robot.nq + 1)), robot.flange_id)


def test_without_compilation_the_chain_is_numpys(chain_cache, monkeypatch) -> None:
    monkeypatch.setenv("REFINE_COMPILE", "0")
    robot = load_robot("abb_irb4600_60_205")
    chain = _fresh(robot.model, robot.flange_id)
    assert not chain.compiled and chain.min_rows == MIN_ROWS
    qs = np.random.default_rng(4).uniform(robot.spec.lower, robot.spec.upper, (50, robot.nq))
    numpy_chain = BatchChain.from_model(robot.model)
    T, J = chain.frame(qs, robot.flange_id)
    T_np, J_np = numpy_chain.frame(qs, robot.flange_id)
    assert np.array_equal(T, T_np) and np.array_equal(J, J_np)
    assert np.array_equal(chain.joint_placements(qs), numpy_chain.joint_placements(qs))
    assert chain.tcp_frames(qs, np.eye(4), np.eye(4)) is None  # the caller composes NumPy's flange


def test_a_compiler_that_fails_leaves_numpys_chain_with_a_warning(tmp_path, monkeypatch, caplog) -> None:
    monkeypatch.setenv("REFINE_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CC", "false")  # found on the PATH, exits 1 for everything
    monkeypatch.setattr(compiled_module, "_loaded", compiled_module.BoundedCache(compiled_module.LOADED_MAX))
    robot = load_robot("abb_irb4600_60_205")
    with caplog.at_level(logging.WARNING, logger=compiled_module.__name__):
        chain = _fresh(robot.model, robot.flange_id)
        assert not chain.compiled
    assert "compiling the batch kinematics failed" in caplog.text
    assert not list(tmp_path.glob("*.so"))


def test_a_library_that_disagrees_with_pinocchio_is_not_used(tmp_path, monkeypatch, caplog) -> None:
    """A wrong sign in one joint's turn in the generated code: the load check finds it, NumPy answers."""
    monkeypatch.setenv("REFINE_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(compiled_module, "_loaded", compiled_module.BoundedCache(compiled_module.LOADED_MAX))
    right = BatchChain.row_axis_frames

    def wrong(self, q, cos, sin):  # the fourth joint turns the other way
        return right(self, [(-x if i == 3 else x) for i, x in enumerate(q)], cos, sin)

    monkeypatch.setattr(BatchChain, "row_axis_frames", wrong)
    robot = load_robot("abb_irb4600_60_205")
    with caplog.at_level(logging.WARNING, logger=compiled_module.__name__):
        chain = _fresh(robot.model, robot.flange_id)
        assert not chain.compiled and chain.min_rows == MIN_ROWS
    assert "differ from Pinocchio" in caplog.text
    qs = np.random.default_rng(6).uniform(robot.spec.lower, robot.spec.upper, (20, robot.nq))
    _assert_pinocchio(robot.model, chain, robot.flange_id, qs)


def test_two_threads_at_once_get_their_own_answers(chain_cache) -> None:
    robot = load_robot("kuka_iiwa14_r820")
    chain = _fresh(robot.model, robot.flange_id)
    rng = np.random.default_rng(8)
    batches = [rng.uniform(robot.spec.lower, robot.spec.upper, (2000 + 7 * k, robot.nq)) for k in range(2)]
    alone = [chain.frame(qs, robot.flange_id) for qs in batches]
    barrier, got, errors = threading.Barrier(2), [None, None], []

    def run(k: int) -> None:
        try:
            barrier.wait()
            for _ in range(20):
                T, J = chain.frame(batches[k], robot.flange_id)
                oMi = chain.joint_placements(batches[k])
                T_tcp, J_tcp = chain.tcp_frames(batches[k], BASE, TCP)
            got[k] = (T, J, oMi, T_tcp, J_tcp)
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    for k in range(2):
        T, J, oMi, T_tcp, J_tcp = got[k]
        assert np.array_equal(T, alone[k][0]) and np.array_equal(J, alone[k][1])
        assert np.array_equal(oMi, chain.joint_placements(batches[k]))
        T_one, J_one = chain.tcp_frames(batches[k], BASE, TCP)
        assert np.array_equal(T_tcp, T_one) and np.array_equal(J_tcp, J_one)


def test_a_pickled_robot_evaluates_its_chain_on_the_other_side(chain_cache) -> None:
    robot = load_robot("abb_irb4600_60_205")
    qs = np.random.default_rng(9).uniform(robot.spec.lower, robot.spec.upper, (30, robot.nq))
    before = robot.fk_many(qs)
    copy = pickle.loads(pickle.dumps(robot))
    assert copy.chain.compiled
    assert np.array_equal(copy.fk_many(qs), before)


def test_bodies_on_the_joints_are_placed_as_pinocchios_joints_say(chain_cache) -> None:
    robot = load_robot("kuka_iiwa14_r820")
    model, data = robot.model, robot.model.createData()
    chain = _fresh(model, robot.flange_id)
    rng = np.random.default_rng(12)
    joints = np.array([0, 3, model.njoints - 1, 3, 1])
    local = np.array([pin.SE3.Random().homogeneous for _ in joints])
    qs = rng.uniform(robot.spec.lower, robot.spec.upper, (29, robot.nq))
    poses = chain.body_poses(qs, BASE, joints, local)
    assert poses.shape == (29, len(joints), 4, 4)
    for k, q in enumerate(qs):
        pin.forwardKinematics(model, data, q)
        for m, j in enumerate(joints):
            np.testing.assert_allclose(
                poses[k, m], BASE @ data.oMi[int(j)].homogeneous @ local[m], rtol=0, atol=1e-12
            )
    assert chain.body_poses(qs[:0], BASE, joints, local).shape == (0, len(joints), 4, 4)
    with pytest.raises(ValueError, match="joint indices"):
        chain.body_poses(qs, BASE, [model.njoints], local[:1])
    numpy_only = CompiledChain.from_model(model, robot.flange_id, compile=False)
    assert numpy_only.body_poses(qs, BASE, joints, local) is None
