"""The page of ``refine serve``: the verdict, the controls and the 3D view; ``page.js`` draws it.

The page carries no data of its own: ``page.js`` opens the websocket, shows every state the server
sends (the verdict as the report draws it, the scene, the values in the controls) and sends the
changes; ``scene3d.js`` draws the cell with three.js and holds the gizmo. three.js is shipped in
``refine/serve/three/`` and Plotly's JavaScript (the calibration's residual plot) comes from the
installed ``plotly`` package (loaded when the first calibration is fitted, not with the page),
both served by the app, so the page works without a network. Uncaught errors and ``console.error``
calls are listed in ``#js-errors`` (hidden while empty), as in the report.
"""

from __future__ import annotations

import html
from pathlib import Path

from refine.serve.edits import SCALARS

HERE = Path(__file__).parent

LABELS: dict[str, str] = {
    "tolerances.orientation_deg": "orientation cone",
    "tolerances.joint_margin_deg": "joint margin",
    "tolerances.singularity_margin": "singularity margin",
    "collision.margin_m": "clearance to the cell",
    "collision.self_margin_m": "clearance between links",
    "robot.velocity_scale": "speed scale (share of the joint speeds)",
    "repair.placement.translate_m": "placement search: largest shift",
    "repair.placement.rotate_deg": "placement search: largest turn",
}
"""The controls' labels."""

FRAMES: dict[str, str] = {
    "frames.cad_in_world": "CAD frame in the world (cad_in_world)",
    "frames.source_in_world": "tracker receiver in the world (source_in_world)",
    "tool.tcp_in_flange": "TCP in the flange (tcp_in_flange)",
    "tool.sensor_in_tcp": "tracker sensor in the TCP frame (sensor_in_tcp)",
    "robot.base_in_world": "robot base in the world (base_in_world)",
}
"""The frames' labels."""

_CSS = """
body{font-family:system-ui,sans-serif;margin:0;color:#222;display:flex;height:100vh}
#side{width:36em;overflow:auto;padding:0 1em 1em;border-right:1px solid #ccc;font-size:.9em}
#main{flex:1;display:flex;flex-direction:column;min-width:0} #scene{flex:1;min-height:400px}
h1{margin:.4em 0 .1em;font-size:1.4em} h2{font-size:1.05em;margin:.8em 0 .3em}
.badge{font-size:.8em;padding:.1em .5em;border-radius:.3em;color:#fff}
.st-ok .badge,.badge.st-ok{background:#2e8b57} .badge.st-repaired{background:#d68910}
.badge.st-infeasible{background:#c0392b}
table.figures{border-collapse:collapse;width:100%} .figures td,.figures th{padding:.2em .4em;text-align:left;border-bottom:1px solid #ddd}
tr.pass td{background:#e8f6ee} tr.fail td{background:#fbe3e1;font-weight:600} tr.neutral td{background:#f6f6f6}
#verdict .cols>div:nth-child(2){display:none}
ul.segments li{margin:.3em 0;cursor:pointer} ul.segments li:hover{text-decoration:underline}
#state{font-family:monospace;margin:.4em 0} #state.busy{color:#d68910}
#error{color:#fff;background:#c0392b;padding:.4em;border-radius:.3em} #js-errors{color:#c0392b}
.row{display:flex;gap:.4em;align-items:center;margin:.15em 0} .row label{flex:1}
.row input.scalar{width:7em} .pose input{width:5.2em} .unit{color:#777;width:2.5em}
.controls{display:flex;gap:.6em;align-items:center;flex-wrap:wrap;padding:.3em .6em}
.controls input[type=range]{width:20em} #frame-label{font-family:monospace;min-width:12em}
pre#diff{background:#f4f4f4;padding:.5em;white-space:pre-wrap;max-height:20em;overflow:auto}
button{margin:.2em .2em .2em 0} .row[hidden]{display:none} pre#cal-lines{white-space:pre-wrap} .note{color:#777}
#scene{position:relative;overflow:hidden} #scene canvas{display:block}
#hover{position:absolute;pointer-events:none;background:rgba(255,255,255,.92);border:1px solid #999;
padding:.2em .4em;margin:0;font-size:.8em} #hover[hidden]{display:none}
ul#motions{display:flex;flex-wrap:wrap;gap:.3em;list-style:none;padding:0;margin:.2em 0}
li.motion{cursor:pointer;padding:.1em .4em;border:1px solid #8e44ad;border-radius:.3em}
li.motion.st-failed{border-color:#c0392b;color:#c0392b} li.motion.selected{background:#8e44ad;color:#fff}
pre#motion-figures{margin:.2em 0;font-size:.85em} #motion-box{padding:0 .6em}
.ramp{display:inline-block;width:8em;height:.8em;margin:0 .3em;vertical-align:middle;
background:linear-gradient(90deg,#440154,#3b528b,#21918c,#5ec962,#fde725)}
"""


