"""FANUC CNT and Yaskawa PL zones and the TP and INFORM speeds, against corner geometry worked by hand.

The TP model (docs/outputs.md): ``CNT n`` starts its corner ``d = n/100 · v · T/2`` before the target
(``T`` = 0.5 s, ``v`` the faster neighbouring move), at most half of either move, and deviates by
``d · sin(turn/2)``. The INFORM model: ``PL=n`` may take up to half of the shorter move.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from refine.errors import InputError
from refine.export.motion import program_motion
from refine.paths import Trajectory
from refine.settings import OutputSettings, ProcessSettings

SIN45 = math.sqrt(0.5)


def _path(xy_m: list[tuple[float, float]], speed_m_s: float) -> Trajectory:
    """Targets in the plane z = 0.5 m, tool z up, at one planned speed."""
    n = len(xy_m)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :2, 3] = np.array(xy_m)
    poses[:, 2, 3] = 0.5
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    return Trajectory(
        s / speed_m_s,
        s,
        np.zeros((n, 6)),
        poses[:, :3, 3].copy(),
        poses,
        poses[:, :3, :3].copy(),
        np.full(n, speed_m_s),
    )


def _l_path(speed_m_s: float) -> Trajectory:
    """0..20 mm along x, then 5..20 mm along y in 5 mm steps: a 90 deg turn at target 4."""
    return _path([(0.005 * i, 0.0) for i in range(5)] + [(0.02, 0.005 * i) for i in range(1, 5)], speed_m_s)


@pytest.fixture(scope="module")
def make(problem):
    """``make(kind, tolerance_m, share)``: the exporter tests' problem with that process and speed share."""

    def build(kind: str, tolerance_m: float | None = None, share: float = 0.02):
        process = ProcessSettings(kind=kind, path_tolerance_m=tolerance_m)
        return dataclasses.replace(problem, process=process, output=OutputSettings(speed_share=share))

    return build


def test_tp_glue_corner_takes_the_largest_cnt_that_keeps_half_a_millimetre(make):
    """50 mm/s: d(100) = 50 x 0.25 = 12.5 mm, capped at 2.5 mm (half a 5 mm move): 1.77 mm off at the
    corner, so n = floor(100 x 0.5 / (12.5 sin 45)) = 5, d = 0.625 mm, 0.442 mm off. The ends turn
    90 deg from the approach (250 mm/s: d(100) = 62.5 mm): n = floor(100 x 0.5 / (62.5 sin 45)) = 1."""
    m = program_motion("tp", _l_path(0.05), make("glue"))
    z = m.zones
    assert z.label == ("CNT1", "CNT100", "CNT100", "CNT100", "CNT5", "CNT100", "CNT100", "CNT100", "CNT1")
    assert z.radius_m[4] == pytest.approx(0.000625) and z.deviation_m[4] == pytest.approx(0.000625 * SIN45)
    assert z.radius_m[2] == pytest.approx(0.0025) and z.deviation_m[2] == pytest.approx(0.0, abs=1e-12)
    assert z.deviation_m[0] == pytest.approx(0.000625 * SIN45) and z.narrowed == (0, 4, 8)
    np.testing.assert_allclose(m.programmed_m_s, 0.05)  # a whole 50 mm/sec


def test_tp_tighter_tolerance_gives_cnt2_at_the_corner_and_fine_at_the_ends(make):
    """0.2 mm: corner floor(20 / 8.84) = 2 (0.177 mm off); the ends floor(20 / 44.2) = 0, so FINE."""
    z = program_motion("tp", _l_path(0.05), make("glue", 0.0002)).zones
    assert (z.label[0], z.label[4], z.label[-1]) == ("FINE", "CNT2", "FINE")
    assert z.deviation_m[4] == pytest.approx(0.00025 * SIN45) and z.deviation_m[0] == 0.0
    assert z.largest_deviation_m <= 0.0002


