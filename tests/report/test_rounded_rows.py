"""The scene's numbers: rows rounded at once, NaN and inf sent as None."""

from __future__ import annotations

import math

from refine.report.scene import rounded_rows


def test_rows_are_rounded_and_non_finite_numbers_become_none():
    rows = [[0.123456, -1.000004, 2.5e-6], [math.nan, 1.0, math.inf]]
    # by hand at 5 decimals: 0.12346, -1.0, 0.0; None, 1.0, None
    assert rounded_rows(rows, 5) == [[0.12346, -1.0, 0.0], [None, 1.0, None]]
    assert rounded_rows([[1.23456789, 3.0]], 2) == [[1.23, 3.0]]
    assert rounded_rows([], 5) == []
