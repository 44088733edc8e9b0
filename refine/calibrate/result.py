"""The result of a calibration: the frames found, the residuals and the rejected measurements."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from refine.errors import InputError
from refine.types import Array


@dataclass(frozen=True)
class Calibration:
    """What one calibration measured.

    Attributes:
        kind: the measurement, e.g. ``"pivot"`` or ``"receiver"``.
        values: the results by their JSON names, each a vector (3,) [m] or a transform (4, 4)
            [m], e.g. ``{"tip_in_sensor_m": ..., "pivot_in_source_m": ...}``.
        residuals_m: residual of every measurement used or rejected [m], shape (K,): per sample
            for a pivot, per point for a registration.
        outliers: indices into ``residuals_m`` of the rejected measurements, increasing.
        figures: further scalar figures worth reporting (spread of the swing, fitted distortion,
            ...), by name with their unit in the name.
        labels: what each residual belongs to (point names), or empty for plain indices.
    """

    kind: str
    values: dict[str, Array]
    residuals_m: Array
    outliers: tuple[int, ...] = ()
    figures: dict[str, float] = field(default_factory=dict)
    labels: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        res = np.asarray(self.residuals_m, dtype=float)
        if res.ndim != 1 or not np.all(np.isfinite(res)):
            raise InputError(f"{self.kind}: residuals must be finite, shape (K,), got {res.shape}")
        object.__setattr__(self, "residuals_m", res)

    @property
    def inliers(self) -> NDArray[np.bool_]:
        """Mask of the measurements kept, shape (K,)."""
        mask = np.ones(len(self.residuals_m), dtype=bool)
        mask[list(self.outliers)] = False
        return mask

    @property
    def rms_residual_m(self) -> float:
        """RMS residual of the kept measurements [m]."""
        kept = self.residuals_m[self.inliers]
        return float(np.sqrt(np.mean(kept**2))) if kept.size else 0.0

    @property
    def max_residual_m(self) -> float:
        """Largest residual of the kept measurements [m]."""
        kept = self.residuals_m[self.inliers]
        return float(kept.max()) if kept.size else 0.0

    def as_dict(self) -> dict[str, Any]:
        """The JSON object ``refine calibrate --json`` prints (lists of floats, metres)."""
        out: dict[str, Any] = {"kind": self.kind}
        out.update({k: np.asarray(v).tolist() for k, v in self.values.items()})
        out["rms_residual_m"] = self.rms_residual_m
        out["max_residual_m"] = self.max_residual_m
        out["outliers"] = list(self.outliers)
        out["residuals_m"] = self.residuals_m.tolist()
        if self.labels:
            out["labels"] = list(self.labels)
        out.update(self.figures)
        return out
