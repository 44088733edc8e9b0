"""The messages the page is sent: the verdict, the scene, the settings' values.

The verdict is the report's first screen (:func:`refine.report.verdict.verdict_html`, from the
``result.json`` document) and the scene the report's 3D data (:func:`refine.report.scene.scene_data`),
so the app and the report never disagree.
"""

from __future__ import annotations

import html
import json
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from refine.export.result_json import result_dict
from refine.report.scene import _mesh_json, rounded, scene_data
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


def scene_sections(answer: Answer, demos: DemoCache | None = None) -> dict[str, str]:
    """The 3D scene of ``answer`` (:func:`refine.report.scene.scene_data`) as JSON text by section."""
    assert answer.result is not None
    scene = scene_data(answer.result)
    robot = dict(scene["robot"])
    parts = robot.pop("parts")
    robot["flange"] = flange_poses(answer.result, robot["where"])
    visual, robot["visual_note"] = (demos or DemoCache()).visual(answer.result.robot)
    if visual:  # the visual meshes after the collision shapes, their poses after theirs in every frame
        parts = parts + [_mesh_json(name, mesh, np.eye(4), "visual") for name, _, mesh, _ in visual]
        extra = visual_poses(answer.result, robot["where"], visual)
        robot["frames"] = [f + e for f, e in zip(robot["frames"], extra, strict=True)]
    sections = {
        "cell": scene["cell"],
        "parts": parts,
        "robot": robot,
        "paths": scene["paths"],
        "motions": motion_lines(answer.result),
        "demo": demonstration_lines(answer.result, demos or DemoCache()),
    }
    return {k: json.dumps(sections[k], allow_nan=False, separators=(",", ":")) for k in SCENE_SECTIONS}


def flange_poses(result: Any, where: list[list[int]]) -> list[list[float | None]]:
    """The flange's pose in {F} at each robot frame of the scene (``where``: pass, waypoint), as 12 numbers.

    The page puts the TCP gizmo at the flange times ``tcp_in_flange`` and turns a drag back into
    ``tcp_in_flange``.
    """
    robot = result.robot
    base = np.asarray(result.problem.robot.base_in_world, dtype=float)
    out = []
    for i, k in where:
        T = base @ robot.link_poses(result.passes[i].refinement.q[k])[robot.spec.flange_frame]
        out.append(rounded(T[:3, :].ravel(), 6))
    return out


def visual_poses(result: Any, where: list[list[int]], visual: list[Any]) -> list[list[list[float | None]]]:
    """Each visual mesh's pose in {F} at each robot frame of the scene, as 12 numbers."""
    base = np.asarray(result.problem.robot.base_in_world, dtype=float)
    out = []
    for i, k in where:
        links = result.robot.link_poses(result.passes[i].refinement.q[k])
        out.append([rounded((base @ links[link] @ T)[:3, :].ravel(), 5) for _, link, _, T in visual])
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

    def messages(self, answer: Answer) -> tuple[str, str]:
        """The message for the open pages (changed sections) and the whole scene for a new page."""
        sections = scene_sections(answer, self.demos)
        changed = [k for k in SCENE_SECTIONS if self.sent.get(k) != sections[k]]
        self.sent = sections
        return scene_message(answer.revision, sections, changed), scene_message(
            answer.revision, sections, SCENE_SECTIONS
        )
