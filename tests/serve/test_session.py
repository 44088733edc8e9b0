"""The session: the latest change wins, the fused path moves with the workpiece, the warm start."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
import tomlkit

from refine.serve.edits import apply_changes
from refine.serve.session import FusedCache, Job, LatestSolver, warm_joints

ROOT = Path(__file__).resolve().parents[2]
GLASS = ROOT / "problems" / "glass_adhesive" / "problem.toml"


def test_a_burst_of_changes_solves_the_first_and_the_last_only():
    release = threading.Event()
    solved, finished = [], threading.Event()

    def solve(job):
        solved.append(job.revision)
        if job.revision == 1:
            release.wait(10)
        return job.revision

    def done(job, answer, error):
        if job.revision == 20:
            finished.set()

    solver = LatestSolver(solve, done)
    try:
        solver.submit(Job(1, None, {}))
        while not solved:
            time.sleep(0.01)
        for revision in range(2, 21):  # a drag: 19 changes while the first solve runs
            solver.submit(Job(revision, None, {}))
        release.set()
        assert finished.wait(10)
        assert solved == [1, 20]
        assert solver.dropped == 18 and solver.solved == 2
    finally:
        solver.stop()


def test_an_error_in_a_solve_is_handed_on_and_the_thread_keeps_serving():
    seen, done_all = [], threading.Event()

    def solve(job):
        if job.revision == 1:
            raise ValueError("boom")
        return "fine"

    def done(job, answer, error):
        seen.append((job.revision, answer, None if error is None else str(error)))
        if job.revision == 2:
            done_all.set()

    solver = LatestSolver(solve, done)
    try:
        solver.submit(Job(1, None, {}))
        while not seen:
            time.sleep(0.01)
        solver.submit(Job(2, None, {}))
        assert done_all.wait(10)
        assert seen == [(1, None, "boom"), (2, "fine", None)]
    finally:
        solver.stop()


@pytest.fixture(scope="module")
def moved():
    base = tomlkit.parse(GLASS.read_text(encoding="utf-8"))
    _, placed = apply_changes(base, {}, GLASS)
    _, shifted = apply_changes(base, {"move": {"xyz": [0.05, -0.03, 0.0], "rpy_deg": [0, 0, 4.0]}}, GLASS)
    return placed, shifted


def test_the_fused_path_moves_with_the_workpiece_as_fusing_the_moved_files_gives(moved):
    from refine.run.stages import fused_path

    placed, shifted = moved
    cache = FusedCache()
    cache.path_for(placed)
    carried = cache.path_for(shifted)
    assert cache.fused == 1 and cache.reused == 1
    fresh = fused_path(shifted)  # read and fused from the moved frames
    assert len(fresh) == len(carried)
    assert np.abs(fresh.positions - carried.positions).max() < 1e-5  # [m]: the poses' rounding in the file
    angle = np.arccos(np.clip((np.einsum("nij,nij->n", fresh.rotations, carried.rotations) - 1) / 2, -1, 1))
    assert np.degrees(angle).max() < 1e-3


def test_the_previous_joints_are_carried_onto_the_moved_path(moved):
    from refine.robot.kinematics import TcpKinematics
    from refine.robot.registry import robot_for
    from refine.run.stages import fused_path

    placed, shifted = moved
    robot = robot_for(placed.robot)
    kin = TcpKinematics(robot, placed.robot.base_in_world, placed.tool.tcp_in_flange)
    path = fused_path(shifted)
    # a start that reaches the path as placed: IK chained along it, each point from the one before
    from refine.robot.kinematics import solve_ik_batch

    old = fused_path(placed)
    targets = np.tile(np.eye(4), (len(old), 1, 1))
    targets[:, :3, :3], targets[:, :3, 3] = old.rotations, old.positions
    q_placed = np.zeros((len(old), robot.nq))
    q = np.radians([[0.0, 20.0, 10.0, 0.0, 60.0, 0.0]])
    for k in range(len(old)):
        q, err = solve_ik_batch(kin, targets[k : k + 1], q, robot.spec.lower, robot.spec.upper, max_iterations=200)
        assert err[0] < 1e-5
        q_placed[k] = q[0]
    assert np.degrees(np.abs(np.diff(q_placed, axis=0)).max()) < 5.0
    q = warm_joints(shifted, robot, path, q_placed)
    assert q is not None
    miss = np.linalg.norm(kin.poses(q)[:, :3, 3] - path.positions, axis=1)
    assert miss.max() < 1e-5  # [m], measured by forward kinematics
    assert warm_joints(placed, robot, old, q_placed) is q_placed  # already on the path: kept as it is
