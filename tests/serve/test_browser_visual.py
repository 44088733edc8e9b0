"""refine serve in Debian's chromium with a robot that has visual meshes of its own: drawn where the
robot's links are, and a toggle between them and the collision shapes.

The registry's ABB IRB 4600 is copied into a registry of the test's own (``REFINE_ROBOTS_DIR``) with
its ``<visual>`` elements naming the public reference meshes of the same robot
(``../shared/robot-meshes/abb_irb4600_60_205``: the same link frames), and the glass cell is served
with it. Screenshots go to tests/artifacts/serve/.
"""

from __future__ import annotations

import base64
import io
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "tests" / "artifacts" / "serve"
CHROMIUM = Path("/usr/bin/chromium")
MESHES = ROOT.parent / "shared" / "robot-meshes" / "abb_irb4600_60_205"
SOLVE_S = 240
LINKS = ("base_link", "link_1", "link_2", "link_3", "link_4", "link_5", "link_6")

playwright = pytest.importorskip("playwright.sync_api", reason="playwright is in the test extra")
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not CHROMIUM.exists(), reason="chromium is not installed (.ci/run installs it)"),
    pytest.mark.skipif(
        not MESHES.is_dir(), reason="the reference meshes (../shared/robot-meshes) are not here"
    ),
]


def _registry_with_visual_meshes(folder: Path) -> Path:
    """A registry holding the ABB whose ``<visual>`` elements name the reference meshes."""
    from lxml import etree

    robot = folder / "abb_irb4600_60_205"
    shutil.copytree(ROOT / "robots" / "abb_irb4600_60_205", robot)
    (robot / "visual").mkdir()
    urdf = robot / "robot.urdf"
    tree = etree.parse(str(urdf))
    for link in tree.getroot().iter("link"):
        for old in link.findall("visual"):
            link.remove(old)
        name = link.get("name")
        if name in LINKS:
            shutil.copy(MESHES / f"{name}.stl", robot / "visual" / f"{name}.stl")
            visual = etree.SubElement(link, "visual", name=f"{name}_mesh")
            etree.SubElement(etree.SubElement(visual, "geometry"), "mesh", filename=f"visual/{name}.stl")
    tree.write(str(urdf), xml_declaration=True, encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def server(tmp_path_factory, served):
    base = tmp_path_factory.mktemp("serve_visual")
    before = os.environ.get("REFINE_ROBOTS_DIR")
    os.environ["REFINE_ROBOTS_DIR"] = str(_registry_with_visual_meshes(base / "robots"))
    folder = base / "glass_adhesive"
    shutil.copytree(ROOT / "problems" / "glass_adhesive", folder)
    try:
        yield served("glass with visual meshes", folder)
    finally:  # stopped with the module: its robot registry is this module's
        served.stop("glass with visual meshes")
        if before is None:
            os.environ.pop("REFINE_ROBOTS_DIR", None)
        else:
            os.environ["REFINE_ROBOTS_DIR"] = before


def _scene_pixels(page) -> np.ndarray:
    from PIL import Image

    url = page.evaluate(
        "() => { const v = document.getElementById('scene').view; v.renderer.render(v.scene, v.camera);"
        " return v.renderer.domElement.toDataURL('image/png'); }"
    )
    return np.asarray(
        Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB"), dtype=float
    )


def _share_of(image: np.ndarray, colour: int) -> float:
    rgb = [(colour >> 16) & 255, (colour >> 8) & 255, colour & 255]
    return float(np.mean(np.linalg.norm(image - rgb, axis=2) < 60))


def _reference_bounds(q: np.ndarray) -> dict[str, np.ndarray]:
    """Each link's reference mesh in {F} at joints ``q``, by Pinocchio on the reference URDF: (2, 3) bounds."""
    import pinocchio
    import trimesh

    model = pinocchio.buildModelFromUrdf(str(MESHES / "reference.urdf"))
    data = model.createData()
    pinocchio.framesForwardKinematics(model, data, q)
    out = {}
    for link in LINKS:
        M = data.oMf[model.getFrameId(link)]
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = M.rotation, M.translation
        mesh = trimesh.load(MESHES / f"{link}.stl", force="mesh")
        v = trimesh.transform_points(mesh.vertices, T)
        out[link] = np.array([v.min(axis=0), v.max(axis=0)])
    return out


def test_the_robot_is_drawn_by_its_visual_meshes_where_its_links_are_and_by_its_collision_shapes_on_demand(
    server, summary, chromium
):
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    errors: list[str] = []
    page = chromium.new_page(viewport={"width": 1500, "height": 900})
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.set_default_timeout(SOLVE_S * 1000)
    page.goto(server["url"], wait_until="domcontentloaded")
    page.wait_for_function(
        "document.body.dataset.revision !== undefined && document.body.dataset.scene === document.body.dataset.revision"
    )
    note = page.inner_text("#visual-note")
    assert note.startswith("visual meshes: 7 ("), note
    assert page.is_enabled("#show-collision") and not page.is_checked("#show-collision")
    view = "document.getElementById('scene').view"
    shown = page.evaluate(f"() => {view}.robotMeshes.map((m) => [m.name, m.userData.shown, m.visible])")
    visual = [name for name, kind, visible in shown if kind == "visual" and visible]
    assert sorted(visual) == sorted(f"{link}/{link}_mesh (visual)" for link in LINKS)
    assert not any(visible for _, kind, visible in shown if kind == "collision")
    # each visual mesh drawn where Pinocchio puts the link on the reference URDF (an independent
    # description of the same robot) at the joints of the robot frame shown, the base at the origin
    from refine.report.scene import robot_frames

    result = server["session"].answer.result
    i, k = robot_frames(result)["where"][0]  # the frame the scrubber starts at
    q = result.passes[i].refinement.q[k]
    expected = _reference_bounds(np.asarray(q, dtype=float))
    drawn = page.evaluate(
        "async () => { const THREE = await import('three'); const v = document.getElementById('scene').view;"
        " v.robotMeshes.forEach((m) => m.updateMatrixWorld(true)); const out = {};"
        " v.robotMeshes.filter((m) => m.userData.shown === 'visual').forEach((m) => {"
        " const b = new THREE.Box3().setFromObject(m, true); out[m.name.split('/')[0]] = [b.min.toArray(), b.max.toArray()]; });"
        " return out; }"
    )
    for link in LINKS:
        assert np.abs(np.array(drawn[link]) - expected[link]).max() < 2e-3, link  # [m]
    page.screenshot(path=str(ARTIFACTS / "visual-meshes.png"))
    orange = _share_of(_scene_pixels(page), 0xF39C12)  # the visual meshes' colour
    assert orange > 0.005
    page.check("#show-collision")  # the collision shapes instead
    shown = page.evaluate(f"() => {view}.robotMeshes.map((m) => [m.userData.shown, m.visible])")
    assert all(visible == (kind != "visual") for kind, visible in shown)
    image = _scene_pixels(page)
    assert _share_of(image, 0xF39C12) < 0.1 * orange
    page.screenshot(path=str(ARTIFACTS / "collision-shapes.png"))
    page.uncheck("#show-collision")
    assert _share_of(_scene_pixels(page), 0xF39C12) > 0.5 * orange
    assert errors == [], errors
    page.close()
    summary.append(
        f"refine serve with visual meshes ({note}): screenshots visual-meshes.png, collision-shapes.png"
    )
