"""The bundled FANUC M-20iA against FANUC's catalogue figures, as robots/fanuc_m20ia/README.md tabulates them.

Figures: FANUC's M-10iA / M-20iA catalogue sheet, "Specifications", M-20iA column (total motion
range and maximum speed per axis, reach, payload).
"""

import numpy as np
import pytest

from refine.robot.registry import load_robot

CATALOGUE_RANGE_DEG = (340.0, 260.0, 458.0, 400.0, 360.0, 900.0)
CATALOGUE_SPEED_DEG_S = (195.0, 175.0, 180.0, 360.0, 360.0, 550.0)
CATALOGUE_REACH_M = 1.811


def test_the_m20ia_keeps_the_catalogues_speeds_reach_and_ranges_or_narrower():
    spec = load_robot("fanuc_m20ia").spec
    span = np.degrees(spec.upper - spec.lower)
    np.testing.assert_allclose(np.degrees(spec.velocity), CATALOGUE_SPEED_DEG_S, atol=0.05)
    assert spec.reach_m == pytest.approx(CATALOGUE_REACH_M, abs=0.001)
    # J1..J4 as the catalogue (J3 to its rounding); J5 and J6 narrower, never wider
    np.testing.assert_allclose(span[:4], CATALOGUE_RANGE_DEG[:4], atol=0.15)
    assert np.all(span <= np.array(CATALOGUE_RANGE_DEG) + 0.15)
    assert span[4] == pytest.approx(280.0) and span[5] == pytest.approx(540.0)