def test_tp_weld_is_fine_at_its_ends_and_the_slow_corner_keeps_cnt20(make):
    """Planned 8.3 mm/s; whole mm/sec would be 8 mm/s, 3.6 % slow (share 2 %), so 49 cm/min =
    8.1667 mm/s, 1.6 % slow, is written. At that speed d(100) = 2.042 mm (below the 2.5 mm cap),
    1.444 mm off at the corner: floor(30 / 1.444) = 20."""
    m = program_motion("tp", _l_path(0.0083), make("weld"))
    np.testing.assert_allclose(m.programmed_m_s, 49.0 / 6000.0)
    assert m.zones.label[0] == m.zones.label[-1] == "FINE" and m.zones.label[4] == "CNT20"
    assert m.zones.deviation_m[4] == pytest.approx(0.2 * (49.0 / 6000.0) * 0.25 * SIN45)
    assert m.beyond_share == []


def test_tp_with_a_lower_cnt_asked_keeps_it_where_the_tolerance_allows(make):
    z = program_motion("tp", _l_path(0.05), make("glue"), cnt=50).zones
    assert z.label[2] == "CNT50" and z.label[4] == "CNT5"
    with pytest.raises(InputError, match="cnt must be 1..100"):
        program_motion("tp", _l_path(0.05), make("glue"), cnt=0)


def test_inform_pl0_at_a_corner_the_half_move_would_cut_and_pl1_on_an_arc(make):
    """PL=1 may take half a 5 mm move: 2.5 sin 45 = 1.77 mm > 0.5 mm at the corner and the ends."""
    z = program_motion("inform", _l_path(0.05), make("glue")).zones
    assert z.label == ("PL=0", "PL=1", "PL=1", "PL=1", "PL=0", "PL=1", "PL=1", "PL=1", "PL=0")
    assert z.largest_deviation_m == pytest.approx(0.0, abs=1e-12)
    # a 20 mm radius arc at 2 mm chords turns 0.1 rad per target: 1 mm x sin(0.05) = 0.05 mm off
    a = np.arange(0.0, 1.5, 0.1)
    arc = _path([(0.02 * math.cos(t), 0.02 * math.sin(t)) for t in a], 0.0083)
    z = program_motion("inform", arc, make("weld")).zones
    assert z.label[0] == z.label[-1] == "PL=0" and set(z.label[1:-1]) == {"PL=1"}
    chord = 2 * 0.02 * math.sin(0.05)
    np.testing.assert_allclose(z.deviation_m[1:-1], 0.5 * chord * math.sin(0.05), rtol=1e-9)


def test_inform_speeds_stay_within_the_share_at_a_tenth_of_a_millimetre(make):
    tr = dataclasses.replace(_l_path(0.05), speed=np.linspace(0.005, 0.05, 9))
    m = program_motion("inform", tr, make("glue", share=0.02))
    planned = 0.5 * (tr.speed[1:] + tr.speed[:-1])
    assert np.all(m.programmed_m_s <= planned + 1e-12)
    assert np.all(m.programmed_m_s >= 0.98 * planned - 1e-12)
    np.testing.assert_allclose(m.programmed_m_s * 1e4, np.round(m.programmed_m_s * 1e4), atol=1e-6)
    assert program_motion("inform", tr, make("glue"), pl=0).zones.label == ("PL=0",) * 9


def test_speed_levels_end_where_the_resolution_cannot_keep_the_share():
    """5.15 mm/s at 1/6 mm/s steps: 5.0 mm/s is 2.9 % slow (share 2 %); the level is 5.0 mm/s alone."""
    from refine.export.program import speed_levels

    levels, index = speed_levels(
        np.array([0.00515, 0.05]), np.array([0.01, 0.01]), 1, 1.0 / 6000.0, share=0.02
    )
    np.testing.assert_allclose(levels[index], [0.005, 0.05])


def test_tp_slow_weld_speeds_fall_back_to_tenths_of_an_inch_per_minute(make):
    """5.15 mm/s: 5 mm/sec and 30 cm/min (5.0 mm/s) are both 2.9 % slow (share 2 %); 5.15 mm/s is
    12.165 inch/min, so 12.1 inch/min = 5.1223 mm/s, 0.5 % slow."""
    m = program_motion("tp", _l_path(0.00515), make("weld"))
    np.testing.assert_allclose(m.programmed_m_s, 12.1 * 0.0254 / 60.0)
    assert m.beyond_share == []
