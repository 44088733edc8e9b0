"""``report.html``: one self-contained page a process engineer opens after a run.

Top to bottom: the verdict (:mod:`refine.report.verdict`: status, the figures against their
tolerances, cycle time, the files written, the repaired or failing segments); the 3D view
(:mod:`refine.report.scene`: cell, robot with its link shapes moved along the path by a slider or
the play button, the path coloured by a chosen quantity, repaired and failing waypoints marked);
the panels along the path for a chosen pass (:mod:`refine.report.panels`); then the run's summary
and where the plan is slower than the demonstration. The data travels as one JSON block and
``report.js`` draws it with Plotly; Plotly's JavaScript is embedded, so the page works offline.

The address ``report.html#scene-only`` shows the 3D view alone, filling the window.

A small script at the top of the page records uncaught errors and ``console.error`` calls into
``#js-errors`` (hidden while empty) so that a broken page says so, also to a headless browser.
"""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import TYPE_CHECKING

from plotly.offline import get_plotlyjs

from refine.report.panels import panel_data
from refine.report.scene import scene_data
from refine.report.verdict import verdict_html

if TYPE_CHECKING:
    from refine.run.result import RunResult

ERRORS_JS = """
(function () {
  var box = null;
  function note(text) {
    box = box || document.getElementById("js-errors");
    if (box) { box.hidden = false; var li = document.createElement("li"); li.textContent = text; box.appendChild(li); }
    else { (window.__pendingErrors = window.__pendingErrors || []).push(text); }
  }
  window.addEventListener("error", function (e) { note("error: " + e.message); });
  window.addEventListener("unhandledrejection", function (e) { note("unhandled rejection: " + e.reason); });
  var original = console.error;
  console.error = function () { note("console.error: " + Array.prototype.join.call(arguments, " ")); original.apply(console, arguments); };
  document.addEventListener("DOMContentLoaded", function () { (window.__pendingErrors || []).forEach(note); });
})();
"""

_CSS = """
body{font-family:system-ui,sans-serif;margin:0 2em 2em;color:#222}
h1{margin:.4em 0 .1em;font-size:1.7em} h2{font-size:1.2em;margin:1em 0 .4em}
.badge{font-size:.8em;padding:.1em .5em;border-radius:.3em;color:#fff;vertical-align:middle}
.badge.st-ok,b.st-ok{background:#2e8b57;color:#fff;padding:0 .3em} .badge.st-repaired,b.st-repaired{background:#d68910;color:#fff;padding:0 .3em}
.badge.st-infeasible,b.st-infeasible{background:#c0392b;color:#fff;padding:0 .3em}
.badge.st-timeout,b.st-timeout{background:#7f8c8d;color:#fff;padding:0 .3em}
.meaning{font-size:1.1em;margin:.2em 0 .6em}
.cols{display:flex;gap:2em;flex-wrap:wrap} .cols>div{flex:1 1 30em}
table.figures{border-collapse:collapse;width:100%} .figures td,.figures th{padding:.3em .6em;text-align:left;border-bottom:1px solid #ddd}
tr.pass td{background:#e8f6ee} tr.fail td{background:#fbe3e1;font-weight:600} tr.neutral td{background:#f6f6f6}
td.mark{font-size:1.2em} tr.pass td.mark{color:#2e8b57} tr.fail td.mark{color:#c0392b}
ul.files{padding-left:1.2em;columns:2} .kind{color:#777;font-size:.85em}
ul.segments li{margin:.3em 0;max-width:70em} #js-errors{color:#c0392b}
.controls{display:flex;gap:1em;align-items:center;flex-wrap:wrap;margin:.4em 0}
.controls input[type=range]{width:28em} #frame-label{font-family:monospace;min-width:16em}
.panels{display:grid;grid-template-columns:repeat(auto-fill,minmax(560px,1fr));gap:.5em}
pre{background:#f4f4f4;padding:.6em;white-space:pre-wrap}
body.scene-only>section:not(#scene-section){display:none} body.scene-only #scene-section>p{display:none}
"""


def _quantity_options(scene: dict) -> str:
    first = scene["paths"][0]["quantities"]
    out = []
    for key in ("deviation", "speed", "clearance", "slack"):
        entry = first[key]
        missing = entry.get("missing")
        attr = f" disabled title='{html.escape(missing)}'" if missing else ""
        label = html.escape(entry["title"]) + (f" (none: {html.escape(missing)})" if missing else "")
        out.append(f"<option value='{key}'{attr}>{label}</option>")
    return "".join(out)


