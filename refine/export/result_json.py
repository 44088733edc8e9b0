"""``result.json``: the status and measured figures of a run (schema in ``docs/outputs.md``)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from refine.export.program import controller_base
from refine.robot.registry import PACKAGED_ROBOTS
from refine.run.outputs import describe_files

if TYPE_CHECKING:
    from refine.run.result import PassResult, RunResult

SCHEMA_VERSION = 1
REPO_ROOT = Path(__file__).resolve().parents[2]


def shown_path(path: Path | str) -> str:
    """A path as ``result.json`` shows it.

    Relative to the source checkout when inside it (the bundled problems and robots), the
    registry's copy in an installed wheel as ``robots/...``, anything else absolute.
    """
    path = Path(path).resolve()
    for root, prefix in ((PACKAGED_ROBOTS, "robots"), (REPO_ROOT, "")):
        if path.is_relative_to(root):
            return str(Path(prefix) / path.relative_to(root)) if prefix else os.path.relpath(path, root)
    return str(path)


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def pass_metrics(p: PassResult) -> dict[str, Any]:
    """The verified figures of one pass, as ``result.json`` writes them (``passes[i].metrics``)."""
    check, timing = p.refinement.check, p.timing
    clearance = p.clearance
    chord = p.cad_chord
    return {
        "max_position_error_m": float(check.position_error_m.max()),
        "max_cad_chord_error_m": None if chord is None else chord.max_m,
        "max_orientation_deviation_deg": float(check.orientation_deviation_deg.max()),
        "mean_orientation_deviation_deg": float(check.orientation_deviation_deg.mean()),
        "max_slack_deg": float(p.refinement.slack_deg.max()) if p.refinement.slack_deg.size else 0.0,
        "min_joint_margin_rad": float(check.joint_margin_rad.min()),
        "min_singularity_measure": float(check.singularity.min()),
        "min_singular_value": float(check.sigma_min.min()),
        "min_clearance_m": None if clearance is None else float(clearance.min_distance_m),
        "min_cell_clearance_m": getattr(p.clearance_kinds, "cell_m", None),
        "min_self_clearance_m": getattr(p.clearance_kinds, "self_m", None),
        "cycle_time_s": None if timing is None else timing.cycle_time_s,
        "speed_tracking_error_rel": None if timing is None else _finite(timing.speed_tracking_error_rel),
        "fusion_residual_median_m": float(np.median(p.fused.residual)),
    }


def program_motions(result: RunResult, p: PassResult) -> dict[str, Any]:
    """The zones and speeds of every program the run wrote for pass ``p`` (:mod:`refine.export.motion`)."""
    from refine.export.motion import MOTION_FORMATS, program_motion

    if p.trajectory is None:
        return {}
    kinds = {key.split("_")[0] for key in result.outputs}
    return {
        kind: program_motion(kind, p.trajectory, result.problem) for kind in MOTION_FORMATS if kind in kinds
    }


def controller_figures(result: RunResult) -> dict[str, Any]:
    """The run's figures of the motion as the controllers run it: the worst over passes and programs."""
    lines = [p.line.as_json() for p in result.passes if p.line is not None]
    motions = [m for p in result.passes for m in program_motions(result, p).values()]
    worst = {
        key: max((d[key] for d in lines), default=None)
        for key in ("max_position_difference_m", "max_orientation_difference_deg", "max_joint_difference_deg")
    }
    return {
        **{f"line_{key}": value for key, value in worst.items()},
        "line_ok": all(d["ok"] for d in lines) if lines else None,
        "path_tolerance_m": result.problem.process.path_tolerance_m,
        "largest_zone_deviation_m": max((m.zones.largest_deviation_m for m in motions), default=None),
        "speed_share": result.problem.output.speed_share,
        "segments_beyond_speed_share": sum(len(m.beyond_share) for m in motions) if motions else None,
    }


