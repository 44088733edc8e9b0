"""The controller line's IK at its samples against a plain Pinocchio IK and figures computed by hand."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation, Slerp

from refine.frames import make_transform
from refine.optimise.controller_line import IK_TOLERANCE, check_controller_lines, sample_parameters
from refine.optimise.line_ik import line_manipulability
from refine.optimise.line_start import CORRECTION_MAX_RAD, newton_start, previous_corrections
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot
from refine.settings import Tolerances

ROBOT = "abb_irb4600_60_205"
TCP = make_transform(p=[0.02, -0.01, 0.3]) @ np.block(
    [
        [Rotation.from_euler("xyz", [0.0, 30.0, 10.0], degrees=True).as_matrix(), np.zeros((3, 1))],
        [0, 0, 0, 1],
    ]
)
BASES = {
    "none": np.eye(4),
    "shifted": make_transform(p=[0.4, -0.2, 0.1]),  # no rotation: the products skip the turn
    "turned": make_transform(p=[0.4, -0.2, 0.1])
    @ np.block(
        [
            [Rotation.from_euler("xyz", [2.0, -3.0, 40.0], degrees=True).as_matrix(), np.zeros((3, 1))],
            [0, 0, 0, 1],
        ]
    ),
}
Q0 = np.radians([10.0, 20.0, 10.0, 30.0, 50.0, -20.0])


def _path(steps_deg: float, n: int = 20, seed: int = 3) -> np.ndarray:
    """A smooth joint path of n waypoints, each joint moving up to ``steps_deg`` per step."""
    rng = np.random.default_rng(seed)
    rate = np.radians(rng.uniform(-steps_deg, steps_deg, 6))
    rate[4] = abs(rate[4])  # the wrist opens: clear of its singularity at joint 5 = 0
    bend = np.radians(rng.uniform(-0.3, 0.3, 6)) * steps_deg
    k = np.arange(n)[:, None]
    return Q0 + rate * k + bend * np.sin(k / n * np.pi)


class PlainIk:
    """TCP pose, Jacobian and a Gauss-Newton IK of one row at a time, from Pinocchio alone."""

    def __init__(self, base: np.ndarray) -> None:
        self.robot = load_robot(ROBOT)
        self.model = self.robot.model
        self.data = self.model.createData()
        self.fid = self.robot.flange_id
        self.base = base

    def pose_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        J = pin.computeFrameJacobian(self.model, self.data, q, self.fid, pin.LOCAL_WORLD_ALIGNED)
        T_bf = self.data.oMf[self.fid].homogeneous
        T = self.base @ T_bf @ TCP
        R = self.base[:3, :3]
        r = T[:3, 3] - (self.base @ T_bf)[:3, 3]  # flange -> TCP, world axes
        Jw = R @ J[3:]
        Jv = R @ J[:3] + np.cross(Jw.T, r).T  # v_TCP = v_flange + ω × r
        return T, np.vstack([Jv, Jw])

    def error(self, q: np.ndarray, target: np.ndarray) -> np.ndarray:
        T, _ = self.pose_jacobian(q)
        rot = Rotation.from_matrix(target[:3, :3] @ T[:3, :3].T).as_rotvec()
        return np.concatenate([target[:3, 3] - T[:3, 3], rot])

    def solve(self, target: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Undamped Newton steps from ``q`` until the pose error is below 1e-14."""
        q = q.copy()
        for _ in range(50):
            e = self.error(q, target)
            if np.linalg.norm(e) < 1e-14:
                return q
            q = q + np.linalg.solve(self.pose_jacobian(q)[1], e)
        raise AssertionError("the plain IK did not converge")


