import json
import re
from pathlib import Path

import pytest
from lxml import html as lxml_html

from refine.problem import load_problem
from refine.report.panels import PANELS
from refine.run.write import run

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_report_is_one_self_contained_page_with_every_panel(tmp_path):
    result = run(load_problem(ROOT / "problems" / "ur10e_sealing"), tmp_path, report=True)
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert result.outputs["report"].name == "report.html"
    assert "<script src=" not in page  # plotly is embedded: the page opens offline
    assert len(page.encode()) < 6_000_000
    doc = lxml_html.fromstring(page)
    data = json.loads(doc.get_element_by_id("report-data").text_content())
    assert [t[0] for t in data["panels"]["titles"]] == [pid for pid, _ in PANELS]
    (only,) = data["panels"]["passes"]
    assert set(only["panels"]) == {pid for pid, _ in PANELS}
    assert all("lines" in panel for panel in only["panels"].values())  # an ok run with a cell fills them all
    for pid, _ in PANELS:
        assert doc.get_element_by_id(f"panel-{pid}") is not None
    # the 3D view: the three cell objects, the robot's link shapes and the tool's, one path
    scene = data["scene"]
    assert [o["name"] for o in scene["cell"]] == ["panel", "table", "fixture"]
    n_parts = len(result.robot.collision_shapes()) + len(result.problem.tool.collision)
    assert len(scene["robot"]["parts"]) == n_parts
    assert all(len(frame) == n_parts for frame in scene["robot"]["frames"])
    assert len(scene["paths"]) == 1 and len(scene["paths"][0]["x"]) == len(result.first.fused)
    verdict = doc.get_element_by_id("verdict")
    assert verdict.xpath(".//span[contains(@class,'badge')]")[0].text_content() == "ok"
    # the cell pairs and the self pairs apart, each against its own margin
    assert re.search(r"clearance to the cell \(min\)\s*\d+\.\d mm", verdict.text_content())
    assert re.search(r"clearance between links and tool \(min\)\s*\d+\.\d mm", verdict.text_content())
    assert "ur10e_sealing.script" in verdict.text_content()


def test_the_report_states_the_circular_moves_and_why_one_was_not_written():
    from refine.report.html import _controller_html

    def check(model, ok, cad_mm):
        return {
            "start": 4,
            "via": 12,
            "end": 20,
            "model": model,
            "max_cad_deviation_m": cad_mm / 1e3,
            "max_axis_vs_refined_deg": 0.4,
            "max_rotation_vs_refined_deg": 1.9,
            "max_vs_demo_deg": 2.0,
            "ok": ok,
            "reasons": [] if ok else ["circular move 0.0124 mm off the CAD arc (limit 0.01 mm)"],
        }

    doc = {
        "passes": [
            {
                "name": "pass 1",
                "line": None,
                "programs": {},
                "circular_moves": {
                    "written": [],
                    "checks": [check("slerp", False, 0.0124), check("path_frame", True, 0.0009)],
                },
            }
        ]
    }
    text = _controller_html(doc)
    assert "0 of 1 circular move(s)" in text and "0.0124 mm from the CAD arc" in text
    assert "waypoints 4-20 (slerp): circular move 0.0124 mm off the CAD arc" in text
