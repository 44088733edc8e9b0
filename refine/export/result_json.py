"""``result.json``: the status and measured figures of a run (schema in ``docs/outputs.md``)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from refine.pipeline import RunResult

SCHEMA_VERSION = 1
REPO_ROOT = Path(__file__).resolve().parents[2]


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def result_dict(result: RunResult) -> dict[str, Any]:
    """The JSON document of ``result`` as plain Python values."""
    problem, ref, check = result.problem, result.refinement, result.refinement.check
    spec = result.robot.spec
    timing = result.timing
    metrics: dict[str, Any] = {
        "max_position_error_m": float(check.position_error_m.max()),
        "max_orientation_deviation_deg": float(check.orientation_deviation_deg.max()),
        "mean_orientation_deviation_deg": float(check.orientation_deviation_deg.mean()),
        "min_joint_margin_rad": float(check.joint_margin_rad.min()),
        "min_singularity_measure": float(check.singularity.min()),
        "min_singular_value": float(check.sigma_min.min()),
        "min_clearance_m": None,  # collision checking is not part of this pipeline yet
        "cycle_time_s": None if timing is None else timing.cycle_time_s,
        "speed_tracking_error_rel": None if timing is None else _finite(timing.speed_tracking_error_rel),
        "fusion_residual_median_m": float(np.median(result.fused.residual)),
    }
    doc: dict[str, Any] = {
        "schema_version": SCHEMA_VERSION,
        "status": ref.status,
        "reason": ref.reason,
        "problem": problem.name,
        "problem_dir": os.path.relpath(problem.root, REPO_ROOT),
        "n_waypoints": len(result.fused),
        "dof": result.robot.nq,
        "path_length_m": float(result.fused.s[-1]),
        "robot": {
            "model": spec.name,
            "urdf": os.path.relpath(spec.urdf, REPO_ROOT),
            "flange_frame": spec.flange_frame,
            "base_in_world": np.asarray(problem.robot.base_in_world).tolist(),
            "joint_lower_rad": spec.lower.tolist(),
            "joint_upper_rad": spec.upper.tolist(),
        },
        "tool": {
            "name": problem.tool.name,
            "tcp_in_flange": np.asarray(problem.tool.tcp_in_flange).tolist(),
            "axisymmetric": problem.tool.axisymmetric,
        },
        "tolerances": {
            "position_m": problem.tolerances.position_m,
            "orientation_deg": problem.tolerances.orientation_deg,
            "joint_margin_deg": problem.tolerances.joint_margin_deg,
            "singularity_margin": problem.tolerances.singularity_margin,
        },
        "metrics": metrics,
        "solver": {"name": "ipopt", "status": ref.solver_status, "iterations": ref.iterations},
        "violations": [v.describe() for v in check.violations],
        "slow_segments": []
        if timing is None
        else [
            {
                "index_start": seg.index_start,
                "index_end": seg.index_end,
                "s_start_m": seg.s_start_m,
                "s_end_m": seg.s_end_m,
                "min_ratio": seg.min_ratio,
                "reason": seg.reason,
            }
            for seg in timing.slow_segments
        ],
        "repairs": [],
        "truth": None if result.truth is None else result.truth.as_json(),
        "timings_s": {k: round(v, 6) for k, v in result.timings_s.items()},
        "outputs": {k: p.name for k, p in result.outputs.items()},
    }
    return doc


def write_result_json(path: Path, result: RunResult) -> Path:
    """Write ``result.json`` for ``result`` to ``path``."""
    path.write_text(json.dumps(result_dict(result), indent=2) + "\n", encoding="utf-8")
    return path