def _details_html(result: RunResult, doc: dict) -> str:
    from refine.run.result import summary_lines

    summary = "\n".join(html.escape(line) for line in summary_lines(result))
    slow = [
        f"<li>{html.escape(p.name)}: s = {seg.s_start_m:.3f}-{seg.s_end_m:.3f} m, down to "
        f"{100 * seg.min_ratio:.0f} % of the demonstrated speed ({html.escape(seg.reason)})</li>"
        for p in result.passes
        if p.timing is not None
        for seg in p.timing.slow_segments
    ]
    clearance = [
        f"<pre>{html.escape(p.clearance.summary())}</pre>" for p in result.passes if p.clearance is not None
    ]
    return (
        "<section id='details'><h2>Run summary</h2>"
        f"<p>{html.escape(result.problem.description)}</p><pre>{summary}</pre>"
        + _order_html(result)
        + "<h2>Where the plan is slower than the demonstration</h2>"
        + (f"<ul>{''.join(slow)}</ul>" if slow else "<p>nowhere</p>")
        + ("<h2>Clearance</h2>" + "".join(clearance) if clearance else "")
        + _motions_html(result)
        + _controller_html(doc)
        + "</section>"
    )


def _motions_html(result: RunResult) -> str:
    """The program's motions as a table (``result.json`` ``motions``), with the program's time."""
    from refine.plan.motion import TABLE_COLUMNS, table_rows

    if not result.motions:
        return ""
    head = "".join(f"<th>{html.escape(c)}</th>" for c in TABLE_COLUMNS)
    body = "".join(
        f"<tr class='{'ok' if row['status'] == 'ok' else 'bad'}'>"
        + "".join(f"<td>{html.escape(row[c])}</td>" for c in TABLE_COLUMNS)
        + "</tr>"
        for row in table_rows(result.motions)
    )
    total = sum(m.duration_s for m in result.motions)
    return (
        "<h2>The program's motions</h2><p id='motions-note'>Every motion the program makes, each verified "
        f"(limits, clearance along the continuous motion, singularity on the lines); {total:.2f} s from home "
        "to home.</p>"
        f"<table id='motions'><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
    )


def _controller_html(doc: dict) -> str:
    """The motion as the controllers run it: the straight-line check, every target's zone, every segment's speed."""
    parts = []
    for p in doc["passes"]:
        line = p.get("line")
        if line is not None:
            change = line["max_clearance_change_m"]
            parts.append(
                f"<p>{html.escape(p['name'])}: the controller's straight TCP line "
                f"{'passes' if line['ok'] else 'fails'} ({line['samples']} samples): it differs from the "
                f"joint-linear motion by {line['max_position_difference_m'] * 1e3:.4f} mm, "
                f"{line['max_orientation_difference_deg']:.4f} deg orientation and "
                f"{line['max_joint_difference_deg']:.4f} deg of joint angle"
                + ("" if change is None else f" (clearance changes by at most {change * 1e3:.3f} mm)")
                + "".join(f"; {html.escape(v)}" for v in line["violations"])
                + ".</p>"
            )
        circular = p.get("circular_moves")
        if circular and circular["checks"]:
            checks = circular["checks"]
            parts.append(
                f"<p>{html.escape(p['name'])}: {len(circular['written'])} of {len(checks) // 2} circular "
                f"move(s) on the CAD's arcs written; in the controllers' orientation models at most "
                f"{max(c['max_cad_deviation_m'] for c in checks) * 1e3:.4f} mm from the CAD arc, "
                f"{max(c['max_axis_vs_refined_deg'] for c in checks):.2f} deg (tool axis) and "
                f"{max(c['max_rotation_vs_refined_deg'] for c in checks):.2f} deg (whole) from the refined "
                f"orientation, {max(c['max_vs_demo_deg'] for c in checks):.2f} deg from the demonstration"
                + "".join(
                    f"; waypoints {c['start']}-{c['end']} ({html.escape(c['model'])}): {html.escape(r)}"
                    for c in checks
                    for r in c["reasons"]
                )
                + ".</p>"
            )
        for kind, m in p.get("programs", {}).items():
            rows = []
            for k, (zone, dev) in enumerate(zip(m["zones"], m["zone_deviation_m"], strict=True)):
                diff = m["speed_difference_rel"][k - 1] if k > 0 else None
                rows.append(
                    f"<tr><td>{k}</td><td>{html.escape(zone)}</td><td>{dev * 1e3:.3f}</td>"
                    f"<td>{'' if diff is None else f'{diff * 100:+.2f}'}</td></tr>"
                )
            parts.append(
                f"<details><summary>{html.escape(p['name'])}, {html.escape(kind)}: largest corner deviation "
                f"{m['largest_zone_deviation_m'] * 1e3:.3f} mm (path tolerance {m['path_tolerance_m'] * 1e3:g} mm, "
                f"{m['narrowed_zones']} zone(s) narrowed); {m['speed_levels']} speed(s), largest shortfall "
                f"{m['largest_speed_shortfall_rel'] * 100:.2f} % of the planned speed (share "
                f"{m['speed_share'] * 100:g} %), {m['segments_beyond_share']} segment(s) beyond it, "
                f"{m['extra_time_s']:+.3f} s</summary><table class='zones'><tr><th>target</th><th>zone</th>"
                "<th>corner deviation [mm]</th><th>speed of the move onto it vs plan [%]</th></tr>"
                + "".join(rows)
                + "</table></details>"
            )
    if not parts:
        return ""
    return "<h2>As the controller runs it</h2>" + "".join(parts)


