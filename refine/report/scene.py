"""The data of the report's 3D view: the cell, the robot's link shapes along the path, the coloured path.

* Cell objects (boxes, cylinders, spheres, meshes) as triangle meshes in the world frame {F}.
* The robot: each link's collision shapes and the tool's shapes as triangle meshes in their own
  frame, and for :data:`ROBOT_FRAMES` waypoints along the passes the 3x4 pose of every shape in
  {F}; the page moves the robot by applying them (slider and play button).
* Per pass, the CAD path with the quantities it can be coloured by (deviation from the
  demonstration, planned speed, clearance, repair slack), the tool axis at some waypoints, and
  the repaired and the failing waypoints as marks. An infeasible pass is drawn the same way with
  the optimiser's best attempt, so the view shows where it fails.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import fcl
import numpy as np

from refine.lazy import on_first_use

if TYPE_CHECKING:
    import trimesh
else:
    trimesh = on_first_use("trimesh")  # the first mesh call imports it

if TYPE_CHECKING:
    from refine.run.result import RunResult

log = logging.getLogger(__name__)

ROBOT_FRAMES = 60
"""How many robot configurations along the path the 3D view can show."""
TOOL_AXIS_M = 0.03
"""Length of the drawn tool axis [m]."""


def rounded(a: Any, decimals: int = 5) -> list[float | None]:
    """A flat JSON-ready list, rounded, with NaN and inf as None."""
    arr = np.round(np.asarray(a, dtype=float), decimals).ravel()
    if np.all(np.isfinite(arr)):
        return arr.tolist()
    return [float(v) if np.isfinite(v) else None for v in arr]


def rounded_rows(a: Any, decimals: int = 5) -> list[list[float | None]]:
    """Each row of a 2-D array as :func:`rounded` gives it (one rounding for all rows)."""
    if not len(a):
        return []
    arr = np.round(np.asarray(a, dtype=float).reshape(len(a), -1), decimals)
    if np.all(np.isfinite(arr)):
        return arr.tolist()
    return [rounded(row, decimals) for row in arr]


def mesh_of_geometry(geometry: Any) -> trimesh.Trimesh | None:
    """A triangle mesh of an FCL box, cylinder, sphere or capsule (centred, axis z), else None."""
    if isinstance(geometry, fcl.Box):
        return trimesh.creation.box(extents=np.asarray(geometry.side, dtype=float))
    if isinstance(geometry, fcl.Cylinder):
        return trimesh.creation.cylinder(
            radius=float(geometry.radius), height=float(geometry.lz), sections=16
        )
    if isinstance(geometry, fcl.Sphere):
        return trimesh.creation.icosphere(subdivisions=1, radius=float(geometry.radius))
    if isinstance(geometry, fcl.Capsule):
        return trimesh.creation.capsule(
            height=float(geometry.lz), radius=float(geometry.radius), count=[8, 8]
        )
    return None


def _shape_mesh(shape: Any) -> trimesh.Trimesh | None:
    """A triangle mesh in the shape's own frame of a problem :class:`refine.settings.Shape`."""
    if shape.shape == "mesh":
        from refine.collision.geometry import load_mesh

        return load_mesh(shape)
    from refine.collision.geometry import fcl_geometry

    return mesh_of_geometry(fcl_geometry(shape))


def _mesh_json(name: str, mesh: trimesh.Trimesh, T: Any, kind: str) -> dict[str, Any]:
    v = trimesh.transformations.transform_points(mesh.vertices, np.asarray(T, dtype=float))
    f = np.asarray(mesh.faces)
    return {
        "name": name,
        "kind": kind,
        "x": rounded(v[:, 0]),
        "y": rounded(v[:, 1]),
        "z": rounded(v[:, 2]),
        "i": f[:, 0].tolist(),
        "j": f[:, 1].tolist(),
        "k": f[:, 2].tolist(),
    }


def cell_objects(result: RunResult) -> list[dict[str, Any]]:
    """The cell's objects as meshes in {F}."""
    out = []
    for shape in result.problem.cell:
        mesh = _shape_mesh(shape)
        if mesh is None:
            continue
        out.append(_mesh_json(shape.name, mesh, shape.pose, "workpiece" if shape.workpiece else "cell"))
    return out


def _robot_parts(result: RunResult) -> list[tuple[str, str, trimesh.Trimesh, Any]]:
    """(name, frame, mesh, frame_T_shape) of every robot link shape and tool shape."""
    parts = []
    robot = result.robot
    for shape in robot.collision_shapes():
        convex = getattr(shape, "convex", None)
        if convex is not None:
            mesh = trimesh.Trimesh(vertices=convex.vertices, faces=convex.faces, process=False)
        else:
            mesh = mesh_of_geometry(shape.geometry)
        if mesh is None:
            log.info("report: link shape %s/%s has no drawable geometry", shape.link, shape.name)
            continue
        parts.append((f"{shape.link}/{shape.name}", shape.link, mesh, shape.link_T_shape))
    for shape in result.problem.tool.collision:
        mesh = _shape_mesh(shape)
        if mesh is not None:
            parts.append((f"tool/{shape.name}", robot.spec.flange_frame, mesh, shape.pose))
    return parts


