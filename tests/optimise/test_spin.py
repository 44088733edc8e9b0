"""The spins a stationary tool's seed turns the part by (refine.optimise.spin) against a brute-force search."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from refine.optimise.reach import reach_model
from refine.optimise.spin import SHORTFALL_WEIGHT, SPIN_INSET_M, SPIN_STEPS, path_spins, spun
from refine.robot.registry import load_robot

BASE = pin.SE3(pin.exp3(np.array([0.0, 0.0, 0.3])), np.array([0.1, -0.1, 0.0])).homogeneous
PART_IN_FLANGE = pin.SE3(pin.exp3(np.array([0.3, -0.2, 0.1])), np.array([0.02, 0.01, 0.12])).homogeneous
TOOL_IN_WORLD = pin.SE3(pin.exp3(np.array([math.pi, 0.0, 0.0])), np.array([0.55, 0.2, 0.45])).homogeneous


def _rz(psi: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[math.cos(psi), -math.sin(psi)], [math.sin(psi), math.cos(psi)]]
    return T


def _brute_force(reach, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every waypoint's cost per spin and every pair's turn, from whole transforms, and the least path cost.

    The wrist centre of the robot holding the part at ``targets[k] · Rz(ψ)``: ``T_world_TCP ·
    (T_part_TCP)⁻¹ · T_flange_part⁻¹ · wrist``; the part's turn between neighbours: the z angle of
    ``(T_k-1 Rz(ψ_i))⁻¹ (T_k Rz(ψ_j))``.
    """
    psi = [2 * math.pi * i / SPIN_STEPS for i in range(SPIN_STEPS)]
    wrist = np.append(reach.point_in_flange, 1.0)
    n = len(targets)
    node = np.empty((n, SPIN_STEPS))
    for k in range(n):
        for i, p in enumerate(psi):
            flange = TOOL_IN_WORLD @ np.linalg.inv(targets[k] @ _rz(p)) @ np.linalg.inv(PART_IN_FLANGE)
            centre = (np.linalg.inv(BASE) @ flange @ wrist)[:3]
            d = float(reach.distance(centre[None])[0])
            room = min(d - reach.r_min_m, reach.r_max_m - d) - SPIN_INSET_M
            node[k, i] = SHORTFALL_WEIGHT * max(-room, 0.0)
    turn = np.empty((n - 1, SPIN_STEPS, SPIN_STEPS))
    for k in range(1, n):
        before = np.linalg.inv(np.array([targets[k - 1] @ _rz(a) for a in psi]))
        after = np.array([targets[k] @ _rz(b) for b in psi])
        rel = np.einsum("irs,jst->ijrt", before[:, :3, :3], after[:, :3, :3])  # every pair (i, j)
        turn[k - 1] = np.abs(np.arctan2(rel[..., 1, 0] - rel[..., 0, 1], rel[..., 0, 0] + rel[..., 1, 1]))
    return node, turn


def test_the_spins_are_a_least_cost_path_of_reach_shortfall_and_turning() -> None:
    robot = load_robot("kuka_iiwa14_r820")
    reach = reach_model(robot, math.radians(2.0))
    assert reach.spherical
    rng = np.random.default_rng(7)
    n = 14
    targets = np.empty((n, 4, 4))
    for k in range(n):  # a part's points turned by up to about 40 deg from one to the next
        targets[k] = pin.SE3(pin.exp3(rng.normal(size=3) * 0.4), rng.normal(size=3) * 0.08).homogeneous
    spins = path_spins(reach, targets, BASE, PART_IN_FLANGE, TOOL_IN_WORLD)
    node, turn = _brute_force(reach, targets)
    assert node.max() > 0.0 and (node == 0.0).any()  # reach decides between the spins somewhere
    # the least cost over all paths by plain dynamic programming, and the cost of the path found
    best = node[0].copy()
    for k in range(1, n):
        best = np.array(
            [min(best[i] + turn[k - 1, i, j] for i in range(SPIN_STEPS)) for j in range(SPIN_STEPS)]
        )
        best += node[k]
    index = np.rint(spins / (2 * math.pi / SPIN_STEPS)).astype(int)
    np.testing.assert_allclose(spins, index * (2 * math.pi / SPIN_STEPS), rtol=0, atol=1e-12)
    found = node[0, index[0]] + sum(
        turn[k - 1, index[k - 1], index[k]] + node[k, index[k]] for k in range(1, n)
    )
    assert found == np.float64(best.min()) or abs(found - best.min()) <= 1e-9
    # and the spun targets keep each z axis (the tool's) and position
    out = spun(targets, spins)
    np.testing.assert_allclose(out[:, :3, 2:], targets[:, :3, 2:], rtol=0, atol=1e-15)
