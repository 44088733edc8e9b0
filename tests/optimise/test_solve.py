import numpy as np
import pytest

from refine.frames import rotation_about, rotation_angle_deg
from refine.optimise.problem import Weights, build_refinement
from refine.optimise.solve import solve_refinement
from refine.paths import FusedPath
from refine.problem import Tolerances
from refine.synthetic import wave_path


@pytest.fixture(scope="module")
def wave_result(irb4600, straight_tool):
    nlp = build_refinement(irb4600, wave_path(120), np.eye(4), straight_tool, Tolerances())
    return nlp, solve_refinement(nlp)


def test_refined_path_is_verified_on_the_cad_path_within_tolerances(wave_result, kin):
    nlp, result = wave_result
    assert result.status == "ok", result.reason
    poses = kin.poses(result.q)  # recomputed here, independently of the result's own check
    assert np.linalg.norm(poses[:, :3, 3] - nlp.fused.positions, axis=1).max() < 1e-6
    assert rotation_angle_deg(poses[:, :3, :3], nlp.fused.rotations).max() <= 3.0 + 1e-6
    spec = kin.robot.spec
    margin = np.radians(2.0)
    assert np.all(result.q >= spec.lower + margin - 1e-9) and np.all(result.q <= spec.upper - margin + 1e-9)


def test_every_stage_timed_on_the_wall_clock_is_timed_on_the_cpu_clock_too(wave_result):
    _, result = wave_result
    wall, cpu = result.timings_s, result.timings_s.cpu
    assert {"seed", "solve", "verify"} <= set(wall) and set(cpu) == set(wall)
    assert all(v >= 0.0 for v in cpu.values()) and cpu["solve"] > 0.0


def test_refining_a_reachable_smooth_demo_stays_close_to_it(wave_result):
    """The demo is exactly reachable and smooth: the refinement follows it to a fraction of a degree."""
    _, result = wave_result
    assert result.check.orientation_deviation_deg.max() < 0.5
    assert np.abs(result.q - result.q_seed).max() < np.radians(1.0)


def test_orientation_cone_holds_when_smoothness_pulls_away_from_a_wavy_demo(irb4600, straight_tool, kin):
    base = wave_path(80, amplitude_m=0.0)
    wobble = np.radians(8.0) * np.sin(np.linspace(0, 6 * np.pi, 80))
    rotations = base.rotations @ rotation_about("x", wobble)
    fused = FusedPath(base.s, base.positions, rotations, base.speed, base.t_demo, base.residual)
    nlp = build_refinement(
        irb4600,
        fused,
        np.eye(4),
        straight_tool,
        Tolerances(orientation_deg=3.0),
        weights=Weights(velocity=50.0, acceleration=0.05),
    )
    result = solve_refinement(nlp)
    assert result.status == "ok", result.reason
    dev = result.check.orientation_deviation_deg
    assert dev.max() <= 3.0 + 1e-6
    assert dev.max() > 2.9  # the cone binds: smoothness wants to cut the wobble


def test_unreachable_points_are_reported_infeasible_with_the_segment(irb4600, straight_tool):
    fused = wave_path(40, centre=(3.5, 0.0, 0.6))  # 3.5 m away: beyond the 2.05 m reach
    nlp = build_refinement(irb4600, fused, np.eye(4), straight_tool, Tolerances())
    result = solve_refinement(nlp)
    assert result.status == "infeasible"
    assert result.reason.startswith("out of reach at waypoints 0-39")
    worst = result.check.violations[0]
    assert worst.reason == "out of reach" and worst.unit == "m"
    # the wave's nearest point is 3.5 - 0.05 m out; the arm reaches about 2.05 m + 0.35 m tool from axis 1
    assert 0.5 < worst.worst < 1.5
    assert not result.check.ok
    assert result.iterations == 0  # diagnosed without running IPOPT


def test_singularity_margin_is_kept_at_and_between_waypoints_when_the_demo_grazes_it(
    irb4600, straight_tool, kin
):
    """A demo that brings the wrist close to q5 = 0 in the middle of the path: the refined path keeps
    the scaled manipulability above the margin everywhere, bounds added only where needed."""
    n = 60
    q = np.zeros((n, 6))
    q[:, 0] = np.linspace(-0.2, 0.2, n)
    q[:, 1], q[:, 2] = 0.3, -0.3
    q[:, 4] = -np.radians(20.0) + np.radians(18.0) * np.sin(np.linspace(0, np.pi, n))  # down to -2 deg
    T = kin.poses(q)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1))])
    fused = FusedPath(s, T[:, :3, 3], T[:, :3, :3], np.full(n, 0.1), s / 0.1, np.zeros(n))
    nlp = build_refinement(
        irb4600, fused, np.eye(4), straight_tool, Tolerances(orientation_deg=10.0, singularity_margin=0.02)
    )
    result = solve_refinement(nlp)
    assert result.status == "ok", result.reason
    assert result.check.singularity.min() >= 0.02 - 1e-6
    assert result.check.singularity_between.min() >= 0.02 - 1e-6
    assert 0 < len(result.active.singular_waypoints) < n


@pytest.fixture(scope="module")
def iiwa_wave():
    from refine.frames import transform_from_xyz_rpy
    from refine.robot.registry import load_robot

    robot = load_robot("kuka_iiwa14_r820")
    tcp = transform_from_xyz_rpy([0.0, 0.0, 0.2], [0.0, 0.0, 0.0])
    fused = wave_path(150, centre=(0.6, 0.0, 0.25), length_m=0.4, amplitude_m=0.03, wavelength_m=0.2)
    return robot, tcp, fused


