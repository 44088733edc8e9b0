"""What the app draws beside the path: every planned motion and the demonstration, recorded and aligned.

* :func:`motion_lines`: for every motion of the run (``result.motions``, in the program's order,
  the same list as ``result.json``'s ``motions``), the TCP's track in {F} [m] (an air move's
  joint-interpolated rows sampled :data:`AIR_SAMPLES` times between two rows, a line's or the
  path's rows thinned to at most :data:`MOTION_POINTS`), its via points' TCP, its status and the
  figures the page lists when the motion is selected.
* :func:`demonstration_lines`: the demonstrated TCP in {F} [m] as the tracker log records it
  (every sample, thinned to at most :data:`DEMO_POINTS`, the first always kept, through the
  problem's ``source_in_world`` and ``sensor_in_tcp``: the tracker's positions as measured, with
  their distortion) and as the fusion uses it (``FusedPath.demo_positions``: the cleaned
  demonstration at the time matched to each waypoint, ``t_demo``, after the fusion's tracker
  position correction, one point per waypoint; its gap to the CAD point is the fusion's
  residual). The log is read once per file and settings and kept (:class:`DemoCache`).
"""

from __future__ import annotations

import math
import threading
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from refine.report.scene import rounded

AIR_SAMPLES = 8
"""TCP points drawn per joint-interpolated step of an air move (between two of its rows)."""
MOTION_POINTS = 200
"""Most TCP points drawn for one line or path motion."""
DEMO_POINTS = 3000
"""Most points drawn for the recorded demonstration."""


def _thin(n: int, most: int) -> np.ndarray:
    """Indices 0..n-1, every k-th so at most ``most`` remain, the first and last kept."""
    if n <= most:
        return np.arange(n)
    return np.unique(np.r_[np.arange(0, n, math.ceil(n / most)), n - 1])


def _xyz(p: np.ndarray) -> dict[str, list[float | None]]:
    return {"x": rounded(p[:, 0]), "y": rounded(p[:, 1]), "z": rounded(p[:, 2])}


def _dense_rows(m: Any) -> np.ndarray:
    """The joint rows the TCP passes through: an air move's rows joint-interpolated, others thinned."""
    q = np.asarray(m.q, dtype=float)
    if m.kind in ("home", "link", "return") and len(q) > 1:
        w = np.linspace(0.0, 1.0, AIR_SAMPLES + 1)[:-1, None]
        steps = [a + w * (b - a) for a, b in zip(q[:-1], q[1:], strict=True)]
        return np.vstack([*steps, q[-1:]])
    return q[_thin(len(q), MOTION_POINTS)]


def _mm(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x * 1e3:.1f} mm"


def motion_figures(m: Any) -> list[str]:
    """The lines the page shows for a selected motion (units in each)."""
    lines = [
        f"{m.name} ({m.kind}): {m.status}",
        f"duration {m.duration_s:.2f} s, planned by {m.planner} in {m.planner_time_s:.2f} s",
        f"via points {len(m.via)}",
        f"least clearance {_mm(m.min_clearance_m)}"
        + (f" ({m.closest[0]} to {m.closest[1]})" if m.closest[0] else ""),
        f"least joint margin {math.degrees(m.min_joint_margin_rad):.1f} deg"
        if math.isfinite(m.min_joint_margin_rad)
        else "least joint margin -",
    ]
    if m.line_deviation_m is not None:
        lines.append(f"largest distance from the straight line {_mm(m.line_deviation_m)}")
    lines += [f"fails: {i.cause}: {i.detail}" for i in m.issues]
    lines += [f"the direct joint move: {i.cause}: {i.detail}" for i in m.direct_issues]
    return lines


def motion_lines(result: Any) -> list[dict[str, Any]]:
    """Every motion of ``result`` as the page draws it (module docstring)."""
    if not result.motions:
        return []
    from refine.robot.kinematics import TcpKinematics

    problem = result.problem
    kin = TcpKinematics(result.robot, problem.robot.base_in_world, problem.tool.tcp_in_flange)
    out = []
    for m in result.motions:
        track = kin.poses(_dense_rows(m))[:, :3, 3]
        via = m.via
        via_p = kin.poses(np.asarray(via, dtype=float))[:, :3, 3] if len(via) else np.zeros((0, 3))
        out.append(
            {
                "name": m.name,
                "kind": m.kind,
                "status": m.status,
                **_xyz(track),
                "via": _xyz(via_p),
                "figures": motion_figures(m),
            }
        )
    return out


class DemoCache:
    """The tracker log and the robot's visual meshes, each read once per file (a file changed is read again).

    The recorded demonstration's line is drawn again only when the log or the frames placing it change.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._key: str | None = None
        self._log: Any = None
        self._recorded: tuple[Any, Any, dict[str, Any]] | None = None  # the recorded line last drawn, by its inputs

    def log(self, settings: Any) -> Any:
        """The tracker log of ``settings`` (``problem.demonstration``) as read, before cleaning."""
        from refine.demo import read_tracker_log

        path = settings.file
        key = repr((settings, path.stat().st_mtime_ns if path.exists() else None))
        with self._lock:
            if self._key != key or self._log is None:
                self._log, self._key = read_tracker_log(settings), key
            return self._log

    def visual(self, robot: Any) -> tuple[list[Any], str]:
        """:func:`visual_meshes` of ``robot``'s URDF, read once per file."""
        path = Path(robot.spec.urdf)
        key = (str(path), path.stat().st_mtime_ns if path.exists() else None)
        with self._lock:
            if getattr(self, "_visual_key", None) != key:
                self._visual, self._visual_key = visual_meshes(path), key
            return self._visual


