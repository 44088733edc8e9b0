"""Which pairs of bodies the collision model checks, and why it leaves the others out.

A pair is left out for one of these reasons, and for no other (nothing is dropped because it
happens to touch at some sampled configuration):

1. ``"static"``: two cell objects; nothing moves them.
2. ``"fixed link"``: a link fixed to the robot base (no joint between it and the world) against a
   cell object. Its distance does not depend on q, so no joint motion could change it; a robot on a
   pedestal touches the pedestal by design.
3. ``"workpiece"``: a tool shape against a cell object marked ``workpiece = true``. The nozzle or
   torch touches the part by design; the links are still checked against it.
4. ``"same body"``: two shapes moved by the same joint (Pinocchio merges links joined by fixed joints
   into one body, e.g. ``link_6`` and ``tool0``; the tool moves with the flange link).
5. ``"adjacent"``: one body's joint is the other's parent joint in the kinematic tree (the two
   bodies meet at that joint). Tool shapes are thus not checked against the flange link and the
   link before it.
6. ``"always close"``: the joints between the two bodies are all revolute and their axes meet in one
   point p that lies within ``self_margin_m`` of the two shapes together
   (``dist(p, A) + dist(p, B) <= self_margin_m``). Every joint between them turns about p, so p keeps
   its place on both bodies at every configuration; their distance can never exceed that sum and the
   margin could never be met. The housings of a spherical wrist are the usual case. The test is
   made once, on the kinematics, at the neutral configuration (where the axes meet they meet at
   every configuration).
"""

from __future__ import annotations

import logging

import fcl
import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from refine.collision.geometry import Body

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

_AXES_MEET_M = 1e-9
"""Axes whose common point is farther than this from one of them do not meet [m]."""


def exclusion(a: Body, b: Body, model: pin.Model, axes: dict[int, tuple[Array, Array] | None],
              self_margin_m: float) -> str | None:
    """Why the pair (a, b) is not checked (one of the reasons above), or None when it is.

    Args:
        a: a body (robot link, tool shape or cell object), placed at the neutral configuration.
        b: another body, placed likewise.
        model: the robot's Pinocchio model.
        axes: per joint index, its axis at the neutral configuration as (unit direction, point)
            in the world, or None for a joint that is not revolute (see :func:`joint_axes`).
        self_margin_m: the clearance kept between the robot's own bodies [m].
    """
    if a.kind == "cell" and b.kind == "cell":
        return "static"
    if a.kind == "cell" or b.kind == "cell":
        mover, cell = (b, a) if a.kind == "cell" else (a, b)
        if mover.joint == 0:
            return "fixed link"
        if mover.kind == "tool" and cell.workpiece:
            return "workpiece"
        return None
    if a.joint == b.joint:
        return "same body"
    if model.parents[a.joint] == b.joint or model.parents[b.joint] == a.joint:
        return "adjacent"
    p = _common_point(_joints_between(model, a.joint, b.joint), axes)
    if p is not None and _point_distance(p, a) + _point_distance(p, b) <= self_margin_m:
        return "always close"
    return None


def joint_axes(model: pin.Model, T_world_base: Array) -> dict[int, tuple[Array, Array] | None]:
    """Every joint's axis at the neutral configuration, (unit direction, point) in the world."""
    data = model.createData()
    q0 = pin.neutral(model)
    pin.computeJointJacobians(model, data, q0)
    J = data.J  # WORLD convention: linear part is the velocity of the point at the base origin
    axes: dict[int, tuple[Array, Array] | None] = {}
    for j in range(1, model.njoints):
        col = J[:, model.joints[j].idx_v]
        v, w = col[:3], col[3:]
        if model.joints[j].nv != 1 or np.linalg.norm(w) < 0.5:
            axes[j] = None  # prismatic or multi-DoF: no fixed point
            continue
        w = w / np.linalg.norm(w)
        p = np.cross(w, v)  # v = p x w for p on the axis, so w x v is such a p
        axes[j] = (T_world_base[:3, :3] @ w, T_world_base[:3, :3] @ p + T_world_base[:3, 3])
    return axes


def _joints_between(model: pin.Model, ja: int, jb: int) -> list[int]:
    sa, sb = set(model.supports[ja]), set(model.supports[jb])
    return sorted((sa ^ sb) - {0})


def _common_point(joints: list[int], axes: dict[int, tuple[Array, Array] | None]) -> Array | None:
    if not joints or any(axes[j] is None for j in joints):
        return None
    lines = [axes[j] for j in joints]
    A = np.zeros((3, 3))
    rhs = np.zeros(3)
    for w, p in lines:  # type: ignore[misc]
        P = np.eye(3) - np.outer(w, w)
        A += P
        rhs += P @ p
    x = np.linalg.lstsq(A, rhs, rcond=None)[0]
    for w, p in lines:  # type: ignore[misc]
        off = (x - p) - w * float(w @ (x - p))
        if float(np.linalg.norm(off)) > _AXES_MEET_M:
            return None
    return x


def _point_distance(p: Array, body: Body) -> float:
    probe_radius = 1e-6
    probe = fcl.CollisionObject(fcl.Sphere(probe_radius), fcl.Transform(np.eye(3), p))
    d = fcl.distance(probe, body.obj, fcl.DistanceRequest(enable_signed_distance=True))
    return max(float(d) + probe_radius, 0.0)
