"""The spin about the tool axis a seed gives an axisymmetric stationary tool, chosen along the path.

A robot holding the part against a standing tool turns the part about the tool's axis freely (the
spin does not change the process), but the spin decides where the flange, and so the wrist centre,
goes: turning the part about the tool axis carries the wrist centre round a circle about that axis.
For an arm with a spherical wrist the wrist centre's distance from the shoulder sets the elbow
(:class:`refine.optimise.reach.ReachModel`), so a spin that keeps it inside the arm's range,
with room, keeps the elbow off its limits. :func:`path_spins` picks one spin per waypoint from a
grid by dynamic programming: the least total turn of the part between neighbours (the targets' own
spin, arbitrary in a CAM toolpath, counted in) among the spins whose wrist
centre stays :data:`SPIN_INSET_M` inside the range, the shortfall weighed far above any turn where
none does (a Viterbi pass over waypoints x spins).
"""

from __future__ import annotations

import math

import numpy as np

from refine.optimise.reach import ReachModel
from refine.types import Array

SPIN_STEPS = 72
"""Spins tried per waypoint (a 5 deg grid)."""

SPIN_INSET_M = 0.03
"""A spin counts as in reach when its wrist centre stays this far inside the arm's range [m]."""

SHORTFALL_WEIGHT = 1e3
"""Cost of a metre of wrist-centre shortfall against a radian of turn between neighbours."""


def path_spins(
    reach: ReachModel, targets: Array, base_in_world: Array, tcp_in_flange: Array, tool_in_world: Array
) -> Array:
    """One spin per waypoint [rad] (N,), about each target's z axis, for a stationary tool.

    Args:
        reach: the robot's reach model (a spherical wrist; otherwise zeros are returned).
        targets: T_part_TCP per waypoint (N, 4, 4).
        base_in_world: T_F_R (4, 4).
        tcp_in_flange: T_flange_part (4, 4).
        tool_in_world: T_F_TCP of the stationary tool (4, 4).

    Returns:
        ψ_k such that ``targets[k] · Rz(ψ_k)`` keeps the wrist centre in reach with the least turning.
    """
    n = len(targets)
    if not reach.spherical or n == 0:
        return np.zeros(n)
    psi = np.arange(SPIN_STEPS) * (2.0 * math.pi / SPIN_STEPS)
    # the wrist centre in the TCP frame of each target: T_TCP_part · T_part_flange · wrist
    v = np.linalg.inv(targets) @ (np.linalg.inv(tcp_in_flange) @ np.append(reach.point_in_flange, 1.0))
    c, s = np.cos(psi), np.sin(psi)  # Rz(ψ)⁻¹ applied to v, for every spin: (N, M, 3)
    turned = np.stack(
        [
            c * v[:, 0, None] + s * v[:, 1, None],
            -s * v[:, 0, None] + c * v[:, 1, None],
            np.repeat(v[:, 2, None], len(psi), 1),
        ],
        axis=-1,
    )
    T_base_tool = np.linalg.inv(base_in_world) @ tool_in_world
    points = turned @ T_base_tool[:3, :3].T + T_base_tool[:3, 3]
    d = reach.distance(points.reshape(-1, 3)).reshape(n, len(psi))
    room = np.minimum(d - reach.r_min_m, reach.r_max_m - d) - SPIN_INSET_M
    node = SHORTFALL_WEIGHT * np.maximum(-room, 0.0)
    # the targets' own spin from one to the next (a CAM toolpath's is arbitrary): about z, from R_k to R_k+1
    rel = np.swapaxes(targets[:-1, :3, :3], 1, 2) @ targets[1:, :3, :3]
    twist = np.arctan2(rel[:, 1, 0] - rel[:, 0, 1], rel[:, 0, 0] + rel[:, 1, 1])
    # the part's turn about the tool axis from spin i at k-1 to spin j at k [rad], (M, M) a step, of
    # ψ_j - ψ_i + twist: the grid's differences take a few hundred values, each wrapped once per step
    steps, where = np.unique(psi[None, :] - psi[:, None], return_inverse=True)
    turns = np.abs(np.angle(np.exp(1j * (steps[None, :] + twist[:, None]))))
    where = where.reshape(len(psi), len(psi)).T.copy()  # row j: the steps from every spin i to spin j
    cost = node[0].copy()
    back = np.empty((n, len(psi)), dtype=np.int64)
    for k in range(1, n):
        total = turns[k - 1][where]  # total[j, i]: the turn from spin i to spin j plus the cost at i
        total += cost
        back[k] = total.argmin(axis=1)
        cost = total.min(axis=1) + node[k]
    path = np.empty(n, dtype=np.int64)
    path[-1] = int(np.argmin(cost))
    for k in range(n - 1, 0, -1):
        path[k - 1] = back[k, path[k]]
    return psi[path]


def spun(targets: Array, spins: Array) -> Array:
    """``targets[k] · Rz(spins[k])``: each target turned about its own z axis, (N, 4, 4)."""
    out = np.array(targets, dtype=float)
    c, s = np.cos(spins), np.sin(spins)
    x, y = out[:, :3, 0].copy(), out[:, :3, 1].copy()
    out[:, :3, 0] = c[:, None] * x + s[:, None] * y
    out[:, :3, 1] = -s[:, None] * x + c[:, None] * y
    return out
