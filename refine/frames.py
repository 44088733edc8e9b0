"""SE(3) helpers and every orientation convention refine reads or writes.

Conventions (one everywhere):

* A homogeneous transform ``T_a_b`` is the pose of frame ``b`` expressed in frame ``a``, a (4, 4)
  array; ``T_a_c = T_a_b @ T_b_c``. Positions are in metres.
* Rotation matrices are (..., 3, 3) arrays; every function here is vectorised over leading axes.
* Quaternions are scalar first, ``(qw, qx, qy, qz)``, as ABB RAPID and ``trajectory.csv`` write them.
* Angles are in degrees in files and in radians inside unless a name says ``_deg``.

The angle conventions the project meets are all the same parametrisation, ``R = Rz(a)·Ry(b)·Rx(c)``,
read in different orders:

========================  ==================================  =======================
convention                angles                              rotation
========================  ==================================  =======================
Polhemus tracker          azimuth ψ, elevation θ, roll φ      Rz(ψ)·Ry(θ)·Rx(φ)
fixed-axis X-Y-Z (robot)  rx=φ about x, ry=θ about y, rz=ψ    Rz(rz)·Ry(ry)·Rx(rx)
KUKA A, B, C              A about z, B about y', C about x''  Rz(A)·Ry(B)·Rx(C)
AutomationML Frame        rx, ry, rz about fixed x, y, z      Rz(rz)·Ry(ry)·Rx(rx)
========================  ==================================  =======================

At gimbal lock (middle angle ±90°) the first and last angles are not separable; the extractors
then return the last angle (roll, rx, C) as zero and put the whole rotation into the first.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from refine.errors import InputError
from refine.lazy import lean_imports

with lean_imports():  # often the first import of SciPy
    from scipy.spatial.transform import Rotation

_GIMBAL_EPS = 1e-9
_EYE3 = np.eye(3)
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_LAST_ROW_TOL = 1e-8 + 1e-5 * _LAST_ROW


# ---- checks -----------------------------------------------------------------------------------


def check_rotation(R: ArrayLike, name: str = "R", atol: float = 1e-6) -> NDArray[np.float64]:
    """Return ``R`` as a float array after checking it is a stack of proper rotations.

    Raises:
        InputError: naming ``name`` and the shape or defect found.
    """
    R = np.asarray(R, dtype=float)
    if R.shape[-2:] != (3, 3):
        raise InputError(f"{name}: expected shape (..., 3, 3), got {R.shape}")
    RtR = np.einsum("...ji,...jk->...ik", R, R)
    err = float(np.abs(RtR - _EYE3).max()) if R.size else 0.0
    if err > atol:
        raise InputError(f"{name}: not orthonormal (max |R^T R - I| = {err:.2e} > {atol:.0e})")
    if R.size and _smallest_determinant(R) < 0.0:
        raise InputError(f"{name}: determinant is negative (a reflection, not a rotation)")
    return R


def _smallest_determinant(R: NDArray[np.float64]) -> float:
    """The least determinant of the stack ``R`` (..., 3, 3), of its sign at least as LAPACK's.

    A stack's by the triple product: for a matrix near orthonormal (|det| near 1) it differs from
    LAPACK's LU determinant by some units of rounding, so where it is 0.5 or more in magnitude the
    sign is the same; anything smaller, and a single matrix, is computed by LAPACK.
    """
    if R.ndim == 2:
        return float(np.linalg.det(R))
    det = np.einsum("...i,...i->...", R[..., 0], np.cross(R[..., 1], R[..., 2]))
    if np.min(np.abs(det)) < 0.5:
        det = np.linalg.det(R)
    return float(np.min(det))


def check_transform(T: ArrayLike, name: str = "T") -> NDArray[np.float64]:
    """Return ``T`` as a float (..., 4, 4) array after checking it is a rigid transform."""
    T = np.asarray(T, dtype=float)
    if T.shape[-2:] != (4, 4):
        raise InputError(f"{name}: expected shape (..., 4, 4), got {T.shape}")
    check_rotation(T[..., :3, :3], name=f"{name} rotation block")
    # NumPy's allclose (rtol 1e-5, atol 1e-8) of the last row to [0, 0, 0, 1], written out
    if not (np.abs(T[..., 3, :] - _LAST_ROW) <= _LAST_ROW_TOL).all():
        raise InputError(f"{name}: last row must be [0, 0, 0, 1], got {T[..., 3, :].tolist()}")
    return T


# ---- SE(3) ------------------------------------------------------------------------------------


def make_transform(R: ArrayLike | None = None, p: ArrayLike | None = None) -> NDArray[np.float64]:
    """Homogeneous transform from a rotation (..., 3, 3) and a translation (..., 3) [m]."""
    R = np.eye(3) if R is None else np.asarray(R, dtype=float)
    p = np.zeros(3) if p is None else np.asarray(p, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    T = np.zeros((*shape, 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def invert_transform(T: ArrayLike) -> NDArray[np.float64]:
    """Inverse of a rigid transform (..., 4, 4), using R^T rather than a general inverse."""
    T = np.asarray(T, dtype=float)
    R_inv = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_transform(R_inv, -np.einsum("...ij,...j->...i", R_inv, T[..., :3, 3]))


def transform_points(T: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Apply a transform (4, 4) to points (..., 3) [m]."""
    T = np.asarray(T, dtype=float)
    points = np.asarray(points, dtype=float)
    return points @ T[:3, :3].T + T[:3, 3]