def robot_parts(result: RunResult) -> list[tuple[str, str, trimesh.Trimesh, Any]]:
    """(name, frame, mesh, frame_T_shape) of every robot link shape and tool shape."""
    return _robot_parts(result)


def robot_frames(
    result: RunResult, parts: list[Any] | None = None, meshes: bool = True, links: list[Any] | None = None
) -> dict[str, Any]:
    """The robot's shapes (local meshes) and their poses in {F} at waypoints along every pass.

    ``parts`` are :func:`robot_parts` of ``result`` when the caller holds them (a re-solve that
    kept robot and tool); ``meshes=False`` leaves their meshes out (``parts`` in the answer).
    ``links``, when given, is appended each frame's link poses in the robot's base frame (by link name).
    """
    parts = _robot_parts(result) if parts is None else parts
    base = np.asarray(result.problem.robot.base_in_world, dtype=float)
    samples = [(i, k) for i, p in enumerate(result.passes) for k in range(len(p.refinement.q))]
    pick = np.unique(np.linspace(0, len(samples) - 1, min(ROBOT_FRAMES, len(samples))).round().astype(int))
    frames, labels, where = [], [], []
    for idx in pick:
        i, k = samples[idx]
        p = result.passes[i]
        at = result.robot.link_poses(p.refinement.q[k])
        if links is not None:
            links.append(at)
        poses = np.array([(base @ at[frame] @ np.asarray(T))[:3, :].ravel() for _, frame, _, T in parts])
        frames.append(rounded_rows(poses, 5))
        labels.append(f"{p.name}, waypoint {k}" if len(result.passes) > 1 else f"waypoint {k}")
        where.append([i, int(k)])
    out: dict[str, Any] = {"frames": frames, "labels": labels, "where": where}
    if meshes:
        out["parts"] = parts_json(parts)
    return out


def parts_json(parts: list[Any]) -> list[dict[str, Any]]:
    """The meshes of :func:`robot_parts`, each in its own frame."""
    return [
        _mesh_json(name, mesh, np.eye(4), "robot" if not name.startswith("tool/") else "tool")
        for name, _, mesh, _ in parts
    ]


def path_data(result: RunResult) -> list[dict[str, Any]]:
    """Per pass: the CAD path, the colouring quantities (or why one is missing), tool axes and marks."""
    out = []
    for p in result.passes:
        pos = p.fused.positions
        check = p.refinement.check
        n = len(pos)
        quantities: dict[str, Any] = {
            "deviation": {
                "title": "deviation from the demonstration [deg]",
                "values": rounded(check.orientation_deviation_deg, 3),
            },
        }
        if p.timing is not None:
            quantities["speed"] = {
                "title": "planned TCP speed [mm/s]",
                "values": rounded(p.timing.speed * 1e3, 2),
            }
        else:
            quantities["speed"] = {
                "title": "planned TCP speed [mm/s]",
                "missing": "no timing: the pass is infeasible",
            }
        if p.clearance is not None:
            bounds = p.clearance.waypoint_measured is not None and not bool(np.all(p.clearance.waypoint_measured))
            quantities["clearance"] = {
                "title": "clearance [mm], a lower bound where not measured" if bounds else "clearance [mm]",
                "values": rounded(p.clearance.waypoint_distance_m * 1e3, 2),
            }
        else:
            quantities["clearance"] = {"title": "clearance [mm]", "missing": "no cell objects or tool shapes"}
        slack = p.refinement.slack_deg if p.refinement.slack_deg.size == n else np.zeros(n)
        quantities["slack"] = {"title": "repair slack [deg]", "values": rounded(slack, 3)}
        step = max(1, n // 60)
        tips = check.poses[::step, :3, 3]
        tails = tips - check.poses[::step, :3, 2] * TOOL_AXIS_M
        axis = np.full((len(tips) * 3, 3), np.nan)
        axis[0::3], axis[1::3] = tails, tips
        marks = []
        for r in p.refinement.repairs:
            marks.append(
                {
                    "label": f"repaired: {r.reason} ({r.slack_deg:.2f} deg)",
                    "kind": "repaired",
                    "index": list(range(r.index_start, r.index_end + 1)),
                }
            )
        if p.refinement.status == "infeasible":
            for v in check.violations:
                marks.append(
                    {
                        "label": f"fails: {v.reason}",
                        "kind": "infeasible",
                        "index": list(range(v.index_start, min(v.index_end, n - 1) + 1)),
                    }
                )
        out.append(
            {
                "name": p.name,
                "status": p.refinement.status,
                "x": rounded(pos[:, 0]),
                "y": rounded(pos[:, 1]),
                "z": rounded(pos[:, 2]),
                "s": rounded(p.fused.s, 4),
                "quantities": quantities,
                "axis": {"x": rounded(axis[:, 0]), "y": rounded(axis[:, 1]), "z": rounded(axis[:, 2])},
                "marks": marks,
            }
        )
    return out


def scene_data(result: RunResult) -> dict[str, Any]:
    """Everything the 3D view draws (module docstring)."""
    return {"cell": cell_objects(result), "robot": robot_frames(result), "paths": path_data(result)}
