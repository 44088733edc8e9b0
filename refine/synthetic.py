"""Generated paths for tests and benchmarks: a fused path with known orientations and speed.

These stand in for the output of :func:`refine.fuse.fuse` when a test or a benchmark needs a
refinement problem of a chosen size without reading files.
"""

from __future__ import annotations

import numpy as np

from refine.frames import matrix_from_zyx, rotation_about
from refine.paths import FusedPath


def wave_path(
    n_waypoints: int,
    *,
    length_m: float = 1.0,
    centre: tuple[float, float, float] = (1.3, 0.0, 0.6),
    amplitude_m: float = 0.05,
    wavelength_m: float = 0.5,
    tilt_deg: float = 12.0,
    speed_m_s: float = 0.1,
) -> FusedPath:
    """A horizontal sine wave along world y with the tool pointing down and following the tangent.

    Args:
        n_waypoints: number of waypoints N (>= 3).
        length_m: extent along y [m] (the arc length is a little longer).
        centre: centre of the wave in {F} [m].
        amplitude_m: amplitude of the wave in x [m].
        wavelength_m: wavelength along y [m].
        tilt_deg: drag angle: the tool axis leans back against the travel direction [deg].
        speed_m_s: constant demonstrated speed [m/s].

    Returns:
        A FusedPath with N waypoints at equal arc-length steps (to 1e-6 relative).
    """
    # dense curve, then equal arc-length resampling
    y = np.linspace(-length_m / 2, length_m / 2, 20 * n_waypoints)
    x = centre[0] + amplitude_m * np.sin(2 * np.pi * y / wavelength_m)
    dense = np.column_stack([x, centre[1] + y, np.full_like(y, centre[2])])
    s_dense = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
    s = np.linspace(0.0, s_dense[-1], n_waypoints)
    positions = np.column_stack([np.interp(s, s_dense, dense[:, i]) for i in range(3)])
    tangent = np.gradient(positions, axis=0)
    heading = np.arctan2(tangent[:, 1], tangent[:, 0])
    # tool x along the travel direction, tool z down, leaning back by the tilt
    rotations = (
        matrix_from_zyx(heading, np.zeros_like(heading), np.zeros_like(heading))
        @ rotation_about("x", np.pi)
        @ rotation_about("y", -np.radians(tilt_deg))
    )
    speed = np.full(n_waypoints, speed_m_s)
    return FusedPath(
        s=s,
        positions=positions,
        rotations=rotations,
        speed=speed,
        t_demo=s / speed_m_s,
        residual=np.zeros(n_waypoints),
    )