def rotation_about(axis: str, angle: ArrayLike) -> NDArray[np.float64]:
    """Elementary rotation about ``"x"``, ``"y"`` or ``"z"`` by ``angle`` [rad], shape (..., 3, 3)."""
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(angle), np.zeros_like(angle)
    rows = {
        "x": [[one, zero, zero], [zero, c, -s], [zero, s, c]],
        "y": [[c, zero, s], [zero, one, zero], [-s, zero, c]],
        "z": [[c, -s, zero], [s, c, zero], [zero, zero, one]],
    }
    if axis not in rows:
        raise InputError(f"axis must be one of 'x', 'y', 'z', got {axis!r}")
    return np.moveaxis(np.array(rows[axis], dtype=float), (0, 1), (-2, -1))


# ---- the Rz·Ry·Rx family ----------------------------------------------------------------------


def matrix_from_zyx(a: ArrayLike, b: ArrayLike, c: ArrayLike) -> NDArray[np.float64]:
    """``Rz(a)·Ry(b)·Rx(c)`` for angles [rad], broadcast together; shape (..., 3, 3)."""
    return rotation_about("z", a) @ rotation_about("y", b) @ rotation_about("x", c)


def zyx_from_matrix(R: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
    """Angles (a, b, c) [rad] with ``R = Rz(a)·Ry(b)·Rx(c)``, b in [-π/2, π/2].

    At gimbal lock (|b| = π/2) ``c`` is returned as 0.
    """
    R = np.asarray(R, dtype=float)
    cb = np.hypot(R[..., 0, 0], R[..., 1, 0])
    b = np.arctan2(-R[..., 2, 0], cb)
    regular = cb > _GIMBAL_EPS
    a = np.where(regular, np.arctan2(R[..., 1, 0], R[..., 0, 0]), np.arctan2(-R[..., 0, 1], R[..., 1, 1]))
    c = np.where(regular, np.arctan2(R[..., 2, 1], R[..., 2, 2]), 0.0)
    return a, b, c


def matrix_from_tracker_angles(
    azimuth: ArrayLike, elevation: ArrayLike, roll: ArrayLike, degrees: bool = True
) -> NDArray[np.float64]:
    """Sensor orientation in the receiver frame from Polhemus angles: ``Rz(ψ)·Ry(θ)·Rx(φ)``."""
    k = np.pi / 180.0 if degrees else 1.0
    return matrix_from_zyx(np.asarray(azimuth) * k, np.asarray(elevation) * k, np.asarray(roll) * k)


def tracker_angles_from_matrix(R: ArrayLike, degrees: bool = True) -> NDArray[np.float64]:
    """Polhemus (azimuth, elevation, roll), shape (..., 3); inverse of matrix_from_tracker_angles."""
    k = 180.0 / np.pi if degrees else 1.0
    return np.stack(zyx_from_matrix(R), axis=-1) * k


def matrix_from_fixed_xyz(angles: ArrayLike, degrees: bool = True) -> NDArray[np.float64]:
    """Rotation from fixed-axis X-Y-Z angles (rx, ry, rz), shape (..., 3): ``Rz·Ry·Rx``.

    This is the AutomationML ``Frame`` convention and the robots' "fixed-axis X-Y-Z".
    """
    angles = np.asarray(angles, dtype=float) * (np.pi / 180.0 if degrees else 1.0)
    return matrix_from_zyx(angles[..., 2], angles[..., 1], angles[..., 0])


def fixed_xyz_from_matrix(R: ArrayLike, degrees: bool = True) -> NDArray[np.float64]:
    """Fixed-axis X-Y-Z angles (rx, ry, rz), shape (..., 3); inverse of matrix_from_fixed_xyz."""
    a, b, c = zyx_from_matrix(R)
    return np.stack([c, b, a], axis=-1) * (180.0 / np.pi if degrees else 1.0)


def matrix_from_kuka_abc(abc_deg: ArrayLike) -> NDArray[np.float64]:
    """Rotation from KUKA (A, B, C) [deg], shape (..., 3): A about z, B about y', C about x''."""
    abc = np.asarray(abc_deg, dtype=float) * (np.pi / 180.0)
    return matrix_from_zyx(abc[..., 0], abc[..., 1], abc[..., 2])


def kuka_abc_from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """KUKA (A, B, C) [deg], shape (..., 3); inverse of matrix_from_kuka_abc."""
    return np.stack(zyx_from_matrix(R), axis=-1) * (180.0 / np.pi)


# ---- quaternions and rotation vectors -----------------------------------------------------------


def quaternion_from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion (qw, qx, qy, qz), shape (..., 4), with qw >= 0."""
    R = np.asarray(R, dtype=float)
    xyzw = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    q = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    q *= np.where(q[:, :1] < 0.0, -1.0, 1.0)
    return q.reshape(*R.shape[:-2], 4)


def matrix_from_quaternion(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix (..., 3, 3) from quaternions (qw, qx, qy, qz) (normalised here)."""
    q = np.asarray(q, dtype=float)
    if q.shape[-1] != 4:
        raise InputError(f"quaternion: expected shape (..., 4), got {q.shape}")
    flat = q.reshape(-1, 4)
    norms = np.linalg.norm(flat, axis=1)
    if flat.size and float(norms.min()) < 1e-9:
        raise InputError("quaternion: zero-length quaternion cannot be normalised")
    R = Rotation.from_quat(np.concatenate([flat[:, 1:], flat[:, :1]], axis=1)).as_matrix()
    return R.reshape(*q.shape[:-1], 3, 3)


def continuous_quaternions(q: ArrayLike) -> NDArray[np.float64]:
    """Flip signs along a sequence (N, 4) so consecutive quaternions have a positive dot product.

    Walking the sequence, ``q[k]`` is negated when its dot product with the (possibly negated)
    ``q[k - 1]`` is negative. Done at once: the sign of ``q[k]`` flips with every negative dot
    product of the unflipped neighbours since the last zero (or NaN) one, where it restarts at +.
    """
    q = np.array(q, dtype=float)
    if len(q) < 2:
        return q
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    flips = np.concatenate([[0], np.cumsum(dots < 0.0)])
    restart = np.concatenate([[True], ~((dots < 0.0) | (dots > 0.0))])
    last = np.maximum.accumulate(np.where(restart, np.arange(len(q)), 0))
    q[(flips - flips[last]) % 2 == 1] *= -1.0
    return q


def rotvec_from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """Rotation vector (axis·angle [rad]), shape (..., 3), angle in [0, π]."""
    R = np.asarray(R, dtype=float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(*R.shape[:-2], 3)


def matrix_from_rotvec(rotvec: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix (..., 3, 3) from a rotation vector (axis·angle [rad])."""
    v = np.asarray(rotvec, dtype=float)
    return Rotation.from_rotvec(v.reshape(-1, 3)).as_matrix().reshape(*v.shape[:-1], 3, 3)


# ---- distances and poses from files -----------------------------------------------------------


def rotation_angle_deg(R_a: ArrayLike, R_b: ArrayLike) -> NDArray[np.float64]:
    """Geodesic angle between rotations [deg], shape (...): the angle of ``R_a^T R_b``."""
    R_a, R_b = np.asarray(R_a, dtype=float), np.asarray(R_b, dtype=float)
    R_rel = np.einsum("...ji,...jk->...ik", R_a, R_b)
    return np.degrees(np.linalg.norm(rotvec_from_matrix(R_rel), axis=-1))


def transform_from_xyz_rpy(xyz: ArrayLike, rpy_deg: ArrayLike) -> NDArray[np.float64]:
    """Transform from a translation [m] and fixed-axis X-Y-Z angles [deg], as problem files give."""
    xyz, rpy = np.asarray(xyz, dtype=float), np.asarray(rpy_deg, dtype=float)
    if xyz.shape != (3,) or rpy.shape != (3,):
        raise InputError(f"pose: xyz and rpy_deg need 3 values each, got {xyz.shape} and {rpy.shape}")
    return make_transform(matrix_from_fixed_xyz(rpy), xyz)
