"""The report's first screen: the verdict, the figures against their tolerances, the files, the segments.

Everything on it comes from ``result.json``'s document (:func:`refine.export.result_json.result_dict`)
so the page and the file never disagree. Rows whose figure has a tolerance are green when it holds and
red when it does not; rows without one (cycle time, speed tracking) are neutral. Repaired and
infeasible segments are listed in plain words first; the solver's own wording stays in a folded
"details" box below.
"""

from __future__ import annotations

import html
import math
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from refine.run.result import RunResult

MEANING = {
    "ok": "every tolerance verified: the programs can be loaded as written",
    "repaired": "executable, verified, with extra orientation slack where the demonstration could not be held",
    "infeasible": "no executable path within the tolerances: no program was written",
    "timeout": "no verdict: the time limit ran out before an answer or a proof; no program was written",
}


def _row(name: str, value: str, limit: str, ok: bool | None) -> str:
    cls = "neutral" if ok is None else ("pass" if ok else "fail")
    mark = "" if ok is None else ("&#10004;" if ok else "&#10008;")
    return (
        f"<tr class='{cls}'><td>{html.escape(name)}</td><td>{html.escape(value)}</td>"
        f"<td>{html.escape(limit)}</td><td class='mark'>{mark}</td></tr>"
    )


def figure_rows(doc: dict[str, Any]) -> list[tuple[str, str, str, bool | None]]:
    """(figure, value, tolerance, holds) of the verdict table; ``holds`` None for figures without one."""
    m, tol = doc["metrics"], doc["tolerances"]
    rows: list[tuple[str, str, str, bool | None]] = []
    pos = m["max_position_error_m"]
    rows.append(
        (
            "TCP position error (max)",
            f"{pos * 1e3:.2g} mm",
            f"<= {tol['position_m'] * 1e3:g} mm",
            pos <= tol["position_m"],
        )
    )
    chord = doc.get("cad_chord_error")
    if chord is not None:
        where = f" ({chord['pass']})" if doc.get("n_passes", 1) > 1 else ""
        rows.append(
            (
                "TCP path from the CAD geometry (max, straight moves between targets)",
                f"{chord['max_m'] * 1e3:.3f} mm at s = {chord['s_m'] * 1e3:.0f} mm{where}",
                f"<= {chord['tolerance_m'] * 1e3:g} mm",
                chord["max_m"] <= chord["tolerance_m"] + tol["position_m"],
            )
        )
    slack = m.get("max_slack_deg") or 0.0
    dev = m["max_orientation_deviation_deg"]
    cone = tol["orientation_deg"]
    limit = f"<= {cone:g} deg" + (f" + {slack:.2f} deg repair slack" if slack > 0 else "")
    rows.append(
        (
            "orientation deviation from the demonstration (max)",
            f"{dev:.2f} deg",
            limit,
            dev <= cone + slack + 1e-6,
        )
    )
    margin = math.degrees(m["min_joint_margin_rad"])
    rows.append(
        (
            "distance of the joints to their limits (min)",
            f"{margin:.1f} deg",
            f">= {tol['joint_margin_deg']:g} deg",
            margin >= tol["joint_margin_deg"] - 1e-6,
        )
    )
    sing = m["min_singularity_measure"]
    rows.append(
        (
            "singularity measure (min)",
            f"{sing:.3f}",
            f">= {tol['singularity_margin']:g}",
            sing >= tol["singularity_margin"] - 1e-9,
        )
    )
    clear, cmargin = m.get("min_clearance_m"), tol.get("clearance_m")
    if m.get("min_cell_clearance_m") is not None or m.get("min_self_clearance_m") is not None:
        rows += _kind_rows(m, cmargin, tol.get("self_clearance_m"))  # each kind against its own margin
    elif clear is None:
        rows.append(("clearance to the cell (min)", "not checked", "no cell objects or tool shapes", None))
    else:
        ok = None if cmargin is None else clear >= cmargin - 1e-6
        rows.append(
            (
                "clearance to the cell and between links (min)",
                f"{clear * 1e3:.1f} mm",
                "collision off" if cmargin is None else f">= {cmargin * 1e3:g} mm",
                ok,
            )
        )
    cycle = m.get("cycle_time_s")
    rows.append(("cycle time", "none: not executable" if cycle is None else f"{cycle:.2f} s", "", None))
    track = m.get("speed_tracking_error_rel")
    if track is not None:
        rows.append(
            (
                "speed below the demonstration (max, outside explained slow-downs)",
                f"{track * 100:.1f} %",
                "",
                None,
            )
        )
    return rows


