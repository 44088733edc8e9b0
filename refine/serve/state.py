"""The messages the page is sent: the verdict, the scene, the settings' values.

The verdict is the report's first screen (:func:`refine.report.verdict.verdict_html`, from the
``result.json`` document) and the scene the report's 3D data (:func:`refine.report.scene.scene_data`),
so the app and the report never disagree; the cell and the robot's shapes are built once
(:class:`SceneCache`) and a section is sent only when it changed.
"""

from __future__ import annotations

import html
import json
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from refine.export.result_json import result_dict
from refine.report.scene import (
    _mesh_json,
    cell_objects,
    parts_json,
    path_data,
    robot_frames,
    robot_parts,
    rounded,
)
from refine.report.verdict import verdict_html
from refine.serve.edits import MOVE, POSES, SCALARS, pose_table
from refine.serve.overlays import DemoCache, demonstration_lines, motion_lines

if TYPE_CHECKING:
    from refine.serve.session import Answer, Session


def _scalar(problem: Any, dotted: str) -> float | None:
    node = problem
    for name in dotted.split("."):
        node = getattr(node, name, None)
        if node is None:
            return None
    return float(node)


def _pose(problem: Any, dotted: str) -> dict[str, list[float]]:
    table, name = dotted.split(".")
    return pose_table(np.asarray(getattr(getattr(problem, table), name)))


def values_of(session: Session) -> dict[str, Any]:
    """The values the controls show: of the problem last asked for, and the workpiece move."""
    problem = session.problem
    move = session.changes.get(MOVE, {})
    return {
        "scalars": {key: _scalar(problem, key) for key in SCALARS},
        "poses": {key: _pose(problem, key) for key in POSES},
        "move": {
            "xyz": list(move.get("xyz", [0.0, 0.0, 0.0])),
            "rpy_deg": list(move.get("rpy_deg", [0.0, 0.0, 0.0])),
        },
        "changed": sorted(session.changes),
    }


def verdict_message(session: Session, answer: Answer) -> dict[str, Any]:
    """The verdict of ``answer`` (or the error that stopped its solve) with the revision it answers."""
    result = answer.result
    out: dict[str, Any] = {
        "type": "verdict",
        "revision": answer.revision,
        "latest": session.revision,
        "error": answer.error,
        "solve_s": answer.solve_s,
        "latency_s": answer.latency_s,
        "values": values_of(session),
        "status": None,
        "verdict_html": None,
    }
    if result is not None and answer.error is None:
        doc = result_dict(result)
        doc["outputs"] = {}
        out["status"] = result.status
        out["verdict_html"] = verdict_html(result, doc)
        out["demo_quality_html"] = demo_quality_html(doc.get("demo_quality"))
    return out


def demo_quality_html(quality: Mapping[str, Any] | None) -> str:
    """The demonstration quality gate's figures (``result.json``'s ``demo_quality``) in plain words.

    The samples and their rate, the dropouts bridged or trimmed, the tracker frame's estimated
    error (rotation with its uncertainty, offset, distortion, what is left) and the gate's warnings;
    empty when the run had no demonstration (a PathML path).
    """
    if not quality:
        return ""
    step = float(quality.get("sample_step_s") or 0.0)
    rate = f" at {1.0 / step:.0f} Hz" if step > 0 else ""
    lines = [f"{quality['n_samples']} tracker samples{rate}"]
    bridged, trimmed = int(quality.get("n_bridged", 0)), int(quality.get("n_trimmed", 0))
    if bridged or trimmed:
        longest = float(quality.get("longest_bridged_s", 0.0)) * 1e3
        lines.append(f"dropouts: {bridged} bridged (the longest {longest:.0f} ms), {trimmed} trimmed")
    else:
        lines.append("no dropouts")
    frame = quality.get("frame")
    if frame:
        lines.append(
            f"tracker frame against the CAD path: rotation {frame['observable_rotation_deg']:.2f} deg "
            f"(± {frame['observable_sigma_deg']:.2f} deg, told from noise above {frame['detectable_deg']:.2f} deg), "
            f"offset {frame['offset_m'] * 1e3:.1f} mm, distortion up to {frame['max_distortion_m'] * 1e3:.1f} mm, "
            f"{frame['rms_after_m'] * 1e3:.2f} mm RMS left over {frame['n_points']} waypoints"
        )
    flagged = int((quality.get("device_errors") or {}).get("n_flagged", 0))
    if flagged:
        lines.append(f"{flagged} samples flagged by the tracker")
    items = "".join(f"<li>{html.escape(line)}</li>" for line in lines)
    warnings = "".join(f"<li class='warning'>{html.escape(str(w))}</li>" for w in quality.get("warnings", []))
    return f"<h2>Demonstration quality</h2><ul class='demo-quality'>{items}{warnings}</ul>"


SCENE_SECTIONS = ("cell", "parts", "robot", "paths", "motions", "demo")
"""The sections of the scene, each sent only when it changed: the cell objects, the robot's shapes
in their own frames, the robot's poses along the path, the paths and their colours, the planned
motions and the demonstration recorded and aligned (:mod:`refine.serve.overlays`)."""


def _json(value: Any) -> str:
    return json.dumps(value, allow_nan=False, separators=(",", ":"))


