"""Where the controller line's IK starts at each sample (:mod:`refine.optimise.controller_line`).

Starts close to the line's joints so that the IK (to ``IK_TOLERANCE``) needs few passes and
stays on the refined joints' branch:

* :func:`newton_start`: the joint-linear joints moved by one damped Newton step;
* :func:`previous_bows`: on a re-solve, the previous answer's line: its bow ``q_line - q_lin`` at
  the same sample, added to the new joint-linear joints. A small move of the waypoints leaves the
  bow the same to first order, so this start is within the IK's tolerance of the new line at most
  samples, and saves the Newton step's pass too;
* :func:`previous_corrections`: on a re-solve whose waypoints moved more, the Newton start plus
  what the previous line's IK changed its own Newton start by at the same sample.
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
:func:`newton_start`'s 8e-12, and a move of 1.6e-8 rad left it within 1e-9 at every sample."""
CORRECTION_MAX_RAD = 1e-6
"""A previous line's correction of its Newton start larger than this on any joint [rad] is not
carried to a re-solve's start (:func:`previous_corrections`): the corrections of converged samples
are about 1e-8 rad; a larger one is a start far from the line (a Newton step not taken)."""


def newton_start(
    J_wp: Array,
    segment: Array,
    t: Array,
    q_lin: Array,
    lin_poses: Array,
    targets: Array,
    errors: Array | None = None,
) -> Array:
    """The IK's start on the line: the joint-linear joints ``q_lin`` moved by one damped Newton step.

    The step ``P e`` takes the damped inverse ``P = Jᵀ (J Jᵀ + λ² I)⁻¹`` (:data:`NEWTON_DAMPING`)
    of the TCP Jacobians at the two waypoints (``J_wp`` (N, 6, n)), interpolated linearly at the
    sample's ``t``, and the pose error ``e`` of the joint-linear pose to the line's. The line lies
    within the square of the step of the joint-linear motion, and the interpolated inverse is off
    the one at ``q_lin`` by the square of the step too, so that step leaves about the IK's
    tolerance and saves it one pass over every sample; it costs one small solve per waypoint, none
    per sample. A row whose step exceeds :data:`NEWTON_STEP_MAX` (near a singularity) starts from
    ``q_lin`` as it is, so every start stays on the refined joints' branch. ``errors``: those pose
    errors (M, 6) when the caller has them (:func:`pose_errors` of ``lin_poses`` to ``targets``),
    else None.
    """
    PP = start_matrices(J_wp)
    e = pose_errors(lin_poses, targets) if errors is None else errors
    dq = _per_segment_products(PP, segment, np.concatenate([e, t[:, None] * e], axis=1))
    dq[~(largest_per_row(np.abs(dq)) <= NEWTON_STEP_MAX)] = 0.0  # and a NaN step: from q_lin
    dq += q_lin
    return dq


def start_matrices(J_wp: Array, chain: Any = None) -> Array:
    """Per segment, ``[P_k, P_k+1 - P_k]`` (N-1, n, 12) of the waypoints' damped inverses (:func:`newton_start`).

    ``P = Jᵀ (J Jᵀ + λ² I)⁻¹`` (:data:`NEWTON_DAMPING`) of the TCP Jacobians ``J_wp`` (N, 6, n), so
    that a sample's step ``P_k e + t (P_k+1 - P_k) e`` is one product with ``[e, t e]`` (12,).
    ``chain``: the robot's chain, whose compiled library forms ``P`` (by a Cholesky factor of
    ``J Jᵀ + λ² I``, :meth:`refine.robot.compiled_chain.CompiledChain.damped_inverses`), or None.
    """
    P_wp = None if chain is None else chain.damped_inverses(J_wp, NEWTON_DAMPING)
    if P_wp is None:
        A = J_wp @ np.swapaxes(J_wp, 1, 2) + NEWTON_DAMPING**2 * np.eye(J_wp.shape[1])
        P_wp = np.swapaxes(np.linalg.solve(A, J_wp), 1, 2)  # (A⁻¹ J)ᵀ = Jᵀ A⁻¹, A symmetric: (N, n, 6)
    return np.concatenate([P_wp[:-1], np.diff(P_wp, axis=0)], axis=2)


