"""Receiver registration from a trace along the CAD path (:func:`register_receiver_to_path`).

A short demonstration with the tip on the path gives ``source_in_world``. A contour cannot tell its
own symmetries apart from distances alone, so the registration is a global search: hypotheses from
the first guess and from the trace laid on the path by their principal axes (upright and turned
over, in :data:`PATH_TURNS` turns), each fitted by ICP (scipy ``cKDTree``) and refined with the
tracker's z error; the fits within the noise are ranked by the tool's attitude (it points down at
the part), the direction of travel, and the residual. Two frames that no cue tells apart, a path
that leaves the frame free to turn or shift, or an answer far from the first guess are refused,
naming the candidates and their figures.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from scipy.stats import spearmanr

from refine.calibrate import zfield
from refine.calibrate.receiver import check_tracker_range, pack_frame, unpack_frame
from refine.calibrate.result import Calibration
from refine.calibrate.rigid import kabsch
from refine.demo.filters import hampel
from refine.errors import InputError
from refine.frames import check_transform, make_transform, rotation_angle_deg
from refine.paths import TrackerLog
from refine.types import Array

logger = logging.getLogger(__name__)

#: Turns about the trace's normal tried by the global search of the path registration.
PATH_TURNS = 12


#: Two fitted frames closer than this are one candidate [m] and [deg].
SAME_FRAME_M = 0.005


SAME_FRAME_DEG = 0.5


#: A cue (share of samples with the tool pointing down, rank correlation of travel) ties two
#: candidates when they differ by less than this.
CUE_TIE = 0.1


#: Least ratio of the weakest to the best determined direction of the path fit (rotations scaled
#: by the path's RMS radius); below it the distances leave a turn or a shift free.
MIN_DETERMINATION = 0.003


#: Starts of the z error coefficients (c2 [1/m], c3 [1/m^2]) of the path registration: none, and
#: errors of either sign that level off at 1.3 m.
Z_STARTS = ((0.0, 0.0), (0.1, -0.05), (-0.1, 0.05))


@dataclass(frozen=True)
class PathCandidate:
    """One fitted hypothesis of the path registration.

    Attributes:
        source_in_world: the fitted T_F_S (4, 4).
        coeffs: the fitted z error coefficients (2,).
        distances_m: distance of every used tip position from the path [m], shape (K,).
        rms_m: RMS of the distances within the outlier threshold [m] (inf when none are).
        outlier_share: share of the tip positions beyond the outlier threshold.
        tool_down: share of the samples where the tip lies below the sensor in {F} (the tool
            points down at the part); NaN when the tip offset is too short to tell.
        travel: Spearman rank correlation of the matched path arc length with time (1: the
            trace runs along the path from its start in its direction).
        iterations: ICP iterations of the final refinement.
    """

    source_in_world: Array
    coeffs: Array
    distances_m: Array
    rms_m: float
    outlier_share: float
    tool_down: float
    travel: float
    iterations: int

    def describe(self) -> str:
        """One line for messages: the frame, its residual and its cues."""
        from refine.calibrate.files import pose_line

        down = "unknown" if np.isnan(self.tool_down) else f"{self.tool_down * 100:.0f} %"
        return (
            f"{pose_line('source_in_world', self.source_in_world)} (RMS {self.rms_m * 1000:.2f} mm, "
            f"tool pointing down in {down} of the samples, travel rank correlation {self.travel:.2f})"
        )


def frame_difference(T_a: ArrayLike, T_b: ArrayLike) -> tuple[float, float]:
    """Distance between the origins [m] and angle between the orientations [deg] of two frames."""
    a, b = np.asarray(T_a, dtype=float), np.asarray(T_b, dtype=float)
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])), float(rotation_angle_deg(a[:3, :3], b[:3, :3]))


def _same_frame(T_a: Array, T_b: Array) -> bool:
    offset_m, angle_deg = frame_difference(T_a, T_b)
    return offset_m <= SAME_FRAME_M and angle_deg <= SAME_FRAME_DEG


def _principal_axes(points: Array) -> tuple[Array, Array]:
    """Centroid (3,) and principal axes (columns, largest spread first, right-handed) of points."""
    centre = points.mean(axis=0)
    _, vectors = np.linalg.eigh(np.cov((points - centre).T))
    axes = vectors[:, ::-1].copy()
    if np.linalg.det(axes) < 0.0:
        axes[:, 2] *= -1.0
    return centre, axes


def _even_in_length(points: Array, step_m: float) -> Array:
    """The points of a track kept every ``step_m`` of its length (a rest counts once)."""
    length = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    idx = np.unique(
        np.searchsorted(length, np.arange(0.0, length[-1] + step_m, step_m)).clip(0, len(points) - 1)
    )
    return points[idx]


def path_hypotheses(tips_source: ArrayLike, path_world: ArrayLike, step_m: float = 0.002) -> list[Array]:
    """First guesses of T_F_S that the shapes of a trace and a path allow, in a fixed order.

    The trace (tip positions in {S}) and the path (in {F}), both taken evenly in length, are put
    onto each other by their centroids and principal axes: the two right-handed sign choices of the
    axes (upright and turned over about the main axis), each turned by :data:`PATH_TURNS` equal
    steps about the normal axis (which covers the sign flips within the plane and the turns a
    round or square contour allows).

    Args:
        tips_source: tip positions of the trace in {S} [m], shape (K, 3).
        path_world: the path in {F} [m], shape (P, 3).
        step_m: spacing of the even resampling [m].

    Returns:
        ``2 * PATH_TURNS`` transforms (4, 4).
    """
    c_s, axes_s = _principal_axes(_even_in_length(np.asarray(tips_source, dtype=float), step_m))
    c_f, axes_f = _principal_axes(_even_in_length(np.asarray(path_world, dtype=float), step_m))
    hypotheses = []
    for flip in (np.diag([1.0, 1.0, 1.0]), np.diag([1.0, -1.0, -1.0])):
        for k in range(PATH_TURNS):
            turn = Rotation.from_rotvec(axes_s[:, 2] * (2.0 * np.pi * k / PATH_TURNS)).as_matrix()
            R = axes_f @ flip @ axes_s.T @ turn
            hypotheses.append(make_transform(R, c_f - R @ c_s))
    return hypotheses


def _coarse_icp(tips: Array, tree: cKDTree, dense: Array, T: Array, iterations: int = 40) -> Array:
    """Point-to-point ICP (nearest path point, Kabsch) from T; the rigid transform (4, 4)."""
    for _ in range(iterations):
        moved = tips @ T[:3, :3].T + T[:3, 3]
        _, nearest = tree.query(moved)
        T_new = kabsch(tips, dense[nearest])
        step_m, step_deg = frame_difference(T, T_new)
        T = T_new
        if step_m + np.radians(step_deg) < 1e-5:
            break
    return T


def _ties(best: PathCandidate, other: PathCandidate, n: int) -> bool:
    """Whether ``other`` fits the distances as well as ``best`` within the noise of ``n`` samples."""
    return other.rms_m <= best.rms_m * (1.0 + 2.0 / np.sqrt(max(n, 1))) + 1e-4


def register_receiver_to_path(
    log: TrackerLog,
    tip_in_sensor: ArrayLike,
    path_world: ArrayLike,
    initial_source_in_world: ArrayLike,
    fit_z: bool = True,
    spacing_m: float = 0.0005,
    max_iterations: int = 60,
    threshold_m: float = 0.01,
    stride: int = 8,
    max_rms_m: float = 0.004,
    max_guess_offset_m: float = 0.2,
    max_guess_turn_deg: float = 30.0,
) -> Calibration:
    """Solve ``source_in_world`` from a demonstration traced with the tip along the CAD path.

    A global search, not one local fit: the trace's tip positions (every ``stride``-th sample,
    spikes removed) are put onto the path resampled every ``spacing_m`` from every hypothesis of
    :func:`path_hypotheses` and from the first guess, each refined by point-to-point ICP; every
    distinct result is then refined by ICP with the z error: each iteration matches every tip
    position to its nearest path point and refits the transform and the z error with a robust
    (soft-L1) least squares on the distances across the path (point to line: the trace slides
    along the path), until the transform moves less than a hundredth of a millimetre.

    The candidates that fit (at most half of the samples farther than ``threshold_m`` from the path,
    the rest at most ``max_rms_m`` RMS) are ranked with every cue the inputs hold, in this order:
    the tool's attitude (the share of samples where the tip lies below the sensor: the tool points
    down at the part), the direction of travel (the rank correlation of the matched arc length with
    time: the trace follows the path from its start in its direction), then the distances. A cue
    decides only by more than :data:`CUE_TIE`; candidates that tie on every cue and fit the
    distances within the noise are a refusal, not a guess.

    Args:
        log: the tracker log of the trace.
        tip_in_sensor: tip offset in {E} [m], shape (3,).
        path_world: the CAD path in {F} [m], shape (P, 3), ordered.
        initial_source_in_world: the expected T_F_S (4, 4) (the problem's); one hypothesis among
            the others, and the registration found must lie near it.
        fit_z: also estimate the tracker's z error.
        spacing_m: resampling step of the path [m].
        max_iterations: ICP iterations at most.
        threshold_m: distance from the path beyond which a sample is an outlier [m].
        stride: use every ``stride``-th sample.
        max_rms_m: largest RMS distance of the kept samples from the path that counts as a fit [m].
        max_guess_offset_m: farthest the registration may lie from the first guess [m]
            (``inf``: any).
        max_guess_turn_deg: largest turn between the registration and the first guess [deg].

    Returns:
        ``source_in_world``, a residual per sample; figures: the search (hypotheses, candidates
        that fit), the winner's cues, the runner-up's residual and angle, the z error.

    Raises:
        InputError: a log beyond the tracker's range; no candidate that fits (the log does not
            trace this path); two candidates that no cue tells apart (naming both with their
            residuals and the angle between them); a registration farther from the first guess
            than allowed (naming it).
    """
    check_tracker_range(log)
    tip = np.asarray(tip_in_sensor, dtype=float)
    _, spikes = hampel(log.positions + log.rotations @ tip, 7, 4.0, min_deviation=0.003)
    keep = ~spikes.any(axis=1)
    keep[np.arange(len(keep)) % stride != 0] = False
    p, R = log.positions[keep], log.rotations[keep]
    path = np.asarray(path_world, dtype=float)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    s_dense = np.arange(0.0, s[-1], spacing_m)
    dense = np.column_stack([np.interp(s_dense, s, path[:, j]) for j in range(3)])
    tangents = np.gradient(dense, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    tree = cKDTree(dense)
    tip_vectors = R @ tip  # sensor to tip in {S}
    attitude_known = float(np.linalg.norm(tip)) >= 0.01

    def off_path(tips: Array, target: Array, tangent: Array) -> Array:
        r = tips - target
        return r - np.sum(r * tangent, axis=1, keepdims=True) * tangent

    def tips_world(x: Array) -> Array:
        T, coeffs = unpack_frame(x)
        true_sensor = zfield.correct(p, coeffs if fit_z else np.zeros(zfield.N_COEFFS))
        tips = true_sensor + tip_vectors
        return tips @ T[:3, :3].T + T[:3, 3]

    def icp(x: Array, free: int) -> tuple[Array, int]:
        """ICP on the first ``free`` parameters of x (the others held); x and the iterations."""
        iterations = 0
        for iterations in range(1, max_iterations + 1):  # noqa: B007 - the count is reported
            _, nearest = tree.query(tips_world(x))
            target, tangent = dense[nearest], tangents[nearest]
            held = x[free:]
            sol = least_squares(
                lambda y, target=target, tangent=tangent, held=held: off_path(
                    tips_world(np.concatenate([y, held])), target, tangent
                ).ravel(),
                x[:free],
                loss="soft_l1",
                f_scale=0.002,
                x_scale="jac",
                max_nfev=20,
            )
            x_new = np.concatenate([sol.x, held])
            moved_m, turned_deg = frame_difference(unpack_frame(x)[0], unpack_frame(x_new)[0])
            bent_m = float(
                np.abs(
                    zfield.z_error(p, unpack_frame(x_new)[1]) - zfield.z_error(p, unpack_frame(x)[1])
                ).max()
            )
            cost_before, cost_after = float(np.sum(robust_cost(x))), float(np.sum(robust_cost(x_new)))
            x = x_new
            # a round contour leaves a turn free: the transform slides while the fit stays the same
            if (
                moved_m + np.radians(turned_deg) + bent_m < 1e-5
                or abs(cost_before - cost_after) <= 1e-4 * cost_before
            ):
                break
        return x, iterations

    def robust_cost(x: Array) -> Array:
        dist, _ = tree.query(tips_world(x))
        return np.minimum(dist, threshold_m) ** 2

    def refine(T0: Array, z_starts: tuple[tuple[float, float], ...]) -> PathCandidate:
        if fit_z:
            # a tilt of the frame and a z error of either sign trade off over a flat trace, and
            # the cubic's hold at its extremum kinks the model where c2 changes sign: ICP starts
            # from several z errors and the best fit is kept
            fits = [icp(pack_frame(T0, np.asarray(c, dtype=float)), 8) for c in z_starts]
            x, iterations = min(fits, key=lambda f: float(np.sum(robust_cost(f[0]))))
        else:
            x, iterations = icp(pack_frame(T0, np.zeros(zfield.N_COEFFS)), 6)
        T, coeffs = unpack_frame(x)
        if not fit_z:
            coeffs = np.zeros(zfield.N_COEFFS)
        dist, nearest = tree.query(tips_world(x))
        kept = dist[dist <= threshold_m]
        down_z = (tip_vectors @ T[:3, :3].T)[:, 2]
        return PathCandidate(
            source_in_world=T,
            coeffs=coeffs,
            distances_m=dist,
            rms_m=float(np.sqrt(np.mean(kept**2))) if kept.size else float("inf"),
            outlier_share=float(np.mean(dist > threshold_m)),
            tool_down=float(np.mean(down_z < 0.0)) if attitude_known else float("nan"),
            travel=float(spearmanr(np.arange(len(nearest)), nearest).statistic) if len(nearest) > 2 else 0.0,
            iterations=iterations,
        )

    guess = check_transform(initial_source_in_world, "initial_source_in_world")
    tips_raw = p + tip_vectors
    hypotheses = [guess, *path_hypotheses(tips_raw, dense)]
    coarse = [_coarse_icp(tips_raw, tree, dense, T) for T in hypotheses]
    coarse_rms = [
        float(np.sqrt(np.mean(tree.query(tips_raw @ T[:3, :3].T + T[:3, 3])[0] ** 2))) for T in coarse
    ]
    distinct: list[Array] = []
    for k in sorted(range(len(coarse)), key=lambda k: (coarse_rms[k], k)):
        if coarse_rms[k] > 10.0 * max_rms_m:
            continue
        if all(not _same_frame(coarse[k], T) for T in distinct):
            distinct.append(coarse[k])
    # the cues of the rigid fits: a hypothesis that the tool's attitude or the direction of travel
    # already rules out is refined from no z error only
    coarse_down = [
        float(np.mean((tip_vectors @ T[:3, :3].T)[:, 2] < 0.0)) if attitude_known else 1.0 for T in distinct
    ]
    coarse_travel = [
        float(spearmanr(np.arange(len(p)), tree.query(tips_raw @ T[:3, :3].T + T[:3, 3])[1]).statistic)
        for T in distinct
    ]
    promising = [
        d >= max(coarse_down) - CUE_TIE and t >= max(coarse_travel) - 2.0 * CUE_TIE
        for d, t in zip(coarse_down, coarse_travel, strict=True)
    ]
    first_pass = [
        refine(T, Z_STARTS if ok else Z_STARTS[:1]) for T, ok in zip(distinct, promising, strict=True)
    ]
    if fit_z and first_pass:
        # the z error belongs to the tracker, not to a hypothesis: every candidate is refined
        # again from the z error of the one that fits best
        best_z = tuple(float(v) for v in min(first_pass, key=lambda c: c.rms_m).coeffs)
        first_pass = [
            min(c, refine(T, (best_z,)), key=lambda c: c.rms_m) if ok else c
            for c, T, ok in zip(first_pass, distinct, promising, strict=True)
        ]
    candidates: list[PathCandidate] = []
    for c in first_pass:
        logger.debug("path candidate: %s", c.describe())
        if all(not _same_frame(c.source_in_world, o.source_in_world) for o in candidates):
            candidates.append(c)
    fitting = [c for c in candidates if c.outlier_share <= 0.5 and c.rms_m <= max_rms_m]
    if not fitting:
        best = min(candidates, key=lambda c: c.rms_m, default=None)
        found = f"; the best leaves {best.rms_m * 1000:.1f} mm RMS" if best is not None else ""
        raise InputError(
            f"path registration: none of the {len(hypotheses)} hypotheses (the first guess, the trace's "
            f"principal axes turned every {360 // PATH_TURNS} deg) fits the CAD path within "
            f"{max_rms_m * 1000:.0f} mm RMS with at most half of the tip positions more than "
            f"{threshold_m * 1000:.0f} mm off it{found}: the log does not trace this path, or the tip "
            f"offset or the units are wrong"
        )
    ranked = fitting
    if attitude_known:
        best_down = max(c.tool_down for c in ranked)
        ranked = [c for c in ranked if c.tool_down >= best_down - CUE_TIE]
    best_travel = max(c.travel for c in ranked)
    ranked = [c for c in ranked if c.travel >= best_travel - CUE_TIE]
    ranked.sort(key=lambda c: (c.rms_m, tuple(np.round(c.source_in_world[:3, 3], 6))))
    winner = ranked[0]
    n = len(winner.distances_m)
    if len(ranked) > 1 and _ties(winner, ranked[1], n):
        offset_m, angle_deg = frame_difference(winner.source_in_world, ranked[1].source_in_world)
        raise InputError(
            f"path registration: two frames fit the trace equally well and no cue (the tool's attitude, "
            f"the direction of travel) tells them apart, {offset_m * 1000:.0f} mm and {angle_deg:.1f} deg "
            f"apart: {winner.describe()}; {ranked[1].describe()}. The path is symmetric for this trace: "
            f"trace it from its start in its direction, over a part that is not symmetric, or register "
            f"on touched points (refine calibrate receiver)"
        )
    # a round path leaves a turn free, a straight one a shift: the distances then do not fix the frame
    x_win = pack_frame(winner.source_in_world, winner.coeffs)
    _, nearest = tree.query(tips_world(x_win))
    target, tangent = dense[nearest], tangents[nearest]
    step = 1e-6
    columns = []
    for j in range(6):
        dx = np.zeros_like(x_win)
        dx[j] = step
        columns.append(
            (
                off_path(tips_world(x_win + dx), target, tangent)
                - off_path(tips_world(x_win - dx), target, tangent)
            ).ravel()
            / (2.0 * step)
        )
    jac = np.column_stack(columns)
    jac[:, :3] *= max(float(np.sqrt(np.mean(np.sum((dense - dense.mean(axis=0)) ** 2, axis=1)))), 1e-3)
    singular = np.linalg.svd(jac, compute_uv=False)
    determination = float(singular[-1] / singular[0])
    if determination < MIN_DETERMINATION:
        others = sorted(
            (c for c in fitting if c is not winner),
            key=lambda c: frame_difference(c.source_in_world, winner.source_in_world)[1],
        )
        other = f"; another fit: {others[0].describe()}, " if others else ""
        apart = (
            "{:.0f} mm and {:.1f} deg away".format(
                *(lambda d: (d[0] * 1000, d[1]))(
                    frame_difference(others[0].source_in_world, winner.source_in_world)
                )
            )
            if others
            else ""
        )
        raise InputError(
            f"path registration: the distances from the path leave the frame free to turn or shift "
            f"(the weakest direction is determined {determination:.1e} times as well as the best, "
            f"at least {MIN_DETERMINATION:.0e} needed): {winner.describe()}{other}{apart}. A round "
            f"or straight path does not fix the receiver: trace a path with corners, or register on "
            f"touched points (refine calibrate receiver)"
        )
    offset_m, turn_deg = frame_difference(winner.source_in_world, guess)
    if offset_m > max_guess_offset_m or turn_deg > max_guess_turn_deg:
        raise InputError(
            f"path registration: the trace fits the CAD path with {winner.describe()}, "
            f"{offset_m * 1000:.0f} mm and {turn_deg:.1f} deg from the first guess (at most "
            f"{max_guess_offset_m * 1000:.0f} mm and {max_guess_turn_deg:.0f} deg allowed): if the "
            f"receiver really sits there, allow it (--max-guess-offset-m, --max-guess-turn-deg) or "
            f"correct source_in_world in the problem"
        )
    figures = {
        "hypotheses": float(len(hypotheses)),
        "candidates_fitting": float(len(fitting)),
        "icp_iterations": float(winner.iterations),
        "samples_used": float(n),
        "travel_rank_correlation": winner.travel,
        "determination": determination,
    }
    if attitude_known:
        figures["tool_down_share"] = winner.tool_down
    others = [c for c in fitting if c is not winner]
    if others:
        runner_up = min(others, key=lambda c: (c.rms_m, tuple(np.round(c.source_in_world[:3, 3], 6))))
        figures["runner_up_rms_m"] = runner_up.rms_m
        figures["runner_up_offset_m"], figures["runner_up_angle_deg"] = frame_difference(
            runner_up.source_in_world, winner.source_in_world
        )
    dz_min, dz_max = zfield.z_error_range_m(p, winner.coeffs)
    figures.update(
        {
            "z_coeffs_c2_per_m": float(winner.coeffs[0]),
            "z_coeffs_c3_per_m2": float(winner.coeffs[1]),
            "z_error_min_m": dz_min,
            "z_error_max_m": dz_max,
        }
    )
    dist = winner.distances_m
    return Calibration(
        kind="receiver_path",
        values={"source_in_world": winner.source_in_world},
        residuals_m=dist,
        outliers=tuple(int(i) for i in np.flatnonzero(dist > threshold_m)),
        figures=figures,
    )
