"""Rotations between two orientations in NumPy, many at once: the controller line's slerp.

The controller's straight line turns from R_a to R_b as ``R_a exp(t log(R_aᵀ R_b))``
(:mod:`refine.optimise.controller_line`). These functions compute that for arrays of rotation
matrices without a rotation object per sample:

* :func:`rotation_angles`: the angle of each rotation, ``atan2(|vee(R - Rᵀ)| / 2, (tr R - 1) / 2)``,
  accurate near 0 (where ``arccos`` of the trace loses half the digits) and near 180 degrees;
* :func:`log_rotations`: the rotation vector of each rotation, the skew part scaled by
  ``angle / sin(angle)``; above :data:`WIDE_RAD` (towards 180 degrees the skew part vanishes) the
  axis comes from ``R + Rᵀ``;
* :func:`exp_rotvecs`: Rodrigues' formula ``I + (sin θ / θ) K + (2 sin²(θ/2) / θ²) K²`` with ``K``
  the skew matrix of the rotation vector, both coefficients by their series below
  :data:`SMALL_RAD`;
* :func:`slerp_rotations`: ``R_k exp(t w_k)`` at many ``t`` per rotation ``R_k``, as Rodrigues'
  formula multiplied out: ``R_k + t a(tθ) (R_k K) + t² b(tθ) (R_k K²)``, the two products once per
  rotation and per sample only two coefficients.

They agree with SciPy's ``Rotation`` (``from_matrix``, ``as_rotvec``, ``from_rotvec``,
``as_matrix``, ``magnitude``) to a few units of the last place on orthonormal matrices
(``tests/optimise/test_slerp.py``).
"""

from __future__ import annotations

import numpy as np

from refine.types import Array

SMALL_RAD = 1e-4
"""Below this angle [rad] the coefficients of :func:`exp_rotvecs` are taken from their series
(terms to θ⁴: their error is below 1e-24)."""
WIDE_RAD = np.pi / 2
"""Above this angle [rad] :func:`log_rotations` takes the axis from the symmetric part (the skew
part, ``sin θ`` times the axis, loses digits towards pi)."""


def _vee(R: Array) -> Array:
    return 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)


def rotation_angles(R: Array) -> Array:
    """Angle [rad] in [0, pi] of each rotation matrix of ``R`` (M, 3, 3), (M,)."""
    cos = (np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0
    return np.arctan2(np.linalg.norm(_vee(R), axis=1), cos)


def log_rotations(R: Array) -> Array:
    """Rotation vectors (M, 3) [rad] of the rotation matrices ``R`` (M, 3, 3), angles in [0, pi]."""
    vee = _vee(R)
    sin = np.linalg.norm(vee, axis=1)
    theta = np.arctan2(sin, (np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0)
    small = sin < 1e-300
    out = vee * np.where(small, 1.0, theta / np.where(small, 1.0, sin))[:, None]
    wide = np.flatnonzero(theta > WIDE_RAD)  # R + Rᵀ - 2 cos I = 2 (1 - cos) a aᵀ: its largest column
    if len(wide):
        Rw = R[wide]
        S = Rw + np.swapaxes(Rw, 1, 2) - (2.0 * np.cos(theta[wide]))[:, None, None] * np.eye(3)
        pick = np.argmax(np.diagonal(S, axis1=1, axis2=2), axis=1)
        col = S[np.arange(len(wide)), :, pick]
        axis = col / np.linalg.norm(col, axis=1)[:, None]
        sign = np.where(np.einsum("ij,ij->i", axis, vee[wide]) < 0.0, -1.0, 1.0)  # the skew part's: sin θ a
        out[wide] = (sign * theta[wide])[:, None] * axis
    return out


def exp_rotvecs(w: Array) -> Array:
    """Rotation matrices (M, 3, 3) of the rotation vectors ``w`` (M, 3) [rad] (Rodrigues).

    With ``K² = w wᵀ - θ² I`` the formula reads ``(1 - b θ²) I + a K + b w wᵀ``, written entry
    by entry for all rows at once.
    """
    theta = np.linalg.norm(w, axis=1)
    a, b = _rodrigues_coefficients(theta)
    t2 = theta**2
    bw = b[:, None] * w
    out = bw[:, :, None] * w[:, None, :]
    diagonal = 1.0 - b * t2
    out[:, 0, 0] += diagonal
    out[:, 1, 1] += diagonal
    out[:, 2, 2] += diagonal
    aw = a[:, None] * w
    out[:, 0, 1] -= aw[:, 2]
    out[:, 1, 0] += aw[:, 2]
    out[:, 0, 2] += aw[:, 1]
    out[:, 2, 0] -= aw[:, 1]
    out[:, 1, 2] -= aw[:, 0]
    out[:, 2, 1] += aw[:, 0]
    return out


def _rodrigues_coefficients(theta: Array) -> tuple[Array, Array]:
    """``sin θ / θ`` and ``2 sin²(θ/2) / θ²`` of angles ``theta`` [rad], by their series below :data:`SMALL_RAD`."""
    small = np.flatnonzero(theta < SMALL_RAD)
    safe = theta.copy()
    safe[small] = 1.0
    a = np.sin(safe) / safe
    b = 2.0 * (np.sin(safe / 2.0) / safe) ** 2
    if len(small):  # the series where the closed forms lose digits
        t2 = theta[small] ** 2
        a[small] = 1.0 - t2 / 6.0 + t2**2 / 120.0
        b[small] = 0.5 - t2 / 24.0 + t2**2 / 720.0
    return a, b


def _skews(w: Array) -> Array:
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    return K


def slerp_factors(R: Array, w: Array) -> tuple[Array, Array, Array]:
    """``R K`` and ``R K²`` (K, 3, 3) and ``θ = |w|`` (K,) [rad] of :func:`slerp_rotations`' product.

    ``K`` the skew matrix of each rotation vector of ``w`` (K, 3) [rad]; ``R`` (K, 3, 3).
    """
    RK = R @ _skews(w)
    return RK, RK @ _skews(w), np.linalg.norm(w, axis=1)


def slerp_rotations(R: Array, w: Array, index: Array, t: Array) -> Array:
    """Rotation matrices ``R[index] exp(t w[index])`` (M, 3, 3) at the parameters ``t`` (M,).

    Args:
        R: rotation matrices (K, 3, 3).
        w: rotation vectors (K, 3) [rad], one per rotation of ``R``.
        index: each sample's rotation, (M,), integers in [0, K).
        t: each sample's fraction of its rotation vector, (M,).

    With ``K`` the skew matrix of ``w`` and ``θ = |w|``, ``exp(t K) = I + t a(tθ) K + t² b(tθ) K²``
    (``a``, ``b`` the coefficients of :func:`exp_rotvecs`), so the product is
    ``R + t a (R K) + t² b (R K²)``: the same as ``R[index] @ exp_rotvecs(t[:, None] * w[index])``
    to rounding.
    """
    RK, RK2, theta = slerp_factors(R, w)
    a, b = _rodrigues_coefficients(t * np.take(theta, index))
    a *= t
    b *= t * t
    out = np.take(R, index, axis=0)
    out += a[:, None, None] * np.take(RK, index, axis=0)
    out += b[:, None, None] * np.take(RK2, index, axis=0)
    return out