def linear_starts(
    kin: Any,
    J_wp: Array,
    segment: Array,
    t: Array,
    q_lin: Array,
    targets: Array,
    lines: Array | None = None,
    newton: bool = True,
) -> tuple[Array, Array, Array] | None:
    """The joint-linear TCP poses (M, 4, 4), their :func:`pose_errors` (M, 6) and :func:`newton_start` (M, n).

    ``kin``: the TCP kinematics (a ``TcpKinematics``); the rest as :func:`newton_start`'s. Where
    the robot's chain is compiled, one pass of it gives all three per sample
    (:meth:`refine.robot.compiled_chain.CompiledChain.line_starts`); the rows whose rotation
    error comes within 1e-3 rad of π, where the compiled error leaves out
    :func:`relative_rotation_vectors`' branch, are taken again in NumPy. Else NumPy's passes.
    ``lines``: the segments' lines (:func:`refine.optimise.line_ik.segment_lines`) from which the
    compiled pass writes the targets into ``targets`` (M, 4, 4) first; then None where the chain
    is not compiled (the caller forms the targets and calls again without). ``newton`` False:
    no row takes the start (a re-solve's bows start them all), the starts returned are ``q_lin``.
    """
    chain = kin.robot.chain
    out = None
    if chain is not None and len(t) >= chain.min_rows:
        placements = (kin.base_in_world, kin.tcp_in_flange, kin.tool_in_world)
        P = (
            start_matrices(J_wp, chain)
            if newton
            else np.broadcast_to(0.0, (len(J_wp) - 1, J_wp.shape[2], 12))
        )
        out = chain.line_starts(q_lin, placements, targets, P, segment, t, NEWTON_STEP_MAX, lines, newton)
    if out is None and lines is not None:
        return None
    if out is None:
        lin_poses = kin.poses(q_lin)
        errors = pose_errors(lin_poses, targets)
        start = newton_start(J_wp, segment, t, q_lin, lin_poses, targets, errors) if newton else q_lin.copy()
        return lin_poses, errors, start
    lin_poses, errors, theta, start = out
    near_pi = np.flatnonzero(theta > np.pi - 1e-3)
    if len(near_pi):
        errors[near_pi] = pose_errors(lin_poses[near_pi], targets[near_pi])
    if len(near_pi) and newton:
        start[near_pi] = newton_start(
            J_wp,
            segment[near_pi],
            t[near_pi],
            q_lin[near_pi],
            lin_poses[near_pi],
            targets[near_pi],
            errors[near_pi],
        )
    return lin_poses, errors, start


def largest_per_row(a: Array) -> Array:
    """The largest entry of each row of ``a`` (M, n), (M,): ``a.max(axis=1)`` column by column.

    NaN where a row holds one, as ``max``.
    """
    out = a[:, 0].copy()
    for j in range(1, a.shape[1]):
        np.maximum(out, a[:, j], out=out)
    return out


def _per_segment_products(A: Array, segment: Array, x: Array) -> Array:
    """The products ``A[segment[i]] @ x[i]`` (M, r) of matrices ``A`` (K, r, c) and vectors ``x`` (M, c).

    Where the samples lie segment after segment (``segment`` non-decreasing) and no segment holds
    more than twice the mean, the vectors are laid out per segment, padded with zeros, and each
    segment's matrix multiplies its block at once; else each sample's matrix is gathered.
    """
    M, K = len(segment), len(A)
    counts = np.bincount(segment, minlength=K)
    width = int(counts.max()) if M else 0
    if M == 0 or width * K > 2 * M or np.any(segment[1:] < segment[:-1]):
        return np.einsum("mij,mj->mi", np.take(A, segment, axis=0), x)
    # each sample's row in the blocks (K, width) laid out flat: its segment's first plus its place in it
    flat = np.arange(M) + (segment * width - (np.cumsum(counts) - counts)[segment])
    blocks = np.zeros((K * width, x.shape[1]))
    blocks[flat] = x
    products = blocks.reshape(K, width, x.shape[1]) @ np.swapaxes(A, 1, 2)
    return np.take(products.reshape(K * width, A.shape[1]), flat, axis=0)


def pose_errors(poses: Array, targets: Array) -> Array:
    """Pose errors (M, 6) of ``poses`` to ``targets`` (M, 4, 4), as the IK's.

    The position difference [m] and the rotation vector of ``R_target Rᵀ`` [rad], both in the
    frame the poses are given in.
    """
    e = np.empty((len(poses), 6))
    e[:, :3] = targets[:, :3, 3] - poses[:, :3, 3]
    e[:, 3:] = relative_rotation_vectors(targets[:, :3, :3], poses[:, :3, :3])
    return e


