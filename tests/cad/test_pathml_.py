"""Behaviour of reading a PathML track as a fused path (refine.cad.pathml_)."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.cad import read_cad_path
from refine.cad.pathml_ import MIN_SPEED_M_S, fused_from_pathml
from refine.errors import InputError
from refine.export import LayerLayout, TrackLayout, write_pathml
from refine.frames import rotation_angle_deg
from refine.paths import Trajectory
from refine.problem import CadSettings, Problem, RobotSettings, ToolSettings

AXIS = np.array([1.0, 2.0, 2.0]) / 3.0
TURN_RAD_PER_M = 1.5  # orientation turns about AXIS in proportion to arc length
R0 = Rotation.from_euler("xyz", [180.0, 10.0, 30.0], degrees=True)


def _truth_rotation(s):
    return (Rotation.from_rotvec(np.outer(s, AXIS) * TURN_RAD_PER_M) * R0).as_matrix()


def _truth_speed(s):
    return 0.05 + 0.2 * s


def _trajectory(n_per_leg=30):
    """An L-shaped path (0.3 m along x, then 0.2 m along y, rising 0.05 m), waypoints every leg/n."""
    a = np.linspace(0.0, 1.0, n_per_leg + 1)[:, None]
    leg1 = np.array([0.5, -0.1, 0.3]) + a * [0.3, 0.0, 0.0]
    leg2 = leg1[-1] + a[1:] * [0.0, 0.2, 0.05]
    positions = np.vstack([leg1, leg2])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])
    n = len(s)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = _truth_rotation(s)
    poses[:, :3, 3] = positions
    speed = _truth_speed(s)
    speed[-1] = 0.0  # a timed path ends at rest
    t = np.linspace(0.0, 3.0, n)
    return Trajectory(
        t=t,
        s=s,
        q=np.zeros((n, 6)),
        positions_ref=positions,
        poses=poses,
        rotations_demo=poses[:, :3, :3],
        speed=speed,
    )


def _problem() -> Problem:
    return Problem(
        name="pathml input",
        root=Path("."),
        robot=RobotSettings(model="abb_irb4600_60_205"),
        tool=ToolSettings(name="nozzle", tcp_in_flange=np.eye(4)),
        cad=CadSettings(file=Path("x.aml"), format="pathml"),
        demonstration=None,
    )


@pytest.fixture(scope="module")
def aml(tmp_path_factory) -> Path:
    problem = _problem()
    traj = _trajectory()
    layers = [
        LayerLayout("Root", (TrackLayout("Seam", 0, len(traj)),)),
        LayerLayout("Cap", (TrackLayout("Left", 0, 31), TrackLayout("Right", 30, len(traj)))),
    ]
    return write_pathml(tmp_path_factory.mktemp("pathml") / "input.aml", traj, problem, layers=layers)


def _distance_to_polyline(q, p):
    a, b = p[:-1], p[1:]
    t = np.clip(np.einsum("ij,ij->i", q - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0, 1)
    return float(np.linalg.norm(a + t[:, None] * (b - a) - q, axis=1).min())


def test_fused_path_recovers_positions_orientations_and_speeds(aml):
    fused = fused_from_pathml(aml, 0.004)
    truth = _trajectory()
    assert np.diff(fused.s).max() <= 0.004 + 1e-12
    assert fused.s[-1] == pytest.approx(truth.s[-1], abs=1e-12)
    assert max(_distance_to_polyline(q, truth.positions_ref) for q in fused.positions) < 1e-12
    np.testing.assert_allclose(fused.positions[[0, -1]], truth.positions_ref[[0, -1]], atol=1e-15)
    # rotation about a fixed axis, angle linear in s: Slerp between the points is exact
    assert rotation_angle_deg(fused.rotations, _truth_rotation(fused.s)).max() < 1e-9
    inner = fused.s < truth.s[-2]  # the last segment ramps down to the rest at the end
    np.testing.assert_allclose(fused.speed[inner], _truth_speed(fused.s[inner]), rtol=1e-12)
    assert fused.speed[-1] == MIN_SPEED_M_S and fused.speed.min() >= MIN_SPEED_M_S
    dt = np.diff(fused.s) / (0.5 * (fused.speed[1:] + fused.speed[:-1]))
    np.testing.assert_allclose(fused.t_demo, np.concatenate([[0.0], np.cumsum(dt)]))
    assert np.all(fused.residual == 0.0)


def test_a_track_is_chosen_by_layer_and_name(aml):
    right = fused_from_pathml(aml, 0.004, track="Cap/Right")
    truth = _trajectory()
    np.testing.assert_allclose(right.positions[0], truth.positions_ref[30], atol=1e-15)
    np.testing.assert_allclose(right.positions[-1], truth.positions_ref[-1], atol=1e-15)
    left = fused_from_pathml(aml, 0.004, track="Left")  # unique without its layer
    np.testing.assert_allclose(left.positions[-1], truth.positions_ref[30], atol=1e-15)


def test_an_unknown_track_lists_the_tracks(aml):
    with pytest.raises(InputError, match="Root/Seam, Cap/Left, Cap/Right"):
        fused_from_pathml(aml, 0.004, track="Cap/Middle")


def test_read_cad_path_points_pathml_to_fused_from_pathml(aml):
    with pytest.raises(InputError, match="fused_from_pathml"):
        read_cad_path(CadSettings(file=aml, format="pathml"), np.eye(4))


def _written(tmp_path, traj) -> Path:
    return write_pathml(tmp_path / "wild.aml", traj, _problem())


def test_a_point_two_kilometres_away_is_refused_naming_the_track_and_point(tmp_path):
    traj = _trajectory()
    traj.positions_ref[7, 1] = 2000.0
    traj.poses[7, 1, 3] = 2000.0
    with pytest.raises(
        InputError, match=r"wild\.aml: track .* point 7: position y = 2000 m is outside the plausible range"
    ):
        fused_from_pathml(_written(tmp_path, traj), 0.004)


def test_a_speed_of_a_kilometre_a_second_is_refused(tmp_path):
    traj = _trajectory()
    traj.speed[5] = 1000.0
    with pytest.raises(
        InputError, match=r"point 5: speed 1000 m/s is outside the plausible range 0\.\.10 m/s"
    ):
        fused_from_pathml(_written(tmp_path, traj), 0.004)


@pytest.mark.parametrize("how", [{"reverse": True}, {"start_near": (0.7, 0.1, 0.35)}])
def test_reverse_and_start_near_run_the_track_from_its_other_end(aml, how):
    fused = fused_from_pathml(aml, 0.004, **how)
    truth = _trajectory()
    np.testing.assert_allclose(fused.positions[[0, -1]], truth.positions_ref[[-1, 0]], atol=1e-15)
    # each point keeps its recorded orientation: the one at arc length L - s of the track
    L = truth.s[-1]
    assert rotation_angle_deg(fused.rotations, _truth_rotation(L - fused.s)).max() < 1e-9
