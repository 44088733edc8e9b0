"""Which pairs of bodies the collision model checks, and why it leaves the others out.

A pair is left out for one of these reasons and for no other. Nothing is dropped because it happens
to touch at some sampled configuration: every rule below is a fact of the kinematics and shapes.

1. ``"static"``: two cell objects; nothing moves them.
2. ``"fixed link"``: a link fixed to the robot base (no joint between it and the world) against a
   cell object. Its distance does not depend on q; a robot on a pedestal touches it by design.
3. ``"workpiece"``: a tool shape against a cell object marked ``workpiece = true``. The nozzle or
   torch touches the part by design; the links are still checked against it.
4. ``"same body"``: two shapes moved by the same joint (Pinocchio merges links joined by fixed
   joints into one body, e.g. ``link_6`` and ``tool0``; the tool moves with the flange link).
5. ``"adjacent"``: one body's joint is the other's parent joint in the kinematic tree (the two
   bodies meet at that joint). Tool shapes are thus not checked against the flange link and the
   link before it.
6. ``"always close"``: the joints between the two bodies are all revolute and their axes meet in
   one point p that lies within ``self_margin_m`` of the two shapes together
   (``dist(p, A) + dist(p, B) <= self_margin_m``). Every joint between them turns about p, so p
   keeps its place on both bodies at every configuration; their distance never exceeds that sum,
   and the margin could never be met. The housings of a spherical wrist are the usual case.
7. ``"constant distance"``: the distance cannot change, because the joints between the two bodies,
   taken in order from A to B, are first joints about whose axes A's shape is symmetric, then joints
   about whose axes B's shape is symmetric (a sphere is symmetric about every axis through its
   centre, a cylinder about its own axis). Turning a shape about its own symmetry axis moves none of
   it. A UR arm's shoulder housing turning about joint 2 above its round base is the usual case.
   Such a pair can neither break its margin by moving nor be repaired; it is logged, with a warning
   when it is closer than ``self_margin_m``.

For a robot with a sampled self-collision matrix (:mod:`refine.robot.self_collision`), two
links of the robot are checked exactly when the matrix enables them (reasons ``"matrix: adjacent"``,
``"matrix: always"``, ``"matrix: never"``), in place of rules 5 to 7; those rules still decide the
tool's shapes against the links.

Rules 6 and 7 are tested once, at the neutral configuration; both hold at every configuration
(joint axes that meet keep meeting, and the relative pose of the two bodies is a product of
rotations about the neutral axes).
"""

from __future__ import annotations

import logging

import numpy as np
import pinocchio as pin

from refine.collision.geometry import Body
from refine.types import Array

log = logging.getLogger(__name__)

Axes = dict[int, "tuple[Array, Array] | None"]

_TOL = 1e-7
"""Lines closer than this [m] meet; directions closer than this [rad] are parallel."""


def exclusion(
    a: Body,
    b: Body,
    T_a: Array,
    T_b: Array,
    model: pin.Model,
    axes: Axes,
    self_margin_m: float,
    matrix: dict[frozenset[str], str] | None = None,
) -> str | None:
    """Why the pair (a, b) is not checked (one of the reasons above), or None when it is.

    Args:
        a: a body (robot link, tool shape or cell object).
        b: another body.
        T_a: world pose of ``a``'s shape frame at the neutral configuration, (4, 4).
        T_b: world pose of ``b``'s shape frame at the neutral configuration, (4, 4).
        model: the robot's Pinocchio model.
        axes: per joint index, its axis at the neutral configuration as (unit direction, point)
            in the world, or None for a joint that is not revolute (see :func:`joint_axes`).
        self_margin_m: the clearance kept between the robot's own bodies [m].
        matrix: the robot's sampled self-collision matrix (disabled link pairs and why), or None.
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
    if matrix is not None and a.kind == "link" and b.kind == "link":
        why = matrix.get(frozenset((str(a.link), str(b.link))))
        return None if why is None else f"matrix: {why}"
    if model.parents[a.joint] == b.joint or model.parents[b.joint] == a.joint:
        return "adjacent"
    joints = joints_between(model, a.joint, b.joint)
    if any(axes[j] is None for j in joints):
        return None
    lines = [axes[j] for j in joints]
    p = _common_point(lines)  # type: ignore[arg-type]
    if p is not None and a.outside_distance(T_a, p) + b.outside_distance(T_b, p) <= self_margin_m:
        return "always close"
    if _constant(a, T_a, b, T_b, lines):  # type: ignore[arg-type]
        return "constant distance"
    return None


def joint_axes(model: pin.Model, T_world_base: Array) -> Axes:
    """Every joint's axis at the neutral configuration, (unit direction, point) in the world."""
    data = model.createData()
    pin.computeJointJacobians(model, data, pin.neutral(model))
    J = data.J  # WORLD convention: linear part is the velocity of the point at the base origin
    R, t = T_world_base[:3, :3], T_world_base[:3, 3]
    axes: Axes = {}
    for j in range(1, model.njoints):
        col = J[:, model.joints[j].idx_v]
        v, w = col[:3], col[3:]
        if model.joints[j].nv != 1 or np.linalg.norm(w) < 0.5:
            axes[j] = None  # prismatic or multi-DoF: no fixed axis
            continue
        w = w / np.linalg.norm(w)
        axes[j] = (R @ w, R @ cross3(w, v) + t)  # v = p x w for p on the axis, so w x v is one
    return axes


def joints_between(model: pin.Model, ja: int, jb: int) -> list[int]:
    """The joints on the tree path between two bodies' joints, in order from ``ja`` to ``jb``."""
    sa, sb = list(model.supports[ja]), list(model.supports[jb])
    common = set(sa) & set(sb)
    return [j for j in reversed(sa) if j not in common] + [j for j in sb if j not in common]


def cross3(a: Array, b: Array) -> Array:
    """``np.cross`` of two 3-vectors, the same products and differences without its array set-up."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _off_line(x: Array, line: tuple[Array, Array]) -> float:
    w, p = line
    d = x - p
    return float(np.linalg.norm(d - w * float(w @ d)))


def _common_point(lines: list[tuple[Array, Array]]) -> Array | None:
    A = np.zeros((3, 3))
    rhs = np.zeros(3)
    for w, p in lines:
        P = np.eye(3) - np.outer(w, w)
        A += P
        rhs += P @ p
    x = np.linalg.lstsq(A, rhs, rcond=None)[0]
    return x if all(_off_line(x, line) <= _TOL for line in lines) else None


def _symmetric_about(body: Body, T: Array, line: tuple[Array, Array]) -> bool:
    tag = body.kind_params[0]
    centre = T[:3, 3]
    if tag == "sphere":
        return _off_line(centre, line) <= _TOL
    if tag == "cylinder":
        parallel = float(np.linalg.norm(cross3(line[0], T[:3, 2]))) <= _TOL
        return parallel and _off_line(centre, line) <= _TOL
    return False


def _constant(a: Body, T_a: Array, b: Body, T_b: Array, lines: list[tuple[Array, Array]]) -> bool:
    for split in range(len(lines) + 1):
        if all(_symmetric_about(a, T_a, line) for line in lines[:split]) and all(
            _symmetric_about(b, T_b, line) for line in lines[split:]
        ):
            return True
    return False
