"""The tracker frame check where the seam runs away from the receiver: rotation told from distortion.

On the bundled TIG cell the seam runs from 0.23 to 0.63 m from the receiver, so every function of
the path position is a function of the distance, and a distance-dependent distortion could absorb
a rotated ``source_in_world``. The problem's frame is turned here by a known angle about a world
axis through the receiver (the truth); the gate must stop and name about that angle. With the
problem's own frame, and with the log perturbed by the tracker's noise, it must not stop or warn
that the frame may be off; a spiral 60 mm across cannot show the frame well and must say so
instead of stopping.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.cad import read_cad_path
from refine.cli import main
from refine.demo import clean_demonstration, read_tracker_log
from refine.demo.quality import FRAME_WARN_DEG, FrameEstimate, gate_dropouts
from refine.demo.simulate import TrackerModel, perturb_log
from refine.errors import InputError
from refine.fuse.frame_check import frame_error_significant, gate_frame
from refine.fuse.fusion import fuse
from refine.problem import load_problem

ROOT = Path(__file__).resolve().parents[2]
TIG = ROOT / "problems" / "tig_weld"
SPIRAL = ROOT / "problems" / "unreachable" / "joint_wrap"


def _cell(folder: Path):
    problem = load_problem(folder)
    cad = read_cad_path(problem.cad, problem.frames.cad_in_world)
    return problem, cad, read_tracker_log(problem.demonstration)


@pytest.fixture(scope="module")
def tig():
    return _cell(TIG)


def _gate(cell, world_axis=(0.0, 0.0, 1.0), angle_deg=0.0, seed=None, shift_m=(0.0, 0.0, 0.0)):
    """The frame gate with source_in_world turned by angle_deg about world_axis through the receiver
    (and moved by shift_m in the world)."""
    problem, cad, log = cell
    if seed is not None:
        log = perturb_log(log, TrackerModel(), seed)
    raw, quality = gate_dropouts(log)
    demo = clean_demonstration(raw, problem.demonstration)
    T = np.array(problem.frames.source_in_world, dtype=float)
    T[:3, :3] = Rotation.from_rotvec(np.radians(angle_deg) * np.asarray(world_axis)).as_matrix() @ T[:3, :3]
    T[:3, 3] += shift_m
    fused = fuse(cad, demo, T, problem.tool.sensor_in_tcp)
    return gate_frame(quality, demo, fused, T, problem.tool.sensor_in_tcp)


def _frame_warnings(quality):
    return [w for w in quality.warnings if "source_in_world" in w]


@pytest.mark.parametrize(
    "world_axis", [(0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)], ids=["about z", "about x", "about y"]
)
@pytest.mark.parametrize("seed", [None, 7001], ids=["as recorded", "with noise"])
def test_a_tig_frame_turned_5_degrees_stops_the_run_naming_the_angle(tig, world_axis, seed):
    with pytest.raises(InputError) as e:
        _gate(tig, world_axis, 5.0, seed=seed)
    msg = str(e.value)
    assert "source_in_world looks wrong" in msg and "--accept-frame-error" in msg
    angle = float(msg.split("rotated by ")[1].split(" ")[0])
    assert abs(angle - 5.0) < 1.0  # the truth is 5 deg, all of it about axes the seam shows


def test_a_tig_frame_turned_10_degrees_about_z_stops_the_run(tig):
    with pytest.raises(InputError) as e:
        _gate(tig, (0.0, 0.0, 1.0), 10.0)
    angle = float(str(e.value).split("rotated by ")[1].split(" ")[0])
    assert abs(angle - 10.0) < 1.5


@pytest.mark.parametrize("seed", [None, 11, 12])
def test_the_tig_cell_with_its_own_frame_passes_without_a_frame_warning(tig, seed):
    quality = _gate(tig, seed=seed)  # no InputError: the frame is right
    assert quality.warnings == ()  # neither a rotation nor an offset
    frame = quality.as_json()["frame"]
    assert frame["observable_rotation_deg"] < FRAME_WARN_DEG  # the truth is 0
    assert not frame["not_observable"]  # the seam's bends show every axis


def test_with_accept_the_tig_rotation_is_a_warning_naming_the_angle(tig):
    problem, cad, log = tig
    raw, quality = gate_dropouts(log)
    demo = clean_demonstration(raw, problem.demonstration)
    T = np.array(problem.frames.source_in_world, dtype=float)
    T[:3, :3] = Rotation.from_rotvec([np.radians(5.0), 0.0, 0.0]).as_matrix() @ T[:3, :3]
    fused = fuse(cad, demo, T, problem.tool.sensor_in_tcp)
    quality = gate_frame(quality, demo, fused, T, problem.tool.sensor_in_tcp, accept=True)
    (warning,) = _frame_warnings(quality)
    assert "may be off" in warning and "rotated by" in warning
    frame = quality.as_json()["frame"]
    assert abs(frame["observable_rotation_deg"] - 5.0) < 1.0
    # the rotation vector in the receiver frame: the world x axis is {S}'s -y (receiver turned 90 deg about z)
    expected = T[:3, :3].T @ np.array([5.0, 0.0, 0.0])
    assert np.linalg.norm(np.asarray(frame["rotation_vector_deg"]) - expected) < 1.0


@pytest.mark.parametrize("seed", [None, 21])
def test_a_small_spiral_with_its_own_frame_is_not_stopped_but_said_to_be_weakly_checked(seed):
    quality = _gate(_cell(SPIRAL), seed=seed)  # no InputError
    assert quality.warnings  # the spiral is 60 mm across: it cannot show the frame well
    assert all("cannot be checked well" in w for w in quality.warnings)  # neither rotation nor offset "off"


@pytest.mark.parametrize("shift_m", [(0.04, 0.0, 0.0), (0.0, 0.0, 0.04)], ids=["along x", "along z"])
def test_a_tig_receiver_moved_40_mm_is_warned_about_as_an_offset(tig, shift_m):
    quality = _gate(tig, shift_m=shift_m)  # a shift does not stop the run
    (warning,) = [w for w in quality.warnings if "offset" in w]
    assert "position may be off" in warning
    assert abs(quality.frame.offset_m - 0.04) < 0.005  # the truth is 40 mm
    assert quality.frame.observable_rotation_deg < FRAME_WARN_DEG


def _estimate(chi2: float, n_hidden: int) -> FrameEstimate:
    hidden = tuple(
        {"axis_in_source": [1.0, 0.0, 0.0], "sigma_deg": 100.0, "about": "x"} for _ in range(n_hidden)
    )
    return FrameEstimate(
        5.0, 1.0, (0.0, 0.0, 1.0), 0.0, 0.0, 0.0, 10, 5.0, 1.0, 2.0, hidden, observable_chi2=chi2
    )


@pytest.mark.parametrize(
    ("n_hidden", "threshold"),
    # chi-square quantiles of the two-sided 2-sigma tail (4.550 %), from tables: 1 dof 4.000 (= 2²),
    # 2 dof -2 ln(0.0455) = 6.180, 3 dof 8.025
    [(2, 4.000), (1, 6.180), (0, 8.025)],
)
def test_significance_is_the_2_sigma_chi_square_quantile_for_the_observable_axes(n_hidden, threshold):
    assert not frame_error_significant(_estimate(threshold - 0.02, n_hidden))
    assert frame_error_significant(_estimate(threshold + 0.02, n_hidden))


def test_no_observable_axis_is_never_significant():
    assert not frame_error_significant(_estimate(1e6, 3))


def test_check_names_the_angle_of_a_turned_tig_frame(tmp_path, capsys):
    problem = tmp_path / "tig"
    shutil.copytree(TIG, problem, ignore=shutil.ignore_patterns("generate.py", "README.md"))
    toml = problem / "problem.toml"
    text = toml.read_text()
    old = "source_in_world = { xyz = [0.60, -0.42, 0.78], rpy_deg = [0.0, 0.0, 90.0] }"
    assert old in text
    # fixed-axis angles: yaw 95 = 5 deg more about the world z axis
    toml.write_text(text.replace(old, old.replace("90.0", "95.0")))
    assert main(["check", str(problem)]) == 2
    err = capsys.readouterr().err
    assert "rotated by" in err and "--accept-frame-error" in err and "Traceback" not in err
    angle = float(err.split("rotated by ")[1].split(" ")[0])
    assert abs(angle - 5.0) < 1.0


def test_frame_estimate_fields_reach_demo_quality(tig):
    frame = _gate(tig).as_json()["frame"]
    assert len(frame["rotation_vector_deg"]) == 3 and len(frame["covariance_deg2"]) == 3
    cov = np.asarray(frame["covariance_deg2"])
    np.testing.assert_allclose(cov, cov.T, rtol=1e-9, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(cov) > 0.0)
    assert frame["observable_chi2"] >= 0.0


@pytest.mark.slow
def test_an_accepted_frame_error_is_named_in_result_json(tmp_path, capsys):
    problem = tmp_path / "glass"
    glass = ROOT / "problems" / "glass_adhesive"
    shutil.copytree(glass, problem, ignore=shutil.ignore_patterns("generate.py", "README.md"))
    toml = problem / "problem.toml"
    old = "source_in_world = { xyz = [1.30, -0.82, 0.72], rpy_deg = [0.0, 0.0, 90.0] }"
    text = toml.read_text()
    assert text.count(old) == 1
    toml.write_text(text.replace(old, old.replace("90.0", "95.0")))  # 5 deg about the world z axis
    out = tmp_path / "out"
    assert main(["run", str(problem), "--out", str(out), "--no-report"]) == 2  # stopped, nothing written
    assert not (out / "result.json").exists()
    assert main(["run", str(problem), "--out", str(out), "--no-report", "--accept-frame-error"]) == 0
    q = json.loads((out / "result.json").read_text())["demo_quality"]
    (warning,) = [w for w in q["warnings"] if "source_in_world may be off" in w]
    assert abs(float(warning.split("rotated by ")[1].split(" ")[0]) - 5.0) < 1.0
    assert abs(q["frame"]["observable_rotation_deg"] - 5.0) < 1.0 and q["frame_stop_deg"] < 5.0


@pytest.mark.parametrize(
    ("sigmas_deg", "n_hidden"),
    [
        ((1.0, 1.5, 1000.0), 1),  # a straight seam: its own direction (ratio rule)
        ((1.0, 3.0, 4.0), 0),  # all within the weak-check limit of 5 deg, ratio 4
        ((1.0, 6.0, 7.0), 2),  # beyond 5 deg each: a 10 deg rotation about them stays within 2 sigma
        ((6.0, 7.0, 8.0), 3),  # nothing shown
    ],
)
def test_an_axis_is_not_observable_by_ratio_or_above_the_weak_check_limit(sigmas_deg, n_hidden):
    from refine.fuse.frame_check import _observable_part

    V = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()  # principal axes, columns
    cov = V @ np.diag(np.radians(sigmas_deg) ** 2) @ V.T
    rv = np.radians(2.0) * V[:, 0]  # 2 deg about the best-determined axis
    points = np.column_stack([np.linspace(0.3, 0.6, 50), np.zeros(50), np.zeros(50)])
    obs, obs_sigma, chi2, hidden = _observable_part(rv, cov, points)
    assert len(hidden) == n_hidden
    assert np.isfinite(obs_sigma)
    if n_hidden < 3:
        assert obs == pytest.approx(2.0) and obs_sigma == pytest.approx(sigmas_deg[0])
        assert chi2 == pytest.approx((2.0 / sigmas_deg[0]) ** 2)
    else:
        assert obs == 0.0 and chi2 == 0.0 and obs_sigma == pytest.approx(min(sigmas_deg))
