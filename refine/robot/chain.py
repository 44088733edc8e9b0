"""Forward kinematics and frame Jacobians of many joint rows at once, in NumPy, for one-axis joints.

Pinocchio evaluates one configuration per call, about 3 µs a row from Python; the optimiser's
verifier, the controller line's IK and the warm seed's projection ask for thousands of rows at a
time. :class:`BatchChain` takes a Pinocchio model's joint placements and axes once and evaluates
all rows of a batch together, joint after joint, with a handful of array operations per joint.

Every joint is turned into a frame whose z axis is its motion axis. With ``A_j`` a fixed rotation
taking z onto joint j's axis, its "axis frame" ``H_j = oMi_j · A_j`` follows its parent's as

    H_j = H_parent · (A_parentᵀ · P_j · A_j) · Z_j(q_j)

where ``P_j`` is the joint's placement in its parent (``model.jointPlacements``) and ``Z_j`` a turn
about z by ``q_j`` (revolute) or a shift along z (prismatic), because the joint's own motion is
``A_j Z_j(q) A_jᵀ``. The constant middle factor is one small matrix product for all rows at once,
and ``Z_j`` mixes two columns of the rotation. A frame on joint j is then
``oMf = H_j · A_jᵀ · F`` with ``F`` its placement on the joint, and the frame's Jacobian
(Pinocchio's ``LOCAL_WORLD_ALIGNED``: the frame origin's linear velocity and the angular velocity,
both in world axes) has for each joint k supporting it the column ``(z_k × (p_f - p_k), z_k)``
(revolute) or ``(z_k, 0)`` (prismatic), with ``z_k`` the third column of ``H_k`` and ``p_k`` its origin.

Only models whose every joint has one configuration variable and one axis fixed in its own frame
are taken: Pinocchio's ``RX``, ``RY``, ``RZ``, ``RevoluteUnaligned``, ``PX``, ``PY``, ``PZ`` and
``PrismaticUnaligned``. Anything else (a continuous joint with its two variables, a mimic joint, a
free flyer) gives no chain (:meth:`BatchChain.from_model` returns None), and the callers keep
Pinocchio's row-by-row evaluation. :data:`MIN_ROWS` is the batch size from which the chain is faster
than the row loop.

The same recursion for one row on any scalars (floats, CasADi's ``SX``) is
:meth:`BatchChain.row_frame` and :meth:`BatchChain.row_joint_placements`: what
:mod:`refine.robot.compiled_chain` writes out as C.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from refine.types import Array

MIN_ROWS = 96
"""Rows from which :class:`BatchChain` beats Pinocchio's row loop: its cost per batch is about
0.3 ms plus 1 µs a row, Pinocchio's about 6 µs a row with the Jacobian and 3 µs without it
(``benchmarks/batch_kinematics.py``)."""

_REVOLUTE = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2, "JointModelRevoluteUnaligned": -1}
_PRISMATIC = {"JointModelPX": 0, "JointModelPY": 1, "JointModelPZ": 2, "JointModelPrismaticUnaligned": -1}

# signed permutations taking z onto x and onto y (exact, so the aligned joints add no rounding)
_TO_AXIS = (
    np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
    np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
    np.eye(3),
)


def axis_frame(axis: Array) -> Array:
    """A rotation (3, 3) whose third column is the unit vector ``axis``; exact for ± a coordinate axis."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    k = int(np.argmax(np.abs(a)))
    if abs(abs(a[k]) - 1.0) < 1e-15 and np.count_nonzero(a) == 1:
        A = _TO_AXIS[k].copy()
        if a[k] < 0.0:  # turn half round the first column: z -> -z and y -> -y, still a rotation
            A[:, 1:] *= -1.0
        return A
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    u = np.cross(helper, a)
    u /= np.linalg.norm(u)
    return np.column_stack([u, np.cross(a, u), a])


@dataclass(frozen=True)
class _Joint:
    """One joint of a :class:`BatchChain` (index i in Pinocchio's model, i >= 1).

    Attributes:
        parent: the parent joint's index (0: the universe).
        q: the joint's index in the configuration and velocity vectors.
        revolute: True for a turn about its axis, False for a shift along it.
        C: ``A_parentᵀ · R(P_j) · A_j`` (3, 3): the axis frame's rotation in the parent's axis frame.
        t: ``A_parentᵀ · p(P_j)`` (3,): the joint's origin in the parent's axis frame.
        A: ``A_j`` (3, 3), z onto the joint's axis in the joint's frame.
    """

    parent: int
    q: int
    revolute: bool
    C: Array
    t: Array
    A: Array


