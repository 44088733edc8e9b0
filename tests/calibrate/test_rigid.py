import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.calibrate.rigid import check_point_geometry, kabsch, point_residuals, ransac
from refine.errors import InputError


def _random_transform(rng):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.uniform(-1, 1, 3)
    return T


def test_kabsch_recovers_a_known_transform():
    rng = np.random.default_rng(0)
    T = _random_transform(rng)
    a = rng.uniform(-1, 1, (7, 3))
    b = a @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(kabsch(a, b), T, atol=1e-12)


def test_ransac_rejects_the_one_wrong_point():
    rng = np.random.default_rng(1)
    T = _random_transform(rng)
    a = rng.uniform(-1, 1, (6, 3))
    b = a @ T[:3, :3].T + T[:3, 3] + rng.normal(scale=2e-4, size=(6, 3))
    b[4] += [0.03, 0.0, 0.0]
    model, inliers = ransac(6, lambda i: kabsch(a[i], b[i]), lambda M: point_residuals(M, a, b), 3, 0.003)
    assert inliers.tolist() == [True, True, True, True, False, True]
    assert np.linalg.norm(model[:3, 3] - T[:3, 3]) < 1e-3


def test_too_few_points():
    with pytest.raises(InputError, match="2 point"):
        check_point_geometry([[0, 0, 0], [1, 0, 0]], "points")


def test_collinear_points():
    with pytest.raises(InputError, match="one line"):
        check_point_geometry([[0, 0, 0], [0.5, 0.001, 0], [1, 0, 0.001], [2, 0, 0]], "points")
