"""A G-code program with two tracks runs as two passes, each on its own CAD track (end to end)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from refine.cli import main


@pytest.mark.slow
def test_two_gcode_tracks_are_two_passes(tmp_path, two_track_line_problem):
    problem = two_track_line_problem  # the tracks: y -100..-10 mm and 10..100 mm (conftest)
    out = tmp_path / "out"
    assert main(["run", str(problem.parent), "--out", str(out), "--no-report"]) == 0
    doc = json.loads((out / "result.json").read_text())
    assert doc["status"] == "ok" and doc["n_passes"] == 2
    assert [p["name"] for p in doc["passes"]] == ["track 1", "track 2"]
    # 90 mm at 5 mm: 18 steps, 19 waypoints each; the connector's waypoints belong to no pass
    assert doc["cad_chord_error"]["n_waypoints"] == [19, 19]
    assert doc["cad_chord_error"]["max_m"] <= 1e-4
    for name, (lo, hi) in (("trajectory_L1P1.csv", (-0.1, -0.01)), ("trajectory_L1P2.csv", (0.01, 0.1))):
        rows = np.genfromtxt(out / name, delimiter=",", names=True)
        y = rows["y_ref"]
        # each pass runs its own track from end to end, in the program's direction
        assert y[0] == pytest.approx(lo, abs=1e-9) and y[-1] == pytest.approx(hi, abs=1e-9)
        assert np.all(np.diff(y) > 0.0)
