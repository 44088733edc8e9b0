"""Convex pieces from meshes: containment, closeness to the hull, and the slab cover of a concave solid."""

from __future__ import annotations

import fcl
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from refine.collision.distance import place, signed_distance
from refine.collision.geometry import Body, convex_parts
from refine.errors import InputError
from refine.robot.convex import ConvexPiece, convex_cover, outer_polytope


def _support_gap(piece: ConvexPiece, points: np.ndarray, n_dirs: int = 4000) -> tuple[float, float]:
    """Least and largest h_piece(u) - h_points(u) over random unit u: for convex sets the largest is
    the Hausdorff distance of the piece from the points' hull, and the least is < 0 if a point is outside."""
    u = np.random.default_rng(3).normal(size=(n_dirs, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    gap = (piece.vertices @ u.T).max(axis=0) - (points @ u.T).max(axis=0)
    return float(gap.min()), float(gap.max())


@pytest.mark.parametrize("tolerance_m", [0.004, 0.008])
def test_outer_polytope_contains_the_points_and_stays_within_its_tolerance(tolerance_m):
    points = trimesh.creation.capsule(height=0.4, radius=0.07, count=[12, 12]).vertices
    points = Rotation.from_rotvec([0.3, -0.2, 0.5]).apply(points) + [0.1, 0.2, 0.3]
    piece = outer_polytope(points, tolerance_m=tolerance_m, max_planes=200)
    least, largest = _support_gap(piece, points)
    assert least >= 0.0  # no point sticks out in any direction
    assert largest <= tolerance_m
    assert piece.contains(points).all()
    assert piece.plane_count < len(trimesh.convex.convex_hull(points).faces)


def test_max_planes_bounds_the_faces_and_keeps_containment():
    points = trimesh.creation.icosphere(subdivisions=3, radius=0.1).vertices
    piece = outer_polytope(points, tolerance_m=1e-4, max_planes=20)
    assert piece.plane_count <= 20
    assert _support_gap(piece, points)[0] >= 0.0


def test_a_concave_l_shape_is_cut_into_slabs_that_cover_it_tightly():
    # two 0.4 x 0.05 x 0.05 m bars meeting at a right angle: the hull adds a 0.35 m triangle
    a = trimesh.creation.box([0.4, 0.05, 0.05])
    a.apply_translation([0.2, 0.025, 0.0])
    b = trimesh.creation.box([0.05, 0.4, 0.05])
    b.apply_translation([0.025, 0.2, 0.0])
    solid = trimesh.boolean.union([a, b]) if trimesh.boolean.engines_available else None
    if solid is None:
        solid = trimesh.util.concatenate([a, b])
    solid = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(solid.vertices, solid.faces, 0.01))
    pieces = convex_cover(solid, max_overshoot_m=0.01, max_pieces=4, tolerance_m=0.002)
    assert len(pieces) >= 2
    inside = np.zeros(len(solid.vertices), dtype=bool)
    for piece in pieces:
        inside |= piece.contains(solid.vertices, 1e-9)
    assert inside.all()
    corner = np.array([[0.3, 0.3, 0.0]])  # inside the hull of the L, far outside the L itself
    assert not any(piece.contains(corner)[0] for piece in pieces)


def test_degenerate_points_are_an_input_error():
    flat = np.c_[np.random.default_rng(0).uniform(size=(20, 2)), np.zeros(20)]
    with pytest.raises(InputError, match="one plane"):
        ConvexPiece.hull_of(flat)


def _convex_body(piece: ConvexPiece, name: str) -> Body:
    parts = convex_parts(piece)
    return Body(
        name=name,
        shape=name,
        kind="link",
        link=name,
        frame_id=0,
        joint=1,
        link_T_shape=np.eye(4),
        obj=fcl.CollisionObject(parts["geometry"]),
        **parts,
    )


def test_convex_bodies_give_true_distances_and_surface_witness_points():
    """Against trimesh's exact point-to-mesh distances, on random poses of two convex bodies."""
    pa = ConvexPiece.hull_of(trimesh.creation.capsule(height=0.3, radius=0.08).vertices)
    pb = ConvexPiece.hull_of(trimesh.creation.box([0.2, 0.1, 0.3]).vertices)
    A, B = _convex_body(pa, "a"), _convex_body(pb, "b")
    rng = np.random.default_rng(1)
    separated = penetrating = 0
    for _ in range(60):
        Ta, Tb = np.eye(4), np.eye(4)
        Ta[:3, :3], Tb[:3, :3] = Rotation.random(2, random_state=int(rng.integers(1e9))).as_matrix()
        Ta[:3, 3], Tb[:3, 3] = rng.normal(size=(2, 3)) * 0.15
        place(A, Ta)
        place(B, Tb)
        d, p_a, p_b, n = signed_distance(A, Ta, B, Tb)
        ma, mb = pa.mesh.apply_transform(Ta), pb.mesh.apply_transform(Tb)
        on_a = trimesh.proximity.signed_distance(ma, [p_a])[0]
        on_b = trimesh.proximity.signed_distance(mb, [p_b])[0]
        assert abs(on_a) < 1e-5 and abs(on_b) < 1e-5
        if d > 0.0:
            separated += 1
            assert np.linalg.norm(p_a - p_b) == pytest.approx(d, abs=1e-7)
            # no vertex of b is closer to a than d (a lower bound from a's surface)
            assert -trimesh.proximity.signed_distance(ma, mb.vertices).min() >= d - 1e-6
        else:
            penetrating += 1
            moved = Ta.copy()
            moved[:3, 3] += (-d + 1e-3) * n  # pushed out along the normal by the depth: just apart
            place(A, moved)
            assert signed_distance(A, moved, B, Tb)[0] == pytest.approx(1e-3, abs=2e-5)
    assert separated > 10 and penetrating > 10


def test_write_obj_round_trips(tmp_path):
    piece = outer_polytope(trimesh.creation.icosphere(2, 0.05).vertices, tolerance_m=0.003)
    piece.write_obj(tmp_path / "p.obj", "a comment")
    back = trimesh.load(tmp_path / "p.obj", force="mesh", process=False)
    np.testing.assert_allclose(back.vertices, piece.vertices, atol=1e-9)
    assert back.is_watertight and back.volume > 0.0
