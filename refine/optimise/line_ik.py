"""The controller line's IK at its samples (:mod:`refine.optimise.controller_line`).

* :func:`line_poses`: the line's poses at the samples (chord and slerp, or the joint-linear wrist);
* :func:`solve_line`: the IK at every sample, from the starts of :mod:`refine.optimise.line_start`,
  and what the check needs of it: the residuals, the manipulability (:func:`line_manipulability`)
  and the joint-linear motion's distance from the line, per segment.

The passes over the samples: the waypoints' poses and Jacobians (for the targets and the start's
interpolated damped inverses), the joint-linear poses (the start's pose errors and the figures), and
the IK's passes, whose first is at the start and the last at the answer (its Jacobians give the
manipulability). A start within the IK's tolerance leaves the IK that one pass; on a re-solve the
previous line's corrections of its starts (:func:`refine.optimise.line_start.previous_corrections`)
bring most samples there.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from refine.optimise.line_start import linear_starts, previous_bows, previous_corrections
from refine.optimise.slerp import log_rotations, slerp_factors, slerp_rotations
from refine.robot.kinematics import TcpKinematics, solve_ik_batch
from refine.types import Array


def line_poses(poses: Array, q: Array, segment: Array, t: Array, kin: TcpKinematics, wrist: Array) -> Array:
    """Poses (M, 4, 4) of the controller's line at ``t`` inside ``segment`` (see the module notes).

    Args:
        poses: T_F_TCP of the targets, (N, 4, 4).
        q: joints at the targets [rad], (N, n) (for the wrist model).
        segment: segment of each sample, (M,).
        t: parameter in [0, 1] of each sample, (M,).
        kin: TCP kinematics (for the wrist model).
        wrist: per segment, True where the orientation follows the joint-linear wrist, (N-1,).
    """
    p = poses[:, :3, 3]
    out = np.empty((len(t), 4, 4))
    out[:, 3, :3] = 0.0
    out[:, 3, 3] = 1.0
    a = np.take(p, segment, axis=0)
    out[:, :3, 3] = a + t[:, None] * (np.take(np.diff(p, axis=0), segment, axis=0))
    R = poses[:, :3, :3]
    steps = log_rotations(np.swapaxes(R[:-1], 1, 2) @ R[1:])  # per segment, then per sample
    out[:, :3, :3] = slerp_rotations(R[:-1], steps, segment, t)
    on_wrist = wrist[segment]
    if on_wrist.any():
        q_lin = joint_linear(q, segment, t)
        out[on_wrist, :3, :3] = kin.poses(q_lin[on_wrist])[:, :3, :3]
    return out


def segment_lines(poses: Array, wrist: Array) -> Array:
    """Per segment what :func:`line_poses` needs of it, (N-1, 36), for the compiled chain.

    The chord's start and step [m] (3 each), ``R``, ``R K`` and ``R K²`` row-major (9 each) with
    ``K`` the skew matrix of the segment's rotation vector (:func:`refine.optimise.slerp.slerp_factors`),
    its angle [rad], 1.0 where the orientation follows the joint-linear wrist, and a 0 pad.

    Args:
        poses: T_F_TCP of the targets, (N, 4, 4).
        wrist: per segment, True where the orientation follows the joint-linear wrist, (N-1,).
    """
    p, R = poses[:, :3, 3], poses[:, :3, :3]
    RK, RK2, theta = slerp_factors(R[:-1], log_rotations(np.swapaxes(R[:-1], 1, 2) @ R[1:]))
    out = np.zeros((len(poses) - 1, 36))
    out[:, :3], out[:, 3:6] = p[:-1], np.diff(p, axis=0)
    out[:, 6:15], out[:, 15:24], out[:, 24:33] = R[:-1].reshape(-1, 9), RK.reshape(-1, 9), RK2.reshape(-1, 9)
    out[:, 33], out[:, 34] = theta, wrist
    return out


def joint_linear(q: Array, segment: Array, t: Array) -> Array:
    """The joint-linear joints ``q_k + t (q_k+1 - q_k)`` [rad] (M, n) at ``t`` (M,) inside ``segment`` (M,)."""
    out = np.take(np.diff(q, axis=0), segment, axis=0)
    out *= t[:, None]
    out += np.take(q, segment, axis=0)
    return out


def segment_starts(segment: Array) -> Array:
    """Each segment's first sample, (N-1,).

    For samples that lie segment after segment, none empty, as
    :func:`refine.optimise.controller_line.sample_parameters` puts them.
    """
    return np.flatnonzero(np.concatenate([[True], segment[1:] != segment[:-1]]))


def line_manipulability(kin: TcpKinematics, jacobians: Array) -> Array:
    """The scaled manipulability ``sqrt(det(Js Jsᵀ))`` [-] of TCP Jacobians (M, 6, n), (M,).

    The measure :func:`refine.optimise.verify.singularity_measures` defines: ``Js`` is ``J`` with its linear rows divided by the robot's reach. For a six-axis arm ``Js`` is
    square and the measure is ``|det Js| = |det J| / reach³``, without forming ``Js Jsᵀ`` (whose
    determinant loses twice the digits near a singularity). The determinants are the compiled
    chain's (:meth:`refine.robot.compiled_chain.CompiledChain.dets6`) where it is compiled.
    """
    reach = kin.robot.spec.reach_m
    if jacobians.shape[2] == 6:
        chain = kin.robot.chain
        dets = None if chain is None else chain.dets6(jacobians)  # compiled, else NumPy's
        return np.abs(np.linalg.det(jacobians) if dets is None else dets) / reach**3
    Js = np.concatenate([jacobians[:, :3] / reach, jacobians[:, 3:]], axis=1)
    return np.sqrt(np.clip(np.linalg.det(Js @ np.swapaxes(Js, 1, 2)), 0.0, None))


def solve_line(
    kin: TcpKinematics,
    q: Array,
    m: Array,
    segment: Array,
    t: Array,
    wrist: Array,
    tolerance: float,
    previous: tuple[Array, Any] | None = None,
    q_lin: Array | None = None,
) -> tuple[Array, Array, Array, Array, Array, Array]:
    """The line's IK at the samples and what depends on it and on ``q`` alone.

    Args:
        kin: TCP kinematics.
        q: joints per waypoint [rad], (N, n).
        m: sub-steps per segment, (N-1,).
        segment: each sample's segment, (M,).
        t: each sample's parameter in its segment, (M,).
        wrist: per segment, True where the orientation follows the joint-linear wrist, (N-1,).
        tolerance: the pose error [m and rad stacked] the IK must reach.
        previous: a previous answer's joints (N, n) [rad] and its line check (a ``LineCheck``):
            where its waypoints barely moved, its bows start the IK
            (:func:`refine.optimise.line_start.previous_bows`); elsewhere the start is
            :func:`refine.optimise.line_start.newton_start` plus its corrections
            (:func:`refine.optimise.line_start.previous_corrections`). None for the Newton start.
        q_lin: the joint-linear joints at the samples [rad] (M, n) (:func:`joint_linear` of ``q``,
            ``segment`` and ``t``) when the caller has them, else None.

    Returns:
        the line's joints (M, n) [rad], the IK residual per sample (M,), the IK's change of the
        Newton start per sample (M, n) [rad] (NaN where the IK started from a bow), and per segment
        the least scaled manipulability [-], the largest distance of the joint-linear TCP from the
        chord [m] and the largest angle between its orientation and the line's [deg], each (N-1,).
    """
    spec = kin.robot.spec
    q_lin = joint_linear(q, segment, t) if q_lin is None else q_lin
    poses, J_wp = kin.poses_jacobians(q)
    bows = None if previous is None else previous_bows(q, m, segment, t, previous, tolerance)
    cold = np.ones(len(t), dtype=bool) if bows is None else np.isnan(bows[:, 0])
    any_cold = bool(cold.any())  # else every sample starts from its bow: no Newton start is formed
    targets = np.empty((len(t), 4, 4))
    chain = kin.robot.chain
    starts = None  # the compiled pass, where the chain is compiled; else NumPy's targets and starts
    if getattr(chain, "compiled", False):
        starts = linear_starts(kin, J_wp, segment, t, q_lin, targets, segment_lines(poses, wrist), any_cold)
    if starts is None:  # not compiled: NumPy's targets and starts
        targets = line_poses(poses, q, segment, t, kin, wrist)
        starts = linear_starts(kin, J_wp, segment, t, q_lin, targets, newton=any_cold)
    lin_poses, errors, start = starts
    if not cold.all():
        start[~cold] = q_lin[~cold] + bows[~cold]
    newton = start.copy()
    if previous is not None:
        corrections = previous_corrections(q, m, segment, t, previous, tolerance)
        if cold.all():
            start += corrections
        else:
            start[cold] += corrections[cold]
    J_line = np.empty((len(t), 6, q.shape[1]))
    q_line, err = solve_ik_batch(
        kin,
        targets,
        start,
        spec.lower,
        spec.upper,
        tol=tolerance,
        max_iterations=60,
        nullspace_gain=0.0,
        jacobians_out=J_line,
    )
    correction = q_line - newton
    correction[~cold] = np.nan
    sing = line_manipulability(kin, J_line)
    p = poses[:, :3, 3]
    chords = np.diff(p, axis=0)  # per segment
    lengths2 = np.maximum(np.einsum("ij,ij->i", chords, chords), 1e-300)
    chord = np.take(chords, segment, axis=0)
    from_a = lin_poses[:, :3, 3] - np.take(p, segment, axis=0)
    along = np.clip(np.einsum("ij,ij->i", from_a, chord) / np.take(lengths2, segment), 0.0, 1.0)
    from_a -= along[:, None] * chord  # the joint-linear TCP less its nearest point of the chord
    off_line = np.sqrt(np.einsum("ij,ij->i", from_a, from_a))
    angle = np.degrees(np.sqrt(np.einsum("ij,ij->i", errors[:, 3:], errors[:, 3:])))  # of R_target R_linᵀ
    first = segment_starts(segment)
    return (
        q_line,
        err,
        correction,
        np.minimum.reduceat(sing, first),
        np.maximum.reduceat(off_line, first),
        np.maximum.reduceat(angle, first),
    )
