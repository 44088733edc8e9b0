"""Rigid registration of matched point sets: Kabsch/Umeyama by SVD, with RANSAC.

``kabsch`` finds the rotation and translation that carry one point set onto another in the least
squares sense (scipy's ``Rotation.align_vectors`` solves the SVD problem); ``ransac`` picks the
largest set of measurements one model explains, so a wrongly touched point cannot pull the answer.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Callable
from typing import TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from refine.errors import InputError
from refine.frames import make_transform, transform_points
from refine.types import Array

logger = logging.getLogger(__name__)

Model = TypeVar("Model")

#: Smallest RMS distance of the reference points from their best-fit line [m]: below it the
#: rotation about that line is not determined by the measurement.
MIN_OFF_LINE_M = 0.01
#: Most hypotheses RANSAC tries; with fewer subsets than this it tries every one.
MAX_HYPOTHESES = 500


def check_point_geometry(points: ArrayLike, where: str, min_points: int = 3) -> Array:
    """Return the points (N, 3) [m] after checking they fix a rigid transform.

    Raises:
        InputError: fewer than ``min_points`` points, or points (nearly) on one line.
    """
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{where}: expected points of shape (N, 3) [m], got {p.shape}")
    if len(p) < min_points:
        raise InputError(
            f"{where}: {len(p)} point(s) given; this registration needs at least {min_points} "
            f"points, not all on one line"
        )
    centred = p - p.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    off_line = math.sqrt(float(np.sum(sv[1:] ** 2)) / len(p))
    if off_line < MIN_OFF_LINE_M:
        raise InputError(
            f"{where}: the points lie on one line (RMS {off_line * 1000:.2f} mm off their best-fit "
            f"line, at least {MIN_OFF_LINE_M * 1000:.0f} mm needed); the rotation about that line "
            f"is undetermined: touch points spread over an area"
        )
    return p


def kabsch(source: ArrayLike, target: ArrayLike, weights: ArrayLike | None = None) -> Array:
    """Rigid transform T (4, 4) minimising sum w_i |T source_i - target_i|^2 (points (N, 3) [m])."""
    a = np.asarray(source, dtype=float)
    b = np.asarray(target, dtype=float)
    w = np.ones(len(a)) if weights is None else np.asarray(weights, dtype=float)
    ca = np.average(a, axis=0, weights=w)
    cb = np.average(b, axis=0, weights=w)
    rot, _ = Rotation.align_vectors(b - cb, a - ca, weights=w)
    R = rot.as_matrix()
    return make_transform(R, cb - R @ ca)


def point_residuals(T: ArrayLike, source: ArrayLike, target: ArrayLike) -> Array:
    """Distances |T source_i - target_i| [m], shape (N,)."""
    return np.linalg.norm(transform_points(T, source) - np.asarray(target, dtype=float), axis=1)


def ransac(
    n: int,
    fit: Callable[[NDArray[np.intp]], Model],
    residuals: Callable[[Model], Array],
    sample_size: int,
    threshold_m: float,
    seed: int = 0,
) -> tuple[Model, NDArray[np.bool_]]:
    """Fit a model to the largest consistent subset of ``n`` measurements.

    Every subset of ``sample_size`` measurements is tried when there are at most
    :data:`MAX_HYPOTHESES` of them, otherwise that many random subsets. The hypothesis explaining
    most measurements within ``threshold_m`` wins (ties: the smaller sum of residuals capped at
    the threshold); the model is then refitted to its inliers, twice.

    Args:
        n: number of measurements.
        fit: fits a model to the measurements at the given indices; may raise InputError for a
            degenerate subset (it is then skipped).
        residuals: residual of every measurement under a model [m], shape (n,).
        sample_size: measurements per hypothesis.
        threshold_m: largest residual of an inlier [m].
        seed: seed of the random subsets.

    Returns:
        The refitted model and the inlier mask (n,).

    Raises:
        InputError: no subset gives a model that explains ``sample_size`` measurements.
    """
    if math.comb(n, sample_size) <= MAX_HYPOTHESES:
        subsets = [np.array(c) for c in itertools.combinations(range(n), sample_size)]
    else:
        rng = np.random.default_rng(seed)
        subsets = [rng.choice(n, sample_size, replace=False) for _ in range(MAX_HYPOTHESES)]
    best: tuple[int, float] | None = None
    best_model: Model | None = None
    for idx in subsets:
        try:
            model = fit(np.sort(idx))
        except InputError:
            continue
        r = residuals(model)
        score = (int((r < threshold_m).sum()), -float(np.minimum(r, threshold_m).sum()))
        if best is None or score > best:
            best, best_model = score, model
    if best is None or best_model is None or best[0] < sample_size:
        raise InputError(
            f"no {sample_size} of the {n} measurements agree within {threshold_m * 1000:.1f} mm: "
            f"check the order of the points, the units and the tool offset; a tracker with large "
            f"position-dependent errors may need a larger threshold (--threshold-m)"
        )
    model = best_model
    mask = residuals(model) < threshold_m
    for _ in range(3):
        refit = fit(np.flatnonzero(mask))
        new_mask = residuals(refit) < threshold_m
        if new_mask.sum() < sample_size:
            break
        model = refit
        if np.array_equal(new_mask, mask):
            break
        mask = new_mask
    mask = residuals(model) < threshold_m
    logger.debug("ransac: %d of %d inliers", int(mask.sum()), n)
    return model, mask
