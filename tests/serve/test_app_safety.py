"""The app's guard: the access token with --host, the loopback names without, other sites' pages,
and no file outside the output folder served (no solve runs: the app's lifespan is not entered)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from refine.serve.app import create_app
from refine.serve.session import Session

ROOT = Path(__file__).resolve().parents[2]
TOKEN = "s3cret-token-for-the-test"
ROUTES = ("/", "/page.js", "/scene3d.js", "/three/TransformControls.js", "/plotly.js", "/api/diff")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    where = tmp_path_factory.mktemp("serve-safety") / "glass"
    shutil.copytree(ROOT / "problems" / "glass_adhesive", where)
    (where / "out").mkdir()
    (where / "out" / "result.json").write_text("{}", encoding="utf-8")
    (where / "out" / "elsewhere.txt").symlink_to(where / "problem.toml")  # a link out of the folder
    return where


@pytest.fixture(scope="module")
def session(folder):
    s = Session(folder)
    yield s
    s.close()


def test_with_a_token_every_route_and_the_websocket_need_it(session, folder):
    client = TestClient(create_app(session, folder / "out", token=TOKEN), base_url="http://10.0.0.5:8000")
    for route in ROUTES:
        client.cookies.clear()  # the page's answer sets the token's cookie
        refused = client.get(route)
        assert refused.status_code == 403, route
        assert "access token" in refused.text
        assert client.get(route, params={"token": "wrong"}).status_code == 403
        assert client.get(route, headers={"X-Refine-Token": TOKEN}).status_code == 200, route
        assert client.get(route, params={"token": TOKEN}).status_code == 200, route
    client.cookies.clear()
    assert client.post("/api/write").status_code == 403
    assert client.post("/api/change", json={"changes": {"tolerances.orientation_deg": 2}}).status_code == 403
    assert session.revision == 0  # nothing reached the session
    with pytest.raises(WebSocketDisconnect) as closed:
        with client.websocket_connect("/ws") as ws:
            ws.receive_text()
    assert closed.value.code == 1008
    page = client.get("/", params={"token": TOKEN})
    assert "refine_token" in page.headers["set-cookie"] and "samesite=strict" in page.headers["set-cookie"].lower()
    assert client.get("/plotly.js").status_code == 200  # the page's own requests carry the cookie


def test_without_a_token_only_the_loopback_names_are_answered(session, folder):
    app = create_app(session, folder / "out")
    assert TestClient(app, base_url="http://127.0.0.1:8000").get("/").status_code == 200
    assert TestClient(app, base_url="http://localhost:8000").get("/page.js").status_code == 200
    rebound = TestClient(app, base_url="http://attacker.example:8000").get("/")
    assert rebound.status_code == 403 and "loopback" in rebound.text


def test_a_page_of_another_site_may_not_call_the_app(session, folder):
    client = TestClient(create_app(session, folder / "out"), base_url="http://127.0.0.1:8000")
    other = {"Origin": "http://attacker.example"}
    assert client.post("/api/write", headers=other).status_code == 403
    assert client.get("/api/diff", headers={"Origin": "http://127.0.0.1:8000"}).status_code == 200


@pytest.mark.parametrize(
    "name", ["../problem.toml", "..%2Fproblem.toml", "%2Fetc%2Fpasswd", "elsewhere.txt", "missing.json"]
)
def test_no_file_outside_the_output_folder_is_served(session, folder, name):
    client = TestClient(create_app(session, folder / "out"), base_url="http://127.0.0.1:8000")
    answer = client.get(f"/files/{name}")
    assert answer.status_code == 404, name
    assert "glass_adhesive" not in answer.text  # not the problem file's text


@pytest.mark.parametrize(
    "name",
    ["..%2Fapp.py", "LICENSE.js", "three.module.js", "%2E%2E%2Fsession.py", "lines/..%2F..%2Fapp.py", "lines/Wireframe.js"],
)
def test_only_the_pages_own_scripts_are_served_from_the_package(session, folder, name):
    client = TestClient(create_app(session, folder / "out"), base_url="http://127.0.0.1:8000")
    assert client.get(f"/three/{name}").status_code == 404, name
    three = client.get("/three/three.module.min.js")
    assert three.status_code == 200 and three.headers["content-type"].startswith("text/javascript")
    assert "Three.js Authors" in three.text[:300]
    line = client.get("/three/lines/Line2.js")  # three.js's fat lines, which import each other as ../lines/
    assert line.status_code == 200 and "class Line2 extends LineSegments2" in line.text


def test_a_file_written_there_is_served(session, folder):
    client = TestClient(create_app(session, folder / "out"), base_url="http://127.0.0.1:8000")
    assert client.get("/files/result.json").text == "{}"


def test_a_bad_change_is_answered_with_the_key_and_unit(session, folder):
    client = TestClient(create_app(session, folder / "out"), base_url="http://127.0.0.1:8000")
    answer = client.post("/api/change", json={"changes": {"tolerances.orientation_deg": 0.0}})
    assert answer.status_code == 400
    assert "tolerances.orientation_deg" in answer.json()["error"] and "deg" in answer.json()["error"]
    assert client.post("/api/change", content=b"not json").status_code == 400
    assert session.revision == 0


@pytest.mark.parametrize(
    "name",
    ["../glass/problem.toml", "/etc/passwd", "measurements/../../x.liberty", "link.liberty", "", "nothere.liberty"],
)
def test_a_calibration_log_outside_the_problem_folder_is_refused(session, folder, name, tmp_path_factory):
    outside = tmp_path_factory.mktemp("outside") / "pivot.liberty"
    shutil.copy(ROOT / "problems" / "glass_calibrated" / "measurements" / "pivot.liberty", outside)
    if not (folder / "link.liberty").exists():
        (folder / "link.liberty").symlink_to(outside)  # a link from inside the folder to outside it
    client = TestClient(create_app(session, folder / "out"), base_url="http://127.0.0.1:8000")
    answer = client.post("/api/calibrate", json={"kind": "pivot", "file": name, "rate_hz": 60})
    assert answer.status_code == 400, name
    assert "problem folder" in answer.json()["error"]
    points = client.post(  # a points file is named the same way
        "/api/calibrate", json={"kind": "receiver", "file": "demo.liberty", "points": name, "rate_hz": 60}
    )
    assert points.status_code == 400 and "problem folder" in points.json()["error"], name


def test_a_pivot_log_in_the_folder_is_fitted_to_the_generators_tip(session, folder):
    shutil.copytree(ROOT / "problems" / "glass_calibrated" / "measurements", folder / "measurements", dirs_exist_ok=True)
    client = TestClient(create_app(session, folder / "out"), base_url="http://127.0.0.1:8000")
    answer = client.post(
        "/api/calibrate", json={"kind": "pivot", "file": "measurements/pivot.liberty", "rate_hz": 60}
    )
    assert answer.status_code == 200, answer.text
    fit = answer.json()
    # the simulated tip (problems/glass_calibrated/README.md, from generate.py): 25.98, 15.00, -250.00 mm
    tip_mm = [v * 1e3 for v in fit["values"]["tip_in_sensor_m"]]
    assert max(abs(a - b) for a, b in zip(tip_mm, [25.98, 15.00, -250.00], strict=True)) < 0.5
    assert len(fit["rejected"]) == 4  # the generator's four spikes
    assert len(fit["residuals_mm"]) == 600
    assert set(fit["change"]) == {"tool.sensor_in_tcp"}
    assert session.revision == 0  # a fit changes nothing until it is accepted
    bad = client.post("/api/calibrate", json={"kind": "pivot", "file": "measurements/pivot.liberty", "rate_hz": 0})
    assert bad.status_code == 400 and "Hz" in bad.json()["error"]


TRUTH = ROOT / "problems" / "glass_adhesive"  # the frames the measurements were simulated from


@pytest.mark.parametrize(
    ("request_", "key", "xyz_m", "tol_m", "rejected"),
    [
        # the tip resting on six fixture points, the fourth touched 20 mm off (generate.py)
        (
            {"kind": "receiver", "file": "measurements/touch.liberty", "points": "measurements/fixture_points.csv",
             "rate_hz": 60},
            "frames.source_in_world", [1.30, -0.82, 0.72], 0.002, ["F4"],
        ),
        # the six-point TCP method: the nozzle 350 mm along the flange z axis
        ({"kind": "tcp", "readings": "measurements/tcp.csv", "six_point": True}, "tool.tcp_in_flange",
         [0.0, 0.0, 0.35], 0.0005, []),
        # the nozzle touched onto five points of the glass
        ({"kind": "workpiece", "readings": "measurements/workpiece.csv", "points": "measurements/glass_points.csv"},
         "frames.cad_in_world", [1.30, 0.0, 0.60], 0.0005, []),
    ],
)
def test_receiver_tcp_and_touched_points_are_fitted_to_the_frames_they_were_simulated_from(
    session, folder, request_, key, xyz_m, tol_m, rejected
):
    shutil.copytree(ROOT / "problems" / "glass_calibrated" / "measurements", folder / "measurements", dirs_exist_ok=True)
    client = TestClient(create_app(session, folder / "out"), base_url="http://127.0.0.1:8000")
    answer = client.post("/api/calibrate", json=request_)
    assert answer.status_code == 200, answer.text
    fit = answer.json()
    assert fit["key"] == key and set(fit["change"]) == {key}
    got = fit["change"][key]["xyz"]
    assert max(abs(a - b) for a, b in zip(got, xyz_m, strict=True)) < tol_m, got
    names = fit["labels"] or [str(k) for k in range(len(fit["residuals_mm"]))]
    assert [names[k] for k in fit["rejected"]] == rejected
    assert len(fit["residuals_mm"]) >= 4 and fit["rms_residual_mm"] < 1.0
    assert session.revision == 0  # nothing changes until the fit is accepted


def test_a_write_that_fails_leaves_the_problem_file_as_it_was_and_keeps_the_changes(folder, monkeypatch):
    import refine.run.write
    from refine.errors import RefineError

    s = Session(folder)
    s.solver.stop()  # no solve: only the change's check and the write matter here
    try:
        before = s.path.read_text(encoding="utf-8")
        s.change({"tolerances.orientation_deg": 2.5})

        def failing(problem, out_dir):
            assert "orientation_deg = 2.5" in s.path.read_text(encoding="utf-8")  # saved before the run
            raise RefineError("the disk is full (a planted failure)")

        monkeypatch.setattr(refine.run.write, "run", failing)
        answer = TestClient(create_app(s, folder / "out"), base_url="http://127.0.0.1:8000").post("/api/write")
        assert answer.status_code == 400 and "disk is full" in answer.json()["error"]
        assert s.path.read_text(encoding="utf-8") == before
        assert s.changes == {"tolerances.orientation_deg": 2.5}
        assert "+orientation_deg = 2.5" in s.diff()
    finally:
        s.close()