def _targets(plain: PlainIk, q: np.ndarray, segment: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The line's poses at every sample: the chord and SciPy's slerp between the waypoints' poses."""
    poses = [plain.pose_jacobian(row)[0] for row in q]
    out = np.tile(np.eye(4), (len(t), 1, 1))
    for i, (k, tk) in enumerate(zip(segment, t, strict=True)):
        a, b = poses[k], poses[k + 1]
        out[i, :3, 3] = a[:3, 3] + tk * (b[:3, 3] - a[:3, 3])
        out[i, :3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix([a[:3, :3], b[:3, :3]]))([tk]).as_matrix()[0]
    return out


@pytest.mark.parametrize("base", list(BASES))
def test_every_sample_is_where_a_plain_pinocchio_ik_puts_it_and_the_figures_are_its(base):
    """A 20-waypoint path (133 samples, the batched chain's rows) on a placed base: every sample's
    joints are those undamped Newton steps on Pinocchio's pose and Jacobian reach from the
    joint-linear joints (1e-8 rad), the residuals and per-segment figures are the ones computed
    from Pinocchio at the check's joints (manipulability |det Js|, the joint-linear TCP's distance
    from the chord and its angle to the slerp)."""
    plain = PlainIk(BASES[base])
    kin = TcpKinematics(plain.robot, BASES[base], TCP)
    q = _path(3.0)
    line = check_controller_lines(kin, q, np.arange(len(q), dtype=float), Tolerances())
    m, segment, t = sample_parameters(q)
    assert len(t) >= 96 and line.ok
    targets = _targets(plain, q, segment, t)
    q_lin = q[segment] + t[:, None] * (q[segment + 1] - q[segment])
    reach = plain.robot.spec.reach_m
    sing, off, angle = (np.full(len(q) - 1, v) for v in (np.inf, 0.0, 0.0))
    for i, k in enumerate(segment):
        exact = plain.solve(targets[i], q_lin[i])
        np.testing.assert_allclose(line.q[i], exact, rtol=0, atol=1e-8)
        e = plain.error(line.q[i], targets[i])
        assert line.ik_error[i] == pytest.approx(np.linalg.norm(e), rel=1e-6, abs=1e-14)
        assert line.ik_error[i] <= IK_TOLERANCE
        J = plain.pose_jacobian(line.q[i])[1]
        sing[k] = min(sing[k], abs(np.linalg.det(np.vstack([J[:3] / reach, J[3:]]))))
        T_lin = plain.pose_jacobian(q_lin[i])[0]
        a, b = plain.pose_jacobian(q[k])[0][:3, 3], plain.pose_jacobian(q[k + 1])[0][:3, 3]
        u = (b - a) / np.linalg.norm(b - a)
        d = T_lin[:3, 3] - a
        off[k] = max(off[k], np.linalg.norm(d - (d @ u) * u))
        rel = Rotation.from_matrix(T_lin[:3, :3].T @ targets[i, :3, :3]).magnitude()
        angle[k] = max(angle[k], np.degrees(rel))
    np.testing.assert_allclose(line.singularity, sing, rtol=1e-9)
    np.testing.assert_allclose(line.position_difference_m, off, rtol=1e-7, atol=1e-15)
    np.testing.assert_allclose(line.orientation_difference_deg, angle, rtol=1e-7, atol=1e-12)


def test_a_re_solve_starts_from_the_newton_step_plus_the_previous_lines_corrections():
    """A path with 2-degree steps (bows up to 6e-4 rad), its line checked; then every waypoint moved
    by up to 3e-3 rad and the last segment's largest step taken to 4.6 deg (another sample count). The corrections are the previous
    IK's change of its Newton starts at the same samples (none in the changed segment); with them,
    the starts of the moved path lie within the IK's tolerance of the line (by Pinocchio) at more
    than twice the samples the Newton start alone does, twenty times closer (median), and the check equals a cold check of the moved path
    (joints 1e-8 rad, residuals under the tolerance, the same violations)."""
    plain = PlainIk(BASES["turned"])
    kin = TcpKinematics(plain.robot, BASES["turned"], TCP)
    q_old = _path(2.0, n=16, seed=5)
    s = np.arange(len(q_old), dtype=float)
    old = check_controller_lines(kin, q_old, s, Tolerances())
    assert old.start_correction is not None and np.isfinite(old.start_correction).all()
    rng = np.random.default_rng(2)
    q = q_old + np.cumsum(rng.uniform(-2e-4, 2e-4, q_old.shape), axis=0)
    last = len(q) - 2
    step = q[-1] - q[-2]
    j = int(np.argmax(np.abs(step)))  # the last segment's largest step to 4.6 deg: another sample count
    q[-1, j] += np.sign(step[j]) * (np.radians(4.6) - abs(step[j]))
    m, segment, t = sample_parameters(q)
    changed = np.flatnonzero(m != old.samples)
    assert changed.tolist() == [last] and 1e-4 < np.abs(q[:-1] - q_old[:-1]).max() < 5e-3

    corrections = previous_corrections(q, m, segment, t, (q_old, old), IK_TOLERANCE)
    in_changed = segment == last
    assert not corrections[in_changed].any()
    first_old = np.concatenate([[0], np.cumsum(old.samples - 1)[:-1]])
    first = np.concatenate([[0], np.cumsum(m - 1)[:-1]])
    for i in np.flatnonzero(~in_changed):
        k = segment[i]
        np.testing.assert_array_equal(corrections[i], old.start_correction[first_old[k] + i - first[k]])
    assert 0 < np.abs(corrections).max() <= CORRECTION_MAX_RAD

    targets = _targets(plain, q, segment, t)
    q_lin = q[segment] + t[:, None] * (q[segment + 1] - q[segment])
    poses, J_wp = kin.poses_jacobians(q)
    newton = newton_start(J_wp, segment, t, q_lin, kin.poses(q_lin), targets)
    alone = np.array([np.linalg.norm(plain.error(x, T)) for x, T in zip(newton, targets, strict=True)])
    carried = np.array(
        [np.linalg.norm(plain.error(x, T)) for x, T in zip(newton + corrections, targets, strict=True)]
    )
    assert (alone > IK_TOLERANCE).sum() >= len(t) / 2
    assert (carried > IK_TOLERANCE).sum() < (alone > IK_TOLERANCE).sum() / 2
    assert np.median(carried) < np.median(alone) / 20

    warm = check_controller_lines(kin, q, s, Tolerances(), previous=(q_old, old))
    cold = check_controller_lines(kin, q, s, Tolerances())
    np.testing.assert_allclose(warm.q, cold.q, rtol=0, atol=1e-8)
    assert warm.ik_error.max() <= IK_TOLERANCE and cold.ik_error.max() <= IK_TOLERANCE
    assert warm.violations == cold.violations
    np.testing.assert_allclose(warm.singularity, cold.singularity, rtol=1e-7)


def test_with_every_segments_sample_count_kept_each_sample_carries_its_own_filtered_correction():
    """Every waypoint moved by up to 2e-5 rad (each segment keeps its sample count): the corrections
    are, sample by sample at the same index, the previous line's where its IK reached the tolerance
    and the correction is at most ``CORRECTION_MAX_RAD`` on every joint, else 0 (a NaN row, one
    from a bow, too); a new array, the previous line's left as it was."""
    plain = PlainIk(BASES["shifted"])
    kin = TcpKinematics(plain.robot, BASES["shifted"], TCP)
    q_old = _path(2.0, n=12, seed=7)
    line = check_controller_lines(kin, q_old, np.arange(len(q_old), dtype=float), Tolerances())
    c_old = line.start_correction.copy()
    err_old = line.ik_error.copy()
    c_old[3] = np.nan  # a sample that started from a bow
    c_old[5, 2] = 2.0 * CORRECTION_MAX_RAD  # a start far from the line
    c_old[6, 4] = -0.5 * CORRECTION_MAX_RAD
    err_old[8] = 10.0 * IK_TOLERANCE  # an IK that stayed short
    err_old[9] = IK_TOLERANCE
    old = replace(line, start_correction=c_old, ik_error=err_old)
    q = q_old + np.random.default_rng(4).uniform(-2e-5, 2e-5, q_old.shape)
    m, segment, t = sample_parameters(q)
    assert np.array_equal(m, old.samples) and len(t) == len(old.t)

    got = previous_corrections(q, m, segment, t, (q_old, old), IK_TOLERANCE)
    want = np.zeros((len(t), q.shape[1]))
    for i in range(len(t)):
        row = c_old[i]
        if err_old[i] <= IK_TOLERANCE and np.all(np.abs(row) <= CORRECTION_MAX_RAD):
            want[i] = row
    np.testing.assert_array_equal(got, want)
    assert not got[[3, 5, 8]].any() and got[6, 4] == -0.5 * CORRECTION_MAX_RAD and got[9].any()
    assert not np.shares_memory(got, old.start_correction)
    assert np.isnan(old.start_correction[3]).all() and old.start_correction[5, 2] == 2.0 * CORRECTION_MAX_RAD


@pytest.mark.parametrize("name", [ROBOT, "kuka_iiwa14_r820"])
def test_the_line_manipulability_is_the_root_of_det_js_js_t(name):
    """Random joints: the measure of six- and seven-axis Jacobians is sqrt(det(Js Jsᵀ)) of the
    Pinocchio Jacobian with its linear rows divided by the reach."""
    robot = load_robot(name)
    kin = TcpKinematics(robot, np.eye(4), TCP)
    qs = np.random.default_rng(1).uniform(robot.spec.lower, robot.spec.upper, (30, robot.nq))
    data = robot.model.createData()
    want = []
    for q in qs:
        J = pin.computeFrameJacobian(robot.model, data, q, robot.flange_id, pin.LOCAL_WORLD_ALIGNED)
        T = data.oMf[robot.flange_id].homogeneous
        r = T[:3, :3] @ TCP[:3, 3]
        Js = np.vstack([(J[:3] + np.cross(J[3:].T, r).T) / robot.spec.reach_m, J[3:]])
        want.append(np.sqrt(np.linalg.det(Js @ Js.T)))
    np.testing.assert_allclose(line_manipulability(kin, kin.jacobians(qs)), want, rtol=1e-9)


def test_a_line_source_starts_the_next_rounds_line_from_its_last_one():
    """The rounds' source checks an answer, then a moved one: the second check is the one started
    from the first's line (the same joints, bit for bit), within 1e-8 rad of a cold check."""
    from types import SimpleNamespace

    from refine.optimise.controller_line import ControllerLineSource

    kin = TcpKinematics(load_robot(ROBOT), BASES["shifted"], TCP)
    q1 = _path(2.0, n=12, seed=8)
    q2 = q1 + np.cumsum(np.random.default_rng(4).uniform(-2e-4, 2e-4, q1.shape), axis=0)
    s = np.arange(len(q1), dtype=float)
    problem = SimpleNamespace(fused=SimpleNamespace(s=s))
    source = ControllerLineSource(kin, Tolerances())
    source.violations(problem, q1)
    first = source.checked(q1, kin, np.zeros(len(q1) - 1, dtype=bool))
    source.violations(problem, q2)
    second = source.checked(q2, kin, np.zeros(len(q1) - 1, dtype=bool))
    from_first = check_controller_lines(kin, q2, s, Tolerances(), previous=(q1, first))
    np.testing.assert_array_equal(second.q, from_first.q)
    cold = check_controller_lines(kin, q2, s, Tolerances())
    np.testing.assert_allclose(second.q, cold.q, rtol=0, atol=1e-8)
    assert source.checks == 2 and second.ik_error.max() <= IK_TOLERANCE


def test_the_final_check_from_the_line_source_has_the_margins_bows_and_breaks_of_a_plain_pinocchio_ik():
    """The rounds' source checks an answer; the final check of the same joints takes the source's
    check (its IK, bows and joint margins) and reports, at the path's arc lengths, what a plain
    Pinocchio IK at every sample gives: per segment the least joint-limit margin, the largest joint
    difference to the joint-linear motion and that difference times the joints' reach, and the
    joint-limit breaks of a margin half the segments miss (runs of segments, the least margin in
    each), as the final check without the source finds them."""
    from types import SimpleNamespace

    from refine.optimise.controller_line import JOINT_TOLERANCE_RAD, ControllerLineSource

    plain = PlainIk(BASES["turned"])
    kin = TcpKinematics(plain.robot, BASES["turned"], TCP)
    q = _path(3.0, n=14, seed=11) + np.radians([0.0, 0.0, 50.0, 0.0, 0.0, 0.0])  # joint 3 up to 7 deg from 75
    s = np.cumsum(np.r_[0.0, np.full(len(q) - 1, 0.004)])
    m, segment, t = sample_parameters(q)
    targets = _targets(plain, q, segment, t)
    q_lin = q[segment] + t[:, None] * (q[segment + 1] - q[segment])
    exact = np.array([plain.solve(T, x) for T, x in zip(targets, q_lin, strict=True)])
    lower, upper = plain.model.lowerPositionLimit, plain.model.upperPositionLimit
    margins = np.minimum(exact - lower, upper - exact)  # per sample and joint [rad]
    per_joint = np.array([margins[segment == k].min(axis=0) for k in range(len(m))])  # (N-1, n)
    margin_deg = float(np.degrees(np.median(per_joint.min(axis=1))))  # about half the segments break it
    tol = Tolerances(joint_margin_deg=margin_deg)
    reach = np.array([2.4, 2.1, 1.3, 0.6, 0.45, 0.3])  # any per-joint reach [m]
    bow = np.abs(exact - q_lin)
    joint_diff = np.array([np.degrees(bow[segment == k].max()) for k in range(len(m))])
    change = np.array([(bow[segment == k] @ reach).max() for k in range(len(m))])

    source = ControllerLineSource(kin, tol)
    source.violations(SimpleNamespace(fused=SimpleNamespace(s=np.arange(len(q), dtype=float))), q)
    known = source.checked(q, kin, np.zeros(len(q) - 1, dtype=bool))
    assert known is not None
    taken = check_controller_lines(kin, q, s, tol, reach=reach, known=known)
    assert known.bow is not None and taken.bow is None  # the source's bows taken, not kept again
    alone = check_controller_lines(kin, q, s, tol, reach=reach)
    limit = np.radians(margin_deg) - JOINT_TOLERANCE_RAD
    for line in (taken, alone):
        np.testing.assert_allclose(line.joint_margin_rad, per_joint.min(axis=1), rtol=0, atol=1e-8)
        np.testing.assert_allclose(line.joint_difference_deg, joint_diff, rtol=0, atol=1e-6)
        np.testing.assert_allclose(line.clearance_change_m, change, rtol=0, atol=1e-7)
        found = sorted(
            (v.reason, v.index_start, v.index_end, v.s_start_m, v.s_end_m, v.worst)
            for v in line.violations
            if v.reason.startswith("joint limit")
        )
        want = []
        for j in range(q.shape[1]):
            bad = per_joint[:, j] < limit
            edges = np.flatnonzero(np.diff(np.r_[0, bad.astype(int), 0]))
            for a, b in zip(edges[::2], edges[1::2] - 1, strict=True):
                worst = per_joint[a : b + 1, j].min()
                reason = f"joint limit on the controller's line (joint {j + 1})"
                want.append((reason, a, b, s[a], s[b], worst))
        want.sort()
        assert want and sum(b - a + 1 for _, a, b, *_ in want) < len(m)
        assert [w[:5] for w in found] == [w[:5] for w in want]
        np.testing.assert_allclose([w[5] for w in found], [w[5] for w in want], rtol=0, atol=1e-8)
    assert taken.violations == alone.violations
    for name in ("joint_margin_rad", "joint_difference_deg", "clearance_change_m", "q", "singularity"):
        np.testing.assert_array_equal(getattr(taken, name), getattr(alone, name))
