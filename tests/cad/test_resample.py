"""Behaviour of arc-length resampling (refine.cad.resample)."""

import numpy as np
import pytest

from refine.cad.resample import drop_duplicate_points, resample_by_arc_length
from refine.errors import InputError


def _distance_to_polyline(points, poly):
    """Distance from each point (N, 3) to the polyline (K, 3)."""
    a, b = poly[:-1], poly[1:]
    ab = b - a
    rel = points[:, None, :] - a[None]
    u = np.clip(np.einsum("nkd,kd->nk", rel, ab) / np.einsum("kd,kd->k", ab, ab), 0.0, 1.0)
    closest = a[None] + u[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=2).min(axis=1)


@pytest.fixture
def zigzag():
    rng = np.random.default_rng(3)
    return np.cumsum(rng.uniform(-0.05, 0.05, size=(30, 3)), axis=0)


def test_waypoints_lie_on_the_input_polyline(zigzag):
    _, pos = resample_by_arc_length(zigzag, 0.004)
    assert _distance_to_polyline(pos, zigzag).max() < 1e-12


def test_steps_are_equal_and_never_longer_than_requested(zigzag):
    spacing = 0.0037
    s, pos = resample_by_arc_length(zigzag, spacing)
    steps = np.diff(s)
    assert np.all(steps <= spacing + 1e-15)
    assert np.ptp(steps) < 1e-12
    length = np.linalg.norm(np.diff(zigzag, axis=0), axis=1).sum()
    assert s[0] == 0.0 and s[-1] == pytest.approx(length, abs=1e-12)
    # on a straight stretch the chord equals the arc length step
    line = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    s_line, p_line = resample_by_arc_length(line, 0.3)
    np.testing.assert_allclose(np.diff(p_line[:, 0]), 0.25, atol=1e-15)
    np.testing.assert_allclose(s_line, [0, 0.25, 0.5, 0.75, 1.0], atol=1e-15)


def test_first_and_last_points_are_kept_exactly(zigzag):
    _, pos = resample_by_arc_length(zigzag, 0.01)
    assert np.array_equal(pos[0], zigzag[0])
    assert np.array_equal(pos[-1], zigzag[-1])


def test_duplicate_input_points_are_dropped():
    pts = np.array([[0.0, 0, 0], [0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 1, 0]])
    assert len(drop_duplicate_points(pts)) == 3
    s, pos = resample_by_arc_length(pts, 0.5)
    assert len(s) == 5 and np.all(np.diff(s) > 0)
    np.testing.assert_allclose(pos[2], [1, 0, 0], atol=1e-15)


def test_closed_path_includes_the_closing_segment_and_ends_at_its_start():
    square = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    s, pos = resample_by_arc_length(square, 0.3, closed=True)
    assert s[-1] == pytest.approx(4.0)
    assert np.array_equal(pos[-1], pos[0])
    # a square already closed gives the same waypoints
    s2, pos2 = resample_by_arc_length(np.vstack([square, square[:1]]), 0.3, closed=True)
    np.testing.assert_allclose(pos2, pos, atol=1e-15)
    np.testing.assert_allclose(s2, s, atol=1e-15)


def test_path_shorter_than_the_spacing_gets_its_two_ends():
    s, pos = resample_by_arc_length(np.array([[0.0, 0, 0], [0.001, 0, 0]]), 0.005)
    assert len(s) == 2 and s[-1] == pytest.approx(0.001)


@pytest.mark.parametrize(
    ("points", "spacing"),
    [(np.zeros((3, 3)), 0.01), (np.zeros((3, 2)), 0.01), (np.eye(3), 0.0), (np.eye(3), -1.0)],
)
def test_degenerate_input_is_rejected(points, spacing):
    with pytest.raises(InputError):
        resample_by_arc_length(points, spacing)
