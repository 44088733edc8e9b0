"""Tests for refine.fuse.passes: passes of a multi-layer weld from the demonstrated root pass."""

from __future__ import annotations

import math

import numpy as np
import pytest

from refine.errors import InputError
from refine.frames import matrix_from_rotvec, rotvec_from_matrix
from refine.fuse.passes import Pass, generate_passes, seam_frames, transported_normals
from refine.paths import FusedPath
from refine.settings import MultipassSettings

THREE_LAYERS = MultipassSettings(
    layers=3,
    layer_height_m=0.002,
    lateral_offsets_m=((0.0,), (-0.0015, 0.0015), (-0.003, 0.0, 0.003)),
    work_angle_change_deg=((0.0,), (5.0, -5.0), (8.0, 0.0, -8.0)),
)


def torch_rotations(t, b, push_deg, work_deg=0.0):
    """R_F_TCP: z into the joint along -b, tilted by the work angle about t and the push angle
    forward along t; x along the travel direction."""
    p = np.radians(np.broadcast_to(push_deg, len(t)))[:, None]
    w = np.radians(np.broadcast_to(work_deg, len(t)))[:, None]
    lateral = np.cross(t, b)
    z = -np.cos(p) * (np.cos(w) * b + np.sin(w) * lateral) + np.sin(p) * t
    x = t - np.sum(t * z, axis=1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def fused(positions, rotations, speed=0.005):
    n = len(positions)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])
    return FusedPath(
        s=s,
        positions=positions,
        rotations=rotations,
        speed=np.full(n, speed) + 1e-4 * np.sin(s * 50.0),
        t_demo=s / speed,
        residual=np.zeros(n),
    )


def straight_seam(n=201, push_deg=12.0):
    """A 0.2 m fillet seam along x in the flat position: bisector straight up."""
    positions = np.column_stack([np.linspace(0.4, 0.6, n), np.full(n, 0.1), np.full(n, 0.05)])
    t = np.tile([1.0, 0.0, 0.0], (n, 1))
    b = np.tile([0.0, 0.0, 1.0], (n, 1))
    return fused(positions, torch_rotations(t, b, push_deg)), t, b


def ramp_seam(spacing=0.001, radius=0.04, ramp_deg=30.0, push_amplitude_deg=3.0):
    """A T-joint seam in the y-z plane: horizontal, a bend up of ``radius``, a ramp, a bend back,
    horizontal. The web is the plane x = 0 facing -x, the base plate's normal turns with the bend;
    the bisector is (-1, -sin(phi), cos(phi)) / sqrt(2) with phi the slope angle. Piece ends fall on
    waypoints. Returns the path, the true t and b, and a mask of waypoints inside pieces."""
    alpha = math.radians(ramp_deg)
    arc = radius * alpha
    lengths = [0.1, arc, 0.12, arc, 0.1]
    counts = [round(length / spacing) for length in lengths]
    kappa = [0.0, 1.0 / radius, 0.0, -1.0 / radius, 0.0]
    sigma_parts, phi_parts = [], []
    start_phi = 0.0
    for length, count, k in zip(lengths, counts, kappa, strict=True):
        d = np.linspace(0.0, length, count, endpoint=False)
        sigma_parts.append(d)
        phi_parts.append(start_phi + k * d)
        start_phi += k * length
    # positions by exact integration of the slope angle, piece by piece
    points, p0, phi0 = [], np.zeros(2), 0.0
    for d, length, k in zip(sigma_parts, lengths, kappa, strict=True):
        if k == 0.0:
            pts = p0 + d[:, None] * np.array([math.cos(phi0), math.sin(phi0)])
            p1 = p0 + length * np.array([math.cos(phi0), math.sin(phi0)])
        else:
            ph = phi0 + k * d
            pts = p0 + np.column_stack([np.sin(ph) - math.sin(phi0), -(np.cos(ph) - math.cos(phi0))]) / k
            ph1 = phi0 + k * length
            p1 = p0 + np.array([math.sin(ph1) - math.sin(phi0), -(math.cos(ph1) - math.cos(phi0))]) / k
        points.append(pts)
        p0, phi0 = p1, phi0 + k * length
    yz = np.vstack(points + [p0[None]])
    phi = np.concatenate(phi_parts + [np.array([phi0])])
    n = len(yz)
    positions = np.column_stack([np.full(n, 0.55), yz[:, 0] - 0.2, yz[:, 1] + 0.1])
    t = np.column_stack([np.zeros(n), np.cos(phi), np.sin(phi)])
    b = np.column_stack([-np.ones(n), -np.sin(phi), np.cos(phi)]) / math.sqrt(2.0)
    push = 12.0 + push_amplitude_deg * np.sin(np.linspace(0.0, 3.0, n))
    ends = np.cumsum([0] + counts)
    inside = np.ones(n, dtype=bool)
    for e in ends:
        inside[max(0, e - 1) : e + 2] = False
    return fused(positions, torch_rotations(t, b, push)), t, b, inside


