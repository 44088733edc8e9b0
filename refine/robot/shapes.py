"""A robot's convex link shapes made from its maker's collision meshes, and how well they fit.

Each link's collision mesh (in the link's frame) is covered by a few convex polytopes
(:func:`refine.robot.convex.convex_cover`) written as ``collision/<link>_<k>.obj`` beside the robot's
URDF, whose ``<collision>`` and ``<visual>`` elements then name these files (:func:`rewrite_urdf`).
``robots/make_shapes.py`` does it for the bundled robots from their reference descriptions, and
``refine robots import`` (:mod:`refine.robot.importer`) for a support package's own meshes.

:func:`shape_fit` measures a link's pieces against its mesh as the registry's shape tests do: how
far any mesh vertex lies outside every piece (the pieces' face planes), and how far the pieces reach
beyond the mesh (their corners and surface samples, trimesh's signed distance; needs ``rtree``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from lxml import etree
from scipy.spatial import ConvexHull

from refine.lazy import on_first_use
from refine.robot.convex import ConvexPiece, convex_cover

if TYPE_CHECKING:
    import trimesh
else:
    trimesh = on_first_use("trimesh")  # the first mesh call imports it

SETTINGS: dict[str, Any] = {"max_overshoot_m": 0.015, "max_pieces": 4, "tolerance_m": 0.006, "max_planes": 48}
"""Slab hulls at most 15 mm beyond the mesh, each simplified to <= 48 planes within 6 mm of its hull."""
FIT_SAMPLES = 1500
"""Surface samples per piece for the overshoot, as the shape tests take them."""


@dataclass(frozen=True)
class LinkShapes:
    """The convex pieces of one link and how they fit its mesh.

    Attributes:
        link: the URDF link name.
        files: the pieces' OBJ files, relative to the URDF's folder (``collision/<link>_<k>.obj``).
        pieces: the pieces [m], in the link frame.
        outside_m: the largest distance of a mesh vertex outside every piece [m] (<= 0: covered).
        overshoot_m: how far the pieces reach beyond the mesh at most [m].
    """

    link: str
    files: tuple[str, ...]
    pieces: tuple[ConvexPiece, ...]
    outside_m: float
    overshoot_m: float


def joint_links(urdf: str | Path) -> dict[str, str]:
    """The link each joint moves (child of the joint), and the root link under ``"universe"``."""
    root = etree.parse(str(urdf)).getroot()
    children = {j.find("child").get("link"): j.get("name") for j in root.iter("joint")}
    links = [link.get("name") for link in root.iter("link")]
    out = {"universe": next(name for name in links if name not in children)}
    for joint in root.iter("joint"):
        if joint.get("type") in ("revolute", "continuous", "prismatic"):
            out[joint.get("name")] = joint.find("child").get("link")
    return out


def outside_distance(points: np.ndarray, corner_sets: list[np.ndarray]) -> np.ndarray:
    """Per point, the least over pieces of the largest face-plane excess [m] (<= 0 inside a piece)."""
    best = np.full(len(points), np.inf)
    for corners in corner_sets:
        eq = ConvexHull(corners).equations  # unit outward normals and offsets: n . x + c <= 0 inside
        best = np.minimum(best, np.max(points @ eq[:, :3].T + eq[:, 3], axis=1))
    return best


def shape_fit(pieces: list[ConvexPiece], mesh: trimesh.Trimesh) -> tuple[float, float]:
    """(largest distance of a mesh vertex outside every piece, largest reach beyond the mesh) [m]."""
    outside = float(outside_distance(np.asarray(mesh.vertices), [p.vertices for p in pieces]).max())
    reach = 0.0
    for k, piece in enumerate(pieces):
        hull = trimesh.convex.convex_hull(piece.vertices)
        points = np.vstack([hull.vertices, trimesh.sample.sample_surface(hull, FIT_SAMPLES, seed=k)[0]])
        depth = trimesh.proximity.signed_distance(mesh, points)  # positive inside the mesh
        reach = max(reach, float(-depth.min()))
    return outside, reach


def make_link_shapes(
    meshes: dict[str, trimesh.Trimesh], folder: Path, label: str, source: str, **settings: Any
) -> list[LinkShapes]:
    """Cover each link's mesh with convex pieces and write them to ``folder/collision/``.

    Args:
        meshes: each link's collision mesh in the link frame [m].
        folder: the robot's folder (beside its URDF); old ``collision/*.obj`` files are removed.
        label: the robot's name, for the files' header.
        source: where the meshes came from, for the files' header.
        **settings: :func:`refine.robot.convex.convex_cover` options in place of :data:`SETTINGS`.

    Returns:
        One entry per link, in the order of ``meshes``.
    """
    out_dir = folder / "collision"
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in out_dir.glob("*.obj"):
        old.unlink()
    out = []
    for link, mesh in meshes.items():
        pieces = convex_cover(mesh, **{**SETTINGS, **settings})
        files = []
        for k, piece in enumerate(pieces):
            path = f"collision/{link}_{k}.obj"
            piece.write_obj(
                folder / path,
                f"{label} {link}: convex piece {k + 1} of {len(pieces)}, link frame, metres.\n"
                f"Computed from {source}; see README.md.",
            )
            files.append(path)
        outside, reach = shape_fit(pieces, mesh)
        out.append(LinkShapes(link, tuple(files), tuple(pieces), outside, reach))
    return out


def rewrite_urdf(urdf: Path, files: dict[str, list[str]] | dict[str, tuple[str, ...]]) -> None:
    """Replace every link's ``<visual>`` and ``<collision>`` by meshes naming ``files[link]``."""
    tree = etree.parse(str(urdf))
    for link in tree.getroot().iter("link"):
        name = link.get("name")
        for old in link.findall("visual") + link.findall("collision"):
            link.remove(old)
        for tag in ("visual", "collision"):
            for path in files.get(name, []):
                element = etree.SubElement(link, tag, name=Path(path).stem)
                geometry = etree.SubElement(element, "geometry")
                etree.SubElement(geometry, "mesh", filename=path)
    etree.indent(tree, space="  ")
    text = etree.tostring(tree, xml_declaration=True, encoding="utf-8").decode("utf-8")
    urdf.write_text(text.replace("--><robot", "-->\n<robot") + "\n", encoding="utf-8")


def shapes_table(shapes: list[LinkShapes]) -> list[str]:
    """Markdown rows: link, pieces, faces per piece, mm outside, mm beyond the mesh."""
    rows = [
        "| link | pieces | faces per piece | mesh vertices outside [mm] | beyond the mesh at most [mm] |",
        "|---|---|---|---|---|",
    ]
    for s in shapes:
        faces = ", ".join(str(p.plane_count) for p in s.pieces)
        rows.append(
            f"| `{s.link}` | {len(s.pieces)} | {faces} | {max(s.outside_m, 0.0) * 1e3:.1f} | {s.overshoot_m * 1e3:.1f} |"
        )
    return rows
