"""Results that travel: a ``Result`` pickles, and comes back from another process whole."""

from __future__ import annotations

import multiprocessing
import pickle
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from scipy.spatial.transform import Rotation

import refine


def _line(n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    positions = np.column_stack([np.full(n, 0.6), np.linspace(-0.1, 0.1, n), np.full(n, 0.3)])
    down = Rotation.from_euler("x", 180.0, degrees=True).as_matrix()  # tool z pointing down
    return positions, np.repeat(down[None], n, axis=0)


def _solve_line(shift_m: float) -> refine.Result:
    positions, R = _line()
    return refine.refine_path("ur10e", positions + [0.0, 0.0, shift_m], R, speeds=0.1, name="line")


def test_a_result_pickles_with_everything_but_its_built_problem(tmp_path):
    result = _solve_line(0.0)
    result.run.robot.collision_shapes()  # the robot's cached FCL shapes, as any collision run leaves them
    back = pickle.loads(pickle.dumps(result))
    assert back.status == result.status == "ok"
    np.testing.assert_array_equal(back.joints, result.joints)
    np.testing.assert_array_equal(back.times, result.times)
    assert back.to_dict()["metrics"] == result.to_dict()["metrics"]
    assert back.run.first.nlp is None and result.run.first.nlp is not None
    # the copy writes like the original, and serves as the start of a re-solve
    files = back.write(tmp_path / "copy", report=False)
    assert files["result"].is_file()
    positions, R = _line()
    again = refine.refine_path("ur10e", positions + [0.0, 0.0, 0.002], R, speeds=0.1, previous=back)
    assert again.status == "ok"


def test_a_result_comes_back_from_a_process_pool():
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        remote = pool.submit(_solve_line, 0.001).result(timeout=300)
    local = _solve_line(0.001)
    assert remote.status == local.status == "ok"
    np.testing.assert_allclose(remote.joints, local.joints, atol=1e-9)
