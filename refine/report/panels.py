"""The data of the report's plots, per pass, along the arc length.

Six panels, each its own plot with its own legend: deviation from the demonstration against the
cone (plus repair slack), joints against their limits, joint speeds against theirs, the
singularity measure against its margin, the clearance against its margin, and the demonstrated
against the planned TCP speed. Joint j has the same colour in every panel (:data:`JOINT_COLOURS`)
and its limits are drawn in that colour. A panel without data carries the reason instead.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from refine.report.scene import rounded

if TYPE_CHECKING:
    from refine.run.result import PassResult, RunResult

JOINT_COLOURS = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
)
"""Colour of joint 1, 2, ... in every panel."""

PANELS = (
    ("deviation", "Orientation deviation from the demonstration [deg]"),
    ("joints", "Joint positions and their limits [deg]"),
    ("speeds", "Joint speeds as a fraction of their limits [-]"),
    ("singularity", "Singularity measure (scaled manipulability) [-]"),
    ("clearance", "Clearance to the cell and between links [mm]"),
    ("tcp_speed", "TCP speed: demonstrated and planned [mm/s]"),
)
"""Panel id and title, in page order."""


def _line(name: str, x: Any, y: Any, **style: Any) -> dict[str, Any]:
    return {"name": name, "x": rounded(x, 4), "y": rounded(y, 4), **style}


def _flat(
    name: str, s: Any, value: float, colour: str, dash: str = "dash", legend: bool = True
) -> dict[str, Any]:
    return _line(name, [s[0], s[-1]], [value, value], colour=colour, dash=dash, legend=legend)


def pass_panels(result: RunResult, p: PassResult) -> dict[str, Any]:
    """The six panels of one pass: ``{panel id: {"lines": [...]} or {"empty": reason}}``."""
    problem, spec = result.problem, result.robot.spec
    tol, check, s = problem.tolerances, p.refinement.check, p.fused.s
    no_timing = "No timing: the pass is infeasible, so it was not timed."
    panels: dict[str, Any] = {}

    cone = np.full(len(s), tol.orientation_deg)
    if p.refinement.slack_deg.size == len(s):
        cone = cone + p.refinement.slack_deg
    panels["deviation"] = {
        "lines": [
            _line("deviation", s, check.orientation_deviation_deg, colour="#1f77b4"),
            _line(
                "cone + repair slack" if np.any(cone > tol.orientation_deg) else "cone",
                s,
                cone,
                colour="#d62728",
                dash="dash",
            ),
        ]
    }

    q_urdf = p.refinement.q
    q = np.degrees(spec.to_controller(q_urdf))  # the joints as the controller shows them
    lines = []
    for j in range(q.shape[1]):
        colour = JOINT_COLOURS[j % len(JOINT_COLOURS)]
        lines.append(_line(f"q{j + 1}", s, q[:, j], colour=colour, group=f"q{j + 1}"))
        for bound, label in ((spec.lower[j], "min"), (spec.upper[j], "max")):
            if abs(bound) < 4 * math.pi:
                at_bound = q_urdf.copy()
                at_bound[:, j] = bound
                moving = np.degrees(spec.to_controller(at_bound)[:, j])  # a coupled joint's limit moves
                style = {"colour": colour, "dash": "dot", "legend": False, "group": f"q{j + 1}"}
                if np.ptp(moving) > 1e-9:
                    lines.append(_line(f"q{j + 1} {label}", s, moving, **style))
                else:
                    lines.append(
                        _flat(f"q{j + 1} {label}", s, float(moving[0]), colour, "dot", legend=False)
                        | {"group": f"q{j + 1}"}
                    )
    panels["joints"] = {"lines": lines}

    if p.timing is None:
        panels["speeds"] = {"empty": no_timing}
        panels["tcp_speed"] = {"empty": no_timing}
    else:
        ratio = np.abs(p.timing.qd) / (spec.velocity * problem.robot.velocity_scale)
        panels["speeds"] = {
            "lines": [
                _line(f"q{j + 1}", s, ratio[:, j], colour=JOINT_COLOURS[j % len(JOINT_COLOURS)])
                for j in range(ratio.shape[1])
            ]
            + [_flat("limit", s, 1.0, "#000000")]
        }
        panels["tcp_speed"] = {
            "lines": [
                _line("demonstrated", s, p.timing.speed_cap * 1e3, colour="#7f7f7f"),
                _line("planned", s, p.timing.speed * 1e3, colour="#1f77b4"),
            ]
        }

    panels["singularity"] = {
        "lines": [
            _line("scaled manipulability", s, check.singularity, colour="#1f77b4"),
            _flat("margin", s, tol.singularity_margin, "#d62728"),
        ]
    }

    if p.clearance is None:
        why = (
            "collision checking is off"
            if not problem.collision.enabled
            else "the problem has no cell objects or tool shapes"
        )
        panels["clearance"] = {"empty": f"No clearance: {why}."}
    else:
        panels["clearance"] = {"lines": clearance_lines(s, p.clearance, problem.collision.margin_m)}
    return panels


def clearance_lines(s: Any, clearance: Any, margin_m: float) -> list[dict[str, Any]]:
    """The clearance panel's lines: per waypoint, per segment and the margin [mm].

    Where the dense check left a waypoint unmeasured (``PathClearance.waypoint_measured`` false),
    its figure is a lower bound on the distance, and so is that of a segment with one sub-step
    that ends at one: those points are drawn apart (open markers, "lower bound" in the legend and
    in the hover text), the measured ones as before.
    """
    wp_mm = np.asarray(clearance.waypoint_distance_m, dtype=float) * 1e3
    seg_mm = np.asarray(clearance.segment_distance_m, dtype=float) * 1e3
    measured = clearance.waypoint_measured
    mid = 0.5 * (s[1:] + s[:-1])
    if measured is None or bool(np.all(measured)):
        return [
            _line("at waypoints", s, wp_mm, colour="#1f77b4"),
            _line("least between waypoints", mid, seg_mm, colour="#ff7f0e", mode="markers"),
            _flat("margin", s, margin_m * 1e3, "#d62728"),
        ]
    measured = np.asarray(measured, dtype=bool)
    seg_bound = (np.asarray(clearance.segment_samples) == 1) & ~(measured[:-1] & measured[1:])
    wp_text = np.where(measured, "measured", "lower bound (waypoint not measured)")
    seg_text = np.where(seg_bound, "lower bound (an end not measured)", "measured")
    lines = [
        _line("at waypoints (lower bound where not measured)", s, wp_mm, colour="#1f77b4", group="wp")
        | {"text": wp_text.tolist()},
        _line(
            "at waypoints: lower bound (not measured)",
            s[~measured],
            wp_mm[~measured],
            colour="#1f77b4",
            mode="markers",
            symbol="circle-open",
            group="wp",
        ),
    ]
    for name, keep, symbol in (
        ("least between waypoints", ~seg_bound, "circle"),
        ("least between waypoints: lower bound", seg_bound, "circle-open"),
    ):
        if keep.any():
            lines.append(
                _line(name, mid[keep], seg_mm[keep], colour="#ff7f0e", mode="markers", symbol=symbol)
                | {"text": seg_text[keep].tolist()}
            )
    return lines + [_flat("margin", s, margin_m * 1e3, "#d62728")]


def panel_data(result: RunResult) -> dict[str, Any]:
    """Titles and, per pass, its name, status and panels."""
    return {
        "titles": [list(t) for t in PANELS],
        "passes": [
            {"name": p.name, "status": p.refinement.status, "panels": pass_panels(result, p)}
            for p in result.passes
        ],
    }
