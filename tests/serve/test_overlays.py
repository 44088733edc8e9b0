"""The robot's visual meshes the app draws: none for the registry's robots (their visual meshes are
their collision pieces), the URDF's own where they differ, read by the collision side's loader."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from refine.serve.overlays import visual_meshes

ROOT = Path(__file__).resolve().parents[2]
ABB = ROOT / "robots" / "abb_irb4600_60_205"


def _files(text: str, tag: str) -> list[str]:
    return re.findall(rf"<{tag}\b.*?<mesh filename=\"([^\"]+)\"", text, flags=re.S)


def test_a_registry_robot_draws_its_collision_pieces_as_its_visual_meshes():
    text = (ABB / "robot.urdf").read_text(encoding="utf-8")
    # the registry's URDF names the same files under <visual> as under <collision> (read here by a regex)
    assert sorted(_files(text, "visual")) == sorted(_files(text, "collision")) != []
    meshes, note = visual_meshes(ABB / "robot.urdf")
    assert meshes == []
    assert "are its collision shapes" in note


@pytest.fixture
def urdf_with_a_box_visual(tmp_path):
    import trimesh

    folder = tmp_path / "robot"
    shutil.copytree(ABB, folder)
    trimesh.creation.box(extents=[0.1, 0.2, 0.3]).export(folder / "link_1_visual.stl")
    path = folder / "robot.urdf"
    text = path.read_text(encoding="utf-8")
    first = text.index('<visual name="link_1_0">')
    end = text.index("</visual>", first)
    block = text[first:end].replace("collision/link_1_0.obj", "link_1_visual.stl")
    block = block.replace("<geometry>", '<origin xyz="0 0 0.5" rpy="0 0 0"/>\n      <geometry>', 1)
    path.write_text(text[:first] + block + text[end:], encoding="utf-8")
    return path


def test_a_urdf_with_its_own_visual_meshes_sends_them_all(urdf_with_a_box_visual):
    meshes, note = visual_meshes(urdf_with_a_box_visual)
    text = urdf_with_a_box_visual.read_text(encoding="utf-8")
    assert len(meshes) == len(_files(text, "visual")) == 7
    name, link, mesh, T = next(m for m in meshes if m[1] == "link_1")
    assert name == "link_1/link_1_0 (visual)"
    assert np.allclose(mesh.bounds[1] - mesh.bounds[0], [0.1, 0.2, 0.3])  # the box written above
    assert np.allclose(T[:3, 3], [0.0, 0.0, 0.5]) and np.allclose(T[:3, :3], np.eye(3))
    assert note.startswith("visual meshes: 7 (")


def test_a_visual_mesh_named_by_url_leaves_the_collision_shapes_drawn(urdf_with_a_box_visual):
    path = urdf_with_a_box_visual
    path.write_text(path.read_text().replace("link_1_visual.stl", "package://x/link_1.stl"), encoding="utf-8")
    meshes, note = visual_meshes(path)
    assert meshes == [] and "is a URL" in note


def test_the_recorded_demonstration_is_every_kth_sample_placed_by_the_receiver_and_the_sensor():
    """Each drawn point is T_F_S T_S_E(t) inv(T_TCP_E)'s origin, of every k-th sample (the first and
    the last kept) of the log as read, so that at most DEMO_POINTS remain."""
    import math
    from types import SimpleNamespace

    from refine.demo import read_tracker_log
    from refine.problem import load_problem
    from refine.serve.overlays import DEMO_POINTS, DemoCache, demonstration_lines

    problem = load_problem(ROOT / "problems" / "glass_adhesive" / "problem.toml")
    log = read_tracker_log(problem.demonstration)
    n = len(log.t)
    assert n > DEMO_POINTS  # the thinning is exercised
    step = math.ceil(n / DEMO_POINTS)
    rows = sorted(set(range(0, n, step)) | {n - 1})
    S, E = np.asarray(problem.frames.source_in_world), np.asarray(problem.tool.sensor_in_tcp)
    # the sensor origin's TCP: p_F = R_FS (R_SE(t) (-R_TCP_Eᵀ p_TCP_E) + p_SE(t)) + p_FS
    tcp_in_sensor = -E[:3, :3].T @ E[:3, 3]
    expected = (S[:3, :3] @ (log.rotations[rows] @ tcp_in_sensor + log.positions[rows]).T).T + S[:3, 3]
    lines = demonstration_lines(SimpleNamespace(problem=problem, passes=[]), DemoCache())
    drawn = np.column_stack([lines["recorded"][k] for k in "xyz"])
    assert drawn.shape == (len(rows), 3)
    np.testing.assert_allclose(drawn, expected, atol=1e-5)
