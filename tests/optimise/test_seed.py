import numpy as np
import pytest

from refine.optimise.seed import ik_chain, shift_turns, start_candidates
from refine.robot.kinematics import solve_ik


def test_dls_ik_reaches_a_reachable_pose(kin):
    spec = kin.robot.spec
    q_true = np.array([0.3, 0.4, -0.2, 0.5, -0.9, 1.2])
    q, err = solve_ik(kin, kin.pose(q_true), np.zeros(6), spec.lower, spec.upper, max_iterations=300)
    assert err < 1e-6
    assert np.abs(kin.pose(q) - kin.pose(q_true)).max() < 1e-6


def test_tcp_jacobian_matches_finite_differences(kin):
    q = np.array([0.3, 0.4, -0.2, 0.5, -0.9, 1.2])
    J = kin.jacobian(q)
    h = 1e-7
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        dp = (kin.pose(q + dq)[:3, 3] - kin.pose(q - dq)[:3, 3]) / (2 * h)
        np.testing.assert_allclose(J[:3, j], dp, atol=1e-6)


def test_pose_and_jacobian_in_one_pass_match_pinocchio_at_a_tcp_frame_and_finite_differences(irb4600):
    """One pose and many rows at once (``batch``), checked against a TCP frame added to a copy of the model (Pinocchio's own Jacobian there) and
    against central differences of the TCP position and orientation, with a base turned and moved."""
    import pinocchio as pin

    from refine.frames import transform_from_xyz_rpy
    from refine.robot.kinematics import TcpKinematics

    base = transform_from_xyz_rpy([0.4, -0.2, 0.1], [0.0, 0.0, 30.0])
    tool = transform_from_xyz_rpy([0.02, -0.01, 0.3], [10.0, 0.0, 20.0])
    kin = TcpKinematics(irb4600, base, tool)
    model = pin.Model(irb4600.model)
    flange = model.frames[irb4600.flange_id]
    tcp = model.addFrame(
        pin.Frame(
            "tcp", flange.parentJoint, irb4600.flange_id, flange.placement * pin.SE3(tool), pin.OP_FRAME
        )
    )
    data = model.createData()
    rng = np.random.default_rng(5)
    for q in rng.uniform(-1.5, 1.5, size=(5, 6)):
        T, J = kin.pose_jacobian(q)
        p_b, R_b, J_b = (v[0] for v in kin.batch(q[None]))
        J_ref = pin.computeFrameJacobian(model, data, q, tcp, pin.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(T, base @ data.oMf[tcp].homogeneous, atol=1e-12)
        np.testing.assert_allclose(p_b, T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(R_b, T[:3, :3], atol=1e-12)
        np.testing.assert_allclose(J_b, J, atol=1e-12)
        np.testing.assert_allclose(
            J, np.vstack([base[:3, :3] @ J_ref[:3], base[:3, :3] @ J_ref[3:]]), atol=1e-12
        )
        h = 1e-6
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = h
            Tp, Tm = kin.pose(q + dq), kin.pose(q - dq)
            np.testing.assert_allclose(J[:3, j], (Tp[:3, 3] - Tm[:3, 3]) / (2 * h), atol=1e-7)
            omega = pin.log3(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * h)
            np.testing.assert_allclose(J[3:, j], omega, atol=1e-7)
    qs = rng.uniform(-1.5, 1.5, size=(7, 6))
    p_all, R_all, J_all = kin.batch(qs)
    for k, q in enumerate(qs):  # row k of the batch is the pose and Jacobian of row k alone
        T, J = kin.pose_jacobian(q)
        np.testing.assert_allclose(p_all[k], T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(R_all[k], T[:3, :3], atol=1e-12)
        np.testing.assert_allclose(J_all[k], J, atol=1e-12)


def test_shift_turns_moves_a_wrapped_joint_by_whole_turns_into_its_limits():
    lower = np.radians([-180, -90, -180, -400, -125, -400])
    upper = np.radians([180, 150, 75, 400, 120, 400])
    qs = np.zeros((10, 6))
    qs[:, 5] = np.radians(np.linspace(-80, -440, 10))  # 360 deg of turn, past -400
    shifted = shift_turns(qs, lower, upper)
    assert np.all(shifted[:, 5] >= lower[5]) and np.all(shifted[:, 5] <= upper[5])
    np.testing.assert_allclose(np.mod(shifted[:, 5] - qs[:, 5], 2 * np.pi) % (2 * np.pi), 0, atol=1e-12)
    np.testing.assert_array_equal(shifted[:, :5], qs[:, :5])


def test_chained_seed_follows_a_full_turn_of_the_tool_without_leaving_the_limits(kin):
    """A closed loop whose tool heading turns 360 degrees: axis 6 must unwind within +-400 deg."""
    n = 120
    theta = np.linspace(0, 2 * np.pi, n)
    positions = np.column_stack([1.3 + 0.2 * np.cos(theta), 0.2 * np.sin(theta), np.full(n, 0.6)])
    heading = theta + np.pi / 2
    R = np.stack(
        [np.array([[np.cos(a), np.sin(a), 0], [np.sin(a), -np.cos(a), 0], [0, 0, -1]]) for a in heading]
    )
    targets = np.tile(np.eye(4), (n, 1, 1))
    targets[:, :3, :3], targets[:, :3, 3] = R, positions
    spec = kin.robot.spec
    lower, upper = spec.lower + np.radians(2), spec.upper - np.radians(2)
    qs, errors = ik_chain(kin, targets, lower, upper, start_candidates(lower, upper, None))
    assert errors.max() < 1e-5
    assert np.all(qs >= lower - 1e-9) and np.all(qs <= upper + 1e-9)
    assert np.degrees(np.abs(np.diff(qs, axis=0)).max()) < 20.0  # continuous: no branch jumps


def test_batched_ik_solves_each_pose_as_the_single_pose_ik_does(kin):
    from refine.robot.kinematics import solve_ik, solve_ik_batch

    rng = np.random.default_rng(4)
    lower, upper = kin.robot.spec.lower, kin.robot.spec.upper
    q_true = rng.uniform(0.6 * lower, 0.6 * upper, size=(12, 6))
    targets = kin.poses(q_true)  # reachable poses from Pinocchio's forward kinematics
    starts = q_true + rng.normal(scale=0.05, size=q_true.shape)
    q_batch, err_batch = solve_ik_batch(kin, targets, starts, lower, upper)
    for k in range(len(targets)):
        q_one, err_one = solve_ik(kin, targets[k], starts[k], lower, upper)
        np.testing.assert_allclose(q_batch[k], q_one, atol=1e-6)
        assert err_batch[k] < 1e-6 and err_one < 1e-6
    np.testing.assert_allclose(kin.poses(q_batch), targets, atol=1e-6)


def test_coarse_chain_with_batched_fill_follows_the_one_by_one_chain(kin, straight_tool):
    from refine.optimise.seed import _chain, _chain_each, _coarse
    from refine.synthetic import wave_path

    fused = wave_path(800, length_m=1.0)
    targets = np.zeros((800, 4, 4))
    targets[:, :3, :3], targets[:, :3, 3], targets[:, 3, 3] = fused.rotations, fused.positions, 1.0
    assert len(_coarse(targets)) < 200  # most waypoints are filled in by the batch
    lower, upper = kin.robot.spec.lower, kin.robot.spec.upper
    q0, _ = _chain_each(kin, targets[:1], np.zeros(6) + [0, 0.3, 0.3, 0, 0.8, 0], lower, upper)
    qs, errors = _chain(kin, targets, q0[0], lower, upper)
    qs_ref, _ = _chain_each(kin, targets, q0[0], lower, upper)
    assert errors.max() < 1e-6
    np.testing.assert_allclose(qs, qs_ref, atol=1e-5)  # the same IK branch everywhere
    np.testing.assert_allclose(kin.poses(qs)[:, :3, 3], fused.positions, atol=1e-6)


def test_rotation_vectors_match_scipy_including_near_zero_and_half_turns():
    from scipy.spatial.transform import Rotation

    from refine.robot.kinematics import rotation_vectors

    rv = Rotation.random(500, random_state=2).as_rotvec()
    rv[:5] *= 1e-9
    rv[5:10] *= (np.pi - 1e-5) / np.linalg.norm(rv[5:10], axis=1)[:, None]
    np.testing.assert_allclose(rotation_vectors(Rotation.from_rotvec(rv).as_matrix()), rv, atol=1e-8)


def test_jacobians_of_many_rows_equal_the_jacobian_of_each_and_finite_differences(kin):
    rng = np.random.default_rng(5)
    qs = rng.uniform(-1.0, 1.0, size=(7, 6))
    J = kin.jacobians(qs)
    assert J.shape == (7, 6, 6)
    for k, q in enumerate(qs):
        np.testing.assert_allclose(J[k], kin.jacobian(q), atol=1e-12)
    # linear rows against central differences of the TCP position (Pinocchio forward kinematics)
    h = 1e-6
    q = qs[0]
    fd = np.column_stack(
        [(kin.pose(q + h * e)[:3, 3] - kin.pose(q - h * e)[:3, 3]) / (2 * h) for e in np.eye(6)]
    )
    np.testing.assert_allclose(J[0, :3], fd, atol=1e-6)


def test_batched_ik_hands_back_the_jacobians_at_the_joints_it_returns(kin):
    from scipy.spatial.transform import Rotation

    from refine.robot.kinematics import solve_ik_batch

    rng = np.random.default_rng(7)
    lower, upper = kin.robot.spec.lower, kin.robot.spec.upper
    q_true = rng.uniform(0.5 * lower, 0.5 * upper, size=(6, 6))
    targets = kin.poses(q_true)
    targets[5, :3, 3] += [5.0, 0.0, 0.0]  # out of reach: this row stalls, the others converge
    starts = q_true + rng.normal(scale=[[0.0], [1e-4], [0.02], [0.1], [0.2], [0.05]], size=q_true.shape)
    J_out = np.full((6, 6, 6), np.nan)
    q, _ = solve_ik_batch(kin, targets, starts, lower, upper, jacobians_out=J_out)
    h = 1e-7
    for k in range(len(q)):  # the Jacobian by central differences of the forward kinematics at q[k]
        J_fd = np.zeros((6, 6))
        for j in range(6):
            Tp, Tm = kin.pose(q[k] + h * np.eye(6)[j]), kin.pose(q[k] - h * np.eye(6)[j])
            J_fd[:3, j] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
            J_fd[3:, j] = Rotation.from_matrix(Tp[:3, :3] @ Tm[:3, :3].T).as_rotvec() / (2 * h)
        np.testing.assert_allclose(J_out[k], J_fd, atol=1e-6)


def _compiled_and_numpy(name: str, tool_in_world=None):
    """The same robot's TCP kinematics on a compiled chain and on one that never compiles."""
    import copy

    import pinocchio as pin

    from refine.robot.compiled_chain import CompiledChain
    from refine.robot.kinematics import TcpKinematics
    from refine.robot.registry import load_robot

    robot = load_robot(name)
    robot.chain = CompiledChain.from_model(robot.model, robot.flange_id)
    slow = copy.copy(robot)
    slow.chain = CompiledChain.from_model(robot.model, robot.flange_id, compile=False)
    assert robot.chain.compiled and not slow.chain.compiled
    base = pin.SE3(pin.exp3(np.array([0.0, 0.1, 0.3])), np.array([0.2, -0.1, 0.05])).homogeneous
    tcp = pin.SE3(pin.exp3(np.array([0.2, -0.3, 0.1])), np.array([0.01, 0.02, 0.2])).homogeneous
    return [TcpKinematics(r, base, tcp, tool_in_world) for r in (robot, slow)]


def _iiwa_path(held: bool):
    """The iiwa compiled and in NumPy (the TCP on the flange or at a standing tool), a straight joint path
    of 30 rows and its TCP poses."""
    import pinocchio as pin

    world = (
        pin.SE3(pin.exp3(np.array([2.8, 0.2, 0.1])), np.array([0.6, 0.2, 0.5])).homogeneous if held else None
    )
    kin, kin_np = _compiled_and_numpy("kuka_iiwa14_r820", world)
    t = np.linspace(0.0, 1.0, 30)[:, None]
    q_path = np.array([0.1, 0.5, -0.2, -1.2, 0.3, 0.8, 0.1]) + t * np.array(
        [0.4, -0.3, 0.2, 0.5, -0.6, 0.3, 0.9]
    )
    return kin, kin_np, q_path, kin_np.poses(q_path)


@pytest.mark.parametrize("held", [False, True])
def test_the_chain_compiled_follows_the_numpy_chain_through_a_half_turn_and_gives_up_alike(chain_cache, held):
    """The waypoint-by-waypoint chain in C (a redundant arm's pull, with and without a standing tool) against
    NumPy's: a waypoint turned by a half turn from the last answer (solved by NumPy's log3 in both), a step bound."""
    import pinocchio as pin

    from refine.optimise.seed import _solve_chain

    kin, kin_np, q_path, targets = _iiwa_path(held)
    spec = kin.robot.spec
    targets[12, :3, :3] = targets[12, :3, :3] @ pin.exp3(np.array([0.0, np.pi - 1e-5, 0.0]))  # about y
    from refine.optimise import seed as seed_module

    calls = []

    def counted(*args, **kwargs):
        calls.append(args[1])
        return solve_ik(*args, **kwargs)

    for give_up in (None, 0.5):
        with pytest.MonkeyPatch.context() as mp:  # in C, the chain hands only the half turn to solve_ik
            mp.setattr(seed_module, "solve_ik", counted)
            got = _solve_chain(kin, targets, q_path[0] + 0.05, spec.lower, spec.upper, give_up=give_up)
        assert len(calls) == 1 and np.array_equal(calls.pop(), targets[12])
        want = _solve_chain(kin_np, targets, q_path[0] + 0.05, spec.lower, spec.upper, give_up=give_up)
        np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-9)
        assert (want[1][:12] < 1e-6).all()
        assert np.isinf(want[1]).any() == (give_up is not None)


@pytest.mark.parametrize("held", [False, True])
def test_the_axis_chain_compiled_follows_the_numpy_chain_through_a_turned_over_axis(chain_cache, held):
    """The spin-free chain (``axis_only``) in C against NumPy's, the iiwa with its pull: targets spun about
    their axes (which the answer need not follow), one axis turned over (NumPy's in both), a step bound."""
    import pinocchio as pin

    from refine.optimise import seed as seed_module
    from refine.optimise.seed import _solve_chain

    kin, kin_np, q_path, targets = _iiwa_path(held)
    spec, t = kin.robot.spec, np.linspace(0.0, 1.0, 30)[:, None]
    for k in range(30):
        targets[k, :3, :3] = targets[k, :3, :3] @ pin.exp3(np.array([0.0, 0.0, 2.0 * t[k, 0]]))
    targets[12, :3, :3] = targets[12, :3, :3] @ pin.exp3(np.array([np.pi - 1e-5, 0.0, 0.0]))  # z over
    calls = []

    def counted(*args, **kwargs):
        calls.append((args[1], kwargs.get("axis_only")))
        return solve_ik(*args, **kwargs)

    for give_up in (None, 0.5):
        with pytest.MonkeyPatch.context() as mp:  # in C, the chain hands only the turned axis to solve_ik
            mp.setattr(seed_module, "solve_ik", counted)
            got = _solve_chain(kin, targets, q_path[0] + 0.05, spec.lower, spec.upper, True, give_up)
        ((target, axis_only),) = calls
        calls.clear()
        assert np.array_equal(target, targets[12]) and axis_only
        want = _solve_chain(kin_np, targets, q_path[0] + 0.05, spec.lower, spec.upper, True, give_up)
        np.testing.assert_allclose(got[0][:12], want[0][:12], rtol=0, atol=1e-9)
        np.testing.assert_allclose(got[1][:12], want[1][:12], rtol=0, atol=1e-9)
        assert (want[1][:12] < 1e-5).all()
        # the turned-over axis is NumPy's from the start the compiled chain handed over; turning over
        # from z x z_t of length 1e-5 its answer is sensitive (on the flange, out of reach with an error
        # ~0.3, NumPy's own moves by ~3e-7 rad for a start moved by 1e-12; held, the two chains'
        # answers there differ by ~1e-8 for starts differing by rounding), so the rows from it on are
        # checked to that sensitivity
        guess = 2.0 * got[0][11] - got[0][10]
        q12, e12 = solve_ik(kin_np, targets[12], guess, spec.lower, spec.upper, axis_only=True)
        assert np.array_equal(got[0][12], q12) and got[1][12] in (e12, np.inf) and (e12 > 0.1) != held
        np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-5)
        np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-6)
        assert np.isinf(want[1]).any() == (give_up is not None)
        for k in np.flatnonzero(np.isfinite(want[1])):  # the axis and position errors, from Pinocchio
            T = kin_np.pose(got[0][k])
            angle = np.arccos(np.clip(T[:3, 2] @ targets[k, :3, 2], -1.0, 1.0))
            miss = np.linalg.norm(targets[k, :3, 3] - T[:3, 3])
            assert got[1][k] == pytest.approx(np.hypot(miss, angle), abs=1e-7)