def _scalar_rows() -> str:
    rows = []
    for key, unit in SCALARS.items():
        rows.append(
            f"<div class='row'><label for='{key}'>{html.escape(LABELS[key])}</label>"
            f"<input type='text' inputmode='decimal' id='{key}' data-key='{key}' class='scalar'>"
            f"<span class='unit'>{html.escape(unit)}</span></div>"
        )
    return "".join(rows)


def _frame_rows() -> str:
    rows = []
    for key, label in FRAMES.items():
        cells = "".join(
            f"<input type='text' inputmode='decimal' data-key='{key}' data-part='{part}' data-axis='{i}' "
            f"aria-label='{key} {part}[{i}]'>"
            for part in ("xyz", "rpy_deg")
            for i in range(3)
        )
        rows.append(
            f"<div class='pose' id='pose-{key}'><div>{html.escape(label)}: x y z [m], "
            f"rx ry rz [deg]</div><div>{cells}</div></div>"
        )
    return "".join(rows)


def _move_rows() -> str:
    spec = (
        ("x", "xyz", 0, "mm", 800),
        ("y", "xyz", 1, "mm", 800),
        ("z", "xyz", 2, "mm", 800),
        ("turn about z", "rpy_deg", 2, "deg", 45),
    )
    return "".join(
        f"<div class='row'><label for='move-{name}'>{name}</label>"
        f"<input type='range' id='move-{name.split()[0]}' class='move' data-part='{part}' data-axis='{i}' "
        f"min='-{limit}' max='{limit}' step='1' value='0'>"
        f"<output id='move-{name.split()[0]}-value'>0</output><span class='unit'>{unit}</span></div>"
        for name, part, i, unit, limit in spec
    )


CALIBRATIONS: dict[str, tuple[str, str]] = {
    "pivot": ("pivot: the tip swung about a divot (tracker log)", "log"),
    "receiver": ("receiver: the tip resting on known points (tracker log + points)", "log points"),
    "trace": ("receiver: the tip traced along the CAD path (tracker log)", "log"),
    "tcp": ("TCP: the robot's tip on one point from four or more poses (robot readings)", "readings six"),
    "workpiece": (
        "workpiece: the robot's TCP touched onto CAD points (robot readings + points)",
        "readings points",
    ),
}
"""The calibrations the page offers (:data:`refine.serve.calibration.KINDS`): label and the inputs shown."""


def _calibration_options() -> str:
    return "".join(
        f"<option value='{kind}' data-inputs='{inputs}'>{html.escape(label)}</option>"
        for kind, (label, inputs) in CALIBRATIONS.items()
    )


GIZMO: dict[str, str] = {
    "": "nothing",
    "move": "the workpiece (CAD path, receiver, workpiece objects; turns about z)",
    "frames.cad_in_world": "cad_in_world (the CAD path alone)",
    "frames.source_in_world": "source_in_world (the receiver alone)",
    "tool.tcp_in_flange": "tcp_in_flange (the TCP, at the robot shown)",
    "robot.base_in_world": "the robot base (base_in_world)",
}
"""What the 3D gizmo can drag: the key it changes and its label."""


def _gizmo_options() -> str:
    return "".join(f"<option value='{k}'>{html.escape(v)}</option>" for k, v in GIZMO.items())


