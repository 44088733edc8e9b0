import re
from pathlib import Path

import pytest

from refine.pipeline import run
from refine.problem import load_problem

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_report_is_one_self_contained_page_with_every_panel(tmp_path):
    result = run(load_problem(ROOT / "problems" / "ur10e_sealing"), tmp_path, report=True)
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert result.outputs["report"].name == "report.html"
    assert "<script src=" not in page  # plotly is embedded: the page opens offline
    assert page.count("Plotly.newPlot") == 2  # the 3D view and the per-pass panels
    for title in ("orientation deviation from the demonstration", "joints [deg]", "joint speeds",
                  "singularity measure", "clearance [mm]", "TCP speed [mm", "Repairs"):
        assert title in page, title
    assert re.search(r"min distance \d+\.\d mm", page)  # the clearance summary
    assert "ur10e_sealing: ok" in page
