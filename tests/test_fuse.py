"""Tests for refine.fuse.align on synthetic demonstrations with a known ground truth."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from refine.errors import InputError
from refine.frames import (
    invert_transform,
    make_transform,
    matrix_from_zyx,
    rotation_angle_deg,
    transform_from_xyz_rpy,
)
from refine.fuse.align import align, demo_tcp_poses, monotone_dtw
from refine.fuse.fusion import fuse
from refine.paths import CadPath, Demonstration

log = logging.getLogger(__name__)

T_F_S = transform_from_xyz_rpy([0.2, -0.3, 0.55], [180.0, 0.0, 30.0])  # receiver under the table
T_TCP_E = transform_from_xyz_rpy([0.03, -0.05, 0.15], [10.0, -20.0, 35.0])  # sensor on the gun
T_F_PART = transform_from_xyz_rpy([0.9, 0.1, 0.75], [0.0, 0.0, 10.0])
TILT = np.radians(15.0)


@dataclass(frozen=True)
class Case:
    cad: CadPath
    demo: Demonstration
    s_of_t: Callable  # true arc length [m] at a demo time [s]
    speed_of_s: Callable  # true speed along the path [m/s]
    position_of_s: Callable  # true TCP position in {F} [m]
    rotation_of_s: Callable  # true R_F_TCP


def rounded_rectangle(width=1.2, height=0.5, r=0.12, ds=1e-4):
    """Dense (s, points (n, 3), heading [rad]) of a closed loop, from the end of a corner."""
    a, b, q = width - 2 * r, height - 2 * r, np.pi * r / 2
    pieces = [a, q, b, q, a, q, b, q]
    edges = np.cumsum([0.0, *pieces])
    s = np.linspace(0.0, edges[-1], int(edges[-1] / ds) + 1)
    k = np.clip(np.searchsorted(edges, s, "right") - 1, 0, 7)
    on_arc = k % 2 == 1
    heading = (k // 2) * np.pi / 2 + np.where(on_arc, (s - edges[k]) / r, 0.0)
    heading[k == 7] = 3 * np.pi / 2 + (s[k == 7] - edges[7]) / r
    xy = cumulative_trapezoid(np.stack([np.cos(heading), np.sin(heading)], 1), s, axis=0, initial=0)
    xy += [-a / 2, -height / 2]
    return s, np.column_stack([xy, np.zeros(len(s))]), heading


def spatial_curve(ds=1e-4):
    """Dense (s, points, heading) of an open rising arc: 270 deg of a 0.35 m circle, 0.2 m climb."""
    u = np.linspace(0.0, 1.5 * np.pi, 200_001)
    pts = np.column_stack([0.35 * np.cos(u), 0.35 * np.sin(u), 0.2 * u / (1.5 * np.pi)])
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]
    heading = np.unwrap(np.arctan2(*np.gradient(pts, axis=0)[:, [1, 0]].T))
    return s, pts, heading


def make_case(
    curve,
    closed,
    seed=0,
    pause=2.0,
    rate=240.0,
    noise=1e-3,
    z_err=0.06,
    xy_err=3e-3,
    spacing=0.005,
    end_pause=0.5,
    stop=(0.0, 0.0),
):
    """CAD path every ``spacing`` and a demonstration with a Liberty's kind of errors.

    The worker rests ``pause`` s at the start and ``end_pause`` s at the end, moves at 60-120 mm/s
    (ramping up and down over the first and last 30 mm), the yaw follows the tangent and the tool
    is tilted 15 deg. The sensor positions in {S} get a z error growing with the squared distance
    from the receiver to ``z_err``, a smooth (not polynomial) x/y error of ``xy_err`` and white
    noise of ``noise`` per axis [m]; orientations are exact.
    """
    rng = np.random.default_rng(seed)
    s_d, pts_d, head_d = curve
    L = s_d[-1]
    pts_d = pts_d @ T_F_PART[:3, :3].T + T_F_PART[:3, 3]
    head_d = head_d + np.radians(10.0)

    def position(s):
        return np.column_stack([np.interp(s, s_d, c) for c in pts_d.T])

    def rotation(s):
        yaw = np.interp(s, s_d, head_d)
        return matrix_from_zyx(yaw, np.full_like(yaw, TILT), np.full_like(yaw, np.pi))

    def ramp(x):
        u = np.clip(x / 0.03, 0.0, 1.0)
        return 0.2 + 0.8 * u * u * (3.0 - 2.0 * u)

    def speed(s):
        return (0.09 + 0.03 * np.sin(2 * np.pi * s / 1.3 + 0.5)) * ramp(s) * ramp(L - s)

    s_cad = np.linspace(0.0, L, int(round(L / spacing)) + 1)
    cad = CadPath(s_cad, position(s_cad), closed=closed, source="synthetic")

    s_f = np.linspace(0.0, L, 50_001)
    t_f = pause + cumulative_trapezoid(1.0 / speed(s_f), s_f, initial=0.0)
    t_f[s_f > stop[0]] += stop[1]  # the worker stops for stop[1] s at s = stop[0]
    t = np.arange(0.0, t_f[-1] + end_pause, 1.0 / rate)
    s_t = np.interp(t, t_f, s_f)
    T_F_TCP = make_transform(rotation(s_t), position(s_t))
    T_S_E = invert_transform(T_F_S) @ T_F_TCP @ T_TCP_E
    p = T_S_E[:, :3, 3]
    d = np.linalg.norm(p, axis=1)
    p = (
        p
        + np.column_stack(
            [
                xy_err * np.sin(2.1 * p[:, 0] + 1.3 * p[:, 1] + 0.3),
                xy_err * np.cos(1.7 * p[:, 0] - 2.2 * p[:, 1] + 0.7),
                z_err * (d / d.max()) ** 2,
            ]
        )
        + rng.normal(0.0, noise, p.shape)
    )
    v = np.linalg.norm(np.gradient(p, t, axis=0), axis=1)
    demo = Demonstration(t, p, T_S_E[:, :3, :3], v, int(np.searchsorted(t, pause)), 0, "synthetic")
    return Case(cad, demo, lambda tq: np.interp(tq, t_f, s_f), speed, position, rotation)


@pytest.fixture(scope="module")
def loop():
    case = make_case(rounded_rectangle(), closed=True)
    return case, fuse(case.cad, case.demo, T_F_S, T_TCP_E)


@pytest.fixture(scope="module")
def arc():
    case = make_case(spatial_curve(), closed=False, seed=1)
    return case, fuse(case.cad, case.demo, T_F_S, T_TCP_E)


def accuracy(case, fused):
    """Arc-length error [m], relative speed error away from the ends, orientation error [deg]."""
    s_err = case.s_of_t(fused.t_demo) - fused.s
    inner = (fused.s > 0.05) & (fused.s < fused.s[-1] - 0.05)
    v_err = fused.speed[inner] / case.speed_of_s(fused.s[inner]) - 1.0
    ang = rotation_angle_deg(fused.rotations, case.rotation_of_s(fused.s))
    log.info(
        "s error RMS %.2f max %.2f mm; speed error RMS %.2f max %.2f %%; orientation error "
        "RMS %.3f max %.3f deg; residual median %.2f mm",
        1e3 * np.sqrt(np.mean(s_err**2)),
        1e3 * np.abs(s_err).max(),
        100 * np.sqrt(np.mean(v_err**2)),
        100 * np.abs(v_err).max(),
        np.sqrt(np.mean(ang**2)),
        ang.max(),
        1e3 * np.median(fused.residual),
    )
    return s_err, v_err, ang


def test_tcp_poses_compose_receiver_sensor_and_mounting():
    case = make_case(rounded_rectangle(), closed=True, noise=0.0, z_err=0.0, xy_err=0.0)
    T = demo_tcp_poses(case.demo, T_F_S, T_TCP_E)
    s = case.s_of_t(case.demo.t)
    assert float(np.abs(T[:, :3, 3] - case.position_of_s(s)).max()) < 1e-9
    assert float(rotation_angle_deg(T[:, :3, :3], case.rotation_of_s(s)).max()) < 1e-6


def test_monotone_dtw_follows_the_cheapest_monotone_path():
    demo = np.array([0.0, 0.0, 0.4, 1.0, 2.1, 3.9, 4.0, 4.0])
    cad = np.arange(5.0)
    cols = monotone_dtw(np.abs(demo[:, None] - cad[None, :]))
    np.testing.assert_array_equal(cols, [0, 0, 0, 1, 2, 4, 4, 4])
    with pytest.raises(InputError, match="cannot cover"):
        monotone_dtw(np.zeros((2, 9)))


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def peak(x):
    return float(np.max(np.abs(x)))


def test_closed_path_is_matched_within_3_mm_of_arc_length(loop):
    case, fused = loop
    s_err, _, _ = accuracy(case, fused)
    assert peak(s_err) < 3e-3
    assert rms(s_err) < 1.5e-3
    np.testing.assert_array_equal(fused.positions, case.cad.positions)
    assert np.all(np.diff(fused.t_demo) > 0.0)


def test_speed_is_within_3_percent_of_truth_away_from_the_ends(loop):
    case, fused = loop
    _, v_err, _ = accuracy(case, fused)
    assert peak(v_err) < 0.03
    assert float(fused.speed.min()) >= 0.1 * float(np.median(fused.speed)) - 1e-12


def test_orientation_follows_the_true_tool_within_a_degree(loop):
    case, fused = loop
    _, _, ang = accuracy(case, fused)
    assert rms(ang) < 0.3
    assert peak(ang) < 1.0


def test_residual_is_small_once_the_tracker_distortion_is_fitted(loop):
    case, fused = loop
    raw = align(case.cad, case.demo, T_F_S, T_TCP_E, fit_distortion=False)
    assert float(np.median(fused.residual)) < 3e-3
    assert float(np.median(raw.residual)) > 3 * float(np.median(fused.residual))
    assert rms(case.s_of_t(raw.t) - case.cad.s) > 2 * rms(case.s_of_t(fused.t_demo) - fused.s)


def test_fitting_the_distortion_does_no_harm_on_an_exact_tracker():
    case = make_case(rounded_rectangle(), closed=True, z_err=0.0, xy_err=0.0)
    plain = align(case.cad, case.demo, T_F_S, T_TCP_E, fit_distortion=False)
    fitted = align(case.cad, case.demo, T_F_S, T_TCP_E)
    assert fitted.max_correction < 2e-3
    assert rms(case.s_of_t(fitted.t) - case.s_of_t(plain.t)) < 0.3e-3


def test_open_spatial_path_is_matched_too(arc):
    case, fused = arc
    s_err, v_err, ang = accuracy(case, fused)
    assert peak(s_err) < 3e-3
    assert peak(v_err) < 0.03
    assert rms(ang) < 0.3 and peak(ang) < 1.0


@pytest.mark.parametrize(
    "variant",
    [
        {"pause": 0.0},  # no rest at the start
        {"rate": 60.0},  # a slower tracker
        {"spacing": 0.001},  # a dense CAD path
        {"late_start_s": 0.5},  # motion_start detected 0.5 s after the tool moved
    ],
)
def test_alignment_holds_for_other_demonstrations(variant):
    variant = dict(variant)
    late = variant.pop("late_start_s", 0.0)
    case = make_case(rounded_rectangle(), closed=True, seed=3, **variant)
    start = int(np.searchsorted(case.demo.t, case.demo.t[case.demo.motion_start] + late))
    fused = fuse(case.cad, replace(case.demo, motion_start=start), T_F_S, T_TCP_E)
    s_err, _, ang = accuracy(case, fused)
    assert peak(s_err) < 3e-3
    assert rms(ang) < 0.3 and peak(ang) < 1.0


def test_demo_in_the_wrong_frame_is_rejected(loop):
    case, _ = loop
    shifted = make_transform(T_F_S[:3, :3], T_F_S[:3, 3] + [0.0, 0.5, 0.0])
    with pytest.raises(InputError, match="does not follow the CAD path.*mm"):
        fuse(case.cad, case.demo, shifted, T_TCP_E)


def test_demo_that_stops_early_is_rejected(loop):
    case, _ = loop
    d, m = case.demo, int(0.7 * len(case.demo.t))
    short = replace(d, t=d.t[:m], positions=d.positions[:m], rotations=d.rotations[:m], speed=d.speed[:m])
    with pytest.raises(InputError, match=r"does not cover .* between s = 2\.\d\d and 3\.19 m"):
        fuse(case.cad, short, T_F_S, T_TCP_E)


def test_demo_in_the_wrong_time_unit_is_rejected(loop):
    case, _ = loop
    with pytest.raises(InputError, match="wrong time units"):
        fuse(case.cad, replace(case.demo, t=case.demo.t / 1000.0), T_F_S, T_TCP_E)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"speed_smoothing_m": 0.0}, "speed_smoothing_m"),
        ({"source_in_world": np.eye(3)}, "source_in_world"),
        ({"sensor_in_tcp": 2 * np.eye(4)}, "sensor_in_tcp"),
    ],
)
def test_bad_arguments_are_named(loop, kwargs, message):
    case, _ = loop
    args = {"source_in_world": T_F_S, "sensor_in_tcp": T_TCP_E, **kwargs}
    with pytest.raises(InputError, match=message):
        fuse(case.cad, case.demo, **args)


def test_non_increasing_demo_times_are_rejected(loop):
    case, _ = loop
    t = case.demo.t.copy()
    t[-5] = t[-6]
    with pytest.raises(InputError, match="strictly increasing"):
        fuse(case.cad, replace(case.demo, t=t), T_F_S, T_TCP_E)


def test_the_demonstration_as_fused_is_the_true_tool_path_once_the_distortion_is_corrected(loop):
    case, fused = loop
    # the worker's true TCP at each matched time, from the simulation itself
    truth = case.position_of_s(case.s_of_t(fused.t_demo))
    # the demonstrated TCP at the matched times before any correction, by hand: the positions in {S}
    # moved by the sensor's lever, interpolated in time, into {F}
    p = case.demo.positions + np.einsum("mij,j->mi", case.demo.rotations, invert_transform(T_TCP_E)[:3, 3])
    raw = (
        np.column_stack([np.interp(fused.t_demo, case.demo.t, c) for c in p.T]) @ T_F_S[:3, :3].T
        + T_F_S[:3, 3]
    )
    corrected = np.linalg.norm(fused.demo_positions - truth, axis=1)
    uncorrected = np.linalg.norm(raw - truth, axis=1)
    log.info(
        "demo as fused: %.2f mm median, %.2f mm max from the truth (%.1f mm before the correction)",
        1e3 * np.median(corrected),
        1e3 * corrected.max(),
        1e3 * np.median(uncorrected),
    )
    assert float(np.median(uncorrected)) > 0.02  # the z distortion (60 mm far from the receiver)
    assert float(np.median(corrected)) < 2e-3 and float(corrected.max()) < 6e-3
    # the fusion's residual is the distance of this demonstration to the CAD point
    np.testing.assert_allclose(
        np.linalg.norm(fused.demo_positions - fused.positions, axis=1), fused.residual, atol=1e-12
    )
