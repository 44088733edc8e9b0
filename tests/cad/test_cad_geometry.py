"""The CAD stage keeps the drawing's feature points and follows its curves within a chord tolerance,
and splits DXF drawings and G-code programs into tracks (refine.cad.read_cad_tracks)."""

import math
from pathlib import Path

import ezdxf
import numpy as np
import pytest

from refine.cad import read_cad_path, read_cad_tracks
from refine.cad.gcode import tracks_from_gcode
from refine.errors import InputError
from refine.fuse.order import reorder
from refine.fuse.tracks import join_tracks, split_tracks
from refine.paths import CadPath, FusedPath, chord_error
from refine.settings import CadSettings

# A bead in mm from (-2.5, 0): a sharp corner at (100, 0), a 20 mm arc (ARC entity, centre (100, 60),
# from -90 to 0 deg) from (100, 40) to (120, 60), a sharp corner at (120, 100) and a 20 mm bulge arc
# (a quarter turn counter-clockwise, bulge tan(pi / 8), centre (42.5, 100)) from (62.5, 100) to
# (42.5, 120). Neither corner falls on an even 5 mm grid from the end before it (102.5 of 142.5 mm,
# 40 of 97.5 mm), so only keeping it puts a waypoint there.
CORNERS_MM = [(-2.5, 0.0), (100.0, 0.0), (120.0, 100.0)]
ARC_CENTRE_MM, BULGE_CENTRE_MM, RADIUS_MM = (100.0, 60.0), (42.5, 100.0), 20.0


def _bead(tmp_path) -> Path:
    doc = ezdxf.new()
    msp = doc.modelspace()
    a = {"layer": "BEAD"}
    msp.add_line((-2.5, 0), (100, 0), dxfattribs=a)
    msp.add_line((100, 0), (100, 40), dxfattribs=a)
    msp.add_arc(ARC_CENTRE_MM, RADIUS_MM, -90.0, 0.0, dxfattribs=a)
    msp.add_line((120, 60), (120, 100), dxfattribs=a)
    msp.add_lwpolyline(
        [(120, 100, 0.0), (62.5, 100, math.tan(math.pi / 8)), (42.5, 120, 0.0)], format="xyb", dxfattribs=a
    )
    path = tmp_path / "bead.dxf"
    doc.saveas(path)
    return path


def _settings(path: Path, **kw) -> CadSettings:
    fmt = "dxf" if path.suffix == ".dxf" else "gcode"
    return CadSettings(file=path, format=fmt, units="mm", **kw)


def _on_circle(p_mm: np.ndarray, centre, r: float) -> np.ndarray:
    # on the circle within the readers' 1 um flattening
    return np.abs(np.hypot(p_mm[:, 0] - centre[0], p_mm[:, 1] - centre[1]) - r) < 1.001e-3


def _sagitta_of_chords_on_circle(p_mm: np.ndarray, centre, r: float) -> list[float]:
    """The largest distance of the circle from each chord whose both ends lie on it: r - |c - mid|."""
    on = _on_circle(p_mm, centre, r)
    out = []
    for i in range(len(p_mm) - 1):
        if on[i] and on[i + 1]:
            mid = 0.5 * (p_mm[i, :2] + p_mm[i + 1, :2])
            out.append(r - math.hypot(mid[0] - centre[0], mid[1] - centre[1]))
    return out


def test_dxf_corners_are_waypoints_and_arcs_are_within_the_chord_tolerance(tmp_path):
    cad = read_cad_path(_settings(_bead(tmp_path), spacing_m=0.005, layer="BEAD"), np.eye(4))
    p = cad.positions * 1e3
    for corner in CORNERS_MM:  # each sharp corner is a waypoint, exactly
        assert np.min(np.linalg.norm(p[:, :2] - corner, axis=1)) < 1e-9
    for ends in ([(100, 40), (120, 60)], [(62.5, 100), (42.5, 120)]):  # so are the ends of the arcs
        for e in ends:
            assert np.min(np.linalg.norm(p[:, :2] - e, axis=1)) < 1e-9
    assert np.all(np.diff(cad.s) <= 0.005 + 1e-12)  # the user's spacing bounds every step
    for centre in (ARC_CENTRE_MM, BULGE_CENTRE_MM):
        sag = _sagitta_of_chords_on_circle(p, centre, RADIUS_MM)
        # a quarter of a 20 mm circle is 31.4 mm: at 5 mm steps the sagitta would be 0.156 mm
        assert len(sag) >= 8
        assert max(sag) <= 0.1
        assert min(sag) > 0.05  # not finer than it needs (8 steps: 0.096 mm)


