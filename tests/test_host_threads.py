"""Threads: calls from several threads on one Robot give the answers of calls one after the other."""

from __future__ import annotations

import threading

import numpy as np

import refine
from refine.robot.registry import load_robot


def _line(n: int, z: float) -> np.ndarray:
    return np.column_stack([np.full(n, 0.6), np.linspace(-0.2, 0.2, n), np.full(n, z)])


def test_two_threads_on_one_robot_give_the_answers_of_calls_in_turn():
    robot = load_robot("ur10e")
    n = 60
    R = np.repeat(np.diag([1.0, -1.0, -1.0])[None], n, axis=0)  # tool z down
    paths = [_line(n, z) for z in (0.3, 0.45)]
    alone = [refine.refine_path(robot, p, R, speeds=0.1).joints for p in paths]
    out: dict[tuple[int, int], np.ndarray] = {}
    errors: list[BaseException] = []

    def run(k: int, r: int) -> None:
        try:
            out[k, r] = refine.refine_path(robot, paths[k], R, speeds=0.1).joints
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    for r in range(2):
        threads = [threading.Thread(target=run, args=(k, r)) for k in (0, 1)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert not errors, errors
    for (k, _), joints in out.items():
        np.testing.assert_array_equal(joints, alone[k])


def test_each_thread_has_its_own_pinocchio_data():
    robot = load_robot("ur10e")
    seen = []
    t = threading.Thread(target=lambda: seen.append(robot.data))
    t.start()
    t.join()
    assert seen[0] is not robot.data and robot.data is robot.data
    q = np.full(robot.nq, 0.3)
    np.testing.assert_allclose(robot.fk(q), robot.fk(q))
