"""The report opens in headless Chromium without a console error, draws its 3D view and every panel."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from refine.problem import load_problem
from refine.run.write import run

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "tests" / "artifacts"
_spec = importlib.util.spec_from_file_location("report_browser", Path(__file__).with_name("browser.py"))
browser = importlib.util.module_from_spec(_spec)
sys.modules["report_browser"] = browser
_spec.loader.exec_module(browser)

CASES = {
    "ok": "ur10e_sealing",
    "repaired": "unreachable/joint_limit",
    "infeasible": "unreachable/out_of_reach",
}
PANELS = ("deviation", "joints", "speeds", "singularity", "clearance", "tcp_speed")
MAX_BYTES = 6_000_000

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(browser.chromium() is None, reason="chromium is not installed (.ci/run installs it)"),
]


@pytest.fixture(scope="module", params=list(CASES))
def report(request, tmp_path_factory):
    out = tmp_path_factory.mktemp(request.param)
    result = run(load_problem(ROOT / "problems" / CASES[request.param]), out)
    assert result.status == request.param, result.first.refinement.reason
    page = result.outputs["report"]
    return request.param, page, result, browser.check_report(page)


def test_the_page_loads_without_a_console_error_or_an_uncaught_error(report):
    case, page, _, check = report
    assert check.console == [], f"{case}: console messages {check.console}"
    errors = check.find("js-errors")
    assert errors.get("hidden") is not None and errors.text_content().strip() == ""
    body = check.dom.find("body")
    assert body.get("data-rendered") == "1", f"{case}: the page did not finish drawing"
    print(
        f"{case}: {page.stat().st_size / 1e6:.2f} MB, drawn {body.get('data-render-ms')} ms after navigation"
    )
    assert page.stat().st_size < MAX_BYTES
    assert "<script src=" not in page.read_text(encoding="utf-8")  # self-contained


def test_the_3d_view_draws_cell_robot_and_path(report):
    case, _, result, check = report
    scene = check.find("scene")
    assert scene.get("data-rendered") == "1"
    assert scene.xpath(".//canvas"), "no WebGL canvas in the 3D view"
    n_shapes = len(result.robot.collision_shapes()) + len(result.problem.tool.collision)
    # cell objects, the robot's shapes, and per pass the path and its tool axis
    assert int(scene.get("data-traces")) >= len(result.problem.cell) + n_shapes + 2 * len(result.passes)
    assert check.find("frame-label").text_content().startswith(("waypoint 0", "pass 1"))


def test_every_panel_is_drawn_or_says_why_it_is_empty(report):
    case, _, result, check = report
    for pid in PANELS:
        div = check.find(f"panel-{pid}")
        assert div.get("data-rendered") == "1", f"{case}: panel {pid} not drawn"
        assert div.xpath(".//svg"), f"{case}: panel {pid} has no plot"
        empty = div.get("data-empty")
        if empty:
            assert empty in div.text_content(), f"{case}: panel {pid} hides its note"
        else:
            assert int(div.get("data-traces")) > 0 and div.xpath(
                ".//*[contains(@class, 'scatterlayer')]//path"
            )
    timed = result.first.timing is not None
    assert (check.find("panel-speeds").get("data-empty") is None) == timed
    joints = check.find("panel-joints")
    assert int(joints.get("data-traces")) >= result.robot.nq  # one line per joint, limits beside


def test_the_first_screen_states_the_verdict_and_is_kept_as_a_screenshot(report):
    case, page, result, check = report
    verdict = check.find("verdict")
    assert verdict.xpath(".//span[contains(@class, 'badge')]")[0].text_content() == case
    rows = verdict.xpath(".//table[@class='figures']/tbody/tr")
    classes = [r.get("class") for r in rows]
    assert len(rows) >= 6 and set(classes) <= {"pass", "fail", "neutral"}
    if case == "ok":
        assert "fail" not in classes
    segments = verdict.xpath(".//ul[@class='segments']/li")
    if case == "repaired":
        assert len(segments) == sum(len(p.refinement.repairs) for p in result.passes) > 0
    if case == "infeasible":
        assert segments and "fail" in classes
    written = [a.get("href") for a in verdict.xpath(".//ul[@class='files']//a")]
    assert set(p.name for p in result.outputs.values() if p.name != "result.json") <= set(written)
    for name, anchor in (("first-screen", ""), ("3d", "scene-only")):
        png = browser.screenshot(page, ARTIFACTS / f"report-{case}-{name}.png", anchor)
        assert png.stat().st_size > 10_000
        print(f"screenshot {png}")
