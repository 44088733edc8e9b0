"""A robot's reach as the makers quote it: the wrist centre's largest distance from axis 1.

The data sheets of industrial arms (ABB, FANUC, Yaskawa Motoman, KUKA) give the reach as the
largest horizontal distance of the wrist centre (point P, where the last three axes meet) from axis
1: for an arm with shoulder offset ``a1``, upper arm ``a2`` and forearm ``(a3, d4)`` stretched
horizontally, ``a1 + a2 + sqrt(a3^2 + d4^2)``. :func:`wrist_centre_reach` computes it for any chain:
the wrist centre is where the last three joint axes meet (within :data:`WRIST_TOLERANCE_M`); an arm
whose axes do not meet (a UR's offset wrist) has the origin of its last joint in its place. Its
distance from axis 1 does not depend on joint 1 nor, for a spherical wrist, on the wrist joints;
it is maximised over the other joints within their limits (samples, then bounded quasi-Newton).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.optimize import minimize

from refine.errors import InputError
from refine.types import Array

WRIST_TOLERANCE_M = 1e-4
"""The last three axes meet within this distance for the wrist to count as spherical [m]."""
SAMPLES = 600
"""Random configurations of the arm joints sampled before the local search."""
STARTS = 4
"""The best samples each started a bounded local search from."""


def _chain(model: pin.Model, flange_frame: str) -> list[int]:
    """The joints from the base to the flange frame, base first."""
    if not model.existFrame(flange_frame):
        raise InputError(f"no frame {flange_frame!r} for the flange to measure the reach from")
    return [int(j) for j in model.supports[model.frames[model.getFrameId(flange_frame)].parentJoint]][1:]


def _axes(model: pin.Model, data: pin.Data, chain: list[int]) -> list[tuple[Array, Array]]:
    """(unit direction, point) in the base frame of each chain joint's axis at the neutral pose."""
    q = pin.neutral(model)
    jac = pin.computeJointJacobians(model, data, q)
    out = []
    for j in chain:
        w = np.array(jac[3:, model.idx_vs[j]])
        out.append((w / np.linalg.norm(w), np.array(data.oMi[j].translation)))
    return out


def _meeting_point(axes: list[tuple[Array, Array]]) -> tuple[Array, float]:
    """The point nearest to every line in the least-squares sense, and its largest distance to one [m]."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    projectors = [np.eye(3) - np.outer(w, w) for w, _ in axes]
    for P, (_, p) in zip(projectors, axes, strict=True):
        A += P
        b += P @ p
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    spread = max(float(np.linalg.norm(P @ (x - p))) for P, (_, p) in zip(projectors, axes, strict=True))
    return x, spread


def wrist_centre_reach(model: pin.Model, flange_frame: str) -> float:
    """The wrist centre's largest distance from axis 1 over the joint limits [m].

    Args:
        model: the arm's Pinocchio model (revolute joint 1).
        flange_frame: the frame the tool is mounted on: the chain to it is the arm.

    Raises:
        InputError: the chain has fewer than three joints or its first joint is not revolute.
    """
    chain = _chain(model, flange_frame)
    revolute = [model.joints[j].shortname().startswith("JointModelR") for j in chain]
    if len(chain) < 3 or not revolute[0]:
        raise InputError(
            f"the reach is the wrist centre's distance from axis 1, but the chain to {flange_frame!r} has "
            f"{len(chain)} joints and a {'revolute' if revolute and revolute[0] else 'non-revolute'} "
            "first joint; give reach_m [m]"
        )
    data = model.createData()
    axes = _axes(model, data, chain)
    centre, spread = _meeting_point(axes[-3:])
    if len(chain) >= 6 and all(revolute[-3:]) and spread < WRIST_TOLERANCE_M:
        carrier = chain[-3]  # the point lies on the first wrist axis: fixed in that joint's frame
        moving = chain[1:-3]
    else:
        carrier = chain[-1]
        centre = np.array(data.oMi[carrier].translation)
        moving = chain[1:-1]
    point_in_carrier = data.oMi[carrier].actInv(centre)
    w1, p1 = axes[0]
    off_axis = np.eye(3) - np.outer(w1, w1)
    q0 = pin.neutral(model)
    index = [model.idx_qs[j] for j in moving]
    lower = np.clip(model.lowerPositionLimit[index], -np.pi, np.pi)
    upper = np.clip(model.upperPositionLimit[index], -np.pi, np.pi)

    def distance(x: Array) -> float:
        q = q0.copy()
        q[index] = x
        pin.forwardKinematics(model, data, q)
        return float(np.linalg.norm(off_axis @ (data.oMi[carrier].act(point_in_carrier) - p1)))

    if not index:
        return distance(np.zeros(0))
    samples = np.random.default_rng(0).uniform(lower, upper, size=(SAMPLES, len(index)))
    samples = np.vstack([samples, np.clip(np.zeros(len(index)), lower, upper)])
    ranked = sorted(samples, key=distance, reverse=True)[:STARTS]
    bounds = list(zip(lower, upper, strict=True))
    best = max(-minimize(lambda x: -distance(x), x0, method="L-BFGS-B", bounds=bounds).fun for x0 in ranked)
    return float(best)
