"""Where the controller line's IK starts at each sample (:mod:`refine.optimise.controller_line`).

Two starts, both close to the line's joints so that the IK (to ``IK_TOLERANCE``) needs few passes
and stays on the refined joints' branch:

* :func:`newton_start`: the joint-linear joints moved by one damped Newton step;
* :func:`previous_bows`: on a re-solve, the previous answer's line: its bow ``q_line - q_lin`` at
  the same sample, added to the new joint-linear joints. A small move of the waypoints leaves the
  bow the same to first order, so this start is within the IK's tolerance of the new line at most
  samples, and saves the Newton step's pass too.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from refine.robot.kinematics import rotation_vectors
from refine.types import Array

NEWTON_DAMPING = 1e-3
"""Damping of :func:`newton_start`'s step, as the IK's own."""
NEWTON_STEP_MAX = 1e-3
"""A larger start step [rad] on any joint is not taken: the row starts from the joint-linear joints."""
PREVIOUS_MOVE_MAX_RAD = 1e-4
"""A previous line's bow starts a sample's IK only where neither waypoint of its segment moved more
than this on any joint since [rad] (:func:`previous_bows`). The bow's change grows with the move:
in the glass cell a move of 8e-3 rad left the bow start 2e-8 (median) from the new line, worse than
:func:`newton_start`'s 5e-12, and a move of 1.6e-8 rad left it within 1e-9 at every sample."""


def newton_start(
    J_wp: Array, segment: Array, t: Array, q_lin: Array, lin_poses: Array, targets: Array
) -> Array:
    """The IK's start on the line: the joint-linear joints ``q_lin`` moved by one damped Newton step.

    The step ``P e`` takes the damped inverse ``P = Jᵀ (J Jᵀ + λ² I)⁻¹`` (:data:`NEWTON_DAMPING`)
    of the TCP Jacobians at the two waypoints (``J_wp`` (N, 6, n)), interpolated linearly at the
    sample's ``t``, and the pose error ``e`` of the joint-linear pose to the line's. The line lies
    within the square of the step of the joint-linear motion, and the interpolated inverse is off
    the one at ``q_lin`` by the square of the step too, so that step leaves about the IK's
    tolerance and saves it one pass over every sample; it costs one small solve per waypoint, none
    per sample. A row whose step exceeds :data:`NEWTON_STEP_MAX` (near a singularity) starts from
    ``q_lin`` as it is, so every start stays on the refined joints' branch.
    """
    A = J_wp @ np.swapaxes(J_wp, 1, 2) + NEWTON_DAMPING**2 * np.eye(J_wp.shape[1])
    P_wp = np.swapaxes(np.linalg.solve(A, J_wp), 1, 2)  # (A⁻¹ J)ᵀ = Jᵀ A⁻¹, A symmetric: (N, n, 6)
    P = np.diff(P_wp, axis=0)[segment]
    P *= t[:, None, None]
    P += P_wp[segment]
    e = np.empty((len(t), 6, 1))
    e[:, :3, 0] = targets[:, :3, 3] - lin_poses[:, :3, 3]
    e[:, 3:, 0] = rotation_vectors(targets[:, :3, :3] @ np.transpose(lin_poses[:, :3, :3], (0, 2, 1)))
    dq = (P @ e)[:, :, 0]
    dq[np.abs(dq).max(axis=1) > NEWTON_STEP_MAX] = 0.0
    dq += q_lin
    return dq


def previous_bows(
    q: Array, m: Array, segment: Array, t: Array, previous: tuple[Array, Any], tolerance: float
) -> Array:
    """Per sample, the bow ``q_line - q_lin`` of a previous answer's line at the same ``t``, (M, n).

    Args:
        q: the new joints per waypoint [rad], (N, n).
        m: the new sub-steps per segment, (N-1,).
        segment: each sample's segment, (M,).
        t: each sample's parameter in its segment, (M,).
        previous: the previous answer's joints (N', n) [rad] and its line check (a
            ``LineCheck``: its ``samples``, ``segment``, ``t``, ``q`` and ``ik_error``).
        tolerance: the IK residual [m and rad stacked] a previous sample must have reached.

    Returns:
        The bows [rad], a row NaN where the previous line has no such sample (another waypoint
        count, or another sample count in the segment), its IK stayed above ``tolerance``, its bow
        exceeds :data:`NEWTON_STEP_MAX`, or a waypoint of the segment moved more than
        :data:`PREVIOUS_MOVE_MAX_RAD`: such a row takes :func:`newton_start` instead.
    """
    q_old, old = previous
    out = np.full((len(t), q.shape[1]), np.nan)
    if q_old.shape != q.shape or old.samples.shape != m.shape:
        return out
    moved = np.abs(q - q_old).max(axis=1) <= PREVIOUS_MOVE_MAX_RAD
    same = (old.samples == m) & moved[:-1] & moved[1:]
    if not same.any():
        return out
    first = np.concatenate([[0], np.cumsum(m - 1)[:-1]])
    first_old = np.concatenate([[0], np.cumsum(old.samples - 1)[:-1]])
    rows = np.flatnonzero(same[segment])
    at = first_old[segment[rows]] + rows - first[segment[rows]]
    s_old, t_old = old.segment[at], old.t[at]
    bow = old.q[at] - (q_old[s_old] + t_old[:, None] * (q_old[s_old + 1] - q_old[s_old]))
    good = (old.ik_error[at] <= tolerance) & (np.abs(bow).max(axis=1) <= NEWTON_STEP_MAX)
    out[rows[good]] = bow[good]
    return out