def _order_html(result: RunResult) -> str:
    """Which way round and from where the run follows the CAD path, and how that was chosen."""
    order = result.fused.order
    if order is None:
        return ""
    way = (
        "as drawn in the CAD file"
        if order.direction == "as_cad"
        else "against the CAD file's order (reversed)"
    )
    chosen = (
        f"found by the alignment: median distance {order.residual_as_cad_m * 1e3:.1f} mm as drawn, "
        f"{order.residual_reversed_m * 1e3:.1f} mm reversed"
        if order.direction_source == "alignment" and order.residual_as_cad_m is not None
        else "set by the problem ([cad] reverse or start_near)"
    )
    start = {
        "alignment": "where the worker started, found by the alignment",
        "problem": "set by [cad] start_near",
        "open path": "an end of the open path",
    }[order.start_source]
    return (
        f"<h2>Direction and start</h2><p id='path-order'>The run goes {html.escape(way)} "
        f"(<code>{html.escape(order.direction)}</code>, {html.escape(chosen)}) and starts "
        f"{order.start_offset_m:.3f} m along the CAD path from its first point ({html.escape(start)}).</p>"
    )


def write_report(path: Path, result: RunResult) -> Path:
    """Write ``report.html`` for ``result`` (self-contained: Plotly's JavaScript is embedded)."""
    from refine.export.result_json import result_dict

    doc = result_dict(result)
    doc["outputs"] = {k: Path(v).name for k, v in result.outputs.items() if k not in ("report", "result")}
    doc["outputs"]["result"] = "result.json"
    scene = scene_data(result)
    data = {"scene": scene, "panels": panel_data(result)}
    payload = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    passes = result.passes
    pass_select = (
        "<label>pass <select id='pass'>"
        + "".join(
            f"<option value='{i}'>{html.escape(p.name)} ({p.refinement.status})</option>"
            for i, p in enumerate(passes)
        )
        + "</select></label>"
        if len(passes) > 1
        else ""
    )
    panels = "".join(f"<div class='panel' id='panel-{pid}'></div>" for pid, _ in data["panels"]["titles"])
    script = (Path(__file__).with_name("report.js")).read_text(encoding="utf-8")
    attempt = (
        " The robot is drawn at the optimiser's best attempt: the path is not executable."
        if result.status in ("infeasible", "timeout")
        else ""
    )
    page = (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>refine: {html.escape(result.problem.name)} ({html.escape(result.status)})</title>"
        f"<script>{ERRORS_JS}</script><style>{_CSS}</style>"
        f"<script>{get_plotlyjs()}</script></head><body>"
        "<ul id='js-errors' hidden></ul>"
        f"{verdict_html(result, doc)}"
        "<section id='scene-section'><h2>The cell, the robot and the path in 3D (world frame)</h2>"
        f"<p>Drag to turn, scroll to zoom. Repaired waypoints are orange, failing ones red.{attempt}</p>"
        "<div class='controls'><button id='play' type='button'>Play</button>"
        "<input id='frame' type='range' min='0' value='0' step='1' aria-label='position along the path'>"
        "<span id='frame-label'></span>"
        f"<label>colour the path by <select id='quantity'>{_quantity_options(scene)}</select></label>"
        "<span id='quantity-note'></span></div><div id='scene'></div></section>"
        f"<section id='panels-section'><h2>Along the path</h2><div class='controls'>{pass_select}</div>"
        f"<div class='panels'>{panels}</div></section>"
        f"{_details_html(result, doc)}"
        f"<script type='application/json' id='report-data'>{payload}</script>"
        f"<script>{script}</script></body></html>"
    )
    path.write_text(page, encoding="utf-8")
    return path
