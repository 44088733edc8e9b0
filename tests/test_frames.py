"""Behaviour of refine.frames: every orientation convention against scipy and an independent
implementation written here, on seeded property tests, 10,000 random rotations and explicit
gimbal-lock neighbourhoods, plus the SE(3) helpers and the input checks.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from refine.errors import InputError
from refine.frames import (
    check_rotation,
    check_transform,
    continuous_quaternions,
    fixed_xyz_from_matrix,
    invert_transform,
    kuka_abc_from_matrix,
    make_transform,
    matrix_from_fixed_xyz,
    matrix_from_kuka_abc,
    matrix_from_quaternion,
    matrix_from_rotvec,
    matrix_from_tracker_angles,
    matrix_from_zyx,
    quaternion_from_matrix,
    rotation_about,
    rotation_angle_deg,
    rotvec_from_matrix,
    tracker_angles_from_matrix,
    transform_from_xyz_rpy,
    transform_points,
    zyx_from_matrix,
)

PROPERTY = settings(max_examples=200, derandomize=True, deadline=None)
N_RANDOM = 10_000
SEED = 20240611

# middle angle exactly at gimbal lock and just either side of it [deg]
GIMBAL_OFFSETS_DEG = (1e-7, 1e-5, 1e-3)
GIMBAL_MIDDLE_DEG = tuple(
    [90.0, -90.0] + [s * 90.0 + d for s in (1.0, -1.0) for o in GIMBAL_OFFSETS_DEG for d in (o, -o)]
)

angle_deg = st.floats(-180.0, 180.0, allow_nan=False, allow_infinity=False)
# middle angles away from gimbal lock, where Euler angles are unique
middle_regular_deg = st.floats(-89.0, 89.0, allow_nan=False, allow_infinity=False)
# middle angles anywhere, gimbal lock and its neighbourhood drawn often
middle_any_deg = st.one_of(
    st.floats(-90.0, 90.0, allow_nan=False, allow_infinity=False), st.sampled_from(GIMBAL_MIDDLE_DEG)
)


# ---- an independent implementation (no refine, no scipy) -----------------------------------------


def ind_rx(c):
    c = np.asarray(c, dtype=float)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack(
        [
            np.stack([o, z, z], -1),
            np.stack([z, np.cos(c), -np.sin(c)], -1),
            np.stack([z, np.sin(c), np.cos(c)], -1),
        ],
        -2,
    )


def ind_ry(b):
    b = np.asarray(b, dtype=float)
    o, z = np.ones_like(b), np.zeros_like(b)
    return np.stack(
        [
            np.stack([np.cos(b), z, np.sin(b)], -1),
            np.stack([z, o, z], -1),
            np.stack([-np.sin(b), z, np.cos(b)], -1),
        ],
        -2,
    )


def ind_rz(a):
    a = np.asarray(a, dtype=float)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack(
        [
            np.stack([np.cos(a), -np.sin(a), z], -1),
            np.stack([np.sin(a), np.cos(a), z], -1),
            np.stack([z, z, o], -1),
        ],
        -2,
    )


def ind_zyx_closed_form(a, b, c):
    """Rz(a)·Ry(b)·Rx(c) [rad] multiplied out by hand, entry by entry."""
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rows = [
        [ca * cb, ca * sb * sc - sa * cc, ca * sb * cc + sa * sc],
        [sa * cb, sa * sb * sc + ca * cc, sa * sb * cc - ca * sc],
        [-sb, cb * sc, cb * cc],
    ]
    return np.stack([np.stack(np.broadcast_arrays(*r), -1) for r in rows], -2)


def ind_zyx_angles(R):
    """(a, b, c) [rad] with R = Rz(a)·Ry(b)·Rx(c), away from gimbal lock (other entries than refine's)."""
    c = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    b = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 2, 1], R[..., 2, 2]))
    a = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return a, b, c


def ind_quaternion_shepperd(R):
    """Shepperd's method: (w, x, y, z) from the largest of 4w², 4x², 4y², 4z², sign fixed to w >= 0."""
    R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    q = np.empty((len(R), 4))
    tr = np.trace(R, axis1=1, axis2=2)
    diag = np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], 1)
    pick = np.argmax(diag, axis=1)
    for i, m in enumerate(R):
        if pick[i] == 0:
            s = 2.0 * np.sqrt(1.0 + tr[i])
            q[i] = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
        elif pick[i] == 1:
            s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
            q[i] = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
        elif pick[i] == 2:
            s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
            q[i] = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
            q[i] = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    return q * np.where(q[:, :1] < 0.0, -1.0, 1.0)


def ind_matrix_from_quaternion(q):
    q = np.asarray(q, dtype=float)
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, -1) for r in rows], -2)


