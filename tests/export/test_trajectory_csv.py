from __future__ import annotations

import numpy as np
import pytest

from refine.errors import InputError
from refine.export.trajectory_csv import read_trajectory_csv, write_trajectory_csv
from refine.frames import quaternion_from_matrix
from refine.paths import Trajectory

HEADER = "t,s,q1,q2,q3,q4,q5,q6,x_ref,y_ref,z_ref,x,y,z,qw,qx,qy,qz,qw_demo,qx_demo,qy_demo,qz_demo,speed"


@pytest.fixture()
def csv_path(tmp_path, trajectory):
    return write_trajectory_csv(tmp_path / "trajectory.csv", trajectory)


def test_header_is_exactly_the_documented_interface(csv_path, trajectory):
    lines = csv_path.read_text().splitlines()
    assert lines[0] == HEADER
    assert len(lines) == len(trajectory) + 1


def test_round_trip_is_exact_to_the_last_bit(csv_path, trajectory):
    back = read_trajectory_csv(csv_path)
    for name in ("t", "s", "q", "positions_ref", "speed"):
        np.testing.assert_array_equal(getattr(back, name), getattr(trajectory, name), err_msg=name)
    np.testing.assert_array_equal(back.poses[:, :3, 3], trajectory.poses[:, :3, 3])
    np.testing.assert_allclose(back.poses, trajectory.poses, rtol=0, atol=1e-14)
    np.testing.assert_allclose(back.rotations_demo, trajectory.rotations_demo, rtol=0, atol=1e-14)


def test_quaternion_signs_are_continuous_and_the_demo_matches_the_reached_sign(tmp_path, trajectory):
    """A path whose orientation turns through 360 deg keeps consecutive quaternions close."""
    n = len(trajectory)
    angle = np.linspace(0.0, 2.0 * np.pi, n)
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros((n, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    poses = trajectory.poses.copy()
    poses[:, :3, :3] = R
    turning = Trajectory(
        trajectory.t, trajectory.s, trajectory.q, trajectory.positions_ref, poses, R, trajectory.speed
    )
    assert np.any(np.sum(quaternion_from_matrix(R)[1:] * quaternion_from_matrix(R)[:-1], 1) < 0)
    path = write_trajectory_csv(tmp_path / "turning.csv", turning)
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    quat, demo = data[:, 14:18], data[:, 18:22]
    assert np.all(np.sum(quat[1:] * quat[:-1], axis=1) > 0.0)
    assert np.all(np.sum(demo[1:] * demo[:-1], axis=1) > 0.0)
    np.testing.assert_allclose(demo, quat, atol=1e-12)


def test_a_renamed_column_is_rejected(csv_path):
    text = csv_path.read_text().replace("speed\n", "velocity\n", 1)
    csv_path.write_text(text)
    with pytest.raises(InputError, match="header"):
        read_trajectory_csv(csv_path)


def test_a_short_row_is_rejected(csv_path):
    lines = csv_path.read_text().splitlines()
    lines[3] = lines[3].rsplit(",", 1)[0]
    csv_path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="values"):
        read_trajectory_csv(csv_path)


def test_a_demo_quaternion_starts_on_the_reached_one_s_side_also_across_180_degrees(tmp_path, trajectory):
    """Reached: 170 deg about x; demonstrated 20 deg further, 190 deg about x. As unit quaternions
    (cos 85°, sin 85°, 0, 0) and (cos 95°, sin 95°, 0, 0): dot cos 10° > 0, while the other sign of
    the same demonstrated rotation, (cos 85°, -sin 85°, 0, 0), has dot -cos 10°."""
    from scipy.spatial.transform import Rotation

    n = len(trajectory)
    reached = Rotation.from_rotvec(np.tile([np.radians(170.0), 0.0, 0.0], (n, 1))).as_matrix()
    demo = Rotation.from_rotvec(np.tile([np.radians(190.0), 0.0, 0.0], (n, 1))).as_matrix()
    poses = trajectory.poses.copy()
    poses[:, :3, :3] = reached
    tr = Trajectory(
        trajectory.t, trajectory.s, trajectory.q, trajectory.positions_ref, poses, demo, trajectory.speed
    )
    data = np.loadtxt(write_trajectory_csv(tmp_path / "flip.csv", tr), delimiter=",", skiprows=1)
    quat, qdemo = data[:, 14:18], data[:, 18:22]
    c85, s85 = np.cos(np.radians(85.0)), np.sin(np.radians(85.0))
    np.testing.assert_allclose(np.abs(quat), np.tile([c85, s85, 0.0, 0.0], (n, 1)), atol=1e-12)
    np.testing.assert_allclose(np.abs(qdemo), np.tile([c85, s85, 0.0, 0.0], (n, 1)), atol=1e-12)
    np.testing.assert_allclose(np.sum(quat * qdemo, axis=1), np.cos(np.radians(10.0)), atol=1e-12)


def test_a_trajectory_of_a_single_axis_reads_back(tmp_path):
    """The header names q1..qn for any n >= 1: one joint column is a valid file."""
    header = HEADER.replace("q1,q2,q3,q4,q5,q6", "q1")
    rows = ["0,0,0.5,0,0,0,0,0,0,1,0,0,0,1,0,0,0,0.1", "1,0.1,0.6,0.1,0,0,0.1,0,0,1,0,0,0,1,0,0,0,0.1"]
    path = tmp_path / "one.csv"
    path.write_text("\n".join([header, *rows]) + "\n")
    back = read_trajectory_csv(path)
    np.testing.assert_array_equal(back.q, [[0.5], [0.6]])
    np.testing.assert_array_equal(back.t, [0.0, 1.0])