def expected_shift(p: Pass, t, b):
    return p.height_m * b + p.lateral_offset_m * np.cross(t, b)


def test_pass_count_and_numbering_follow_the_lateral_offsets():
    root, *_ = straight_seam()
    passes = generate_passes(root, THREE_LAYERS)
    assert len(passes) == sum(len(row) for row in THREE_LAYERS.lateral_offsets_m) == 6
    assert [(p.layer, p.index) for p in passes] == [(1, 1), (2, 1), (2, 2), (3, 1), (3, 2), (3, 3)]
    assert [p.lateral_offset_m for p in passes] == [0.0, -0.0015, 0.0015, -0.003, 0.0, 0.003]
    assert [p.work_angle_change_deg for p in passes] == [0.0, 5.0, -5.0, 8.0, 0.0, -8.0]
    assert [p.height_m for p in passes] == pytest.approx([0.0, 0.002, 0.002, 0.004, 0.004, 0.004])


def test_the_first_pass_is_the_root_pass_unchanged():
    root, *_ = straight_seam()
    first = generate_passes(root, THREE_LAYERS)[0]
    assert first.path is root


def test_a_single_layer_gives_the_root_pass_only():
    root, *_ = straight_seam()
    assert [p.path for p in generate_passes(root, MultipassSettings())] == [root]


def test_offsets_are_exact_on_a_straight_seam():
    """Every point moves by h along the bisector and o along l = t x b: sqrt(h^2 + o^2) away."""
    root, t, b = straight_seam()
    for p in generate_passes(root, THREE_LAYERS)[1:]:
        shift = p.path.positions - root.positions
        distance = np.linalg.norm(shift, axis=1)
        assert distance == pytest.approx(
            np.full(len(root), math.hypot(p.height_m, p.lateral_offset_m)), abs=1e-12
        )
        np.testing.assert_allclose(shift, expected_shift(p, t, b), atol=1e-12)
    # on this seam l = t x b = x cross z = -y: the direction is the world's
    third = generate_passes(root, THREE_LAYERS)[5]
    np.testing.assert_allclose(third.path.positions[0] - root.positions[0], [0.0, -0.003, 0.004], atol=1e-12)


def test_offsets_are_exact_on_a_bent_seam_without_smoothing():
    """Through the bends of a ramp the shift follows the true, turning bisector."""
    root, t, b, inside = ramp_seam()
    for p in generate_passes(root, THREE_LAYERS, smoothing_m=0.0)[1:]:
        shift = p.path.positions - root.positions
        distance = np.linalg.norm(shift, axis=1)
        assert distance == pytest.approx(
            np.full(len(root), math.hypot(p.height_m, p.lateral_offset_m)), abs=1e-12
        )
        err = np.linalg.norm(shift - expected_shift(p, t, b), axis=1)
        assert err[inside].max() < 1e-12
        # where a line meets an arc the discrete tangent is off by about spacing / (4 radius)
        assert err.max() < 0.01 * np.linalg.norm(shift, axis=1).max()


def test_smoothing_keeps_the_bisector_on_a_bent_seam():
    """The smoothing works on the angle about the tangent, so it does not pull b into the bends."""
    root, t, b, inside = ramp_seam()
    _, b_smooth, _ = seam_frames(root)
    angle = np.degrees(np.arccos(np.clip(np.sum(b_smooth * b, axis=1), -1.0, 1.0)))
    assert angle[inside].max() < 0.01
    for p in generate_passes(root, THREE_LAYERS)[1:]:
        err = np.linalg.norm(p.path.positions - root.positions - expected_shift(p, t, b), axis=1)
        assert err[inside].max() < 1e-6


