"""The alignment finds the worker's direction and start on the CAD path (refine.fuse.order.orient).

Each demonstration is simulated with the project's generators (``refine.synthetic``) and tracker
simulator (``refine.demo.simulate``) along a glass-like rounded rectangle; the expected direction,
start and drag angle come from how the demonstration was generated.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import ezdxf
import numpy as np
import pytest

from refine.cad import read_cad_path
from refine.cad.resample import resample_by_arc_length
from refine.demo import clean_demonstration
from refine.demo.simulate import TrackerModel, simulate_demonstration
from refine.errors import InputError
from refine.frames import transform_from_xyz_rpy, transform_points
from refine.fuse.fusion import fuse
from refine.paths import CadPath
from refine.settings import CadSettings, DemoSettings
from refine.synthetic import periodic_wave, rounded_rectangle, tool_rotations

T_F_CAD = transform_from_xyz_rpy([1.2, 0.0, 0.6], [0.0, 0.0, 90.0])  # the glass on the table
T_F_S = transform_from_xyz_rpy([1.2, -0.6, 0.72], [0.0, 0.0, 90.0])  # receiver beside it
T_TCP_E = transform_from_xyz_rpy([-0.03, 0.0, -0.25], [180.0, 0.0, 30.0])  # sensor on the gun barrel
N_FOOT = 4000  # footprint points; starts are chosen among them
SPACING = 0.005  # waypoint spacing [m]
DRAG_DEG = 15.0


def footprint():
    """Points of the bead in the CAD frame, counter-clockwise from the middle of an edge, and L."""
    u, v, du, dv, _, L = rounded_rectangle(0.55, 0.23, 0.1, N_FOOT)
    z = np.zeros(N_FOOT)
    return np.column_stack([u, v, z]), np.column_stack([du, dv, z]), L


def demonstrate(index, seed=7, model=None):
    """Simulate a worker along footprint points ``index`` (in travel order), pushing the gun.

    Returns:
        the cleaned demonstration and the true drag angle [deg] as a function of the worker's
        arc length [m].
    """
    pts, tan, L = footprint()
    forward = (index[1] - index[0]) % N_FOOT == 1
    p = transform_points(T_F_CAD, pts[index % N_FOOT])
    t = (tan[index % N_FOOT] if forward else -tan[index % N_FOOT]) @ T_F_CAD[:3, :3].T  # travel direction
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    drag = np.radians(DRAG_DEG) + np.radians(
        periodic_wave(s, s[-1] + 1e-9, (3.0,), np.random.default_rng(seed))
    )
    normals = np.repeat(T_F_CAD[:3, 2][None], len(s), axis=0)
    R = tool_rotations(t, normals, drag)
    speed = np.full(len(s), 0.11)
    sim = simulate_demonstration(s, p, R, speed, T_F_S, T_TCP_E, model or TrackerModel(seed=seed))
    demo = clean_demonstration(sim.log, DemoSettings(file=Path("simulated.liberty"), units="m"))
    return demo, (lambda x: np.degrees(np.interp(x, s, drag)))


def cad_path(closed=True, last=N_FOOT):
    """The CAD path as drawn (counter-clockwise from the footprint's first point), resampled."""
    pts, _, _ = footprint()
    pts = transform_points(T_F_CAD, np.vstack([pts, pts[:1]]) if closed else pts[:last])
    s, positions = resample_by_arc_length(pts, SPACING, closed=closed)
    return CadPath(s=s, positions=positions, closed=closed, source="bead")


def drag_deg(fused):
    """Signed drag angle of the fused orientations against the fused path's own travel [deg]."""
    tangent = np.gradient(fused.positions, fused.s, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    z = fused.rotations[:, :, 2]
    normal = T_F_CAD[:3, 2]
    return np.degrees(np.arctan2(-np.einsum("ij,ij->i", z, tangent), -(z @ normal)))


def test_a_loop_demonstrated_the_other_way_round_is_run_that_way_with_the_push_angle_kept():
    _, _, L = footprint()
    start = 1234  # the worker starts at footprint point 1234 and goes clockwise
    demo, drag_true = demonstrate(start - np.arange(N_FOOT + 1))
    fused = fuse(cad_path(), demo, T_F_S, T_TCP_E)
    order = fused.order
    assert order.direction == "reversed" and order.direction_source == "alignment"
    assert order.start_offset_m == pytest.approx(start * L / N_FOOT, abs=SPACING)
    assert order.residual_as_cad_m > 2.0 * order.residual_reversed_m
    # the run goes the worker's way: the tool leans back against the travel as the worker held it
    err = drag_deg(fused) - drag_true(fused.s)
    inner = slice(3, -3)  # the tangent by differences is one-sided at the ends
    assert np.sqrt(np.mean(err[inner] ** 2)) < 1.0 and np.abs(err[inner]).max() < 3.0
    assert np.median(fused.residual) < 3e-3


def test_a_loop_demonstrated_from_another_start_starts_there():
    _, _, L = footprint()
    start = 2900
    demo, drag_true = demonstrate(start + np.arange(N_FOOT + 1), seed=11)
    fused = fuse(cad_path(), demo, T_F_S, T_TCP_E)
    assert fused.order.direction == "as_cad"
    assert fused.order.start_offset_m == pytest.approx(start * L / N_FOOT, abs=SPACING)
    np.testing.assert_allclose(fused.positions[0], fused.positions[-1])
    err = drag_deg(fused) - drag_true(fused.s)
    assert np.sqrt(np.mean(err[3:-3] ** 2)) < 1.0


def test_an_open_path_demonstrated_backwards_is_reversed_without_a_start_search():
    last = 2500  # the open path: footprint points 0 .. 2499, counter-clockwise
    cad = cad_path(closed=False, last=last)
    demo, drag_true = demonstrate(np.arange(last - 1, -1, -1), seed=5)
    fused = fuse(cad, demo, T_F_S, T_TCP_E)
    assert fused.order.direction == "reversed" and fused.order.start_source == "open path"
    assert fused.order.start_offset_m == pytest.approx(cad.length)
    np.testing.assert_allclose(fused.positions[0], cad.positions[-1])
    err = drag_deg(fused) - drag_true(fused.s)
    assert np.sqrt(np.mean(err[3:-3] ** 2)) < 1.0


def test_a_demonstration_that_stays_mid_seam_is_ambiguous_and_names_both_distances():
    last = 400  # a straight stretch of the bead, L = 0.32 m; the worker only wiggles about its middle
    cad = cad_path(closed=False, last=last)
    demo, _ = demonstrate(np.r_[np.arange(200, 240), np.arange(238, 160, -1), np.arange(162, 201)], seed=2)
    with pytest.raises(InputError, match=r"which way round") as e:
        fuse(cad, demo, T_F_S, T_TCP_E)
    msg = str(e.value)
    drawn, rev = (float(x) for x in re.search(r"(\d+\.\d) mm as drawn, (\d+\.\d) mm reversed", msg).groups())
    # a demo about the middle is as far from the seam's ends either way: the path points lie
    # about L / 4 = 80 mm from it in the median, whichever end the run starts at
    L = cad.length
    assert 0.6 * L / 4 < drawn * 1e-3 < 1.4 * L / 4 and 0.6 * L / 4 < rev * 1e-3 < 1.4 * L / 4
    assert "[cad] reverse" in msg


def _write_dxf(path, pts_mm):
    doc = ezdxf.new("R2010")
    doc.modelspace().add_polyline3d(pts_mm.tolist(), close=True)
    doc.saveas(path)


@pytest.mark.parametrize("fmt", ["csv", "dxf", "gcode"])
def test_reverse_and_start_near_override_the_search_in_every_format(tmp_path, fmt):
    pts, _, L = footprint()
    mm = pts[::10] * 1e3  # 400 vertices, counter-clockwise
    f = tmp_path / f"bead.{ {'csv': 'csv', 'dxf': 'dxf', 'gcode': 'nc'}[fmt] }"
    if fmt == "csv":
        f.write_text("x,y,z\n" + "".join(f"{x},{y},{z}\n" for x, y, z in np.vstack([mm, mm[:1]])))
    elif fmt == "dxf":
        _write_dxf(f, mm)
    else:
        moves = "".join(f"G1 X{x:.6f} Y{y:.6f} Z0\n" for x, y, _ in np.vstack([mm[1:], mm[:1]]))
        f.write_text(f"G21 G90\nG0 X{mm[0, 0]:.6f} Y{mm[0, 1]:.6f} Z0\n" + moves)
    near = mm[100] + [0.0, 0.0, 5.0]  # vertex 100 = footprint point 1000, 5 mm above it
    settings = CadSettings(
        file=f, format=fmt, units="mm", spacing_m=SPACING, reverse=True, start_near=tuple(near)
    )
    cad = read_cad_path(settings, T_F_CAD)
    assert cad.closed and cad.reversed and cad.direction_given and cad.start_given
    assert cad.start_offset_m == pytest.approx(1000 * L / N_FOOT, abs=1e-3)
    np.testing.assert_allclose(cad.positions[0], transform_points(T_F_CAD, mm[100] * 1e-3), atol=1e-9)
    second = cad.positions[1] - cad.positions[0]  # clockwise: towards vertex 99
    assert second @ (transform_points(T_F_CAD, mm[99] * 1e-3) - cad.positions[0]) > 0
    # a worker going the other way from another start: the overrides win, nothing is searched
    demo, _ = demonstrate(1000 - np.arange(N_FOOT + 1), seed=4)
    fused = fuse(cad, demo, T_F_S, T_TCP_E)
    assert fused.order.direction == "reversed" and fused.order.direction_source == "problem"
    assert fused.order.start_source == "problem" and fused.order.residual_as_cad_m is None
    assert fused.order.start_offset_m == pytest.approx(1000 * L / N_FOOT, abs=1e-3)
    np.testing.assert_array_equal(fused.positions, cad.positions)


def test_start_near_alone_keeps_the_direction_search(tmp_path):
    pts, _, L = footprint()
    mm = pts[::10] * 1e3
    f = tmp_path / "bead.csv"
    f.write_text("".join(f"{x},{y},{z}\n" for x, y, z in np.vstack([mm, mm[:1]])))
    cad = read_cad_path(
        CadSettings(file=f, format="csv", spacing_m=SPACING, start_near=tuple(mm[300])), T_F_CAD
    )
    assert cad.start_given and not cad.direction_given
    demo, _ = demonstrate(3000 - np.arange(N_FOOT + 1), seed=9)
    fused = fuse(cad, demo, T_F_S, T_TCP_E)
    assert fused.order.direction == "reversed" and fused.order.direction_source == "alignment"
    assert fused.order.start_offset_m == pytest.approx(3000 * L / N_FOOT, abs=1e-3)  # chords of 400 vertices
    assert math.isclose(fused.order.start_offset_m, cad.start_offset_m)