def test_dxf_chord_error_against_the_analytic_arcs(tmp_path):
    cad = read_cad_path(_settings(_bead(tmp_path), spacing_m=0.005, layer="BEAD"), np.eye(4))
    p = cad.positions[:, :2] * 1e3
    worst = 0.0
    for centre, a0, a1 in ((ARC_CENTRE_MM, -90.0, 0.0), (BULGE_CENTRE_MM, 0.0, 90.0)):
        ang = np.radians(np.linspace(a0, a1, 20001))
        arc = np.column_stack([centre[0] + RADIUS_MM * np.cos(ang), centre[1] + RADIUS_MM * np.sin(ang)])
        # the distance of each point of the true arc to the nearest straight move between waypoints
        a, b = p[:-1], p[1:]
        ab = b - a
        t = np.clip(np.einsum("kij,ij->ki", arc[:, None, :] - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
        d = np.linalg.norm(a + t[..., None] * ab - arc[:, None, :], axis=2).min(axis=1)
        worst = max(worst, float(d.max()))
    assert 0.05 < worst <= 0.1
    # the library's own figure agrees with the analytic one within the 1 um flattening
    assert abs(chord_error(cad.exact_s, cad.exact, cad.s, cad.positions).max_m * 1e3 - worst) < 2e-3


def test_a_coarser_tolerance_gives_fewer_waypoints_on_arcs_only(tmp_path):
    f = _bead(tmp_path)
    fine = read_cad_path(_settings(f, spacing_m=0.005, layer="BEAD", chord_tolerance_m=1e-4), np.eye(4))
    coarse = read_cad_path(_settings(f, spacing_m=0.005, layer="BEAD", chord_tolerance_m=1e-3), np.eye(4))
    # lines between kept points: 102.5 + 40 + 40 + 57.5 mm at 5 mm -> 21 + 8 + 8 + 12 steps; each
    # arc: 31.4 mm, which 5 mm steps (7, sagitta 0.126 mm) keep within 1 mm but not within 0.1 mm
    # (8 steps: 0.096 mm)
    assert len(coarse.s) - 1 == 49 + 2 * 7
    assert len(fine.s) - 1 == 49 + 2 * 8


def test_a_tolerance_out_of_range_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match=r"chord_tolerance_m.*m"):
        _settings(tmp_path / "x.dxf", chord_tolerance_m=0.0)


def test_disconnected_dxf_entities_are_tracks(tmp_path):
    doc = ezdxf.new()
    msp = doc.modelspace()
    msp.add_line((0, 0), (50, 0))
    msp.add_line((50, 0), (50, 30))
    msp.add_line((200, 0), (260, 0))  # not touching the first two
    msp.add_lwpolyline([(0, 100), (40, 100), (40, 140)], close=True)
    msp.add_lwpolyline([(0, 200), (10, 200)])
    f = tmp_path / "two.dxf"
    doc.saveas(f)
    tracks = read_cad_tracks(_settings(f, spacing_m=0.005, layer="0"), np.eye(4))
    np.testing.assert_allclose([t.length * 1e3 for t in tracks], [80.0, 60.0, 40 + 40 + math.hypot(40, 40), 10.0])
    assert [t.closed for t in tracks] == [False, False, True, False]
    with pytest.raises(InputError, match="4 tracks"):
        read_cad_path(_settings(f, spacing_m=0.005, layer="0"), np.eye(4))
    (third,) = read_cad_tracks(_settings(f, spacing_m=0.005, layer="0", track="3"), np.eye(4))
    np.testing.assert_allclose(third.positions[0] * 1e3, [0, 100, 0], atol=1e-9)
    with pytest.raises(InputError, match="tracks 1..4"):
        read_cad_tracks(_settings(f, spacing_m=0.005, layer="0", track="5"), np.eye(4))


LOOPS = 8


def _loops_with_plunges(tmp_path) -> Path:
    lines = ["G21 G90 G17"]
    for k in range(1, LOOPS + 1):  # eight concentric circles, each entered and left along Z
        r = 5.0 * k
        lines += [f"G0 X{r} Y0 Z5", "G1 Z0 F300", f"G2 X{r} Y0 I{-r} J0", "G1 Z5"]
    path = tmp_path / "loops.nc"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_gcode_concentric_loops_with_plunges_are_one_track_each(tmp_path):
    tracks = tracks_from_gcode(_loops_with_plunges(tmp_path))
    assert len(tracks) == LOOPS
    for k, t in enumerate(tracks, start=1):
        assert t.closed
        r = np.hypot(t.points[:, 0], t.points[:, 1]) * 1e3
        np.testing.assert_allclose(r, 5.0 * k, atol=1e-9)  # a plunge is no part of a track
        np.testing.assert_allclose(t.points[:, 2], 0.0, atol=1e-12)


def test_gcode_loops_joined_at_depth_split_at_each_closed_loop(tmp_path):
    # a square (closed by G1), a step-over, a circle (closed by one G2), a step-over, another square,
    # then a rapid and an open seam: no rapid or plunge between the first five pieces
    text = "\n".join(
        [
            "G21 G90",
            "G0 X0 Y0 Z0",
            "G1 X10 F300",
            "G1 Y10",
            "G1 X0",
            "G1 Y0",
            "G1 X-5",
            "G2 X-5 Y0 I5 J0",
            "G1 X-10",
            "G1 Y-10",
            "G1 X10",
            "G1 Y0",
            "G1 X-10",
            "G0 X50 Y50",
            "G1 X60 Y60",
        ]
    )
    f = tmp_path / "joined.nc"
    f.write_text(text + "\n")
    tracks = tracks_from_gcode(f)
    assert [t.closed for t in tracks] == [True, False, True, False, True, False]
    lengths = [float(np.linalg.norm(np.diff(t.points, axis=0), axis=1).sum()) * 1e3 for t in tracks]
    # the circle as flattened within 1 um: 2.1 um short of 2 pi 5 mm
    np.testing.assert_allclose(lengths, [40.0, 5.0, 2 * math.pi * 5.0, 5.0, 60.0, math.hypot(10, 10)], atol=0.01)
    paths = read_cad_tracks(_settings(f, spacing_m=0.005), np.eye(4))
    assert len(paths) == 6


def test_geometry_follows_the_waypoints_when_the_path_is_reordered(tmp_path):
    doc = ezdxf.new()
    doc.modelspace().add_lwpolyline([(0, 0, 0.0), (40, 0, 1.0), (40, 30, 0.0), (0, 30, 0.0)], format="xyb", close=True)
    f = tmp_path / "ring.dxf"
    doc.saveas(f)
    cad = read_cad_path(_settings(f, spacing_m=0.005), np.eye(4))
    before = chord_error(cad.exact_s, cad.exact, cad.s, cad.positions).max_m
    for reverse, start in ((True, 0), (False, 7), (True, 11)):
        run = reorder(cad, reverse, start)
        # each waypoint sits on the geometry at its own arc length
        k = np.argmin(np.abs(run.exact_s[:, None] - run.s[None, :]), axis=0)
        np.testing.assert_allclose(run.exact[k], run.positions, atol=1e-9)
        assert chord_error(run.exact_s, run.exact, run.s, run.positions).max_m == pytest.approx(before, abs=1e-9)
        # a reached path off the geometry by 1 mm at one waypoint shows as 1 mm
        moved = run.positions.copy()
        moved[5] += [0.0, 0.0, 1e-3]
        worst = chord_error(run.exact_s, run.exact, run.s, moved, run.positions)
        assert worst.max_m == pytest.approx(1e-3, abs=1e-12) and worst.s_m == run.s[5]


def _line(a, b, n) -> CadPath:
    s = np.linspace(0.0, float(np.linalg.norm(np.subtract(b, a))), n)
    p = np.asarray(a, float) + (s / s[-1])[:, None] * (np.subtract(b, a))
    return CadPath(s=s, positions=p, exact_s=s.copy(), exact=p.copy())


def test_tracks_are_joined_by_connectors_and_cut_back_into_themselves():
    tracks = [_line([0, 0, 0], [0.1, 0, 0], 21), _line([0.1, 0.02, 0], [0, 0.02, 0], 11), _line([0, 0.02, 0], [0, 0.05, 0], 4)]
    joined, ranges = join_tracks(tracks, 0.005)
    # 21 + 3 connector points (20 mm at 5 mm) + 11 + 0 (the third starts where the second ends) + 3
    assert len(joined.s) == 21 + 3 + 11 + 3
    assert ranges == [(0, 20), (24, 34), (34, 37)]
    assert joined.direction_given and joined.start_given and not joined.closed
    n = len(joined.s)
    fused = FusedPath(
        joined.s, joined.positions, np.repeat(np.eye(3)[None], n, axis=0), np.full(n, 0.02), joined.s / 0.02, np.zeros(n)
    )
    for track, piece in zip(tracks, split_tracks(fused, tracks, ranges), strict=True):
        np.testing.assert_array_equal(piece.positions, track.positions)
        np.testing.assert_array_equal(piece.s, track.s)
        assert piece.exact is track.exact
