"""The tracker's distance-dependent z error, modelled as a polynomial in the distance.

A magnetic tracker near steel reads positions with an error that grows with the distance ``d``
from the receiver; its largest part is along the receiver's z axis. refine models it as

    ``dz(d) = c2 d^2 + c3 d^3``        (``d`` in metres, ``dz`` in metres)

zero and flat at the receiver and smooth; when the cubic bends over (``c2`` and ``c3`` of opposite
signs) it is held at its extremum beyond it, ``d* = -2 c2 / (3 c3)``, so the error levels off in
the far field instead of turning back. The two
coefficients are unknowns of the calibrations that measure over a range of distances (pivot,
receiver registration) and are reported, so a user sees how large the error was. The model is
meant for the measured range only; beyond it, a cubic is not an extrapolation to trust.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from refine.types import Array

#: Number of coefficients of the model, ``(c2, c3)``.
N_COEFFS = 2
#: Distances are clipped here [m]: no tracker of this kind reads farther, and it keeps the
#: fixed-point inversion bounded while a fit tries large coefficients.
MAX_DISTANCE_M = 3.0


def z_error(positions: ArrayLike, coeffs: ArrayLike) -> Array:
    """Z error [m] at true sensor positions in {S} [m], shape (..., 3) -> (...)."""
    d = np.minimum(np.linalg.norm(np.asarray(positions, dtype=float), axis=-1), MAX_DISTANCE_M)
    c2, c3 = np.asarray(coeffs, dtype=float)
    if c2 * c3 < 0.0:
        d = np.minimum(d, -2.0 * c2 / (3.0 * c3))
    return d * d * (c2 + c3 * d)


def distort(positions: ArrayLike, coeffs: ArrayLike) -> Array:
    """What the tracker reads at true positions [m] (..., 3): z shifted by :func:`z_error`."""
    p = np.array(positions, dtype=float)
    p[..., 2] += z_error(p, coeffs)
    return p


def correct(measured: ArrayLike, coeffs: ArrayLike, iterations: int = 6) -> Array:
    """True positions [m] (..., 3) from measured ones, inverting :func:`distort` by fixed point.

    The map converges while the slope of ``dz(d)`` stays well below 1 m/m (a tracker's is a few
    hundredths).
    """
    m = np.asarray(measured, dtype=float)
    p = m.copy()
    for _ in range(iterations):
        p[..., 2] = m[..., 2] - z_error(p, coeffs)
    return p


def z_error_range_m(positions: ArrayLike, coeffs: ArrayLike) -> tuple[float, float]:
    """Smallest and largest z error [m] the model gives over the positions [m] (..., 3)."""
    dz = z_error(positions, coeffs)
    return float(np.min(dz)), float(np.max(dz))
