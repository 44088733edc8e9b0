"""How far one body of a checked pair can move relative to the other while the joints move.

Between two samples of a joint path the joints move linearly, ``q(t) = q0 + t (q1 - q0)``. Seen
from body B of a pair, a point x of body A moves only through the joints on the tree path between
the two bodies (for a link against the cell: the joints from the base to the link; for link i
against link j of one arm: the joints between them). Joint j turns a point about its axis at the
speed ``|dq_j| dist(x, axis_j)``, so along ``t`` in [t0, t1] no point of A moves further, relative
to B, than

    |t1 - t0| * Σ_j |Δq_j| R_j,

with ``R_j`` the largest distance any point of the pair's moving body can have from axis j at any
configuration (:func:`pair_reach`; for a prismatic joint ``R_j = 1``: the body moves with it).
Where both bodies hang from the path (two branches of a tree), each side's joints count with its
own body's reach and the two motions add up.

``R_j`` is a constant of the robot and shapes, bounded by the triangle inequality along the chain:
for the body's own joint it is the largest distance of the shape's corners from that joint's axis
(exact); for a joint j further up, it is the distance of the next joint's origin from axis j (fixed
on link j) plus the lengths of the links down to the body's joint, plus the largest distance of the
shape's corners from that joint's origin. A shape's corners are the vertices of a convex piece or
the corners of the box bounding a primitive; distance to a point or line is convex, so its largest
value over a shape is reached at a corner of any convex set holding the shape.
"""

from __future__ import annotations

import threading
import weakref
from typing import Any

import numpy as np
import pinocchio as pin

from refine.collision.geometry import Body
from refine.collision.pairs import joint_axes
from refine.errors import InputError
from refine.types import Array

_JOINT_REACH: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
""":func:`joint_reach` per collision model."""


def corners(body: Body) -> Array:
    """Points (K, 3) in the body's shape frame whose convex hull holds the body [m]."""
    if body.vertices is not None:
        return np.asarray(body.vertices, dtype=float)
    if body.kind_params[0] == "convex":
        return np.asarray(body.kind_params[1], dtype=float)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    return body.centre + signs * body.half_extent


def _off_axis(points: Array, axis: tuple[Array, Array]) -> Array:
    w, p = axis
    d = points - p
    return np.linalg.norm(d - np.outer(d @ w, w), axis=1)


class _Chain:
    """The robot's joint origins and axes at the neutral configuration, in the base frame."""

    def __init__(self, model: pin.Model) -> None:
        self.model = model
        data = model.createData()
        pin.forwardKinematics(model, data, pin.neutral(model))
        self.oMi = [data.oMi[j].homogeneous.copy() for j in range(model.njoints)]
        self.axes = joint_axes(model, np.eye(4))
        for j in range(1, model.njoints):
            if model.joints[j].nv != 1:
                raise InputError(
                    f"collision motion bound: joint {model.names[j]!r} has {model.joints[j].nv} degrees "
                    "of freedom; only revolute and prismatic joints (one each) are supported"
                )

    def side(self, body: Body, points: Array, stop: int) -> dict[int, float]:
        """Per velocity index, R_j for the joints from ``body``'s joint up to (not incl.) ``stop``'s."""
        model = self.model
        oMi = self.oMi
        world = points @ oMi[body.joint][:3, :3].T + oMi[body.joint][:3, 3]  # at the neutral configuration
        chain = [j for j in reversed(list(model.supports[body.joint])) if j != 0]  # body's joint first
        common = set(model.supports[stop])
        out: dict[int, float] = {}
        below = float(np.max(np.linalg.norm(world - oMi[body.joint][:3, 3], axis=1)))  # from body's joint
        child = body.joint
        for j in chain:
            if j in common:
                break
            axis = self.axes[j]
            if axis is None:  # prismatic: every point moves with it, one metre per metre
                r = 1.0
            elif j == body.joint:
                r = float(np.max(_off_axis(world, axis)))
            else:
                r = float(_off_axis(oMi[child][None, :3, 3], axis)[0]) + below
            out[model.joints[j].idx_v] = r
            if j != body.joint:
                below += float(np.linalg.norm(oMi[child][:3, 3] - oMi[j][:3, 3]))
            child = j
        return out