def aggregate_metrics(per_pass: list[dict[str, Any]]) -> dict[str, Any]:
    """The run's figures over its passes: the worst of each (largest error, smallest margin), times summed."""
    out: dict[str, Any] = {}
    for key in per_pass[0]:
        values = [m[key] for m in per_pass if m[key] is not None]
        if not values:
            out[key] = None
        elif key.startswith("min_"):
            out[key] = min(values)
        elif key.startswith("max_") or key.endswith("_error_rel") or key.startswith("fusion"):
            out[key] = max(values)
        elif key == "cycle_time_s":
            out[key] = sum(values)
        else:
            out[key] = float(np.mean(values))
    return out


def cad_chord_json(result: RunResult) -> dict[str, Any] | None:
    """The largest distance of the CAD geometry from the straight moves, and where (``cad_chord_error``)."""
    worst = None
    for p in result.passes:
        chord = p.cad_chord
        if chord is not None and (worst is None or chord.max_m > worst[1].max_m):
            worst = (p, chord)
    if worst is None:
        return None
    p, chord = worst
    cad = result.problem.cad
    return {
        "max_m": chord.max_m,
        "tolerance_m": None if cad is None else cad.chord_tolerance_m,
        "pass": p.name,
        "segment": chord.segment,
        "s_m": chord.s_m,
        "point_m": chord.point.tolist(),
        "n_waypoints": [len(q.fused) for q in result.passes],
    }