def page_html(title: str, errors_js: str) -> str:
    """The whole page (its script and Plotly are separate requests)."""
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>refine serve: {html.escape(title)}</title>"
        f"<script>{errors_js}</script><style>{_CSS}</style>"
        '<script type=\'importmap\'>{"imports": {"three": "./three/three.module.min.js", '
        '"three/addons/": "./three/"}}</script></head><body>'
        "<div id='side'><ul id='js-errors' hidden></ul>"
        "<div id='state'>connecting...</div><div id='error' hidden></div>"
        "<div id='verdict-box'></div><div id='demo-quality' hidden></div>"
        "<h2>Move the workpiece (the CAD path, the receiver and the workpiece objects together)</h2>"
        f"{_move_rows()}"
        f"<h2>Tolerances, margins, speed</h2>{_scalar_rows()}"
        f"<h2>Frames</h2>{_frame_rows()}"
        "<h2>Calibration: measurement files in the problem folder</h2>"
        "<div class='row'><label for='cal-kind'>measurement</label><select id='cal-kind'>"
        f"{_calibration_options()}</select></div>"
        "<div class='row cal-log'><label for='cal-file'>tracker log (path in the problem folder)</label>"
        "<input type='text' id='cal-file' placeholder='measurements/pivot.liberty'></div>"
        "<div class='row cal-log'><label for='cal-format'>log format</label><select id='cal-format'>"
        "<option>liberty_ascii</option><option>liberty_binary</option><option>csv</option></select></div>"
        "<div class='row cal-log'><label for='cal-rate'>sample rate of the log</label>"
        "<input type='text' inputmode='decimal' id='cal-rate' value='240'><span class='unit'>Hz</span></div>"
        "<div class='row cal-readings' hidden><label for='cal-readings'>robot readings (CSV of joints [deg] "
        "or flange poses)</label><input type='text' id='cal-readings' placeholder='measurements/tcp.csv'></div>"
        "<div class='row cal-six' hidden><label for='cal-six'>six-point method (the last two readings on +z "
        "and +x): measures the orientation too</label><input type='checkbox' id='cal-six'></div>"
        "<div class='row cal-points' hidden><label for='cal-points'>touched points (CSV name,x,y,z [m])</label>"
        "<input type='text' id='cal-points' placeholder='measurements/fixture_points.csv'></div>"
        "<button id='cal-fit' type='button'>Fit</button>"
        "<button id='cal-accept' type='button' disabled>Accept into the problem</button>"
        "<pre id='cal-lines' hidden></pre><div id='cal-plot'></div>"
        "<h2>Save and write</h2>"
        "<button id='reset' type='button'>Undo all changes</button>"
        "<button id='show-diff' type='button'>Show the changes to problem.toml</button>"
        "<button id='write' type='button' disabled>Save problem.toml and write the outputs</button>"
        "<pre id='diff' hidden></pre><div id='written'></div></div>"
        "<div id='main'><div class='controls'><button id='play' type='button'>Play</button>"
        "<input id='frame' type='range' min='0' value='0' step='1' aria-label='position along the path'>"
        "<span id='frame-label'></span>"
        "<label>colour the path by <select id='quantity'>"
        "<option value='deviation'>deviation from the demonstration [deg]</option>"
        "<option value='clearance'>clearance [mm]</option>"
        "<option value='slack'>repair slack [deg]</option>"
        "<option value='speed'>planned TCP speed [mm/s]</option></select></label>"
        "<span id='colour-bar' hidden><span id='colour-lo'></span><span class='ramp'></span>"
        "<span id='colour-hi'></span></span><span id='quantity-note'></span></div>"
        "<div class='controls'><label>drag in the scene <select id='gizmo'>"
        f"{_gizmo_options()}</select></label><select id='gizmo-mode' aria-label='gizmo mode'>"
        "<option value='translate'>move</option><option value='rotate'>turn</option></select>"
        "<span class='note'>(the numbers on the left follow; a drag re-solves as it goes)</span></div>"
        "<div class='controls'><span>show</span>"
        "<label><input type='checkbox' id='show-motions' checked> the planned motions (purple)</label>"
        "<label><input type='checkbox' id='show-recorded' checked> the demonstration as recorded (green: "
        "the tracker's positions, before the correction of its distortion)</label>"
        "<label><input type='checkbox' id='show-aligned'> the demonstration as the fusion uses it (brown: "
        "at each waypoint's matched time, the tracker's distortion corrected)</label>"
        "<label id='collision-toggle' hidden><input type='checkbox' id='show-collision' disabled> the robot's "
        "collision shapes instead of "
        "its visual meshes</label>"
        "<span id='visual-note' class='note'></span></div>"
        "<div id='scene'><pre id='hover' hidden></pre></div>"
        "<div id='motion-box'><h2>Planned motions (a click selects one)</h2>"
        "<p id='motions-none' class='note' hidden>no motions: a pass is not executable</p>"
        "<ul id='motions'></ul><pre id='motion-figures' hidden></pre></div></div>"
        "<script type='module' src='page.js'></script></body></html>"
    )


def page_script() -> str:
    """``page.js``."""
    return (Path(__file__).with_name("page.js")).read_text(encoding="utf-8")


MODULES: dict[str, Path] = {
    "scene3d.js": HERE / "scene3d.js",
    **{
        name: HERE / "three" / name
        for name in ("three.module.min.js", "OrbitControls.js", "TransformControls.js")
    },
    **{
        f"lines/{name}.js": HERE / "three" / "lines" / f"{name}.js"
        for name in ("Line2", "LineGeometry", "LineMaterial", "LineSegments2", "LineSegmentsGeometry")
    },
}
"""The scripts the page imports, by the name it asks for: the 3D view and three.js with its fat lines
(``lines/``: lines of a width in pixels, which WebGL's own lines do not have) (MIT, shipped in
``refine/serve/three/`` with its licence, so the page needs no network)."""


def module_script(name: str) -> str:
    """The text of the page's module ``name`` (only the names of :data:`MODULES`).

    Raises:
        KeyError: any other name.
    """
    return MODULES[name].read_text(encoding="utf-8")