class BatchChain:
    """Joint placements, frame placements and frame Jacobians of a Pinocchio model, for many rows at once.

    Made by :meth:`from_model`; agrees with ``pin.forwardKinematics``, ``updateFramePlacement`` and
    ``computeFrameJacobian(..., LOCAL_WORLD_ALIGNED)`` to rounding (``tests/robot/test_chain.py``).
    """

    def __init__(self, model: pin.Model, joints: tuple[_Joint, ...]) -> None:
        self.nq = int(model.nq)
        self._joints = joints
        self._frames = [(int(f.parentJoint), f.placement.homogeneous.copy()) for f in model.frames]
        self._support = [tuple(int(k) for k in model.supports[i])[1:] for i in range(model.njoints)]

    @classmethod
    def from_model(cls, model: pin.Model) -> BatchChain | None:
        """The chain of ``model``, or None if a joint is of a kind it does not evaluate (see the module notes)."""
        joints = [None]  # the universe, index 0
        axes = [np.eye(3)]
        for i in range(1, model.njoints):
            jm = model.joints[i]
            name = jm.shortname()
            if name in _REVOLUTE:
                revolute, k = True, _REVOLUTE[name]
            elif name in _PRISMATIC:
                revolute, k = False, _PRISMATIC[name]
            else:
                return None
            if jm.nq != 1 or jm.nv != 1 or jm.idx_q != jm.idx_v:
                return None
            axis = np.eye(3)[k] if k >= 0 else np.asarray(jm.extract().axis, dtype=float)
            A = axis_frame(axis)
            parent = int(model.parents[i])
            P = model.jointPlacements[i]
            Ap = axes[parent]
            joints.append(
                _Joint(parent, int(jm.idx_q), revolute, Ap.T @ P.rotation @ A, Ap.T @ P.translation, A)
            )
            axes.append(A)
        return cls(model, tuple(joints[1:]))

    def axis_frames(self, qs: Array) -> tuple[list[Array], list[Array]]:
        """Every joint's axis frame for joint rows ``qs`` (N, nq): rotations (N, 3, 3) and origins (N, 3).

        Item 0 of each list is the universe (identity); item i is joint i's ``H_i`` (see the module notes).
        """
        qs = np.asarray(qs, dtype=float)
        N = len(qs)
        R = [np.broadcast_to(np.eye(3), (N, 3, 3))]
        p = [np.zeros((N, 3))]
        for jt in self._joints:
            Rp = R[jt.parent]
            Ri = (
                (Rp.reshape(3 * N, 3) @ jt.C).reshape(N, 3, 3)
                if jt.parent
                else np.broadcast_to(jt.C, (N, 3, 3)).copy()
            )
            pi = (
                p[jt.parent] + (Rp.reshape(3 * N, 3) @ jt.t).reshape(N, 3)
                if jt.parent
                else np.broadcast_to(jt.t, (N, 3)).copy()
            )
            q = qs[:, jt.q, None]
            if jt.revolute:
                c, s = np.cos(q), np.sin(q)
                x, y = Ri[:, :, 0].copy(), Ri[:, :, 1].copy()
                Ri[:, :, 0] = c * x + s * y
                Ri[:, :, 1] = c * y - s * x
            else:
                pi += q * Ri[:, :, 2]
            R.append(Ri)
            p.append(pi)
        return R, p

    def joint_placements(self, qs: Array, joints: Array | None = None) -> Array:
        """Pinocchio's ``data.oMi`` (N, K, 4, 4) of the joints ``joints`` (default: all, universe first)."""
        R, p = self.axis_frames(qs)
        idx = np.arange(len(self._joints) + 1) if joints is None else np.asarray(joints, dtype=int)
        out = np.zeros((len(p[0]), len(idx), 4, 4))
        for slot, i in enumerate(idx):
            A = np.eye(3) if i == 0 else self._joints[i - 1].A
            out[:, slot, :3, :3] = (R[i].reshape(-1, 3) @ A.T).reshape(-1, 3, 3)
            out[:, slot, :3, 3] = p[i]
        out[..., 3, 3] = 1.0
        return out

    def frame(self, qs: Array, frame_id: int, jacobian: bool = True) -> tuple[Array, Array | None]:
        """Frame ``frame_id``'s placements (N, 4, 4) and, with ``jacobian``, its Jacobians (N, 6, nv).

        The Jacobian is Pinocchio's ``LOCAL_WORLD_ALIGNED`` one: linear rows (the frame origin's
        velocity) first, both halves in the model's world axes.
        """
        R, p = self.axis_frames(qs)
        parent, F = self._frames[frame_id]
        N = len(p[0])
        A = np.eye(3) if parent == 0 else self._joints[parent - 1].A
        Rf = R[parent].reshape(3 * N, 3)
        T = np.zeros((N, 4, 4))
        T[:, :3, :3] = (Rf @ (A.T @ F[:3, :3])).reshape(N, 3, 3)
        T[:, :3, 3] = p[parent] + (Rf @ (A.T @ F[:3, 3])).reshape(N, 3)
        T[:, 3, 3] = 1.0
        if not jacobian:
            return T, None
        J = np.zeros((N, 6, self.nq))
        origin = T[:, :3, 3]
        for k in self._support[parent]:
            jt = self._joints[k - 1]
            z = R[k][:, :, 2]
            if not jt.revolute:
                J[:, :3, jt.q] = z
                continue
            r = origin - p[k]
            J[:, 0, jt.q] = z[:, 1] * r[:, 2] - z[:, 2] * r[:, 1]
            J[:, 1, jt.q] = z[:, 2] * r[:, 0] - z[:, 0] * r[:, 2]
            J[:, 2, jt.q] = z[:, 0] * r[:, 1] - z[:, 1] * r[:, 0]
            J[:, 3:, jt.q] = z
        return T, J

    # ---- one row on generic scalars (the compiled chain's source)

    def row_axis_frames(self, q: Sequence[Any], cos: Callable, sin: Callable) -> tuple[list, list]:
        """Every joint's axis frame for one joint row ``q`` (nq scalars), as nested lists of scalars.

        The recursion of :meth:`axis_frames` on any scalar type with ``+``, ``*``, ``cos`` and
        ``sin`` (floats, CasADi's ``SX``); products with a constant 0 are left out, so the aligned
        joints' signed permutations cost nothing. Returns the rotations (3 × 3 lists) and origins
        (3 lists), item 0 the universe.
        """
        R: list = [[[1.0 if r == c else 0.0 for c in range(3)] for r in range(3)]]
        p: list = [[0.0, 0.0, 0.0]]
        for jt in self._joints:
            Rp, pp = R[jt.parent], p[jt.parent]
            Ri = [[_dot(Rp[r], jt.C[:, c]) for c in range(3)] for r in range(3)]
            pi = [pp[r] + _dot(Rp[r], jt.t) for r in range(3)]
            qj = q[jt.q]
            if jt.revolute:
                c, s = cos(qj), sin(qj)
                for r in range(3):
                    x, y = Ri[r][0], Ri[r][1]
                    Ri[r][0], Ri[r][1] = c * x + s * y, c * y - s * x
            else:
                pi = [pi[r] + qj * Ri[r][2] for r in range(3)]
            R.append(Ri)
            p.append(pi)
        return R, p

    def row_joint_placements(self, q: Sequence[Any], cos: Callable, sin: Callable) -> list:
        """Every joint's ``data.oMi`` for one row as 4 × 4 nested lists of scalars (see :meth:`row_axis_frames`)."""
        R, p = self.row_axis_frames(q, cos, sin)
        out = []
        for i in range(len(self._joints) + 1):
            A = np.eye(3) if i == 0 else self._joints[i - 1].A
            rows = [[_dot(R[i][r], A[c]) for c in range(3)] + [p[i][r]] for r in range(3)]
            out.append([*rows, [0.0, 0.0, 0.0, 1.0]])
        return out

    def row_frame(
        self, q: Sequence[Any], frame_id: int, cos: Callable, sin: Callable, jacobian: bool = True
    ) -> tuple[list, list | None]:
        """Frame ``frame_id``'s placement (4 × 4) and Jacobian (6 × nv) for one row, nested lists of scalars.

        :meth:`frame` for one row on any scalars (see :meth:`row_axis_frames`); entries the
        Jacobian does not depend on are the float 0.0.
        """
        R, p = self.row_axis_frames(q, cos, sin)
        parent, F = self._frames[frame_id]
        A = np.eye(3) if parent == 0 else self._joints[parent - 1].A
        M, m = A.T @ F[:3, :3], A.T @ F[:3, 3]
        Rf = [[_dot(R[parent][r], M[:, c]) for c in range(3)] for r in range(3)]
        origin = [p[parent][r] + _dot(R[parent][r], m) for r in range(3)]
        T = [[*Rf[r], origin[r]] for r in range(3)] + [[0.0, 0.0, 0.0, 1.0]]
        if not jacobian:
            return T, None
        J: list = [[0.0] * self.nq for _ in range(6)]
        for k in self._support[parent]:
            jt = self._joints[k - 1]
            z = [R[k][r][2] for r in range(3)]
            if not jt.revolute:
                for r in range(3):
                    J[r][jt.q] = z[r]
                continue
            d = [origin[r] - p[k][r] for r in range(3)]
            J[0][jt.q] = z[1] * d[2] - z[2] * d[1]
            J[1][jt.q] = z[2] * d[0] - z[0] * d[2]
            J[2][jt.q] = z[0] * d[1] - z[1] * d[0]
            for r in range(3):
                J[3 + r][jt.q] = z[r]
        return T, J


def _dot(row: Sequence[Any], constants: Array) -> Any:
    """``Σ row[i] · constants[i]`` with the terms of a constant 0 left out and those of a constant 1 not multiplied."""
    total: Any = 0.0
    for x, c in zip(row, constants, strict=True):
        c = float(c)
        if c == 0.0:
            continue
        term = x if c == 1.0 else (-x if c == -1.0 else x * c)
        total = term if isinstance(total, float) and total == 0.0 else total + term
    return total
