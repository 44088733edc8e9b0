"""A chain asked for again inside one refinement is solved once, and is the same chain to the bit."""

from __future__ import annotations

import numpy as np
import pytest

import refine.optimise.seed as seed
from refine.robot.kinematics import TcpKinematics


@pytest.fixture()
def counted(monkeypatch):
    """The number of waypoints the chains solve (one IK each, in NumPy or in C)."""
    calls = {"n": 0}
    solve = seed._solve_chain

    def counting(kin, targets, *args, **kwargs):
        calls["n"] += len(targets)
        return solve(kin, targets, *args, **kwargs)

    monkeypatch.setattr(seed, "_solve_chain", counting)
    return calls


def _path(kin):
    """Targets along a smooth joint path (the poses its joints reach) and its first joints [rad]."""
    t = np.linspace(0.0, 1.0, 12)[:, None]
    qs = np.array([0.1, 0.4, 0.2, 0.3, 0.5, 0.1]) + t * np.array([0.3, -0.1, 0.2, 0.4, -0.2, 0.6])
    return kin.poses(qs), qs


def test_a_chain_asked_again_is_solved_once_and_is_the_same(kin, counted):
    targets, qs = _path(kin)
    lower, upper = np.full(6, -3.0), np.full(6, 3.0)
    fresh, fresh_err = seed._chain_each(kin, targets, qs[0], lower, upper)  # outside: not remembered
    alone = counted["n"]
    assert alone == len(targets)
    # the chain reaches the poses of the joints the targets were made from (forward kinematics)
    assert np.allclose(kin.poses(fresh)[:, :3, 3], targets[:, :3, 3], atol=1e-6)

    @seed.remembering_chains
    def twice():
        first = seed._chain_each(kin, targets, qs[0], lower, upper)
        first[0][:] = 99.0  # the caller's copy: the remembered chain stays as solved
        return seed._chain_each(kin, targets, qs[0], lower, upper)

    again, again_err = twice()
    assert counted["n"] == 2 * alone  # solved once inside, the repeat remembered
    assert np.array_equal(again, fresh) and np.array_equal(again_err, fresh_err)


def test_other_first_joints_or_tool_are_chained_afresh(kin, counted):
    targets, qs = _path(kin)
    lower, upper = np.full(6, -3.0), np.full(6, 3.0)
    other_tool = np.eye(4)
    other_tool[2, 3] = 0.1
    longer = TcpKinematics(kin.robot, kin.base_in_world, kin.tcp_in_flange @ other_tool)

    @seed.remembering_chains
    def three():
        seed._chain_each(kin, targets, qs[0], lower, upper)
        seed._chain_each(kin, targets, qs[0] + 0.05, lower, upper)
        return seed._chain_each(longer, targets, qs[0], lower, upper)

    three()
    assert counted["n"] == 3 * len(targets)


def test_outside_a_refinement_nothing_is_remembered(kin, counted):
    targets, qs = _path(kin)
    lower, upper = np.full(6, -3.0), np.full(6, 3.0)
    seed._chain_each(kin, targets, qs[0], lower, upper)
    seed._chain_each(kin, targets, qs[0], lower, upper)
    assert counted["n"] == 2 * len(targets)
