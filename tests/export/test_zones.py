"""Blend zones against corner geometry computed by hand, and speed levels within the speed share."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from refine.errors import InputError
from refine.export.motion import program_motion
from refine.export.program import corner_deviation, speed_levels
from refine.paths import Trajectory
from refine.problem import Problem
from refine.settings import (
    CadSettings,
    DemoSettings,
    OutputSettings,
    ProcessSettings,
    RobotSettings,
    ToolSettings,
)

SIN45 = math.sqrt(0.5)


@pytest.mark.parametrize(
    ("legs_m", "turn_deg", "radius_m", "share", "expected_r", "expected_dev"),
    [
        ((0.01, 0.01), 90.0, 0.001, 0.5, 0.001, 0.001 * SIN45),  # r sin(45 deg)
        ((0.001, 0.01), 90.0, 0.001, 0.5, 0.0005, 0.0005 * SIN45),  # halved to half the shorter move
        ((0.01, 0.01), 0.0, 0.001, 0.5, 0.001, 0.0),  # straight on: no deviation
        ((0.01, 0.01), 60.0, 0.002, 0.4, 0.002, 0.002 * 0.5),  # sin(30 deg) = 1/2
        ((0.01, 0.01), 180.0, 0.001, 0.5, 0.001, 0.001),  # turning back: the whole radius
    ],
)
def test_the_corner_deviation_is_the_radius_times_the_sine_of_half_the_turn(
    legs_m, turn_deg, radius_m, share, expected_r, expected_dev
):
    corner = np.array([0.3, 0.1, 0.2])
    a = math.radians(turn_deg)
    before = corner - legs_m[0] * np.array([1.0, 0.0, 0.0])
    after = corner + legs_m[1] * np.array([math.cos(a), math.sin(a), 0.0])
    r, dev = corner_deviation(before, corner, after, radius_m, share)
    assert r == pytest.approx(expected_r, abs=1e-15) and dev == pytest.approx(expected_dev, abs=1e-12)


def _l_path(step_m: float = 0.005) -> Trajectory:
    """An L in the world xy plane, tool z up: 0..20 mm along x, then 5..20 mm along y (90 deg at k=4)."""
    xs = [(x, 0.0) for x in np.arange(0.0, 0.0201, step_m)] + [
        (0.02, y) for y in np.arange(step_m, 0.0201, step_m)
    ]
    n = len(xs)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :2, 3] = np.array(xs)
    poses[:, 2, 3] = 0.5
    speed = np.full(n, 0.05)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))])
    return Trajectory(
        s / 0.05, s, np.zeros((n, 6)), poses[:, :3, 3].copy(), poses, poses[:, :3, :3].copy(), speed
    )


def _problem(kind: str, tolerance_m: float | None = None, share: float = 0.02) -> Problem:
    return Problem(
        name="l",
        root=Path("."),
        robot=RobotSettings(model="abb_irb4600_60_205"),
        tool=ToolSettings(name="gun", tcp_in_flange=np.eye(4)),
        cad=CadSettings(file=Path("l.csv")),
        demonstration=DemoSettings(file=Path("d.txt")),
        process=ProcessSettings(kind=kind, path_tolerance_m=tolerance_m),
        output=OutputSettings(speed_share=share),
    )


def test_default_path_tolerance_per_process():
    assert ProcessSettings(kind="glue").path_tolerance_m == 0.0005
    assert ProcessSettings(kind="seal").path_tolerance_m == 0.0005
    assert ProcessSettings(kind="weld").path_tolerance_m == 0.0003
    assert ProcessSettings(kind="weld", path_tolerance_m=0.001).path_tolerance_m == 0.001
    with pytest.raises(InputError, match=r"path_tolerance_m .* m, got -0.001"):
        ProcessSettings(path_tolerance_m=-0.001)


def test_rapid_glue_corner_and_ends_take_z0_where_z1_would_cut_them_by_0_71_mm():
    """z1 at a 90 deg turn: 1 mm sin(45 deg) = 0.707 mm > 0.5 mm; z0: 0.3 mm sin(45 deg) = 0.212 mm.
    The ends turn 90 deg from the approach and onto the retract along the tool axis."""
    tr = _l_path()
    zones = program_motion("rapid", tr, _problem("glue")).zones
    corner, last = 4, len(tr) - 1
    assert [zones.label[k] for k in (0, corner, last)] == ["z0"] * 3
    assert set(np.delete(np.array(zones.label), [0, corner, last])) == {"z1"}
    assert zones.largest_deviation_m == pytest.approx(0.0003 * SIN45)
    assert zones.narrowed == (0, corner, last)
    tight = program_motion("rapid", tr, _problem("glue", 0.0002)).zones  # below 0.212 mm: exact stops
    assert [tight.label[k] for k in (0, corner, last)] == ["fine"] * 3 and tight.largest_deviation_m == 0.0


def test_a_weld_stops_exactly_at_its_ends_and_keeps_0_3_mm_at_the_corner():
    zones = program_motion("rapid", _l_path(), _problem("weld")).zones
    assert zones.label[0] == zones.label[-1] == "fine"
    assert zones.label[4] == "z0" and zones.deviation_m[4] == pytest.approx(0.0003 * SIN45)


def test_krl_is_exact_and_urscript_blends_as_far_as_the_tolerance_allows_at_a_corner():
    tr = _l_path()
    krl = program_motion("krl", tr, _problem("glue")).zones
    assert krl.label[4] == "exact" and krl.label[2] == "C_DIS" and krl.deviation_m[4] == 0.0
    ur = program_motion("urscript", tr, _problem("glue")).zones
    # r with r sin(45 deg) = 0.5 mm: 0.707 mm (40 % of the 5 mm moves is 2 mm, no cap)
    assert ur.radius_m[4] == pytest.approx(0.0005 / SIN45) and ur.deviation_m[4] == pytest.approx(0.0005)
    assert ur.radius_m[2] == pytest.approx(0.001)  # a straight target keeps the asked 1 mm


def test_with_a_share_every_segment_runs_within_it_with_the_fewest_levels():
    """Speeds 1.0, 0.97, 0.9, 0.5 m/s, 5 % share: 0.5 serves only itself (0.9 x 0.95 > 0.5), 0.9 only
    itself (0.97 x 0.95 > 0.9), 0.97 serves 0.97 and 1.0 (1.0 x 0.95 <= 0.97): three levels."""
    speeds, lengths = np.array([1.0, 0.97, 0.9, 0.5]), np.array([0.1, 0.1, 0.1, 0.1])
    levels, index = speed_levels(speeds, lengths, 1, 1e-3, share=0.05)
    np.testing.assert_allclose(levels, [0.5, 0.9, 0.97])
    np.testing.assert_allclose(levels[index], [0.97, 0.97, 0.9, 0.5])
    (single,), _ = speed_levels(speeds, lengths, 1, 1e-3)  # without a share: one level, the slowest
    assert single == pytest.approx(0.5)


def test_rapid_speeds_of_a_ramp_stay_within_the_share_and_the_report_figures_say_so():
    tr = _l_path()
    tr = dataclasses.replace(tr, speed=np.linspace(0.02, 0.1, len(tr)))
    for share in (0.02, 0.2):
        m = program_motion("rapid", tr, _problem("glue", share=share))
        planned = 0.5 * (tr.speed[1:] + tr.speed[:-1])
        assert np.all(m.programmed_m_s <= planned + 1e-12)
        assert np.all(m.programmed_m_s >= (1.0 - share) * planned - 1e-12)
        assert m.beyond_share == [] and m.as_json()["largest_speed_shortfall_rel"] <= share
        np.testing.assert_allclose(m.difference_rel, (m.programmed_m_s - planned) / planned)


def test_the_problem_file_sets_the_path_tolerance_and_the_speed_share(tmp_path):
    import shutil

    from refine.problem import load_problem

    folder = tmp_path / "glass_adhesive"
    shutil.copytree(Path(__file__).resolve().parents[2] / "problems" / "glass_adhesive", folder)
    toml = folder / "problem.toml"
    text = toml.read_text(encoding="utf-8")
    text = text.replace("[process]\n", "[process]\npath_tolerance_m = 0.0002\n", 1)
    toml.write_text(text.replace("[output]\n", "[output]\nspeed_share = 0.05\n", 1), encoding="utf-8")
    problem = load_problem(folder)
    assert problem.process.path_tolerance_m == 0.0002 and problem.output.speed_share == 0.05
    toml.write_text(toml.read_text(encoding="utf-8").replace("speed_share = 0.05", "speed_share = 0.9"))
    with pytest.raises(InputError, match=r"output.speed_share must be a finite number in \[0.0001, 0.5\]"):
        load_problem(folder)


def test_a_pass_motion_asked_for_again_is_the_one_computed_and_another_problem_is_its_own():
    """The same trajectory and problem objects (options spelled out as their defaults or not) give
    the motion computed first, read-only; a problem with another tolerance gets its own zones (the
    hand figures of the z1/z0 test above), and so does an equal trajectory that is another object."""
    tr, problem = _l_path(), _problem("glue")
    first = program_motion("rapid", tr, problem)
    assert program_motion("rapid", tr, problem, zone="z1", retract_m=0.1) is first
    assert not first.zones.deviation_m.flags.writeable and not first.programmed_m_s.flags.writeable
    tight = program_motion("rapid", tr, _problem("glue", 0.0002))
    assert tight.zones.largest_deviation_m == 0.0 and first.zones.largest_deviation_m == pytest.approx(0.0003 * SIN45)
    again = program_motion("rapid", dataclasses.replace(tr), problem)
    assert again is not first and again.zones.label == first.zones.label
    assert program_motion("krl", tr, problem) is not program_motion("urscript", tr, problem)