class SceneCache:
    """The sections a re-solve seldom changes, kept as JSON text with the plain values they are drawn from.

    The cell (its objects' settings: a workpiece move changes it) and the robot's shapes (the same
    robot, the same tool shapes, the same visual meshes) are meshed and encoded once; a re-solve
    that leaves them alone reuses the text, and the page, which already has them, is not sent them.
    """

    def __init__(self) -> None:
        self._cell: tuple[str, str] | None = None
        self._robot: tuple[Any, str, Any] | None = None
        self.built = {"cell": 0, "parts": 0}

    def cell(self, result: Any) -> str:
        """The cell section of ``result`` (:func:`refine.report.scene.cell_objects`)."""
        key = repr(result.problem.cell)
        if self._cell is None or self._cell[0] != key:
            self._cell = (key, _json(cell_objects(result)))
            self.built["cell"] += 1
        return self._cell[1]

    def robot(self, result: Any, demos: DemoCache) -> tuple[list[Any], str, list[Any], str]:
        """The robot's parts, their section (collision shapes, then visual meshes), the visual meshes and the note."""
        visual, note = demos.visual(result.robot)
        key = repr(result.problem.tool.collision)
        held = self._robot
        if held is None or held[0] is not result.robot or held[1] != key or held[2][2] is not visual:
            parts = robot_parts(result)
            meshes = parts_json(parts)
            if visual:  # the visual meshes after the collision shapes
                meshes += [_mesh_json(name, mesh, np.eye(4), "visual") for name, _, mesh, _ in visual]
            self._robot = held = (result.robot, key, (parts, _json(meshes), visual, note))
            self.built["parts"] += 1
        return held[2]


def scene_sections(
    answer: Answer, demos: DemoCache | None = None, cache: SceneCache | None = None
) -> dict[str, str]:
    """The 3D scene of ``answer`` (:func:`refine.report.scene.scene_data`) as JSON text by section.

    ``cache`` keeps the cell and the robot's shapes from one answer to the next (:class:`SceneCache`).
    """
    assert answer.result is not None
    result = answer.result
    demos, cache = demos or DemoCache(), cache or SceneCache()
    parts, parts_text, visual, note = cache.robot(result, demos)
    links: list[Any] = []  # each frame's link poses, for the flange and the visual meshes too
    robot = robot_frames(result, parts, meshes=False, links=links)
    robot["flange"] = flange_poses(result, robot["where"], links)
    robot["visual_note"] = note
    if visual:  # the visual meshes' poses after the collision shapes' in every frame
        extra = visual_poses(result, robot["where"], visual, links)
        robot["frames"] = [f + e for f, e in zip(robot["frames"], extra, strict=True)]
    return {
        "cell": cache.cell(result),
        "parts": parts_text,
        "robot": _json(robot),
        "paths": _json(path_data(result)),
        "motions": _json(motion_lines(result)),
        "demo": _json(demonstration_lines(result, demos)),
    }


def flange_poses(result: Any, where: list[list[int]], links: list[Any] | None = None) -> list[list[float | None]]:
    """The flange's pose in {F} at each robot frame of the scene (``where``: pass, waypoint), as 12 numbers.

    The page puts the TCP gizmo at the flange times ``tcp_in_flange`` and turns a drag back into
    ``tcp_in_flange``. ``links``: the link poses at those frames (:func:`frame_links`) when held.
    """
    robot = result.robot
    base = np.asarray(result.problem.robot.base_in_world, dtype=float)
    out = []
    for at in links if links is not None else frame_links(result, where):
        T = base @ at[robot.spec.flange_frame]
        out.append(rounded(T[:3, :].ravel(), 6))
    return out


def frame_links(result: Any, where: list[list[int]]) -> list[Any]:
    """The robot's link poses (by name, in its base frame) at each robot frame of the scene."""
    return [result.robot.link_poses(result.passes[i].refinement.q[k]) for i, k in where]


def visual_poses(
    result: Any, where: list[list[int]], visual: list[Any], links: list[Any] | None = None
) -> list[list[list[float | None]]]:
    """Each visual mesh's pose in {F} at each robot frame of the scene, as 12 numbers (``links``: :func:`flange_poses`)."""
    base = np.asarray(result.problem.robot.base_in_world, dtype=float)
    out = []
    for at in links if links is not None else frame_links(result, where):
        out.append([rounded((base @ at[link] @ T)[:3, :].ravel(), 5) for _, link, _, T in visual])
    return out


def scene_message(revision: int, sections: Mapping[str, str], keys: Iterable[str]) -> str:
    """The scene message of ``revision`` with the sections ``keys`` of ``sections`` (JSON text).

    The page keeps the sections it has and replaces those a message carries, so a change that
    moves only the robot and the path does not resend the cell or the robot's shapes.
    """
    body = ",".join(f'"{k}":{sections[k]}' for k in keys)
    return f'{{"type":"scene","revision":{int(revision)},"scene":{{{body}}}}}'


class SceneDiff:
    """The sections sent last, to send only what changed (a newly opened page gets them all)."""

    def __init__(self) -> None:
        self.sent: dict[str, str] = {}
        self.demos = DemoCache()
        self.cache = SceneCache()

    def messages(self, answer: Answer) -> tuple[str, str]:
        """The message for the open pages (changed sections) and the whole scene for a new page."""
        sections = scene_sections(answer, self.demos, self.cache)
        changed = [k for k in SCENE_SECTIONS if self.sent.get(k) != sections[k]]
        self.sent = sections
        return scene_message(answer.revision, sections, changed), scene_message(
            answer.revision, sections, SCENE_SECTIONS
        )
