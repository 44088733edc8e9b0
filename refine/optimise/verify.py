"""Numeric verification of a joint path with plain Pinocchio, independent of the CasADi model.

Every refined path is checked here before it is reported: TCP position against the CAD points,
orientation against the demonstration, joint-limit margins and the singularity measure, all per
waypoint, with the segments that break a tolerance listed with their reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from refine.frames import rotation_angle_deg
from refine.paths import FusedPath
from refine.robot.coupling import interaction_rows
from refine.robot.kinematics import TcpKinematics
from refine.settings import Tolerances
from refine.types import Array


@dataclass(frozen=True)
class Violation:
    """A run of consecutive waypoints breaking one tolerance.

    Attributes:
        index_start, index_end: first and last waypoint (inclusive).
        s_start_m, s_end_m: their arc lengths [m].
        reason: ``"position"``, ``"orientation"``, ``"joint limit (joint 3)"``, ``"singularity"``,
            ``"singularity between waypoints"`` (a run k..m means the segments after k..m).
        worst: the worst value inside, in the unit of ``unit``.
        unit: unit of ``worst`` and ``limit``.
        limit: the tolerance it breaks.
    """

    index_start: int
    index_end: int
    s_start_m: float
    s_end_m: float
    reason: str
    worst: float
    unit: str
    limit: float

    def describe(self) -> str:
        """One line for messages and reports."""
        return (
            f"{self.reason} at waypoints {self.index_start}-{self.index_end} "
            f"(s = {self.s_start_m:.3f}-{self.s_end_m:.3f} m): worst {self.worst:.4g} {self.unit}, "
            f"limit {self.limit:.4g} {self.unit}"
        )


@dataclass(frozen=True)
class PathCheck:
    """Per-waypoint figures of a joint path and the tolerances it breaks.

    Attributes:
        poses: T_F_TCP reached, shape (N, 4, 4).
        position_error_m: |TCP - CAD point| [m], shape (N,).
        orientation_deviation_deg: angle to the demonstrated orientation (tool axis only for an
            axisymmetric tool) [deg], shape (N,).
        joint_margin_rad: distance of each waypoint's closest joint to its limit (or to an interaction
            limit of the controller's joints) [rad], shape (N,).
        singularity: scaled manipulability sqrt(det(Js Jsᵀ)) [-], shape (N,).
        scaled_jacobians: the TCP Jacobians with their linear rows divided by the robot's reach
            (:func:`singularity_measures`) [-], shape (N, 6, n).
        singularity_between: smallest scaled manipulability inside each segment, joints
            interpolated linearly (:func:`segment_singularity`) [-], shape (N-1,).
        violations: the runs that break a tolerance (empty when the path passes).
        singularity_between_at: where in each segment that least measure is, as a fraction in
            (0, 1), shape (N-1,); None where not kept.
    """

    poses: Array
    position_error_m: Array
    orientation_deviation_deg: Array
    joint_margin_rad: Array
    singularity: Array
    scaled_jacobians: Array
    singularity_between: Array
    violations: tuple[Violation, ...]
    singularity_between_at: Array | None = None

    @property
    def ok(self) -> bool:
        """True when no tolerance is broken."""
        return not self.violations

    @cached_property
    def sigma_min(self) -> Array:
        """Smallest singular value of the scaled Jacobian [-], shape (N,).

        Computed when first asked for (:func:`smallest_singular_values`; no tolerance depends on
        it, and most checks of a solve's rounds are never reported).
        """
        return smallest_singular_values(self.scaled_jacobians)


def runs(mask: Array) -> list[tuple[int, int]]:
    """First and last index (inclusive) of every run of True in ``mask``."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]])
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


SVD_BELOW = 1e-2
"""A row whose smallest singular value is under this fraction of its largest (by the eigenvalues of
``Js Jsᵀ``) takes its singular values from an SVD of ``Js`` instead (:func:`singularity_measures`)."""


def singularity_measures(
    kin: TcpKinematics, q: Array, *, smallest: bool = True, jacobians: Array | None = None
) -> tuple[Array, Array]:
    """Scaled manipulability and smallest singular value of the scaled TCP Jacobian per row of ``q``.

    The Jacobian's linear rows are divided by the robot's reach so both halves are unitless.
    ``smallest=False`` skips the singular values (most of the cost) for callers that only need the
    manipulability; the second array is then NaN. ``jacobians``: the TCP Jacobians (N, 6, n) at
    ``q`` when the caller has them already (:func:`refine.robot.kinematics.solve_ik_batch`'s
    ``jacobians_out``), else None to compute them.

    For a square ``Js`` (6 joints) ``sqrt(det(Js Jsᵀ)) = |det Js|``, taken without the product
    (the compiled chain's determinant, :meth:`refine.robot.compiled_chain.CompiledChain.dets6`,
    where it is compiled).
    The smallest singular value is the root of the smallest eigenvalue of the symmetric 6 × 6
    ``Js Jsᵀ``, whose rounding error is a small multiple of ``eps·σ_max²``: relative to ``σ_min``
    that is ``eps·(σ_max / σ_min)² / 2`` times that multiple, under 1e-11 above
    :data:`SVD_BELOW`; below it the row's SVD gives it (to about ``eps·σ_max``).

    Returns:
        ``sqrt(det(Js Jsᵀ))`` (N,) and the smallest singular value of ``Js`` (N,) [-]
        (0 for a robot with fewer than 6 joints).
    """
    Js = scaled_jacobians(kin, q, jacobians)
    w = scaled_manipulability(Js, kin.robot.chain)
    if not smallest:
        return w, np.full(len(Js), np.nan)
    return w, smallest_singular_values(Js)


def scaled_jacobians(kin: TcpKinematics, q: Array, jacobians: Array | None = None) -> Array:
    """The TCP Jacobians at ``q`` (N, n) (or ``jacobians``), linear rows divided by the reach, (N, 6, n) [-]."""
    scale = np.array([1.0 / kin.robot.spec.reach_m] * 3 + [1.0] * 3)[:, None]
    return scale * (kin.jacobians(q) if jacobians is None else jacobians)


def scaled_manipulability(Js: Array, chain: object = None) -> Array:
    """``sqrt(det(Js Jsᵀ))`` of scaled Jacobians ``Js`` (N, 6, n), shape (N,) [-] (see :func:`singularity_measures`).

    ``chain``: the robot's batch chain, whose compiled determinant
    (:meth:`refine.robot.compiled_chain.CompiledChain.dets6`) takes the square case where it is
    compiled; None (or a chain without one) for NumPy's.
    """
    if Js.shape[2] == 6:
        dets = None if chain is None or not hasattr(chain, "dets6") else chain.dets6(Js)
        return np.abs(np.linalg.det(Js) if dets is None else dets)
    return np.sqrt(np.clip(np.linalg.det(Js @ np.swapaxes(Js, 1, 2)), 0.0, None))


def smallest_singular_values(Js: Array) -> Array:
    """The smallest singular value of each scaled Jacobian ``Js`` (N, 6, n), shape (N,) [-].

    0 for fewer than 6 joints; else as :func:`singularity_measures` describes (eigenvalues of
    ``Js Jsᵀ``, an SVD below :data:`SVD_BELOW`).
    """
    if Js.shape[2] < 6:
        return np.zeros(len(Js))
    eig = np.linalg.eigvalsh(Js @ np.swapaxes(Js, 1, 2))  # ascending: σ_min², ..., σ_max²
    smin = np.sqrt(np.clip(eig[:, 0], 0.0, None))
    close = eig[:, 0] < SVD_BELOW**2 * eig[:, -1]
    if close.any():
        smin[close] = np.linalg.svd(Js[close], compute_uv=False)[:, -1]
    return smin


ORTHONORMAL = 1e-12
"""A rotation matrix whose ``RᵀR`` is within this of the identity (every entry) counts as
orthonormal for :func:`rotation_angles_deg`'s closed form."""


def rotation_angles_deg(R_a: Array, R_b: Array) -> Array:
    """Geodesic angle between rotations ``R_a`` and ``R_b`` (N, 3, 3) [deg], shape (N,).

    The angle θ of ``R_aᵀ R_b`` from ``|R_a - R_b|_F = 2√2 sin(θ/2)`` and
    ``1 + tr(R_aᵀ R_b) = 4 cos²(θ/2)``: ``θ = 2 atan2(sin, cos)``, exact to rounding (about
    1e-14 deg) where θ < 90 deg and both matrices are orthonormal (:data:`ORTHONORMAL`: the
    formulas then differ from those of the nearest rotations by about 1e-12 rad), as
    :func:`refine.frames.rotation_angle_deg` is. The other rows (at 90 deg or more, where the
    cosine's square root loses digits, or off orthonormal, as rounded input may be) are given by
    that function.
    """
    sin = np.sqrt(np.einsum("kij,kij->k", d := R_a - R_b, d)) / (2.0 * math.sqrt(2.0))
    cos = np.sqrt(np.clip(1.0 + np.einsum("kij,kij->k", R_a, R_b), 0.0, None)) / 2.0
    angle = np.degrees(2.0 * np.arctan2(sin, cos))
    off = [orthonormal_error(R) > ORTHONORMAL for R in (R_a, R_b)]
    wide = (sin >= cos) | off[0] | off[1]
    if wide.any():
        angle[wide] = rotation_angle_deg(R_a[wide], R_b[wide])
    return angle


def orthonormal_error(R: Array) -> Array:
    """The largest entry of ``|RᵀR - I|`` of each matrix ``R`` (N, 3, 3), shape (N,) [-].

    ``RᵀR`` of every matrix in one contraction, the matrices on the last axis (contiguous).
    """
    columns = np.ascontiguousarray(np.moveaxis(R, 0, -1))  # (3, 3, N): entry [l, i] of matrix k in [l, i, k]
    gram = np.einsum("lik,ljk->ijk", columns, columns)
    gram[[0, 1, 2], [0, 1, 2]] -= 1.0
    return np.abs(gram).max(axis=(0, 1))


def segment_singularity(
    kin: TcpKinematics, q: Array, max_step_deg: float = 1.0, midpoint_jacobians: Array | None = None
) -> tuple[Array, Array]:
    """Smallest scaled manipulability inside each segment between consecutive waypoints [-].

    Joints are interpolated linearly inside each segment with steps of at most ``max_step_deg`` on
    every joint (at least the midpoint), which is how a wrist flip between two waypoints that are
    each clear of the singularity shows up. ``midpoint_jacobians``: the TCP Jacobians (N-1, 6, n)
    at the segments' midpoints ``q[k] + (q[k+1] - q[k]) / 2`` when the caller has them (used when
    the midpoint is every segment's only sample), else None.

    Returns:
        the smallest measure per segment (N-1,) and the fraction of the segment in (0, 1) where it
        occurs (N-1,); entry k covers the open segment between waypoints k and k+1.
    """
    dq = np.diff(q, axis=0)
    if len(dq) == 0:
        return np.zeros(0), np.zeros(0)
    n_sub = np.maximum(2, np.ceil(np.degrees(np.abs(dq).max(axis=1)) / max_step_deg)).astype(int)
    seg = np.repeat(np.arange(len(dq)), n_sub - 1)
    start = np.concatenate([[0], np.cumsum(n_sub - 1)[:-1]])  # each segment's first sample
    frac = (np.arange(len(seg)) - start[seg] + 1) / n_sub[seg]  # 1/m, ..., (m-1)/m per segment
    given = midpoint_jacobians if midpoint_jacobians is not None and np.all(n_sub == 2) else None
    w, _ = singularity_measures(kin, q[seg] + frac[:, None] * dq[seg], smallest=False, jacobians=given)
    # per segment its least measure (NaN only where all are), then the first sample that has it
    least = np.fmin.reduceat(w, start)
    at = (w == least[seg]) | np.isnan(least)[seg]
    first = np.minimum.reduceat(np.where(at, np.arange(len(w)), len(w)), start)
    return least, frac[first]


def check_path(
    kin: TcpKinematics,
    q: Array,
    fused: FusedPath,
    tolerances: Tolerances,
    axisymmetric: bool,
    slack_deg: Array | None = None,
) -> PathCheck:
    """Check joints ``q`` (N, n) [rad] against ``fused`` and ``tolerances`` with Pinocchio.

    ``slack_deg`` (N,) widens the orientation cone per waypoint (a repaired path) [deg].
    """
    poses, jacobians = kin.poses_jacobians(q)
    pos_err = np.linalg.norm(poses[:, :3, 3] - fused.positions, axis=1)
    if axisymmetric:
        cosines = np.einsum("ij,ij->i", poses[:, :3, 2], fused.rotations[:, :, 2])
        ori = np.degrees(np.arccos(np.clip(cosines, -1.0, 1.0)))
    else:
        ori = rotation_angles_deg(np.asarray(fused.rotations, dtype=float), poses[:, :3, :3])
    spec = kin.robot.spec
    margins = np.minimum(q - spec.lower, spec.upper - q)
    A, lower, upper = interaction_rows(spec.joint_coupling, spec.joint_interaction, q.shape[1])
    inter = np.minimum(q @ A.T - lower, upper - q @ A.T)  # (N, m): the controller's interaction limits
    joint_margin = np.minimum(margins.min(axis=1), inter.min(axis=1, initial=np.inf))
    Js = scaled_jacobians(kin, q, jacobians)
    sing = scaled_manipulability(Js, kin.robot.chain)  # the smallest singular values when asked for (PathCheck.sigma_min)

    s = fused.s
    violations: list[Violation] = []

    def add(mask: Array, reason: str, values: Array, unit: str, limit: float, worst_is_max: bool) -> None:
        for a, b in runs(mask):
            seg = values[a : b + 1]
            worst = float(seg.max() if worst_is_max else seg.min())
            violations.append(Violation(a, b, float(s[a]), float(s[b]), reason, worst, unit, limit))

    add(pos_err > tolerances.position_m, "position", pos_err, "m", tolerances.position_m, True)
    ori_limit = tolerances.orientation_deg + (0.0 if slack_deg is None else np.asarray(slack_deg))
    add(ori - ori_limit > 1e-6, "orientation", ori, "deg", float(np.max(ori_limit)), True)
    margin = math.radians(tolerances.joint_margin_deg) - 1e-7
    # runs only of the joints with a waypoint (or a step) past the limit, in joint order
    close = margins < margin
    for j in np.flatnonzero(close.any(axis=0)).tolist():
        add(close[:, j], f"joint limit (joint {j + 1})", margins[:, j], "rad", margin, False)
    for i, it in enumerate(spec.joint_interaction):
        add(inter[:, i] < margin, f"joint limit ({it.label})", inter[:, i], "rad", margin, False)
    steps = np.abs(np.diff(q, axis=0))
    step_limit = math.radians(tolerances.joint_step_deg) + 1e-9
    over = steps > step_limit
    for j in np.flatnonzero(over.any(axis=0)).tolist():
        add(
            np.append(over[:, j], False),
            f"joint step (joint {j + 1})",
            np.degrees(np.append(steps[:, j], 0.0)),
            "deg",
            tolerances.joint_step_deg,
            True,
        )
    sing_tol = tolerances.singularity_margin - 1e-9
    add(sing < sing_tol, "singularity", sing, "-", tolerances.singularity_margin, False)
    between, between_at = segment_singularity(kin, q)
    add(
        np.append(between < sing_tol, False),
        "singularity between waypoints",
        np.append(between, np.inf),
        "-",
        tolerances.singularity_margin,
        False,
    )
    return PathCheck(poses, pos_err, ori, joint_margin, sing, Js, between, tuple(violations), between_at)
