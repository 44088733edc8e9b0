from pathlib import Path

import numpy as np
import pytest

from refine.cad import read_cad_path
from refine.calibrate.receiver_path import register_receiver_to_path
from refine.calibrate.simulate import calibration_tracker_model
from refine.demo.simulate import simulate_demonstration
from refine.errors import InputError
from refine.frames import invert_transform, rotation_angle_deg, transform_from_xyz_rpy
from refine.problem import load_problem

GLASS = Path(__file__).resolve().parents[2] / "problems" / "glass_adhesive"


@pytest.fixture(scope="module")
def trace():
    problem = load_problem(GLASS)
    cad = read_cad_path(problem.cad, problem.frames.cad_in_world)
    n = len(cad.s)
    down = np.broadcast_to(np.diag([1.0, -1.0, -1.0]), (n, 3, 3))  # the gun pointing down
    model = calibration_tracker_model(seed=7, pause_s=0.5)
    demo = simulate_demonstration(
        cad.s,
        cad.positions,
        down,
        np.full(n, 0.25),
        problem.frames.source_in_world,
        problem.tool.sensor_in_tcp,
        model,
    )
    tip = invert_transform(problem.tool.sensor_in_tcp)[:3, 3]
    return problem, cad, demo, tip


def test_a_trace_along_the_path_registers_the_receiver(trace):
    """From 4 cm and 2.5 deg off, ICP with the z model ends within 1 mm and 0.1 deg."""
    problem, cad, demo, tip = trace
    truth = problem.frames.source_in_world
    guess = truth @ transform_from_xyz_rpy([0.02, -0.03, 0.01], [1.0, -1.0, 2.0])
    cal = register_receiver_to_path(demo.log, tip, cad.positions, guess)
    T = cal.values["source_in_world"]
    assert np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 1e-3
    assert rotation_angle_deg(T[:3, :3], truth[:3, :3]) < 0.1
    plain = register_receiver_to_path(demo.log, tip, cad.positions, guess, fit_z=False, max_rms_m=0.05)
    assert np.linalg.norm(plain.values["source_in_world"][:3, 3] - truth[:3, 3]) > 3e-3


def test_a_far_first_guess_is_an_error(trace):
    problem, cad, demo, tip = trace
    guess = problem.frames.source_in_world @ transform_from_xyz_rpy([0.5, 0.4, 0.0], [0.0, 0.0, 60.0])
    with pytest.raises(InputError, match="first guess"):
        register_receiver_to_path(demo.log, tip, cad.positions, guess)


FAR_GUESSES = [
    ([0.5, 0.4, 0.0], [0.0, 0.0, 60.0]),
    ([0.3, -0.2, 0.05], [0.0, 0.0, 120.0]),
    ([-0.4, 0.3, 0.0], [0.0, 0.0, 175.0]),
    ([0.2, 0.35, -0.1], [0.0, 0.0, -90.0]),
]


@pytest.mark.parametrize(("xyz", "rpy"), FAR_GUESSES)
def test_far_guesses_allowed_find_the_true_frame_not_its_turned_copy(trace, xyz, rpy):
    """The window fits turned 180 deg about the vertical as well; the direction of travel decides."""
    problem, cad, demo, tip = trace
    truth = problem.frames.source_in_world
    guess = truth @ transform_from_xyz_rpy(xyz, rpy)
    cal = register_receiver_to_path(
        demo.log, tip, cad.positions, guess, max_guess_offset_m=np.inf, max_guess_turn_deg=360.0
    )
    T = cal.values["source_in_world"]
    assert np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 1e-3
    assert rotation_angle_deg(T[:3, :3], truth[:3, :3]) < 0.1
    assert cal.figures["tool_down_share"] == 1.0 and cal.figures["travel_rank_correlation"] > 0.5


def test_the_far_guess_error_names_the_distance_to_the_frame_found(trace):
    problem, cad, demo, tip = trace
    guess = problem.frames.source_in_world @ transform_from_xyz_rpy([0.5, 0.4, 0.0], [0.0, 0.0, 60.0])
    with pytest.raises(InputError, match=r"64[01] mm and 60\.0 deg from the first guess"):
        register_receiver_to_path(demo.log, tip, cad.positions, guess)
