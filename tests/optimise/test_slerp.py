"""The controller line's rotations in NumPy against SciPy's ``Rotation`` objects."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.optimise.line_ik import line_poses
from refine.optimise.line_start import relative_rotation_vectors
from refine.optimise.slerp import exp_rotvecs, log_rotations, rotation_angles, slerp_rotations


def rotvecs(rng, n):
    """Rotation vectors whose angles span 0, 1e-12 .. 1e-2, generic and near or at pi [rad]."""
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    angles = np.concatenate(
        [
            [0.0, 1e-12, 1e-9, 1e-6, 9.9e-5, 1e-4, 1.01e-4, 1e-3, 1e-2],
            rng.uniform(0.0, np.pi, n - 15),
            np.pi - np.array([1e-2, 1.01e-3, 9.9e-4, 1e-6, 1e-9]),
            [np.pi],
        ]
    )
    return axes * angles[:, None]


def test_exp_log_and_angle_agree_with_scipy_from_zero_to_pi():
    rng = np.random.default_rng(3)
    w = rotvecs(rng, 400)
    R_ref = Rotation.from_rotvec(w).as_matrix()
    assert np.abs(exp_rotvecs(w) - R_ref).max() < 1e-15
    angles = rotation_angles(R_ref)
    assert np.abs(angles - Rotation.from_matrix(R_ref).magnitude()).max() < 2e-15
    assert np.abs(angles - np.linalg.norm(w, axis=1)).max() < 1e-14
    assert angles[1] == pytest.approx(1e-12, rel=1e-6)  # arccos of the trace would give 0 here
    logs = log_rotations(R_ref)
    ref = Rotation.from_matrix(R_ref).as_rotvec()
    at_pi = np.isclose(np.linalg.norm(ref, axis=1), np.pi, atol=1e-8)  # at pi: w and -w are one rotation
    assert np.abs(logs[~at_pi] - ref[~at_pi]).max() < 4e-15
    assert np.abs(exp_rotvecs(logs) - R_ref).max() < 1e-14


def test_the_line_poses_are_scipys_slerp_between_targets():
    """``line_poses`` on random targets 0-40 degrees apart, t in (0, 1), against SciPy's composition."""
    rng = np.random.default_rng(5)
    N = 60
    R = Rotation.random(1, random_state=7) * Rotation.from_rotvec(
        np.cumsum(rng.normal(scale=0.2, size=(N, 3)), axis=0)
    )
    poses = np.tile(np.eye(4), (N, 1, 1))
    poses[:, :3, :3] = R.as_matrix()
    poses[:, :3, 3] = rng.normal(size=(N, 3))
    segment = np.repeat(np.arange(N - 1), 5)
    t = np.tile([0.1, 0.25, 0.5, 0.75, 0.9], N - 1)
    got = line_poses(poses, np.zeros((N, 6)), segment, t, None, np.zeros(N - 1, dtype=bool))
    Ra = Rotation.from_matrix(poses[:-1, :3, :3])
    steps = (Ra.inv() * Rotation.from_matrix(poses[1:, :3, :3])).as_rotvec()
    ref = (Ra[segment] * Rotation.from_rotvec(t[:, None] * steps[segment])).as_matrix()
    assert np.abs(got[:, :3, :3] - ref).max() < 1e-14
    a, b = poses[segment, :3, 3], poses[segment + 1, :3, 3]
    assert np.abs(got[:, :3, 3] - (a + t[:, None] * (b - a))).max() == 0.0


def test_slerp_rotations_are_scipys_composition_from_zero_to_pi():
    """``R_k exp(t w_k)`` for steps 0 .. pi and t in [0, 1], against SciPy's composition of rotations."""
    rng = np.random.default_rng(11)
    w = rotvecs(rng, 200)
    R = Rotation.random(len(w), random_state=12)
    index = rng.integers(0, len(w), size=3000)
    t = np.concatenate([[0.0, 1.0, 1e-9, 0.5], rng.uniform(0.0, 1.0, 2996)])
    got = slerp_rotations(R.as_matrix(), w, index, t)
    ref = (R[index] * Rotation.from_rotvec(t[:, None] * w[index])).as_matrix()
    assert np.abs(got - ref).max() < 2e-15


def test_relative_rotation_vectors_are_scipys_rotvec_of_the_product():
    """The rotation vector of ``Ra Rbᵀ`` for relative angles 0 .. pi, against SciPy's."""
    rng = np.random.default_rng(13)
    w = rotvecs(rng, 400)
    Rb = Rotation.random(len(w), random_state=14)
    Ra = Rotation.from_rotvec(w) * Rb
    got = relative_rotation_vectors(Ra.as_matrix(), Rb.as_matrix())
    ref = (Ra * Rb.inv()).as_rotvec()
    at_pi = np.isclose(np.linalg.norm(ref, axis=1), np.pi, atol=1e-8)  # at pi: w and -w are one rotation
    # the arccos of the trace, as the IK's: loses digits near pi
    assert np.abs(got[~at_pi] - ref[~at_pi]).max() < 1e-9
    assert np.abs(np.linalg.norm(got, axis=1) - np.linalg.norm(w, axis=1)).max() < 1e-9


def test_the_rodrigues_coefficients_are_the_closed_forms_above_the_series_threshold():
    """Angles all above ``SMALL_RAD`` and the same angles beside one below it give the same
    coefficients to the bit, ``sin θ / θ`` and ``2 sin²(θ/2) / θ²`` (against ``math`` per angle);
    the one below takes the series, within rounding of the closed forms."""
    import math

    from refine.optimise.slerp import SMALL_RAD, _rodrigues_coefficients

    theta = np.concatenate([[SMALL_RAD, 1.5 * SMALL_RAD], np.random.default_rng(2).uniform(1e-3, np.pi, 50)])
    a, b = _rodrigues_coefficients(theta)
    a_mixed, b_mixed = _rodrigues_coefficients(np.append(theta, 0.5 * SMALL_RAD))
    np.testing.assert_array_equal(a_mixed[:-1], a)
    np.testing.assert_array_equal(b_mixed[:-1], b)
    for x, ai, bi in zip(theta.tolist(), a, b, strict=True):
        assert ai == pytest.approx(math.sin(x) / x, rel=1e-15, abs=0.0)
        assert bi == pytest.approx(2.0 * (math.sin(x / 2.0) / x) ** 2, rel=1e-15, abs=0.0)
    x = 0.5 * SMALL_RAD
    assert a_mixed[-1] == pytest.approx(math.sin(x) / x, rel=1e-15)
    assert b_mixed[-1] == pytest.approx(2.0 * (math.sin(x / 2.0) / x) ** 2, rel=1e-12)
