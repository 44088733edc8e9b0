"""``report.html``: one self-contained page a process engineer opens after a run.

The path in 3D with the robot drawn at a few waypoints; per pass, along the arc length: deviation
from the demonstration and repair slack against the cone, joint positions against their limits,
joint speeds against theirs, the singularity measure and the clearance against their margins, and
the demonstrated against the planned speed; the status, the figures and the repairs as text. Plotly
draws it; its JavaScript is embedded so the page works offline.
"""

from __future__ import annotations

import html
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import plotly.graph_objects as go
from plotly.offline import get_plotlyjs
from plotly.subplots import make_subplots

if TYPE_CHECKING:
    from refine.result import PassResult, RunResult

ROBOT_POSES = 5
"""How many configurations of the robot the 3D view draws along the path."""


def _robot_lines(result: RunResult, q: np.ndarray) -> tuple[list[float], list[float], list[float]]:
    """Polyline through the robot's joint origins and the TCP for one configuration, world frame."""
    robot, problem = result.robot, result.problem
    base = problem.robot.base_in_world
    pts = [base[:3, 3]]
    model, data = robot.model, robot.model.createData()
    import pinocchio as pin

    pin.forwardKinematics(model, data, q)
    for j in range(1, model.njoints):
        pts.append((base @ np.append(data.oMi[j].translation, 1.0))[:3])
    flange = base @ robot.fk(q)
    pts += [flange[:3, 3], (flange @ problem.tool.tcp_in_flange)[:3, 3]]
    xs, ys, zs = (list(c) for c in np.array(pts).T)
    return xs, ys, zs


