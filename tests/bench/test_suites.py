"""Suites files: every key checked, generated families with their documented parameters, noise and obstacles."""

from __future__ import annotations

import numpy as np
import pytest

from refine.bench.contenders import greedy_ik, refine_assembled, verify
from refine.bench.suites import FAMILY_KEYS, generated_problem, load_suites
from refine.errors import InputError
from refine.frames import rotation_angle_deg

FAMILY = """
[suite.s]
generated = ["wave"]
sizes = [20]

[generated.wave]
robot = "abb_irb4600_60_205"
centre_m = [1.3, 0.0, 0.6]
"""


def test_a_misspelt_family_key_is_an_error_naming_it_and_the_allowed_ones(tmp_path):
    path = tmp_path / "suites.toml"
    path.write_text(FAMILY + "lenght_m = 0.4\n")
    with pytest.raises(
        InputError,
        match=r"\[generated.wave\]: unknown key\(s\) \['lenght_m'\]; the keys are robot, centre_m, shape, length_m",
    ) as e:
        load_suites(path)
    assert e.value.key == "lenght_m"
    path.write_text(FAMILY + 'boxes = [{ name = "b", centre_m = [1, 0, 0], size = [0.1, 0.1, 0.1] }]\n')
    with pytest.raises(InputError, match=r"boxes\[0\] has keys \['centre_m', 'name', 'size'\]"):
        load_suites(path)
    path.write_text(FAMILY.replace('robot = "abb_irb4600_60_205"\n', ""))
    with pytest.raises(InputError, match="robot missing"):
        load_suites(path)
    path.write_text(FAMILY + "noise_deg = -1\n")
    with pytest.raises(InputError, match="noise_deg = -1 must be"):
        load_suites(path)
    path.write_text(FAMILY + "[suite.t]\nproblems = []\nsize = [1]\n")
    with pytest.raises(InputError, match=r"\[suite.t\] has unknown keys \['size'\]"):
        load_suites(path)


def test_the_wave_parameters_shape_the_path():
    base = {"robot": "abb_irb4600_60_205", "centre_m": [1.3, 0.0, 0.6]}
    wide = generated_problem(
        "s", "w", {**base, "length_m": 0.4, "amplitude_m": 0.08, "wavelength_m": 0.4}, 41
    )
    y, x = wide.fused.positions[:, 1], wide.fused.positions[:, 0]
    assert y[0] == pytest.approx(-0.2) and y[-1] == pytest.approx(0.2)
    assert x.max() - 1.3 == pytest.approx(0.08, abs=2e-3)  # a crest at y = 0.1 m of a 0.4 m wave
    # the drag angle: the tool's z axis leans from straight down by tilt_deg
    down = generated_problem("s", "w", {**base, "tilt_deg": 0.0}, 20).fused.rotations[:, :, 2]
    leaning = generated_problem("s", "w", {**base, "tilt_deg": 20.0}, 20).fused.rotations[:, :, 2]
    assert np.allclose(down, [0, 0, -1], atol=1e-9)
    assert np.degrees(np.arccos(-leaning[:, 2])) == pytest.approx(np.full(20, 20.0))
    assert set(FAMILY_KEYS) >= {"noise_deg", "noise_seed", "boxes", "speed_m_s"}


def test_orientation_noise_is_seeded_and_of_the_stated_size():
    base = {"robot": "abb_irb4600_60_205", "centre_m": [1.3, 0.0, 0.6]}
    clean = generated_problem("s", "w", base, 2000).fused
    noisy = generated_problem("s", "w", {**base, "noise_deg": 1.0}, 2000).fused
    again = generated_problem("s", "w", {**base, "noise_deg": 1.0}, 2000).fused
    other = generated_problem("s", "w", {**base, "noise_deg": 1.0, "noise_seed": 1}, 2000).fused
    angle = rotation_angle_deg(clean.rotations, noisy.rotations)
    # three independent normal components of 1 deg: E[angle²] = 3 deg²
    assert np.mean(angle**2) == pytest.approx(3.0, rel=0.1)
    assert np.array_equal(noisy.rotations, again.rotations) and not np.allclose(
        noisy.rotations, other.rotations
    )
    assert np.array_equal(noisy.positions, clean.positions)  # the CAD points stay exact


def test_the_tight_family_separates_greedy_ik_from_refine():
    data = load_suites()
    problem = generated_problem("separate", "irb4600_tight", data["generated"]["irb4600_tight"], 100)
    greedy = verify(problem, greedy_ik(problem).q)
    assert not greedy.verified and greedy.reason.startswith("collision") and "post" in greedy.reason
    refined = verify(problem, refine_assembled(problem).q)
    assert refined.verified and refined.min_clearance_m >= 0.0


def test_a_loop_family_is_a_closed_rounded_rectangle_the_tool_dragged_along_it():
    spec = {"robot": "abb_irb4600_60_205", "centre_m": [1.3, 0.0, 0.6], "shape": "loop", "length_m": 0.6}
    spec |= {"width_m": 0.3, "corner_radius_m": 0.05, "tilt_deg": 10.0}
    fused = generated_problem("s", "loop", spec, 400).fused
    x, y = fused.positions[:, 0], fused.positions[:, 1]
    # a 0.6 x 0.3 m rectangle about (1.3, 0): straights at x = 1.15 / 1.45 and y = -0.3 / 0.3
    assert x.min() == pytest.approx(1.15) and x.max() == pytest.approx(1.45, abs=1e-4)
    assert y.min() == pytest.approx(-0.3, abs=1e-4) and y.max() == pytest.approx(0.3, abs=1e-4)
    assert (x[0], y[0]) == pytest.approx((1.15, 0.0))  # the middle of the edge nearer the robot
    # the perimeter: 2 (0.5 + 0.2) of straights and a whole circle of 5 cm radius
    perimeter = 2 * (0.5 + 0.2) + 2 * np.pi * 0.05
    step = np.linalg.norm(np.diff(fused.positions, axis=0), axis=1)
    assert fused.s[-1] + step.mean() == pytest.approx(perimeter, rel=1e-4)
    assert np.linalg.norm(fused.positions[0] - fused.positions[-1]) == pytest.approx(step.mean(), rel=1e-2)
    # counter-clockwise seen from above (x right, y up): at the edge of least x the travel is -y; the tool's x axis along
    # the travel, its z axis down and leaning back against it by 10 deg
    travel = np.gradient(fused.positions, axis=0)[1:-1]
    travel /= np.linalg.norm(travel, axis=1, keepdims=True)
    R = fused.rotations[1:-1]
    assert travel[0] == pytest.approx([0.0, -1.0, 0.0], abs=1e-3)
    assert np.all(np.cross(fused.positions[1:-1] - [1.3, 0.0, 0.6], travel)[:, 2] > 0)  # turning left
    assert np.degrees(np.arccos(-R[:, 2, 2])) == pytest.approx(np.full(len(R), 10.0))
    assert np.einsum("ij,ij->i", R[:, :, 2], travel) == pytest.approx(-np.sin(np.radians(10.0)), abs=0.02)


def test_a_loop_needs_room_for_its_corners(tmp_path):
    path = tmp_path / "suites.toml"
    path.write_text(FAMILY + 'shape = "loop"\nwidth_m = 0.08\n')
    with pytest.raises(InputError, match="width_m must exceed twice corner_radius_m"):
        load_suites(path)
    path.write_text(FAMILY + 'shape = "spiral"\n')
    with pytest.raises(InputError, match="the shapes are wave, loop"):
        load_suites(path)
