"""speed_levels: the fewest-time choice of at most ``count`` levels, checked by trying every choice."""

from itertools import combinations

import numpy as np
import pytest

from refine.export.program import speed_levels


def _least_time_by_trying_every_choice(speeds, lengths, count, resolution=1e-3):
    """Every set of at most ``count`` levels among the rounded speeds; each segment at the fastest
    level not above its own speed (the slowest speed is always a level, or some segment has none)."""
    v = np.maximum(np.floor(np.asarray(speeds) / resolution), 1.0) * resolution
    cand = np.unique(v)
    best = np.inf
    for k in range(1, min(count, len(cand)) + 1):
        for rest in combinations(cand[1:], k - 1):
            levels = np.array([cand[0], *rest])
            at = levels[np.searchsorted(levels, v, side="right") - 1]
            best = min(best, float(np.sum(np.asarray(lengths) / at)))
    return best


@pytest.mark.parametrize("seed", range(40))
def test_the_levels_take_the_least_time_any_choice_takes(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 14))
    speeds = rng.uniform(0.001, 0.3, n) if seed % 2 else np.round(rng.uniform(0.005, 0.05, n), 2)
    lengths = rng.uniform(0.0, 0.01, n)
    count = int(rng.integers(1, 6))
    levels, index = speed_levels(speeds, lengths, count)
    assert len(levels) <= count and np.all(np.diff(levels) > 0)
    at = levels[index]
    assert np.all(at <= np.maximum(np.floor(speeds / 1e-3), 1.0) * 1e-3 + 1e-15)  # never above the plan
    time = float(np.sum(lengths / at))
    assert time == pytest.approx(_least_time_by_trying_every_choice(speeds, lengths, count), rel=1e-12)