def _path_figure(result: RunResult) -> go.Figure:
    fig = go.Figure()
    for p in result.passes:
        pos = p.fused.positions
        fig.add_trace(
            go.Scatter3d(
                x=pos[:, 0],
                y=pos[:, 1],
                z=pos[:, 2],
                mode="lines",
                name=f"{p.name}: CAD path",
                line={"width": 5},
            )
        )
    first = result.first
    poses = first.refinement.check.poses
    step = max(1, len(poses) // 40)
    axes = poses[::step, :3, 2] * 0.05
    tips = poses[::step, :3, 3]
    fig.add_trace(
        go.Cone(
            x=tips[:, 0],
            y=tips[:, 1],
            z=tips[:, 2],
            u=-axes[:, 0],
            v=-axes[:, 1],
            w=-axes[:, 2],
            sizemode="absolute",
            sizeref=0.02,
            anchor="tip",
            showscale=False,
            name="tool axis",
        )
    )
    if first.refinement.status in ("ok", "repaired"):
        for k in np.linspace(0, len(poses) - 1, ROBOT_POSES).astype(int):
            xs, ys, zs = _robot_lines(result, first.refinement.q[k])
            fig.add_trace(
                go.Scatter3d(
                    x=xs,
                    y=ys,
                    z=zs,
                    mode="lines+markers",
                    name=f"robot at waypoint {k}",
                    line={"width": 6, "color": "grey"},
                    marker={"size": 3},
                )
            )
    fig.update_layout(
        scene={"aspectmode": "data", "xaxis_title": "x [m]", "yaxis_title": "y [m]", "zaxis_title": "z [m]"},
        height=600,
        margin={"l": 0, "r": 0, "t": 30, "b": 0},
        title="Path and robot (world frame)",
    )
    return fig


def _pass_figure(result: RunResult, p: PassResult) -> go.Figure:
    spec, tol = result.robot.spec, result.problem.tolerances
    s = p.fused.s
    check = p.refinement.check
    rows = [
        "orientation deviation from the demonstration [deg]",
        "joints [deg] (dashed: limits)",
        "joint speeds / their limits [-]",
        "singularity measure [-]",
        "clearance [mm]",
        "TCP speed [mm/s]",
    ]
    fig = make_subplots(rows=len(rows), cols=1, shared_xaxes=True, subplot_titles=rows, vertical_spacing=0.04)
    fig.add_trace(go.Scatter(x=s, y=check.orientation_deviation_deg, name="deviation"), 1, 1)
    limit = tol.orientation_deg + (p.refinement.slack_deg if p.refinement.slack_deg.size else 0.0)
    fig.add_trace(
        go.Scatter(x=s, y=np.broadcast_to(limit, s.shape), name="cone + slack", line={"dash": "dash"}), 1, 1
    )
    q = np.degrees(p.refinement.q)
    for j in range(q.shape[1]):
        fig.add_trace(go.Scatter(x=s, y=q[:, j], name=f"q{j + 1}", legendgroup="joints"), 2, 1)
        for bound in (spec.lower[j], spec.upper[j]):
            if abs(bound) < 2 * math.pi:
                fig.add_trace(
                    go.Scatter(
                        x=[s[0], s[-1]],
                        y=[math.degrees(bound)] * 2,
                        showlegend=False,
                        line={"dash": "dot", "width": 1},
                        hoverinfo="skip",
                    ),
                    2,
                    1,
                )
    if p.timing is not None:
        ratio = np.abs(p.timing.qd) / (spec.velocity * result.problem.robot.velocity_scale)
        for j in range(ratio.shape[1]):
            fig.add_trace(
                go.Scatter(x=s, y=ratio[:, j], name=f"|qd{j + 1}|/limit", legendgroup="speeds"), 3, 1
            )
        fig.add_trace(go.Scatter(x=s, y=p.timing.speed_cap * 1e3, name="demonstrated"), 6, 1)
        fig.add_trace(go.Scatter(x=s, y=p.timing.speed * 1e3, name="planned"), 6, 1)
    fig.add_trace(go.Scatter(x=s, y=check.singularity, name="scaled manipulability"), 4, 1)
    fig.add_trace(
        go.Scatter(
            x=[s[0], s[-1]], y=[tol.singularity_margin] * 2, name="singularity margin", line={"dash": "dash"}
        ),
        4,
        1,
    )
    if p.clearance is not None:
        mid = 0.5 * (s[1:] + s[:-1])
        fig.add_trace(
            go.Scatter(x=s, y=p.clearance.waypoint_distance_m * 1e3, name="distance at waypoints"), 5, 1
        )
        fig.add_trace(
            go.Scatter(
                x=mid,
                y=p.clearance.segment_distance_m * 1e3,
                name="least between waypoints",
                mode="markers",
                marker={"size": 3},
            ),
            5,
            1,
        )
        fig.add_trace(
            go.Scatter(
                x=[s[0], s[-1]],
                y=[result.problem.collision.margin_m * 1e3] * 2,
                name="clearance margin",
                line={"dash": "dash"},
            ),
            5,
            1,
        )
    fig.update_xaxes(title_text="arc length s [m]", row=len(rows), col=1)
    fig.update_layout(height=1500, title=f"{p.name}: along the path", margin={"t": 60})
    return fig


def _summary_html(result: RunResult) -> str:
    from refine.result import summary_lines

    items = "\n".join(html.escape(line) for line in summary_lines(result))
    repairs = [
        f"<li>{html.escape(p.name)}: {html.escape(r.describe())}</li>"
        for p in result.passes
        for r in p.refinement.repairs
    ]
    slow = [
        f"<li>{html.escape(p.name)}: s = {seg.s_start_m:.3f}-{seg.s_end_m:.3f} m, down to {100 * seg.min_ratio:.0f} % "
        f"of the demonstrated speed ({html.escape(seg.reason)})</li>"
        for p in result.passes
        if p.timing is not None
        for seg in p.timing.slow_segments
    ]
    clearance = [
        f"<pre>{html.escape(p.clearance.summary())}</pre>" for p in result.passes if p.clearance is not None
    ]
    return (
        f"<pre>{items}</pre>"
        + "<h2>Repairs</h2>"
        + (f"<ul>{''.join(repairs)}</ul>" if repairs else "<p>none</p>")
        + "<h2>Where the plan is slower than the demonstration</h2>"
        + (f"<ul>{''.join(slow)}</ul>" if slow else "<p>nowhere</p>")
        + ("<h2>Clearance</h2>" + "".join(clearance) if clearance else "")
    )


def write_report(path: Path, result: RunResult) -> Path:
    """Write ``report.html`` for ``result`` (self-contained: plotly's JavaScript is embedded)."""
    figures = [_path_figure(result)] + [_pass_figure(result, p) for p in result.passes]
    body = "\n".join(f.to_html(full_html=False, include_plotlyjs=False) for f in figures)
    page = (
        "<!DOCTYPE html><html><head><meta charset='utf-8'>"
        f"<title>refine: {html.escape(result.problem.name)}</title>"
        f"<script>{get_plotlyjs()}</script>"
        "<style>body{font-family:sans-serif;margin:1em 2em} pre{background:#f4f4f4;padding:0.6em}</style>"
        f"</head><body><h1>{html.escape(result.problem.name)}: {html.escape(result.status)}</h1>"
        f"<p>{html.escape(result.problem.description)}</p>{_summary_html(result)}{body}</body></html>"
    )
    path.write_text(page, encoding="utf-8")
    return path