def ind_rodrigues(v):
    """exp of the skew matrix of v: I + sin θ K + (1 - cos θ) K², K the unit-axis skew matrix."""
    v = np.asarray(v, dtype=float)
    theta = np.linalg.norm(v, axis=-1)
    axis = v / np.where(theta > 0, theta, 1.0)[..., None]
    x, y, z = np.moveaxis(axis, -1, 0)
    zero = np.zeros_like(x)
    K = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)
    s, c = np.sin(theta)[..., None, None], np.cos(theta)[..., None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def ind_geodesic_angle_deg(Ra, Rb):
    """Angle of Ra^T Rb via atan2(|vee(skew part)|, (trace - 1) / 2), accurate near 0 and π."""
    Rr = np.swapaxes(Ra, -1, -2) @ Rb
    vee = np.stack(
        [Rr[..., 2, 1] - Rr[..., 1, 2], Rr[..., 0, 2] - Rr[..., 2, 0], Rr[..., 1, 0] - Rr[..., 0, 1]], -1
    )
    return np.degrees(
        np.arctan2(0.5 * np.linalg.norm(vee, axis=-1), 0.5 * (np.trace(Rr, axis1=-2, axis2=-1) - 1))
    )


def wrap_deg(d):
    """Angle difference folded into [-180, 180)."""
    return (np.asarray(d) + 180.0) % 360.0 - 180.0


def canonical_zyx_deg(a, b, c):
    """The same rotation with the middle angle folded into [-90, 90] (as the extractors return it)."""
    if abs(b) <= 90.0:
        return a, b, c
    return a + 180.0, np.copysign(180.0, b) - b, c + 180.0


@pytest.fixture(scope="module")
def rotations():
    return Rotation.random(N_RANDOM, random_state=SEED)


@pytest.fixture(scope="module")
def rotation_pairs():
    return Rotation.random(N_RANDOM, random_state=SEED + 1), Rotation.random(N_RANDOM, random_state=SEED + 2)


def gimbal_grid(middle_deg, n=400, seed=0):
    """n random (first, last) angle pairs with the middle angle fixed, shape (n, 3) [deg]."""
    rng = np.random.default_rng(seed)
    first, last = rng.uniform(-180, 180, n), rng.uniform(-180, 180, n)
    return np.stack([first, np.full(n, middle_deg), last], -1)


# ---- tracker angles: Rz(ψ)·Ry(θ)·Rx(φ), intrinsic z-y'-x'' ------------------------------------


@PROPERTY
@given(az=angle_deg, el=middle_any_deg, roll=angle_deg)
def test_tracker_angles_compose_as_intrinsic_zyx_like_scipy(az, el, roll):
    expected = Rotation.from_euler("ZYX", [az, el, roll], degrees=True).as_matrix()
    np.testing.assert_allclose(matrix_from_tracker_angles(az, el, roll), expected, atol=1e-12)


def test_tracker_angles_of_random_rotations_rebuild_the_scipy_matrix(rotations):
    angles = rotations.as_euler("ZYX", degrees=True)
    R = matrix_from_tracker_angles(angles[:, 0], angles[:, 1], angles[:, 2])
    assert R.shape == (N_RANDOM, 3, 3)
    np.testing.assert_allclose(R, rotations.as_matrix(), atol=1e-12)


def test_tracker_angles_accept_radians_when_asked():
    a, b, c = 0.3, -1.1, 2.5
    np.testing.assert_allclose(
        matrix_from_tracker_angles(a, b, c, degrees=False),
        Rotation.from_euler("ZYX", [a, b, c]).as_matrix(),
        atol=1e-14,
    )


def test_tracker_azimuth_is_about_z_elevation_about_new_y_and_roll_about_new_x():
    # azimuth 90 alone turns x onto y; then elevation 90 about the new y (world -x) tips the new x down
    ex = np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(matrix_from_tracker_angles(90, 0, 0) @ ex, [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(matrix_from_tracker_angles(90, 90, 0) @ ex, [0, 0, -1], atol=1e-15)
    # roll spins about the sensor's own x axis, which the azimuth put on world y
    np.testing.assert_allclose(matrix_from_tracker_angles(90, 0, 90) @ [0, 1, 0], [0, 0, 1], atol=1e-15)


@pytest.mark.parametrize("middle", GIMBAL_MIDDLE_DEG)
def test_tracker_angles_match_scipy_at_and_around_gimbal_lock(middle):
    angles = gimbal_grid(middle)
    expected = Rotation.from_euler("ZYX", angles, degrees=True).as_matrix()
    np.testing.assert_allclose(matrix_from_tracker_angles(*angles.T), expected, atol=1e-12)


@PROPERTY
@given(az=angle_deg, el=middle_regular_deg, roll=angle_deg)
def test_tracker_angles_round_trip_away_from_gimbal_lock(az, el, roll):
    R = matrix_from_tracker_angles(az, el, roll)
    back = tracker_angles_from_matrix(R)
    assert back.shape == (3,)
    np.testing.assert_allclose(matrix_from_tracker_angles(*back), R, atol=1e-12)
    np.testing.assert_allclose(wrap_deg(back - [az, el, roll]), 0.0, atol=1e-9)


@PROPERTY
@given(az=angle_deg, el=middle_any_deg, roll=angle_deg)
def test_tracker_angles_from_matrix_rebuilds_the_same_matrix_everywhere(az, el, roll):
    R = Rotation.from_euler("ZYX", [az, el, roll], degrees=True).as_matrix()
    back = tracker_angles_from_matrix(R)
    assert -90.0 <= back[1] <= 90.0
    # near gimbal lock the first and last angles are ill-conditioned (scipy loses as much), so the
    # rebuilt matrix is only good to ~1e-7 there; that is far below a tracker's 0.0012 deg resolution
    np.testing.assert_allclose(matrix_from_tracker_angles(*back), R, atol=1e-6)


def test_tracker_angles_of_random_rotations_agree_with_scipy_and_round_trip(rotations):
    R = rotations.as_matrix()
    back = tracker_angles_from_matrix(R)
    assert back.shape == (N_RANDOM, 3)
    np.testing.assert_allclose(wrap_deg(back - rotations.as_euler("ZYX", degrees=True)), 0.0, atol=1e-9)
    np.testing.assert_allclose(matrix_from_tracker_angles(*back.T), R, atol=1e-12)


@pytest.mark.parametrize("middle", GIMBAL_MIDDLE_DEG)
def test_tracker_angles_round_trip_at_and_around_gimbal_lock(middle):
    angles = gimbal_grid(middle, seed=1)
    for R in (
        matrix_from_tracker_angles(*angles.T),
        Rotation.from_euler("ZYX", angles, degrees=True).as_matrix(),
    ):
        back = tracker_angles_from_matrix(R)
        assert np.all(np.abs(back[:, 1]) <= 90.0)
        np.testing.assert_allclose(matrix_from_tracker_angles(*back.T), R, atol=1e-6)
    R = matrix_from_tracker_angles(*angles.T)
    back = tracker_angles_from_matrix(R)
    if abs(middle) == 90.0:
        # exactly at gimbal lock only a + c (or a - c) is defined: roll comes back 0, the rest in azimuth
        np.testing.assert_array_equal(back[:, 2], 0.0)
        np.testing.assert_allclose(back[:, 1], middle, atol=1e-12)
        combined = angles[:, 0] - np.sign(middle) * angles[:, 2]
        np.testing.assert_allclose(wrap_deg(back[:, 0] - combined), 0.0, atol=1e-9)
        np.testing.assert_allclose(matrix_from_tracker_angles(*back.T), R, atol=1e-12)
    else:
        # not at gimbal lock: the angles themselves come back (middle folded into [-90, 90])
        expected = np.array([canonical_zyx_deg(*row) for row in angles])
        cb = np.cos(np.radians(expected[0, 1]))
        tol_deg = np.degrees(1e-14 / cb) + 1e-9
        np.testing.assert_allclose(wrap_deg(back - expected), 0.0, atol=tol_deg)


# ---- fixed-axis X-Y-Z (robots, AutomationML Frame) -------------------------------------------


@PROPERTY
@given(rx=angle_deg, ry=middle_any_deg, rz=angle_deg)
def test_fixed_xyz_is_extrinsic_xyz_and_equals_tracker_angles_reversed(rx, ry, rz):
    R = matrix_from_fixed_xyz([rx, ry, rz])
    np.testing.assert_allclose(
        R, Rotation.from_euler("xyz", [rx, ry, rz], degrees=True).as_matrix(), atol=1e-12
    )
    # the paper's identity R_XYZ(φ, θ, ψ) = R_Z'Y'X'(ψ, θ, φ)
    np.testing.assert_allclose(R, matrix_from_tracker_angles(rz, ry, rx), atol=1e-15)


def test_fixed_xyz_rotates_about_fixed_x_first_then_fixed_y():
    # x by 90 moves y onto z; a following 90 about the *fixed* y moves that z onto x
    np.testing.assert_allclose(matrix_from_fixed_xyz([90, 90, 0]) @ [0, 1, 0], [1, 0, 0], atol=1e-15)


def test_fixed_xyz_of_random_rotations_round_trip_and_agree_with_scipy(rotations):
    R = rotations.as_matrix()
    angles = fixed_xyz_from_matrix(R)
    assert angles.shape == (N_RANDOM, 3)
    np.testing.assert_allclose(wrap_deg(angles - rotations.as_euler("xyz", degrees=True)), 0.0, atol=1e-9)
    np.testing.assert_allclose(matrix_from_fixed_xyz(angles), R, atol=1e-12)


def test_fixed_xyz_accepts_radians_and_stacks_of_angles():
    angles = np.array([[[0.1, 0.2, 0.3], [-1.0, 0.5, 2.0]]])
    R = matrix_from_fixed_xyz(angles, degrees=False)
    assert R.shape == (1, 2, 3, 3)
    np.testing.assert_allclose(R[0], Rotation.from_euler("xyz", angles[0]).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(fixed_xyz_from_matrix(R, degrees=False), angles, atol=1e-12)


@pytest.mark.parametrize("middle", GIMBAL_MIDDLE_DEG)
def test_fixed_xyz_round_trip_at_and_around_gimbal_lock(middle):
    rz_ry_rx = gimbal_grid(middle, seed=2)
    rx_ry_rz = rz_ry_rx[:, ::-1]
    R = Rotation.from_euler("xyz", rx_ry_rz, degrees=True).as_matrix()
    np.testing.assert_allclose(matrix_from_fixed_xyz(rx_ry_rz), R, atol=1e-12)
    back = fixed_xyz_from_matrix(R)
    np.testing.assert_allclose(matrix_from_fixed_xyz(back), R, atol=1e-6)
    if abs(middle) == 90.0:
        np.testing.assert_array_equal(back[:, 0], 0.0)  # rx, the last angle applied intrinsically


# ---- KUKA A, B, C -----------------------------------------------------------------------------


@PROPERTY
@given(a=angle_deg, b=middle_any_deg, c=angle_deg)
def test_kuka_abc_is_z_then_new_y_then_new_x_like_scipy(a, b, c):
    expected = Rotation.from_euler("ZYX", [a, b, c], degrees=True).as_matrix()
    np.testing.assert_allclose(matrix_from_kuka_abc([a, b, c]), expected, atol=1e-12)


@PROPERTY
@given(a=angle_deg, b=middle_regular_deg, c=angle_deg)
def test_kuka_abc_round_trip_away_from_gimbal_lock(a, b, c):
    back = kuka_abc_from_matrix(matrix_from_kuka_abc([a, b, c]))
    np.testing.assert_allclose(wrap_deg(back - [a, b, c]), 0.0, atol=1e-9)


def test_kuka_abc_of_random_rotations_round_trip(rotations):
    R = rotations.as_matrix()
    abc = kuka_abc_from_matrix(R)
    np.testing.assert_allclose(wrap_deg(abc - rotations.as_euler("ZYX", degrees=True)), 0.0, atol=1e-9)
    np.testing.assert_allclose(matrix_from_kuka_abc(abc), R, atol=1e-12)


@pytest.mark.parametrize("middle", GIMBAL_MIDDLE_DEG)
def test_kuka_abc_round_trip_at_and_around_gimbal_lock(middle):
    abc = gimbal_grid(middle, seed=3)
    R = Rotation.from_euler("ZYX", abc, degrees=True).as_matrix()
    np.testing.assert_allclose(matrix_from_kuka_abc(abc), R, atol=1e-12)
    back = kuka_abc_from_matrix(R)
    np.testing.assert_allclose(matrix_from_kuka_abc(back), R, atol=1e-6)
    if abs(middle) == 90.0:
        np.testing.assert_array_equal(back[:, 2], 0.0)


# ---- quaternions (scalar first) -----------------------------------------------------------------


def test_quaternions_are_scalar_first_unit_with_nonnegative_w(rotations):
    q = quaternion_from_matrix(rotations.as_matrix())
    assert q.shape == (N_RANDOM, 4)
    assert np.all(q[:, 0] >= 0.0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    xyzw = rotations.as_quat()
    wxyz = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    sign = np.sign(np.sum(q * wxyz, axis=1))
    np.testing.assert_allclose(q, sign[:, None] * wxyz, atol=1e-12)


def test_quaternion_of_a_known_rotation_is_scalar_first():
    # 90 deg about z: (cos 45, 0, 0, sin 45)
    h = np.sqrt(0.5)
    np.testing.assert_allclose(
        quaternion_from_matrix(rotation_about("z", np.pi / 2)), [h, 0, 0, h], atol=1e-15
    )
    np.testing.assert_allclose(matrix_from_quaternion([h, 0, 0, h]) @ [1, 0, 0], [0, 1, 0], atol=1e-15)


def test_quaternions_round_trip_through_matrices(rotations):
    R = rotations.as_matrix()
    np.testing.assert_allclose(matrix_from_quaternion(quaternion_from_matrix(R)), R, atol=1e-12)


@PROPERTY
@given(
    q=st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=4, max_size=4).filter(
        lambda v: np.linalg.norm(v) > 1e-3
    ),
    scale=st.floats(1e-2, 1e2),
)
def test_quaternion_to_matrix_normalises_and_ignores_sign(q, scale):
    q = np.asarray(q)
    R = matrix_from_quaternion(q)
    np.testing.assert_allclose(matrix_from_quaternion(scale * q), R, atol=1e-12)
    np.testing.assert_allclose(matrix_from_quaternion(-q), R, atol=1e-12)
    check_rotation(R, atol=1e-12)
    back = quaternion_from_matrix(R)
    q_unit = q / np.linalg.norm(q)
    np.testing.assert_allclose(back, np.sign(back @ q_unit) * q_unit, atol=1e-9)


def test_quaternion_functions_keep_leading_axes():
    R = Rotation.random(10, random_state=SEED).as_matrix().reshape(2, 5, 3, 3)
    q = quaternion_from_matrix(R)
    assert q.shape == (2, 5, 4)
    np.testing.assert_allclose(matrix_from_quaternion(q), R, atol=1e-12)


def test_half_turn_quaternion_has_zero_w_and_rebuilds_the_matrix():
    R = rotation_about("x", np.pi)
    q = quaternion_from_matrix(R)
    np.testing.assert_allclose(np.abs(q), [0, 1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(matrix_from_quaternion(q), R, atol=1e-15)


@PROPERTY
@given(flips=st.lists(st.booleans(), min_size=2, max_size=60), step_deg=st.floats(0.0, 90.0))
def test_continuous_quaternions_make_consecutive_dot_products_positive(flips, step_deg):
    n = len(flips)
    # a smooth path (steps below 180 deg) with arbitrary sign flips: the fix must undo every flip
    path = Rotation.from_rotvec(
        np.outer(np.arange(n) * np.radians(step_deg), [1.0, 2.0, -0.5]) / np.sqrt(5.25)
    )
    q = quaternion_from_matrix(path.as_matrix())
    flipped = np.where(np.array(flips)[:, None], -q, q)
    fixed = continuous_quaternions(flipped)
    assert fixed.shape == (n, 4)
    assert np.all(np.sum(fixed[1:] * fixed[:-1], axis=1) > 0.0)
    np.testing.assert_array_equal(fixed[0], flipped[0])
    np.testing.assert_allclose(np.abs(np.sum(fixed * flipped, axis=1)), 1.0, atol=1e-12)  # same rotations
    np.testing.assert_allclose(matrix_from_quaternion(fixed), path.as_matrix(), atol=1e-12)


def test_continuous_quaternions_do_not_modify_their_input():
    q = np.array([[1.0, 0, 0, 0], [-1.0, 0, 0, 0]])
    continuous_quaternions(q)
    np.testing.assert_array_equal(q, [[1.0, 0, 0, 0], [-1.0, 0, 0, 0]])


# ---- rotation vectors ---------------------------------------------------------------------------


def test_rotation_vectors_round_trip_with_angle_in_zero_to_pi(rotations):
    R = rotations.as_matrix()
    v = rotvec_from_matrix(R)
    assert v.shape == (N_RANDOM, 3)
    angle = np.linalg.norm(v, axis=1)
    assert np.all((angle >= 0.0) & (angle <= np.pi + 1e-12))
    np.testing.assert_allclose(matrix_from_rotvec(v), R, atol=1e-12)


@PROPERTY
@given(
    axis=st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=3, max_size=3).filter(
        lambda v: np.linalg.norm(v) > 1e-3
    ),
    angle=st.floats(0.0, 3.14),
)
def test_rotation_vector_below_half_turn_comes_back_unchanged(axis, angle):
    v = np.asarray(axis) / np.linalg.norm(axis) * angle
    np.testing.assert_allclose(rotvec_from_matrix(matrix_from_rotvec(v)), v, atol=1e-9)


def test_rotation_vector_of_a_large_rotation_is_folded_to_at_most_pi():
    v = np.array([0.0, 0.0, 1.5 * np.pi])  # 270 deg about z is 90 deg about -z
    np.testing.assert_allclose(rotvec_from_matrix(matrix_from_rotvec(v)), [0, 0, -0.5 * np.pi], atol=1e-12)


# ---- the module against the independent implementation, 10,000 random rotations --------------


def test_angle_conventions_agree_with_hand_multiplied_elementary_matrices(rotations):
    rng = np.random.default_rng(SEED)
    a, c = rng.uniform(-np.pi, np.pi, (2, N_RANDOM))
    b = rng.uniform(-np.pi / 2, np.pi / 2, N_RANDOM)
    by_hand = ind_rz(a) @ ind_ry(b) @ ind_rx(c)
    np.testing.assert_allclose(ind_zyx_closed_form(a, b, c), by_hand, atol=1e-14)  # the helpers agree
    np.testing.assert_allclose(matrix_from_zyx(a, b, c), by_hand, atol=1e-14)
    deg = np.degrees(np.stack([a, b, c], -1))
    np.testing.assert_allclose(matrix_from_tracker_angles(*deg.T), by_hand, atol=1e-14)
    np.testing.assert_allclose(matrix_from_kuka_abc(deg), by_hand, atol=1e-14)
    np.testing.assert_allclose(matrix_from_fixed_xyz(deg[:, ::-1]), by_hand, atol=1e-14)
    for axis, ind in (("x", ind_rx), ("y", ind_ry), ("z", ind_rz)):
        np.testing.assert_allclose(rotation_about(axis, a), ind(a), atol=1e-15)


def test_angle_extraction_agrees_with_an_independent_extraction(rotations):
    R = rotations.as_matrix()
    np.testing.assert_allclose(np.stack(zyx_from_matrix(R), -1), np.stack(ind_zyx_angles(R), -1), atol=1e-10)
    a, b, c = ind_zyx_angles(R)
    np.testing.assert_allclose(ind_zyx_closed_form(a, b, c), R, atol=1e-12)


def test_quaternions_agree_with_shepperds_method(rotations):
    R = rotations.as_matrix()
    q = quaternion_from_matrix(R)
    q_ind = ind_quaternion_shepperd(R)
    np.testing.assert_allclose(q, q_ind, atol=1e-12)
    np.testing.assert_allclose(matrix_from_quaternion(q_ind), ind_matrix_from_quaternion(q_ind), atol=1e-12)


def test_rotation_vectors_agree_with_rodrigues_formula(rotations):
    R = rotations.as_matrix()
    v = rotvec_from_matrix(R)
    np.testing.assert_allclose(ind_rodrigues(v), R, atol=1e-12)
    np.testing.assert_allclose(matrix_from_rotvec(v), ind_rodrigues(v), atol=1e-12)


def test_rotation_angle_agrees_with_scipy_and_an_independent_formula(rotation_pairs):
    ra, rb = rotation_pairs
    got = rotation_angle_deg(ra.as_matrix(), rb.as_matrix())
    assert got.shape == (N_RANDOM,)
    np.testing.assert_allclose(got, np.degrees((ra.inv() * rb).magnitude()), atol=1e-9)
    np.testing.assert_allclose(got, ind_geodesic_angle_deg(ra.as_matrix(), rb.as_matrix()), atol=1e-9)
    np.testing.assert_allclose(
        rotation_angle_deg(rb.as_matrix(), ra.as_matrix()), got, atol=1e-9
    )  # symmetric


def test_rotation_angle_is_exact_for_known_rotations_and_zero_for_equal_ones(rotations):
    R = rotations.as_matrix()[:100]
    np.testing.assert_allclose(rotation_angle_deg(R, R), 0.0, atol=1e-6)
    np.testing.assert_allclose(
        rotation_angle_deg(R, R @ rotation_about("y", np.radians(3.0))), 3.0, atol=1e-9
    )
    np.testing.assert_allclose(rotation_angle_deg(np.eye(3), rotation_about("x", np.pi)), 180.0, atol=1e-9)
    # broadcast: one rotation against a stack
    assert rotation_angle_deg(np.eye(3), R).shape == (100,)


# ---- elementary rotations -----------------------------------------------------------------------


def test_elementary_rotations_follow_the_right_hand_rule():
    quarter = np.pi / 2
    np.testing.assert_allclose(rotation_about("x", quarter) @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(rotation_about("y", quarter) @ [0, 0, 1], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rotation_about("z", quarter) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    assert rotation_about("z", np.zeros((4, 2))).shape == (4, 2, 3, 3)


def test_rotation_about_rejects_an_unknown_axis_listing_the_valid_ones():
    with pytest.raises(InputError, match=r"'x', 'y', 'z'.*'w'"):
        rotation_about("w", 0.1)


# ---- SE(3) --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def random_transforms(rotations):
    p = np.random.default_rng(SEED).uniform(-2.0, 2.0, (N_RANDOM, 3))
    return make_transform(rotations.as_matrix(), p)


def test_make_transform_puts_rotation_and_translation_in_place():
    R = rotation_about("z", 0.4)
    T = make_transform(R, [1.0, 2.0, 3.0])
    expected = np.eye(4)
    expected[:3, :3], expected[:3, 3] = R, [1.0, 2.0, 3.0]
    np.testing.assert_array_equal(T, expected)
    np.testing.assert_array_equal(make_transform(), np.eye(4))
    np.testing.assert_array_equal(make_transform(p=[1, 2, 3])[:3, :3], np.eye(3))
    # one rotation broadcast over a stack of translations
    assert make_transform(R, np.zeros((7, 3))).shape == (7, 4, 4)


def test_inverted_transform_times_transform_is_identity(random_transforms):
    T = random_transforms
    T_inv = invert_transform(T)
    assert T_inv.shape == T.shape
    np.testing.assert_allclose(T @ T_inv, np.broadcast_to(np.eye(4), T.shape), atol=1e-12)
    np.testing.assert_allclose(T_inv @ T, np.broadcast_to(np.eye(4), T.shape), atol=1e-12)
    np.testing.assert_allclose(T_inv, np.linalg.inv(T), atol=1e-12)
    check_transform(T_inv)


def test_transform_points_equals_homogeneous_multiplication(random_transforms):
    rng = np.random.default_rng(SEED)
    points = rng.uniform(-1.0, 1.0, (50, 3))
    for T in random_transforms[:20]:
        homogeneous = (T @ np.c_[points, np.ones(len(points))].T).T[:, :3]
        np.testing.assert_allclose(transform_points(T, points), homogeneous, atol=1e-14)
        np.testing.assert_allclose(
            transform_points(invert_transform(T), transform_points(T, points)), points, atol=1e-12
        )
    assert transform_points(np.eye(4), np.zeros((2, 5, 3))).shape == (2, 5, 3)


def test_composed_transforms_map_points_like_applying_them_in_turn(random_transforms):
    T_a_b, T_b_c = random_transforms[0], random_transforms[1]
    p_c = np.array([[0.1, -0.2, 0.3]])
    np.testing.assert_allclose(
        transform_points(T_a_b @ T_b_c, p_c),
        transform_points(T_a_b, transform_points(T_b_c, p_c)),
        atol=1e-14,
    )


@PROPERTY
@given(
    xyz=st.lists(st.floats(-5.0, 5.0, allow_nan=False), min_size=3, max_size=3),
    rpy=st.tuples(angle_deg, middle_any_deg, angle_deg),
)
def test_transform_from_xyz_rpy_uses_metres_and_fixed_xyz_degrees(xyz, rpy):
    T = transform_from_xyz_rpy(xyz, rpy)
    assert T.shape == (4, 4)
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
    np.testing.assert_array_equal(T[:3, 3], xyz)
    np.testing.assert_allclose(
        T[:3, :3], Rotation.from_euler("xyz", rpy, degrees=True).as_matrix(), atol=1e-12
    )


@pytest.mark.parametrize(
    ("xyz", "rpy"), [([0, 0], [0, 0, 0]), ([0, 0, 0], [0, 0, 0, 0]), ([[0, 0, 0]], [0, 0, 0])]
)
def test_transform_from_xyz_rpy_rejects_wrong_lengths(xyz, rpy):
    with pytest.raises(InputError, match="3 values"):
        transform_from_xyz_rpy(xyz, rpy)


# ---- checks -------------------------------------------------------------------------------------


def test_check_rotation_accepts_rotations_and_returns_floats(rotations):
    R = check_rotation(rotations.as_matrix(), name="stack")
    assert R.dtype == np.float64 and R.shape == (N_RANDOM, 3, 3)
    assert check_rotation(np.eye(3, dtype=int)).dtype == np.float64


def test_check_rotation_rejects_a_reflection_naming_the_field():
    with pytest.raises(InputError, match=r"tool\.tcp_in_flange.*(reflection|determinant)"):
        check_rotation(np.diag([1.0, 1.0, -1.0]), name="tool.tcp_in_flange")


@pytest.mark.parametrize(
    "bad",
    [
        np.diag([1.0, 1.0, 1.1]),
        np.array([[1.0, 0.2, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
        np.zeros((3, 3)),
    ],
    ids=["scaled", "sheared", "zero"],
)
def test_check_rotation_rejects_non_orthonormal_matrices_naming_the_field(bad):
    with pytest.raises(InputError, match=r"frames\.cad_in_world.*orthonormal"):
        check_rotation(bad, name="frames.cad_in_world")


def test_check_rotation_tolerates_rounding_up_to_its_default_of_one_millionth():
    """|RᵀR - I| = 2e + e² for a diagonal scaled by 1 + e: 4e-7 passes, 4e-6 does not."""
    check_rotation(np.diag([1.0, 1.0, 1.0 + 2e-7]))
    with pytest.raises(InputError, match=r"orthonormal \(max \|R\^T R - I\| = 4\.00e-06 > 1e-06\)"):
        check_rotation(np.diag([1.0, 1.0, 1.0 + 2e-6]))


def test_check_rotation_rejects_one_bad_matrix_in_a_stack():
    stack = np.stack([np.eye(3), np.eye(3), np.diag([1.0, -1.0, 1.0])])
    with pytest.raises(InputError, match="R"):
        check_rotation(stack)


def test_check_rotation_rejects_wrong_shape_naming_field_and_shape():
    with pytest.raises(InputError, match=r"orientation.*\(4, 4\)"):
        check_rotation(np.eye(4), name="orientation")


def test_check_transform_rejects_a_bad_last_row_and_a_bad_rotation_block():
    T = np.eye(4)
    T[3, 0] = 1.0
    with pytest.raises(InputError, match=r"robot\.base_in_world.*last row"):
        check_transform(T, name="robot.base_in_world")
    with pytest.raises(InputError, match=r"robot\.base_in_world rotation block"):
        check_transform(make_transform(np.diag([1.0, 1.0, -1.0])), name="robot.base_in_world")


@pytest.mark.parametrize("q", [[0.0, 0.0, 0.0, 0.0], [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]]])
def test_matrix_from_quaternion_rejects_a_zero_quaternion(q):
    with pytest.raises(InputError, match="zero"):
        matrix_from_quaternion(q)


def test_matrix_from_quaternion_rejects_three_components():
    with pytest.raises(InputError, match=r"\(\.\.\., 4\).*\(3,\)"):
        matrix_from_quaternion([1.0, 0.0, 0.0])


def _continuous_by_walking(q):
    """The definition, one step at a time: negate q[k] when it points away from the (fixed) q[k-1]."""
    q = np.array(q, dtype=float)
    for k in range(1, len(q)):
        if float(q[k] @ q[k - 1]) < 0.0:
            q[k] = -q[k]
    return q


@PROPERTY
@given(
    signs=st.lists(st.sampled_from([-1.0, 1.0]), min_size=0, max_size=40),
    kinds=st.lists(st.sampled_from(["near", "far", "perpendicular", "nan"]), min_size=40, max_size=40),
)
def test_continuous_quaternions_agree_with_walking_the_sequence(signs, kinds):
    rng = np.random.default_rng(len(signs))
    q = np.empty((len(signs), 4))
    for k, sign in enumerate(signs):
        if k == 0 or kinds[k] == "far":
            q[k] = rng.normal(size=4)
        elif kinds[k] == "near":
            q[k] = q[k - 1] + 0.1 * rng.normal(size=4)
        elif kinds[k] == "perpendicular":  # an exactly zero dot product with the previous one
            q[k - 1] = np.round(4.0 * q[k - 1])  # small integers: every product and sum is exact
            a = q[k - 1]
            q[k] = [-a[1], a[0], -a[3], a[2]]
        else:
            q[k] = [np.nan, 0.0, 0.0, 0.0]
        q[k] *= sign
    np.testing.assert_array_equal(continuous_quaternions(q), _continuous_by_walking(q))


def _refuses(check, value) -> bool:
    try:
        check(value)
    except InputError:
        return True
    return False


def _reference_rotation_refuses(R, atol=1e-6) -> bool:
    """check_rotation's rule written plainly: orthonormal within atol, no negative determinant (LAPACK)."""
    R = np.asarray(R, dtype=float)
    if R.size == 0:
        return False
    RtR = np.einsum("...ji,...jk->...ik", R, R)
    return bool(np.max(np.abs(RtR - np.eye(3))) > atol or np.min(np.linalg.det(R)) < 0.0)


def _reference_transform_refuses(T) -> bool:
    T = np.asarray(T, dtype=float)
    return _reference_rotation_refuses(T[..., :3, :3]) or not np.allclose(T[..., 3, :], [0.0, 0.0, 0.0, 1.0])


def test_rotation_and_transform_checks_refuse_exactly_what_the_plain_rule_refuses():
    """Rotations, reflections, matrices off orthonormal near the tolerance, stacks with one bad
    matrix, NaN, and last rows on either side of NumPy's allclose tolerance (rtol 1e-5, atol 1e-8)."""
    rng = np.random.default_rng(5)
    flip = np.diag([1.0, 1.0, -1.0])
    cases = []
    for R in Rotation.random(40, random_state=3).as_matrix():
        cases += [R, R @ flip, R * (1 + 4.9e-7), R * (1 + 5.1e-7), R + rng.normal(scale=3e-7, size=(3, 3))]
        cases += [R * 0.7, R @ flip * 0.4, np.zeros((3, 3)), np.full((3, 3), np.nan)]
    stacks = [np.stack(cases[i : i + 5]) for i in range(0, len(cases), 5)]
    stacks += [Rotation.random(9, random_state=4).as_matrix(), np.zeros((0, 3, 3))]
    refused = 0
    for R in cases + stacks:
        assert _refuses(check_rotation, R) == _reference_rotation_refuses(R)
        refused += _refuses(check_rotation, R)
    assert 0 < refused < len(cases + stacks)  # both outcomes were met
    for R in Rotation.random(10, random_state=6).as_matrix():
        for last in ([0, 0, 0, 1], [0, 0, 0, 1 + 1.01e-5], [0, 0, 0, 1 + 0.99e-5], [0.99e-8, 0, 0, 1], [1.01e-8, 0, 0, 1],
                     [0, 0, 0, np.inf], [0, 0, np.nan, 1], [0, -2e-8, 0, 1 - 1.2e-5]):  # fmt: skip
            T = make_transform(R, rng.normal(size=3))
            T[3] = last
            assert _refuses(check_transform, T) == _reference_transform_refuses(T), last
            stack = np.stack([make_transform(R), T])
            assert _refuses(check_transform, stack) == _reference_transform_refuses(stack), last
