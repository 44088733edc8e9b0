"""How the repair search picks its IK branches and warm-starts its rounds."""

import numpy as np

from refine.frames import rotation_angle_deg
from refine.optimise.correction import row_names
from refine.optimise.problem import ActiveSet, LinearRow, build_refinement
from refine.optimise.repair import ELASTIC_ONLY, solve_with_repair
from refine.optimise.seed import initial_guess
from refine.optimise.steady import rank_chains
from refine.problem import Tolerances
from refine.synthetic import wave_path


def test_chains_on_the_targets_everywhere_come_first_then_the_larger_margin_over_the_whole_path(kin, irb4600):
    lower, upper = irb4600.spec.lower, irb4600.spec.upper
    t = np.linspace(0.0, 1.0, 12)[:, None]
    good_wide = lower + (upper - lower) * (0.5 + 0.02 * np.sin(3.0 * t))  # mid-range
    targets = kin.poses(good_wide)
    good_narrow = good_wide.copy()
    good_narrow[6:, 3] += (
        2.0 * np.pi
    )  # axis 4 a whole turn on (+-400 deg): the same poses, 24 deg from its limit
    assert np.all(good_narrow <= upper)
    off = good_wide.copy()
    off[7, 0] += 0.01  # 0.01 rad off at one waypoint: misses its target by about 2 cm
    ranked = rank_chains(kin, targets, lower, upper, [off, good_narrow, good_wide])
    assert [id(c) for c in ranked] == [id(good_wide), id(good_narrow), id(off)]


def test_row_names_follow_each_row_when_the_active_set_grows(irb4600, straight_tool):
    """The multipliers of a warm-started round are carried over by row name, not by position."""
    N, n = 8, 6
    small = ActiveSet((3,), ((5, 0.5),), (LinearRow(2, 0.0, np.ones(n), 0.0, "a / b"),))
    grown = ActiveSet((1, 3), ((2, 0.5), (5, 0.5)), small.linear_rows)
    built = [
        build_refinement(irb4600, wave_path(N), np.eye(4), straight_tool, Tolerances(), active=a)
        for a in (small, grown)
    ]
    keys = [row_names(b) for b in built]
    for b, k in zip(built, keys, strict=True):
        assert len(k) == len(b.lbg) == len(set(k))
    base = 4 * N + n * (N - 1)
    # rows: base, then singular waypoints, then segment points, then linear rows
    assert keys[0][base:] == [("singular", 3, 0.0), ("singular", 5, 0.5), ("row", 2, 0.0, "a / b")]
    assert keys[1][base:] == [
        ("singular", 1, 0.0),
        ("singular", 3, 0.0),
        ("singular", 2, 0.5),
        ("singular", 5, 0.5),
        ("row", 2, 0.0, "a / b"),
    ]
    # the bounds of a row carried over are the same in both problems
    where = {k: i for i, k in enumerate(keys[1])}
    for i, k in enumerate(keys[0]):
        assert built[0].lbg[i] == built[1].lbg[where[k]]


def test_the_elastic_problem_alone_gives_ok_where_the_strict_problem_is_feasible(irb4600, straight_tool, kin):
    """Another IK branch solves the elastic problem only: an answer without slack is the strict answer."""
    nlp = build_refinement(irb4600, wave_path(60), np.eye(4), straight_tool, Tolerances())
    q_seed = initial_guess(nlp)
    result = solve_with_repair(nlp, q_seed, (), 15.0, 8, {}, skip_strict=ELASTIC_ONLY)
    assert result.status == "ok", result.reason
    assert not result.repairs and not result.slack_deg.any()
    # recomputed here: on the CAD path, inside the strict cone
    poses = kin.poses(result.q)
    assert np.linalg.norm(poses[:, :3, 3] - nlp.fused.positions, axis=1).max() < 1e-6
    assert rotation_angle_deg(poses[:, :3, :3], nlp.fused.rotations).max() <= 3.0 + 1e-6