def segment_lines(result: RunResult) -> list[str]:
    """Plain-language lines for the repaired segments and the segments that break a tolerance."""
    lines = []
    tol = result.problem.tolerances
    for p in result.passes:
        head = f"{p.name}: " if len(result.passes) > 1 else ""
        for r in p.refinement.repairs:
            objs = f" ({', '.join(r.objects)})" if r.objects else ""
            lines.append(
                f"{head}waypoints {r.index_start}-{r.index_end} (s = {r.s_start_m * 1e3:.0f}-"
                f"{r.s_end_m * 1e3:.0f} mm): the tool turns up to {r.slack_deg:.2f} deg beyond the "
                f"{tol.orientation_deg:g} deg cone, because of the {r.reason}{objs}"
            )
        if p.refinement.status == "infeasible":
            for v in p.refinement.check.violations:
                lines.append(
                    f"{head}waypoints {v.index_start}-{v.index_end} (s = {v.s_start_m * 1e3:.0f}-"
                    f"{v.s_end_m * 1e3:.0f} mm): {v.reason}, worst {v.worst:.4g} {v.unit} where "
                    f"{v.limit:.4g} {v.unit} is allowed"
                )
    return lines


def verdict_html(result: RunResult, doc: dict[str, Any]) -> str:
    """The first screen of the report as HTML."""
    status = doc["status"]
    rows = "".join(_row(*r) for r in figure_rows(doc))
    files = [
        f"<li><a href='{html.escape(name)}'>{html.escape(name)}</a> <span class='kind'>{html.escape(kind)}</span></li>"
        for kind, name in doc["outputs"].items()
    ]
    files.append("<li><a href='report.html'>report.html</a> <span class='kind'>this page</span></li>")
    segments = segment_lines(result)
    if segments:
        title = "Repaired segments" if status == "repaired" else "Where the path fails"
        seg_html = (
            f"<h2>{title}</h2><ul class='segments'>"
            + "".join(f"<li>{html.escape(s)}</li>" for s in segments)
            + "</ul>"
        )
    else:
        seg_html = "<p class='nosegments'>No segment needed a repair.</p>" if status == "ok" else ""
    if result.placement is not None and result.placement.status != "not needed":
        seg_html += (
            "<h2>Or move the workpiece</h2>"
            f"<p class='placement'>{html.escape(result.placement.describe())}</p>"
        )
    passes = ""
    if len(result.passes) > 1:
        passes = (
            "<p>"
            + ", ".join(
                f"{html.escape(p.name)}: <b class='st-{p.refinement.status}'>{p.refinement.status}</b>"
                for p in result.passes
            )
            + "</p>"
        )
    details = (
        f"<details><summary>Solver details</summary><p>{html.escape(doc['reason'])}</p>"
        f"<p>{html.escape(str(doc['solver']['name']))} status {html.escape(str(doc['solver']['status']))}, {doc['solver']['iterations']} iterations</p>"
        "</details>"
        if doc["reason"]
        else ""
    )
    return (
        f"<section id='verdict' class='verdict st-{status}'>"
        f"<h1>{html.escape(result.problem.name)} <span class='badge st-{status}'>{status}</span></h1>"
        f"<p class='meaning'>{html.escape(MEANING.get(status, status))}</p>{passes}"
        "<div class='cols'><div><table class='figures'><thead><tr><th>figure</th><th>value</th>"
        f"<th>tolerance</th><th></th></tr></thead><tbody>{rows}</tbody></table></div>"
        f"<div><h2>Files written</h2><ul class='files'>{''.join(files)}</ul></div></div>"
        f"{seg_html}{details}</section>"
    )


def _kind_rows(
    m: dict[str, Any], cell_margin: float | None, self_margin: float | None
) -> list[tuple[str, str, str, bool | None]]:
    """The verdict rows of the cell pairs and the self pairs, each against its own margin."""
    rows = []
    for label, key, margin in (
        ("clearance to the cell (min)", "min_cell_clearance_m", cell_margin),
        ("clearance between links and tool (min)", "min_self_clearance_m", self_margin),
    ):
        d = m.get(key)
        if d is None:
            rows.append((label, "no pair checked", "", None))
            continue
        ok = None if margin is None else d >= margin - 1e-6
        rows.append(
            (label, f"{d * 1e3:.1f} mm", "collision off" if margin is None else f">= {margin * 1e3:g} mm", ok)
        )
    return rows
