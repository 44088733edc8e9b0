"""The demonstration quality gate: dropouts bridged or refused, a rotated tracker frame caught."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from refine.cli import main
from refine.demo.quality import MAX_BRIDGE_S, find_bad_runs, gate_dropouts
from refine.demo.simulate import TrackerModel, inject_dropout, simulate_demonstration
from refine.errors import InputError
from refine.frames import transform_from_xyz_rpy

ROOT = Path(__file__).resolve().parents[2]
GLASS = ROOT / "problems" / "glass_adhesive"
T_F_S = transform_from_xyz_rpy([0.9, -0.3, 0.45], [0.0, 0.0, 90.0])
T_TCP_E = transform_from_xyz_rpy([-0.03, 0.0, -0.25], [180.0, 0.0, 30.0])


@pytest.fixture(scope="module")
def log():
    """A 240 Hz demonstration along a gentle arc, with the simulator's noise, spikes and distortion."""
    s = np.linspace(0.0, 0.8, 161)
    positions = np.column_stack([0.95 + 0.6 * s, -0.25 + 0.8 * s, 0.35 + 0.05 * np.sin(4 * s)])
    rotations = np.repeat(np.diag([1.0, -1.0, -1.0])[None], len(s), axis=0)
    demo = simulate_demonstration(
        s, positions, rotations, np.full(len(s), 0.1), T_F_S, T_TCP_E, TrackerModel(seed=3)
    )
    return demo.log


def test_a_clean_simulated_log_has_no_dropouts(log):
    runs = find_bad_runs(log)
    assert [r for r in runs if r.action != "bridged"] == []
    assert all(r.last - r.first + 1 <= 1 for r in runs)  # at most the simulator's single-sample spikes


@pytest.mark.parametrize("kind", ["zero", "frozen", "flip", "gap"])
def test_a_dropout_of_40_samples_mid_log_is_refused_and_named(log, kind):
    first = 1200  # mid-motion (the pause is 480 samples)
    bad = inject_dropout(log, first, 40, kind)
    with pytest.raises(InputError) as e:
        gate_dropouts(bad)
    msg = str(e.value)
    assert "ms" in msg and f"{MAX_BRIDGE_S * 1e3:.0f} ms" in msg
    if kind == "gap":
        assert f"gap after sample {first - 1}" in msg
    else:
        assert f"sample(s) {first}..{first + 39}" in msg and kind.replace("flip", "jump") in msg
    # 40 samples at 240 Hz: the bridge would span 41 steps = 171 ms
    assert "171 ms" in msg


@pytest.mark.parametrize("kind", ["zero", "frozen", "flip", "gap"])
def test_a_short_dropout_is_bridged_by_interpolation(log, kind):
    first, count = 1500, 5  # 6 steps = 25 ms
    fixed, quality = gate_dropouts(inject_dropout(log, first, count, kind))
    (run,) = [r for r in quality.bad_runs if r.last - r.first + 1 == count or r.kind == "gap"]
    assert run.action == "bridged" and run.duration_s == pytest.approx((count + 1) / 240.0)
    if kind != "gap":
        # the bridge lies on the straight line between the good neighbours (linear in time)
        u = np.arange(1, count + 1) / (count + 1)
        expected = log.positions[first - 1] + u[:, None] * (
            log.positions[first + count] - log.positions[first - 1]
        )
        np.testing.assert_allclose(fixed.positions[first : first + count], expected, atol=1e-12)


def test_zeros_at_the_start_are_trimmed_not_refused(log):
    p = log.positions.copy()
    p[:100] = 0.0  # the sensor was plugged in 0.4 s after the log started
    fixed, quality = gate_dropouts(dataclasses.replace(log, positions=p))
    assert quality.bad_runs[0].action == "trimmed" and len(fixed.t) == len(log.t) - 100
    assert fixed.t[0] == 0.0


def _glass_copy(tmp_path: Path) -> Path:
    dst = tmp_path / "glass"
    shutil.copytree(GLASS, dst, ignore=shutil.ignore_patterns("generate.py", "README.md"))
    return dst


def test_the_glass_demo_with_40_zero_samples_is_refused_by_check(tmp_path, capsys):
    problem = _glass_copy(tmp_path)
    lines = (problem / "demo.liberty").read_text().splitlines()
    data = [i for i, line in enumerate(lines) if line and not line.startswith("#")]
    for i in data[1500:1540]:  # mid-bead
        lines[i] = "01    0.0000    0.0000    0.0000    0.000    0.000    0.000"
    (problem / "demo.liberty").write_text("\n".join(lines) + "\n")
    assert main(["check", str(problem)]) == 2
    err = capsys.readouterr().err
    assert "40 zero sample(s) 1500..1539" in err and "171 ms" in err and "Traceback" not in err


@pytest.mark.parametrize("axis", [pytest.param(0, marks=pytest.mark.slow), 2])
def test_a_tracker_frame_rotated_5_degrees_stops_the_run_naming_the_angle(tmp_path, capsys, axis):
    problem = _glass_copy(tmp_path)
    toml = problem / "problem.toml"
    rotated = ["0.0", "0.0", "90.0"]
    rotated[axis] = str(float(rotated[axis]) + 5.0)
    toml.write_text(
        toml.read_text().replace(
            "source_in_world = { xyz = [1.30, -0.82, 0.72], rpy_deg = [0.0, 0.0, 90.0] }",
            f"source_in_world = {{ xyz = [1.30, -0.82, 0.72], rpy_deg = [{', '.join(rotated)}] }}",
        )
    )
    assert main(["check", str(problem)]) == 2
    err = capsys.readouterr().err
    assert "rotated by" in err and "--accept-frame-error" in err and "source_in_world" in err
    angle = float(err.split("rotated by ")[1].split(" ")[0])
    assert 3.5 < angle < 6.5  # the truth is 5 deg
    assert main(["check", str(problem), "--accept-frame-error"]) == 0


@pytest.mark.slow
def test_result_json_carries_the_demo_quality_figures(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(GLASS), "--out", str(out), "--no-report"]) == 0
    doc = json.loads((out / "result.json").read_text())
    q = doc["demo_quality"]
    assert q["max_bridge_s"] == MAX_BRIDGE_S and q["frame"]["rotation_deg"] < 2.5
    assert q["n_samples"] > 1000 and q["frame"]["n_points"] == doc["n_waypoints"]