def test_smoothing_removes_orientation_noise_from_the_bisector():
    root, t, b, _ = ramp_seam()
    rng = np.random.default_rng(7)
    noisy = (
        matrix_from_rotvec(np.radians(1.0) * rng.normal(size=(len(root), 3)) / math.sqrt(3)) @ root.rotations
    )
    root = FusedPath(root.s, root.positions, noisy, root.speed, root.t_demo, root.residual)
    raw = np.degrees(np.arccos(np.clip(np.sum(seam_frames(root, 0.0)[1] * b, axis=1), -1.0, 1.0)))
    smooth = np.degrees(np.arccos(np.clip(np.sum(seam_frames(root)[1] * b, axis=1), -1.0, 1.0)))
    assert np.sqrt(np.mean(smooth**2)) < 0.4 * np.sqrt(np.mean(raw**2))


def test_the_tool_turns_about_the_seam_tangent_by_the_work_angle_change():
    root, t_true, _, inside = ramp_seam()
    t = seam_frames(root)[0]  # the path's own tangent: the true one inside the pieces
    np.testing.assert_allclose(t[inside], t_true[inside], atol=1e-12)
    for p in generate_passes(root, THREE_LAYERS)[1:]:
        rotvec = rotvec_from_matrix(p.path.rotations @ np.transpose(root.rotations, (0, 2, 1)))
        np.testing.assert_allclose(rotvec, t * math.radians(p.work_angle_change_deg), atol=1e-9)
        # the push angle (torch against the tangent) is kept
        np.testing.assert_allclose(
            np.sum(p.path.rotations[:, :, 2] * t, axis=1),
            np.sum(root.rotations[:, :, 2] * t, axis=1),
            atol=1e-12,
        )


def test_a_positive_work_angle_change_turns_the_torch_towards_minus_l():
    root, t, b = straight_seam(push_deg=0.0)
    p = generate_passes(root, THREE_LAYERS)[1]  # +5 deg
    z = p.path.rotations[:, :, 2]
    lateral = np.cross(t, b)
    assert np.all(np.sum(z * -lateral, axis=1) == pytest.approx(math.sin(math.radians(5.0)), abs=1e-12))


def test_speeds_are_the_root_speeds_and_arc_length_is_the_pass_own():
    root, *_ = ramp_seam()
    for p in generate_passes(root, THREE_LAYERS)[1:]:
        np.testing.assert_array_equal(p.path.speed, root.speed)
        np.testing.assert_array_equal(p.path.t_demo, root.t_demo)
        steps = np.linalg.norm(np.diff(p.path.positions, axis=0), axis=1)
        np.testing.assert_allclose(np.diff(p.path.s), steps, atol=1e-15)
        assert p.path.s[0] == root.s[0]
    straight, *_ = straight_seam()
    for p in generate_passes(straight, THREE_LAYERS)[1:]:
        np.testing.assert_allclose(p.path.s, straight.s, atol=1e-12)


def test_transported_normals_stay_normal_and_do_not_twist_on_a_planar_curve():
    root, t, b, _ = ramp_seam()
    u = transported_normals(t, np.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(np.sum(u * t, axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(u, np.tile([1.0, 0.0, 0.0], (len(t), 1)), atol=1e-12)


def test_layer_one_must_be_the_single_root_pass():
    root, *_ = straight_seam()
    bad = MultipassSettings(layers=2, layer_height_m=0.002, lateral_offsets_m=((0.001,), (0.0,)))
    with pytest.raises(InputError, match="layer 1 is the demonstrated root pass"):
        generate_passes(root, bad)


def test_work_angle_changes_default_to_zero():
    root, *_ = straight_seam()
    settings = MultipassSettings(layers=2, layer_height_m=0.002, lateral_offsets_m=((0.0,), (-0.001, 0.001)))
    passes = generate_passes(root, settings)
    assert [p.work_angle_change_deg for p in passes] == [0.0, 0.0, 0.0]
    for p in passes:
        np.testing.assert_allclose(p.path.rotations, root.rotations, atol=1e-15)


def test_a_torch_along_the_seam_has_no_bisector():
    root, t, b = straight_seam(push_deg=80.0)
    with pytest.raises(InputError, match="from the seam tangent"):
        generate_passes(root, THREE_LAYERS)


def test_an_offset_larger_than_the_bend_radius_is_refused():
    root, *_ = ramp_seam(radius=0.002, spacing=0.0005)
    deep = MultipassSettings(layers=2, layer_height_m=0.01, lateral_offsets_m=((0.0,), (0.0,)))
    with pytest.raises(InputError, match="folds back"):
        generate_passes(root, deep, smoothing_m=0.0)