def demonstration_lines(result: Any, cache: DemoCache) -> dict[str, Any]:
    """The demonstration recorded and aligned, in {F} (module docstring); empty without a tracker log."""
    problem = result.problem
    cad = problem.cad
    if problem.demonstration is None or (cad is not None and cad.format in ("pathml", "toolpath")):
        return {}
    from refine.fuse.align import demo_tcp_poses

    raw = cache.log(problem.demonstration)
    source, sensor = np.asarray(problem.frames.source_in_world), np.asarray(problem.tool.sensor_in_tcp)
    key = (id(raw), source.tobytes(), sensor.tobytes())  # the log as read, the frames it is placed by
    with cache._lock:
        held = cache._recorded if cache._recorded is not None and cache._recorded[0] == key else None
    if held is None:
        keep = _thin(len(raw.t), DEMO_POINTS)  # only the samples drawn are placed
        shown = replace(
            raw, t=raw.t[keep], positions=raw.positions[keep], rotations=raw.rotations[keep], device_error=None
        )
        recorded = demo_tcp_poses(shown, source, sensor)[:, :3, 3]
        held = (key, raw, _xyz(recorded))  # the log kept: its id stays its own
        with cache._lock:
            cache._recorded = held
    out = {
        "recorded": {
            "title": f"as recorded ({problem.demonstration.file.name}, before the tracker correction)",
            **held[2],
        }
    }
    aligned = [p.fused.demo_positions for p in result.passes if p.fused.demo_positions is not None]
    if aligned:
        out["aligned"] = {
            "title": "as the fusion uses it (at each waypoint's matched time, after the tracker correction)",
            **_xyz(np.vstack(aligned)),
        }
    return out


VISUAL_FACES = 60_000
"""Most triangles of a robot's visual meshes the page is sent (sent once, with the robot's shapes):
a mesh is decimated to its share of them (quadric decimation, trimesh)."""


def _origin(element: Any) -> np.ndarray:
    from refine.frames import make_transform, matrix_from_fixed_xyz

    origin = element.find("origin")
    if origin is None:
        return np.eye(4)
    xyz = [float(v) for v in (origin.get("xyz") or "0 0 0").split()]
    rpy = [float(v) for v in (origin.get("rpy") or "0 0 0").split()]
    return make_transform(matrix_from_fixed_xyz(rpy, degrees=False), xyz)


def _meshes(root: Any, tag: str) -> list[tuple[str, str, str, np.ndarray, list[float]]]:
    """(link, name, filename, link_T_mesh, scale) of every ``<tag>`` mesh of the URDF."""
    out = []
    for link in root.iter("link"):
        for k, element in enumerate(link.findall(tag)):
            mesh = element.find("geometry/mesh")
            if mesh is None or not mesh.get("filename"):
                continue
            scale = [float(v) for v in (mesh.get("scale") or "1 1 1").split()]
            name = element.get("name") or f"{link.get('name')}_{k}"
            out.append((link.get("name", ""), name, mesh.get("filename"), _origin(element), scale))
    return out


def visual_meshes(urdf: Any) -> tuple[list[tuple[str, str, Any, np.ndarray]], str]:
    """The ``<visual>`` meshes of a robot's URDF where they are not its collision meshes, and a note.

    Returns:
        ``[(name, link, trimesh mesh in the link's mesh frame, link_T_mesh)]`` read by the loader
        the collision side uses (:func:`refine.robot.geometry.read_mesh`, scaled, decimated to
        :data:`VISUAL_FACES` in all), or ``[]`` with why none is drawn: every visual names the same
        file at the same place as a collision element (the registry's robots: their visual meshes
        are their convex collision pieces), a URL (``package://``) rather than a path beside the
        URDF, or a file that cannot be read.
    """
    from lxml import etree

    from refine.errors import InputError
    from refine.robot.geometry import read_mesh

    root = etree.parse(str(urdf)).getroot()
    visual, collision = _meshes(root, "visual"), _meshes(root, "collision")
    if not visual:
        return [], "the robot's URDF has no visual meshes: its collision shapes are drawn"

    def key(m: tuple[str, str, str, np.ndarray, list[float]]) -> tuple[Any, ...]:
        return (m[0], m[2], tuple(np.round(m[3], 9).ravel()), tuple(m[4]))

    if {key(m) for m in visual} <= {key(m) for m in collision}:
        return [], "the robot's visual meshes are its collision shapes (drawn)"
    folder = Path(urdf).parent
    loaded = []
    for link, name, filename, T, scale in visual:
        if "://" in filename:
            return (
                [],
                f"visual mesh {filename!r} is a URL, not a file beside the URDF: the collision shapes are drawn",
            )
        try:
            mesh = read_mesh(folder / filename, f"{Path(urdf).name}: link {link!r}, visual {name!r}")
        except InputError as e:
            return [], f"{e}: the collision shapes are drawn"
        mesh.apply_transform(np.diag([*scale, 1.0]))
        loaded.append((f"{link}/{name} (visual)", link, mesh, T))
    total = sum(len(m.faces) for _, _, m, _ in loaded)
    if total > VISUAL_FACES:
        share = VISUAL_FACES / total
        loaded = [(n, link, _decimated(m, share), T) for n, link, m, T in loaded]
    faces = sum(len(m.faces) for _, _, m, _ in loaded)
    return loaded, f"visual meshes: {len(loaded)} ({faces} triangles)"


def _decimated(mesh: Any, share: float) -> Any:
    """``mesh`` with about ``share`` of its triangles (trimesh's quadric decimation), or as it is."""
    try:
        return mesh.simplify_quadric_decimation(percent=1.0 - share)
    except Exception:  # the decimation's optional package is missing: the mesh is sent whole
        return mesh
