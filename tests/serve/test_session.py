"""The session: the latest change wins, the fused path moves with the workpiece, the warm start."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
import tomlkit

from refine.serve.edits import apply_changes
from refine.serve.session import WARM_MOVE_M, FusedCache, Job, LatestSolver, near

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


def test_a_solve_under_way_stops_when_a_newer_change_comes_and_only_the_newest_is_answered():
    from refine.control import check_cancelled, controlled

    started, answered = threading.Event(), []
    finished = threading.Event()
    solver = None

    def solve(job):  # a long solve that checks for a cancel as the pipeline's stages do
        with controlled(cancel=solver.superseded):
            started.set()
            for _ in range(500):
                time.sleep(0.01)
                check_cancelled("solve")
        return job.revision

    def done(job, answer, error):
        answered.append(job.revision)
        finished.set()

    solver = LatestSolver(solve, done)
    try:
        solver.submit(Job(1, None, {}))
        assert started.wait(10)
        t0 = time.perf_counter()
        solver.submit(Job(2, None, {}))  # revision 1 is stale now: its solve stops
        while solver.cancelled == 0 and time.perf_counter() - t0 < 10:
            time.sleep(0.01)
        assert solver.cancelled == 1
        assert time.perf_counter() - t0 < 4.0  # not the 5 s revision 1 would have taken
        assert not finished.is_set() or answered == [2]
    finally:
        solver.stop()
    assert 1 not in answered  # a stopped solve is never answered


@pytest.mark.slow
def test_the_scene_resends_only_the_sections_that_changed_and_each_is_the_reports(moved):
    import json
    from types import SimpleNamespace

    from refine.report.scene import scene_data
    from refine.serve.overlays import DemoCache, demonstration_lines
    from refine.serve.session import resolve
    from refine.serve.state import SceneDiff

    placed, shifted = moved
    _, cone = apply_changes(
        tomlkit.parse(GLASS.read_text(encoding="utf-8")), {"tolerances.orientation_deg": 2.9}, GLASS
    )
    cache = FusedCache()
    first = resolve(placed, cache.path_for(placed), None)
    diff = SceneDiff()
    sent = []
    for revision, problem in enumerate((placed, cone, shifted), start=1):
        result = first if revision == 1 else resolve(problem, cache.path_for(problem), first)
        changed, whole = diff.messages(SimpleNamespace(revision=revision, result=result))
        sent.append(sorted(json.loads(changed)["scene"]))
        scene = json.loads(whole)["scene"]
        report = json.loads(json.dumps(scene_data(result)))  # the report's scene, built from nothing
        assert scene["cell"] == report["cell"]
        assert scene["parts"] == report["robot"]["parts"]
        assert scene["paths"] == report["paths"]
        assert scene["robot"]["frames"] == report["robot"]["frames"]
        assert scene["robot"]["where"] == report["robot"]["where"]
        # the flange drawn at each frame, times tcp_in_flange, is the TCP on the CAD path
        tcp = np.asarray(result.problem.tool.tcp_in_flange)
        for (i, k), row in zip(scene["robot"]["where"], scene["robot"]["flange"], strict=True):
            T = np.vstack([np.reshape(row, (3, 4)), [0, 0, 0, 1]]) @ tcp
            assert np.linalg.norm(T[:3, 3] - result.passes[i].fused.positions[k]) < 2e-6  # [m]
        fresh = json.loads(json.dumps(demonstration_lines(result, DemoCache())))  # the log read anew
        assert scene["demo"] == fresh
    assert sent[0] == ["cell", "demo", "motions", "parts", "paths", "robot"]
    assert (
        "cell" not in sent[1] and "parts" not in sent[1] and "demo" not in sent[1]
    )  # the cone: the path and robot
    assert (
        "cell" in sent[2] and "demo" in sent[2] and "parts" not in sent[2]
    )  # the part moved, the robot as it was
    assert diff.cache.built == {"cell": 2, "parts": 1}


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


def test_a_previous_answer_is_a_start_only_for_a_path_moved_a_little():
    from types import SimpleNamespace

    line = np.column_stack([np.linspace(0.0, 1.0, 11), np.zeros(11), np.zeros(11)])  # 1 m along x
    previous = SimpleNamespace(first=SimpleNamespace(fused=SimpleNamespace(positions=line)))

    def path(points):
        return SimpleNamespace(positions=points)

    assert near(previous, path(line + [0.0, 0.0, 0.05]))  # 50 mm up
    assert near(previous, path(line + [0.0, 0.59 * WARM_MOVE_M, 0.79 * WARM_MOVE_M]))  # just inside the limit
    assert not near(previous, path(line + [0.6, 0.0, 0.0]))  # the jump of the browser test
    turned = line @ np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    assert not near(previous, path(turned))  # the far end moved by sqrt(2) m
    assert not near(previous, path(line[:10]))  # another number of waypoints


def test_a_change_that_leaves_every_value_as_it_was_is_not_solved_again(tmp_path, monkeypatch):
    import shutil

    from refine.serve.session import Session

    folder = tmp_path / "glass_adhesive"
    shutil.copytree(ROOT / "problems" / "glass_adhesive", folder)
    session = Session(folder)
    asked = []
    monkeypatch.setattr(session.solver, "submit", lambda job: asked.append((job.revision, job.changes)))
    try:
        pose = {"xyz": [0.002, 0.0, 0.0], "rpy_deg": [0.0, 0.0, 0.0]}
        assert session.change({"tolerances.orientation_deg": 2.9}) == 1
        assert session.change({"move": pose}) == 2
        assert session.change({"move": dict(pose)}) == 2  # the drag's last pose again, on release
        assert session.change({"tolerances.orientation_deg": 2.9}) == 2  # 2.9 deg as it was
        assert session.change({"tolerances.orientation_deg": 3}) == 3  # 3 deg is a change
        assert [r for r, _ in asked] == [1, 2, 3]
        assert asked[-1][1] == {"tolerances.orientation_deg": 3, "move": pose}
        assert session.problem.tolerances.orientation_deg == 3.0
    finally:
        session.close()