def pair_reach(model: pin.Model, pairs: list[tuple[Body, Body]]) -> Array:
    """Per pair and joint, the bound R_j [m/rad, or m/m for a prismatic joint], shape (P, n).

    Along a joint segment ``dq`` the pair's distance changes by at most ``|dq| @ R[p]``: in a serial
    arm no point of the first (distal) body moves further than that relative to the second body
    (see the module notes).

    Args:
        model: the robot's Pinocchio model (joint frames as in the collision model's bodies).
        pairs: the checked pairs as (body, other); a cell object has joint -1 and does not move.
    """
    chain, known = _chain_of(model)
    out = np.zeros((len(pairs), model.nv))
    points: dict[int, Array] = {}  # per body: its corners in its joint's frame
    for p, (a, b) in enumerate(pairs):
        for body, other in ((a, b), (b, a)):
            if body.joint <= 0:
                continue
            if id(body) not in points:
                T = (
                    model.frames[body.frame_id].placement.homogeneous @ body.link_T_shape
                )  # in the joint frame
                points[id(body)] = corners(body) @ T[:3, :3].T + T[:3, 3]
            key = (body.joint, max(other.joint, 0), points[id(body)].tobytes())
            sides = known.get(key)
            if sides is None:
                sides = chain.side(body, points[id(body)], max(other.joint, 0))
                with _CHAINS_LOCK:
                    known[key] = sides
            for v, r in sides.items():
                out[p, v] += r
    return out


_CHAINS: dict[int, tuple[pin.Model, _Chain, dict[tuple[int, int, bytes], dict[int, float]]]] = {}
"""Per Pinocchio model (by id, the model kept with it): its :class:`_Chain` and the bounds of each
side worked out so far, by the body's joint, the other body's joint and the body's corners: the
same robot and tool in a new collision model (a problem solved again) take them as they are."""
_CHAINS_LOCK = threading.Lock()
CHAINS_KEPT = 16
"""Pinocchio models whose chains :data:`_CHAINS` keeps."""


def _chain_of(model: pin.Model) -> tuple[_Chain, dict[tuple[int, int, bytes], dict[int, float]]]:
    with _CHAINS_LOCK:
        entry = _CHAINS.get(id(model))
        if entry is not None and entry[0] is model:
            return entry[1], entry[2]
    chain = _Chain(model)
    with _CHAINS_LOCK:
        _CHAINS[id(model)] = (model, chain, {})
        while len(_CHAINS) > CHAINS_KEPT:
            del _CHAINS[next(iter(_CHAINS))]
        return chain, _CHAINS[id(model)][2]


def joint_reach(model: Any) -> Array:  # a CollisionModel (which imports this module)
    """Per joint, the largest distance [m] any body downstream of it can have from its axis, (n,).

    A bound that holds at every configuration: the joint offsets along the chain from the joint to
    the body's joint, plus the body's extent from its own joint's origin. A constant of the model
    (its robot and bodies do not change), worked out once per model.
    """
    known = _JOINT_REACH.get(model)
    if known is not None:
        return known.copy()
    pm = model.robot.model
    offset = [float(np.linalg.norm(pm.jointPlacements[j].translation)) for j in range(pm.njoints)]
    reach = np.zeros(model.robot.nq)
    for body in model.bodies:
        if body.kind == "cell" or body.joint <= 0:
            continue
        jMs = pm.frames[body.frame_id].placement.homogeneous @ body.link_T_shape
        centre = jMs[:3, :3] @ body.centre + jMs[:3, 3]
        extent = float(np.linalg.norm(centre) + np.linalg.norm(body.half_extent))
        chain = list(pm.supports[body.joint])[1:]  # joints from the base to the body's joint
        for i, j in enumerate(chain):
            along = sum(offset[k] for k in chain[i + 1 :])
            v = pm.joints[j].idx_v
            reach[v] = max(reach[v], along + extent)
    _JOINT_REACH[model] = reach
    return reach.copy()