def test_redundant_arm_keeps_its_joints_away_from_the_limits_with_the_mid_range_cost(iiwa_wave):
    robot, tcp, fused = iiwa_wave
    plain = solve_refinement(build_refinement(robot, fused, np.eye(4), tcp, Tolerances()))
    mid = solve_refinement(
        build_refinement(robot, fused, np.eye(4), tcp, Tolerances(), weights=Weights(mid_range=2.0))
    )
    assert plain.status == mid.status == "ok"
    assert np.degrees(mid.check.joint_margin_rad.min()) > 10.0
    assert mid.check.joint_margin_rad.min() > plain.check.joint_margin_rad.min()
    assert mid.check.orientation_deviation_deg.max() < 1.0


def test_redundant_arm_solution_is_stable_under_small_changes_of_the_demo(iiwa_wave):
    """0.2 deg of orientation noise and 0.1 mm of position noise move the joints by a fraction of a degree."""
    robot, tcp, fused = iiwa_wave
    weights = Weights(mid_range=2.0)
    base = solve_refinement(build_refinement(robot, fused, np.eye(4), tcp, Tolerances(), weights=weights))
    rng = np.random.default_rng(1)
    rotations = fused.rotations @ rotation_about("x", np.radians(0.2) * rng.standard_normal(len(fused)))
    positions = fused.positions + 1e-4 * rng.standard_normal((len(fused), 3))
    nudged = FusedPath(fused.s, positions, rotations, fused.speed, fused.t_demo, fused.residual)
    other = solve_refinement(build_refinement(robot, nudged, np.eye(4), tcp, Tolerances(), weights=weights))
    assert other.status == "ok"
    assert np.degrees(np.abs(other.q - base.q)).max() < 0.5
    # the elbow moves smoothly along the path: no step larger than 2 deg per 3 mm waypoint
    assert np.degrees(np.abs(np.diff(base.q[:, 2]))).max() < 2.0


def test_an_infeasible_answer_is_retried_from_other_ik_branches_and_says_so(irb4600, straight_tool):
    """2.6 turns of tool spin on a short line cannot fit axis 6 (+-400 deg) within 15 deg of slack."""
    n = 80
    s = np.linspace(0.0, 0.3, n)
    positions = np.column_stack([np.full(n, 1.3), s - 0.15, np.full(n, 0.6)])
    rotations = rotation_about("x", np.pi) @ rotation_about("z", np.linspace(0.0, 2.6 * 2 * np.pi, n))
    fused = FusedPath(s, positions, rotations, np.full(n, 0.1), s / 0.1, np.zeros(n))
    nlp = build_refinement(irb4600, fused, np.eye(4), straight_tool, Tolerances())
    result = solve_refinement(nlp, repair_max_slack_deg=15.0)
    assert result.status == "infeasible"
    assert "no repair within 15 deg" in result.reason
    assert "IK branch(es) tried" in result.reason


# ---- a problem built with only some joint-step rows ----------------------------------------------


@pytest.fixture(scope="module")
def steep_wave(irb4600, straight_tool):
    """40 waypoints on 1 m: axis 6 turns 12.9 deg between two of them where no bound holds it."""
    fused = wave_path(40, length_m=1.0)
    start = solve_refinement(
        build_refinement(irb4600, fused, np.eye(4), straight_tool, Tolerances(joint_step_deg=12.4))
    )
    assert start.status == "ok", start.reason
    return fused, start.q  # every step within 12.4 deg


def test_a_problem_with_some_joint_step_rows_is_solved_with_those_that_bind(
    steep_wave, irb4600, straight_tool, monkeypatch
):
    """No row from the seed; the first answer steps past the bound, so the rows are added and it is
    solved again: the answer is the complete problem's, on the bound and not past it."""
    import refine.optimise.rounds as rounds_module

    fused, q0 = steep_wave
    tol = Tolerances(joint_step_deg=12.5)
    complete = solve_refinement(build_refinement(irb4600, fused, np.eye(4), straight_tool, tol), q0)
    monkeypatch.setattr(rounds_module, "STEP_NEAR", 10.0)  # rows only for steps past the bound
    lazy = solve_refinement(
        build_refinement(irb4600, fused, np.eye(4), straight_tool, tol, joint_steps=()), q0
    )
    assert complete.status == lazy.status == "ok"
    assert complete.outer_iterations == 1 and lazy.outer_iterations == 2
    steps = np.degrees(np.abs(np.diff(lazy.q, axis=0)))
    assert steps.max() <= 12.5 + 1e-7 and steps.max() >= 12.5 - 1e-4  # the bound binds
    np.testing.assert_allclose(lazy.q, complete.q, atol=1e-6)


def test_joint_step_rows_near_their_bound_in_the_seed_are_there_from_the_first_solve(
    steep_wave, irb4600, straight_tool
):
    fused, q0 = steep_wave
    tol = Tolerances(joint_step_deg=12.5)
    lazy = solve_refinement(
        build_refinement(irb4600, fused, np.eye(4), straight_tool, tol, joint_steps=()), q0
    )
    assert lazy.status == "ok" and lazy.outer_iterations == 1
    assert np.degrees(np.abs(np.diff(lazy.q, axis=0))).max() <= 12.5 + 1e-7


def test_joint_step_rows_outside_the_path_are_refused(irb4600, straight_tool):
    from refine.errors import InputError

    with pytest.raises(InputError, match=r"joint-step rows must lie in \[0, 54\)"):
        build_refinement(irb4600, wave_path(10), np.eye(4), straight_tool, Tolerances(), joint_steps=(54,))