def result_dict(result: RunResult) -> dict[str, Any]:
    """The JSON document of ``result`` as plain Python values."""
    problem = result.problem
    spec = result.robot.spec
    per_pass = [pass_metrics(p) for p in result.passes]
    first = result.first
    doc: dict[str, Any] = {
        "schema_version": SCHEMA_VERSION,
        "status": result.status,
        "reason": "; ".join(
            [
                (f"{p.name}: " if len(result.passes) > 1 else "") + p.refinement.reason
                for p in result.passes
                if p.refinement.reason
            ]
            + [m.reason for m in result.failed_motions]
        ),
        "problem": problem.name,
        "problem_dir": shown_path(problem.root),
        "n_waypoints": len(first.fused),
        "n_passes": len(result.passes),
        "dof": result.robot.nq,
        "path_length_m": float(first.fused.s[-1]),
        "robot": {
            "model": spec.name,
            "urdf": shown_path(spec.urdf),
            "flange_frame": spec.flange_frame,
            "base_in_world": np.asarray(problem.robot.base_in_world).tolist(),
            "joint_lower_rad": spec.lower.tolist(),
            "joint_upper_rad": spec.upper.tolist(),
            "joint_coupling": spec.joint_coupling,
            "controller_in_base": controller_base(result.robot).tolist(),
        },
        "tool": {
            "name": problem.tool.name,
            "tcp_in_flange": np.asarray(problem.tool.tcp_in_flange).tolist(),
            "axisymmetric": problem.tool.axisymmetric,
            "tcp_in_world": None if problem.tool.tcp_in_world is None else np.asarray(problem.tool.tcp_in_world).tolist(),
        },
        "tolerances": {
            "position_m": problem.tolerances.position_m,
            "orientation_deg": problem.tolerances.orientation_deg,
            "joint_margin_deg": problem.tolerances.joint_margin_deg,
            "singularity_margin": problem.tolerances.singularity_margin,
            "joint_step_deg": problem.tolerances.joint_step_deg,
            "clearance_m": problem.collision.margin_m if problem.collision.enabled else None,
            "self_clearance_m": problem.collision.self_margin_m if problem.collision.enabled else None,
        },
        "metrics": aggregate_metrics(per_pass),
        "cad_chord_error": cad_chord_json(result),
        "solver": {
            "name": problem.optimise.solver,
            "status": first.refinement.solver_status,
            "iterations": sum(p.refinement.iterations for p in result.passes),
            "outer_iterations": sum(p.refinement.outer_iterations for p in result.passes),
            "time_limit_reached": any(p.refinement.time_limit_reached for p in result.passes),
        },
        # the stage a time limit stopped: a pass's refinement here (a library call stopped by its
        # limit elsewhere returns a result without a run, refine.run.timeout)
        "stopped_stage": "refine" if any(p.refinement.status == "timeout" for p in result.passes) else None,
        "violations": [v.describe() for p in result.passes for v in p.refinement.check.violations],
        "slow_segments": [
            {
                "pass": p.name,
                "index_start": seg.index_start,
                "index_end": seg.index_end,
                "s_start_m": seg.s_start_m,
                "s_end_m": seg.s_end_m,
                "min_ratio": seg.min_ratio,
                "reason": seg.reason,
            }
            for p in result.passes
            if p.timing is not None
            for seg in p.timing.slow_segments
        ],
        "diagnosis": [{"pass": p.name, **f.as_json()} for p in result.passes for f in p.refinement.diagnosis],
        "repairs": [
            {
                "pass": p.name,
                "index_start": r.index_start,
                "index_end": r.index_end,
                "s_start_m": r.s_start_m,
                "s_end_m": r.s_end_m,
                "reason": r.reason,
                "slack_deg": r.slack_deg,
                "objects": list(r.objects),
            }
            for p in result.passes
            for r in p.refinement.repairs
        ],
        "passes": [
            {
                "name": p.name,
                "layer": p.layer,
                "index": p.index,
                "status": p.refinement.status,
                "metrics": m,
                "line": None
                if p.line is None
                else p.line.as_json(None if p.clearance is None else p.clearance.segment_clearance_m),
                "programs": {kind: motion.as_json() for kind, motion in program_motions(result, p).items()},
                "circular_moves": None
                if getattr(p, "circular", None) is None
                else {
                    "written": [[a.start, a.via, a.end] for a in getattr(p.trajectory, "arcs", ())],
                    "checks": [c.as_json() for c in p.circular],
                },
            }
            for p, m in zip(result.passes, per_pass, strict=True)
        ],
        "motions": [m.as_json(result.robot.spec.to_controller) for m in result.motions],
        "program_time_s": sum(m.duration_s for m in result.motions) if result.motions else None,
        "controller": controller_figures(result),
        "truth": None if result.truth is None else result.truth.as_json(),
        "demo_quality": _demo_quality(result),
        "placement": None if result.placement is None else result.placement.as_json(),
        "timings_s": _timings(result),
        "outputs": {k: p.name for k, p in result.outputs.items()},
        "files": describe_files(result.outputs),
    }
    return doc


def _demo_quality(result: RunResult) -> dict[str, Any] | None:
    """The quality gate's figures with the alignment's choice of direction and start (``fused.order``)."""
    if result.demo_quality is None:
        return None
    doc = result.demo_quality.as_json()
    order = result.fused.order
    if order is not None:
        doc.update(order.as_json())
    return doc


def _timings(result: RunResult) -> dict[str, float]:
    return {k: round(v, 6) for k, v in result.timings_s.items()}


def write_result_json(path: Path, result: RunResult) -> Path:
    """Write ``result.json`` for ``result`` to ``path``, atomically (a temporary file, then a rename)."""
    return _write(path, result_dict(result))


def write_timings(path: Path, result: RunResult) -> Path:
    """Rewrite only ``timings_s`` of the ``result.json`` at ``path`` written for ``result`` (atomically).

    For the times known only once the files are in place (the run's total): the rest of the
    document, its files' sizes and SHA-256 among them, stands as written and is not computed again.
    """
    doc = json.loads(path.read_text(encoding="utf-8"))
    doc["timings_s"] = _timings(result)
    return _write(path, doc)


def _write(path: Path, doc: dict[str, Any]) -> Path:
    text = json.dumps(doc, indent=2) + "\n"
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)
    return path
