"""The puzzle piece turned round: the part fixed in the world, the grinder on the flange, the same toolpath.

Expected values come from the problem files read with tomllib, the toolpath read with NumPy, the
poses made with SciPy and the part's mesh measured with trimesh, not from refine's readers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

PROBLEMS = Path(__file__).parent.parent / "problems"
TURNED = PROBLEMS / "puzzle_piece_turned"
HELD = PROBLEMS / "puzzle_piece"


def _pose(pose: dict) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", pose["rpy_deg"], degrees=True).as_matrix()  # fixed axes X-Y-Z
    T[:3, 3] = pose["xyz"]
    return T


def _toml(folder: Path) -> dict:
    return tomllib.loads((folder / "problem.toml").read_text())


def _toolpath() -> tuple[np.ndarray, np.ndarray]:
    """The CSV's points [m] and unit tool axes in the part's frame (label lines skipped)."""
    rows = [line.split(",") for line in (HELD / "puzzle_bent.csv").read_text().splitlines()]
    values = np.array([r[1:7] for r in rows if len(r) == 7 and r[1].strip()], dtype=float)
    axes = values[:, 3:]
    return values[:, :3] / 1000.0, axes / np.linalg.norm(axes, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def turned():
    from refine.problem import load_problem
    from refine.run.stages import fused_path

    problem = load_problem(TURNED)
    return problem, fused_path(problem)


def test_the_files_are_the_held_problems_own():
    for name in ("puzzle_bent.csv", "puzzle_bent.dae", "grinder_collision.dae"):
        assert (TURNED / name).read_bytes() == (HELD / name).read_bytes()


def test_the_toolpath_in_the_world_is_the_part_pose_times_the_path(turned):
    problem, fused = turned
    part_in_world = _pose(_toml(TURNED)["frames"]["cad_in_world"])
    points, axes = _toolpath()
    world = points @ part_in_world[:3, :3].T + part_in_world[:3, 3]
    world_axes = axes @ part_in_world[:3, :3].T
    assert problem.frames.cad_in_world == pytest.approx(part_in_world, abs=1e-12)
    # the resampled path starts and ends on the toolpath's end points, and every waypoint lies on
    # one of its straight pieces
    assert fused.positions[0] == pytest.approx(world[0], abs=1e-9)
    assert fused.positions[-1] == pytest.approx(world[-1], abs=1e-9)
    a, b = world[:-1], world[1:]
    d = b - a
    t = np.clip(
        np.einsum("kij,ij->ki", fused.positions[:, None] - a[None], d) / np.einsum("ij,ij->i", d, d), 0, 1
    )
    gap = np.linalg.norm(fused.positions[:, None] - (a[None] + t[..., None] * d[None]), axis=2)
    assert gap.min(axis=1).max() < 1e-9
    # the tool axis of each waypoint lies between the axes of the two points it falls between
    piece = gap.argmin(axis=1)
    z = fused.rotations[:, :, 2]
    between = np.degrees(
        np.arccos(np.clip(np.einsum("ij,ij->i", world_axes[piece], world_axes[piece + 1]), -1, 1))
    )
    off = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", z, world_axes[piece]), -1, 1)))
    assert np.all(off <= between + 1e-6)
    assert np.degrees(np.arccos(np.clip(z[0] @ world_axes[0], -1, 1))) < 1e-6


def test_it_is_the_held_problems_path_carried_by_the_part_pose():
    from refine.problem import load_problem
    from refine.run.stages import fused_path

    held = fused_path(load_problem(HELD))  # in the part's frame (the part on the flange)
    turned = fused_path(load_problem(TURNED))
    part_in_world = _pose(_toml(TURNED)["frames"]["cad_in_world"])
    assert held.positions.shape == turned.positions.shape
    assert turned.positions == pytest.approx(
        held.positions @ part_in_world[:3, :3].T + part_in_world[:3, 3], abs=1e-12
    )
    assert turned.rotations == pytest.approx(part_in_world[:3, :3] @ held.rotations, abs=1e-12)


def test_the_part_mesh_stands_under_the_path_and_its_mean_tool_axis_points_up():
    import trimesh

    spec = _toml(TURNED)
    (part,) = [o for o in spec["cell"]["objects"] if o["name"] == "part"]
    assert part["workpiece"] is True
    assert _pose(part["pose"]) == pytest.approx(_pose(spec["frames"]["cad_in_world"]), abs=1e-12)
    mesh = trimesh.load(TURNED / part["file"], force="mesh")
    mesh.apply_transform(_pose(part["pose"]))
    points, axes = _toolpath()
    T = _pose(spec["frames"]["cad_in_world"])
    _, distance, _ = trimesh.proximity.closest_point(mesh, points @ T[:3, :3].T + T[:3, 3])
    assert distance.max() < 0.005  # the edge being ground, within the grinder's 3.4 mm offset
    mean = (axes @ T[:3, :3].T).mean(axis=0)
    assert np.degrees(np.arccos(mean[2] / np.linalg.norm(mean))) < 1.0
    # the table under it, the path above the robot's base
    assert mesh.bounds[0, 2] > 0.5


def test_the_grinding_point_keeps_the_example_relation_to_the_grinder_mesh():
    held, turned = _toml(HELD), _toml(TURNED)
    (grinder,) = [o for o in held["cell"]["objects"] if o["name"] == "grinder"]
    in_world = np.linalg.inv(_pose(grinder["pose"])) @ _pose(held["tool"]["tcp_in_world"])
    (mounted,) = turned["tool"]["collision"]
    on_flange = np.linalg.inv(_pose(mounted["pose"])) @ _pose(turned["tool"]["tcp_in_flange"])
    assert on_flange == pytest.approx(in_world, abs=1e-12)
    assert turned["tool"]["axisymmetric"] and turned["tolerances"] == held["tolerances"]
    # the grinder's mesh sits outside the flange: its lowest point on the flange plane
    import trimesh

    mesh = trimesh.load(TURNED / mounted["file"], force="mesh")
    assert mesh.bounds[0, 2] + mounted["pose"]["xyz"][2] == pytest.approx(0.0, abs=5e-4)