def relative_rotation_vectors(Ra: Array, Rb: Array) -> Array:
    """Rotation vectors (M, 3) [rad] of ``Ra Rbᵀ`` for rotation matrices ``Ra``, ``Rb`` (M, 3, 3).

    :func:`refine.robot.kinematics.rotation_vectors` of the products, to rounding, without
    forming them: the trace of ``Ra Rbᵀ`` is the sum of the entries of ``Ra * Rb``, and its skew
    part's entry ``(i, j)`` is ``Σ_k Ra_ik Rb_jk - Ra_jk Rb_ik``. Near 180 degrees, where that
    function takes the axis from the whole matrix, the products are formed for those rows.
    """
    cos = np.clip((np.einsum("mij,mij->m", Ra, Rb) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    vee = np.empty((len(Ra), 3))
    for out, i, j in ((0, 2, 1), (1, 0, 2), (2, 1, 0)):
        vee[:, out] = np.einsum("mk,mk->m", Ra[:, i], Rb[:, j]) - np.einsum("mk,mk->m", Ra[:, j], Rb[:, i])
    vee *= 0.5
    small = theta < 1e-6
    scale = np.where(small, 1.0 + theta**2 / 6.0, theta / np.where(small, 1.0, np.sin(theta)))
    vee *= scale[:, None]
    near_pi = np.flatnonzero(theta > np.pi - 1e-3)
    if len(near_pi):
        vee[near_pi] = rotation_vectors(Ra[near_pi] @ np.swapaxes(Rb[near_pi], 1, 2))
    return vee


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
    moved = largest_per_row(np.abs(q - q_old)) <= PREVIOUS_MOVE_MAX_RAD
    still = moved[:-1] & moved[1:]
    if not still.any():  # no segment whose waypoints both stayed: no sample takes a bow
        return out
    rows, at = _same_samples(m, segment, old, still)
    s_old, t_old = old.segment[at], old.t[at]
    bow = old.q[at] - (q_old[s_old] + t_old[:, None] * (q_old[s_old + 1] - q_old[s_old]))
    good = (old.ik_error[at] <= tolerance) & (np.abs(bow).max(axis=1) <= NEWTON_STEP_MAX)
    out[rows[good]] = bow[good]
    return out


def previous_corrections(
    q: Array, m: Array, segment: Array, t: Array, previous: tuple[Array, Any], tolerance: float
) -> Array:
    """Per sample, what a previous answer's line IK changed its Newton start by at the same ``t``, (M, n).

    The Newton start (:func:`newton_start`) misses the line by the square of its step (the pose's
    curvature along the step, the interpolated inverse's error) and the IK's next pass takes that
    up: about 1e-8 rad where the bow is largest, above the IK's tolerance at a sixth of the glass
    cell's samples. That correction is a smooth function of the waypoints, so a re-solve's moved
    waypoints leave it the same to first order in the move: added to the new Newton start, it
    brings the start within the tolerance (the glass cell's 2 mm part shift, waypoints moved up to
    8e-3 rad: at all but 2 of 4,319 samples, against 698 without it). The IK still converges from
    that start to the same tolerance; the correction only saves it a pass.

    Args:
        q: the new joints per waypoint [rad], (N, n).
        m: the new sub-steps per segment, (N-1,).
        segment: each sample's segment, (M,).
        t: each sample's parameter in its segment, (M,).
        previous: the previous answer's joints (N', n) [rad] and its line check (a
            ``LineCheck``: its ``samples``, ``ik_error`` and ``start_correction``).
        tolerance: the IK residual [m and rad stacked] a previous sample must have reached.

    Returns:
        The corrections [rad], a row 0 where the previous line has no such sample (another
        waypoint count, another sample count in the segment, no correction recorded), its IK
        stayed above ``tolerance``, or its correction exceeds :data:`CORRECTION_MAX_RAD`.
    """
    q_old, old = previous
    if old.start_correction is None or q_old.shape != q.shape or old.samples.shape != m.shape:
        return np.zeros((len(t), q.shape[1]))
    every = np.array_equal(old.samples, m)  # each sample's own at the same index (a re-solve's usual case)
    rows, at = (None, None) if every else _same_samples(m, segment, old, np.ones(len(m), dtype=bool))
    c = old.start_correction.copy() if every else np.take(old.start_correction, at, axis=0)
    with np.errstate(invalid="ignore"):
        err = old.ik_error if every else np.take(old.ik_error, at)
        good = (err <= tolerance) & (largest_per_row(np.abs(c)) <= CORRECTION_MAX_RAD)
    c[~good] = 0.0
    if every or len(rows) == len(t):  # every sample has one (rows are in order, without repeats)
        return c
    out = np.zeros((len(t), q.shape[1]))
    out[rows] = c
    return out


def _same_samples(m: Array, segment: Array, old: Any, wanted: Array) -> tuple[Array, Array]:
    """The samples (K,) of the segments ``wanted`` (N-1,) whose sub-steps equal the previous line's.

    Returns them with each one's index in the previous line's samples (K,).
    """
    same = (old.samples == m) & wanted
    first = np.concatenate([[0], np.cumsum(m - 1)[:-1]])
    first_old = np.concatenate([[0], np.cumsum(old.samples - 1)[:-1]])
    rows = np.flatnonzero(same[segment])
    return rows, first_old[segment[rows]] + rows - first[segment[rows]]
