"""Tests of the shared helpers of the problem generators in refine.synthetic."""

from __future__ import annotations

import math

import numpy as np
import pytest

from refine.collision import CollisionModel
from refine.frames import make_transform
from refine.optimise.seed import start_candidates
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot
from refine.settings import Shape
from refine.synthetic import (
    periodic_wave,
    polish_ik,
    reachability_report,
    rounded_rectangle,
    tool_rotations,
    wave_path,
)


def test_rounded_rectangle_perimeter_spacing_and_tangents():
    half_u, half_v, r, n = 0.4, 0.25, 0.08, 800
    u, v, du, dv, corner, perimeter = rounded_rectangle(half_u, half_v, r, n)
    assert perimeter == pytest.approx(4 * (half_u + half_v) - (8 - 2 * math.pi) * r)
    assert (u[0], v[0]) == (0.0, -half_v)
    steps = np.hypot(np.diff(np.append(u, u[0])), np.diff(np.append(v, v[0])))
    assert np.allclose(steps, perimeter / n, rtol=1e-3)  # chords on the arcs are a little shorter
    assert np.allclose(np.hypot(du, dv), 1.0)
    assert np.sum(u * np.roll(v, -1) - np.roll(u, -1) * v) > 0.0  # counter-clockwise
    on_arc = (np.abs(u) > half_u - r + 1e-12) & (np.abs(v) > half_v - r + 1e-12)
    assert np.array_equal(corner, on_arc)
    assert np.abs(u).max() <= half_u + 1e-12 and np.abs(v).max() <= half_v + 1e-12


def test_periodic_wave_closes_and_draws_one_phase_per_amplitude():
    rng = np.random.default_rng(1)
    sigma = np.linspace(0.0, 2.0, 201)
    w = periodic_wave(sigma, 2.0, (1.0, 0.5), rng)
    assert w[0] == pytest.approx(w[-1])
    assert np.abs(w).max() <= 1.5
    reference = np.random.default_rng(1)
    reference.uniform(size=2)
    assert rng.uniform() == reference.uniform()


def test_tool_rotations_are_rotations_with_the_drag_angle():
    n = 50
    phi = np.linspace(0.0, 2 * np.pi, n)
    tangents = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(n)])
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    drag = np.radians(np.full(n, 15.0))
    R = tool_rotations(tangents, normals, drag)
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3))
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(-R[:, 2, 2], np.cos(drag))  # tool z leans 15 deg off straight down
    assert np.allclose(np.einsum("ij,ij->i", R[:, :, 2], tangents), -np.sin(drag))  # leans back
    tilted = tangents + 0.3 * normals  # not orthogonal: projecting gives the same frames
    assert np.allclose(tool_rotations(tilted, normals, drag, project=True), R)


@pytest.fixture(scope="module")
def kin():
    robot = load_robot("ur10e")
    return TcpKinematics(robot, np.eye(4), make_transform(None, [0.0, 0.0, 0.15]))


def problem_targets(n=12):
    path = wave_path(n, length_m=0.4, centre=(0.7, 0.0, 0.3))
    return make_transform(path.rotations, path.positions)


def test_reachability_report_reaches_a_wave(kin):
    margin = math.radians(2.0)
    lower, upper = kin.robot.spec.lower + margin, kin.robot.spec.upper - margin
    targets = problem_targets()
    report = reachability_report(
        kin,
        targets,
        joint_margin_rad=margin,
        starts=start_candidates(lower, upper, None),
        polish_iterations=5,
    )
    assert report.qs.shape == (len(targets), 6)
    assert report.chain_errors.max() < 1e-6
    assert report.errors.max() < 1e-9
    assert report.joint_margins.min() > margin - 1e-9
    assert 1 <= report.worst_joint <= 6
    assert np.all(report.manipulability > 0.0) and np.all(report.sigma_min > 0.0)
    assert report.max_step_deg < 45.0
    assert report.clearance is None
    assert np.allclose(kin.poses(report.qs)[:, :3, 3], targets[:, :3, 3], atol=1e-9)


def test_reachability_report_clearance_to_a_box(kin):
    margin = math.radians(2.0)
    lower, upper = kin.robot.spec.lower + margin, kin.robot.spec.upper - margin
    floor = Shape("floor", "box", make_transform(None, [0.7, 0.0, 0.05]), size_m=(0.6, 0.8, 0.1))
    model = CollisionModel(
        kin.robot, kin.base_in_world, kin.tcp_in_flange, (), (floor,), margin_m=0.01, self_margin_m=0.005
    )
    report = reachability_report(
        kin,
        problem_targets(6),
        joint_margin_rad=margin,
        starts=start_candidates(lower, upper, None),
        collision=model,
    )
    assert set(report.clearance) == {"floor"}
    d, who = report.clearance["floor"]
    assert 0.0 < d < 0.3  # the TCP runs 0.2 m above the box's top face
    assert who


def test_polish_ik_reduces_the_error(kin):
    q = np.radians([10.0, -80.0, 100.0, -110.0, -90.0, 0.0])
    T = kin.pose(q)
    q_polished, err = polish_ik(kin, T, q + 1e-3)
    assert err < 1e-10
    assert np.allclose(kin.pose(q_polished), T, atol=1e-9)
