import casadi as ca
import numpy as np
import pytest

from refine.errors import InputError
from refine.optimise.problem import ActiveSet, Weights, build_refinement
from refine.optimise.waypoint import waypoint_function
from refine.problem import Tolerances
from refine.synthetic import wave_path


def test_build_returns_an_inspectable_problem_without_solving(irb4600, straight_tool):
    fused = wave_path(50)
    nlp = build_refinement(irb4600, fused, np.eye(4), straight_tool, Tolerances())
    assert nlp.nlp["x"].shape == (6 * 50, 1)
    assert nlp.nlp["g"].shape == (4 * 50 + 6 * 49, 1)  # per waypoint, then joint steps per segment
    assert nlp.lbg.shape == nlp.ubg.shape == (4 * 50 + 6 * 49,)
    assert nlp.lbx.shape == (300,)
    assert nlp.solver.name() == "refine"  # IPOPT is set up, not run
    # joint bounds are the limits shrunk by the margin
    margin = np.radians(Tolerances().joint_margin_deg)
    np.testing.assert_allclose(nlp.lbx[:6], irb4600.spec.lower + margin)
    np.testing.assert_allclose(nlp.ubx[:6], irb4600.spec.upper - margin)


def test_problem_parameters_hold_the_cad_points_and_demo_rotations(irb4600, straight_tool, kin):
    """Evaluating the NLP's constraints at the IK solution of each pose gives zero position rows."""
    fused = wave_path(20)
    nlp = build_refinement(irb4600, fused, np.eye(4), straight_tool, Tolerances())
    from refine.optimise.seed import initial_guess

    q = initial_guess(nlp)
    g = ca.Function("g", [nlp.nlp["x"], nlp.nlp["p"]], [nlp.nlp["g"]])(q.ravel(), nlp.params)
    g = np.asarray(g).ravel()[: 4 * 20].reshape(20, 4)
    assert np.abs(g[:, :3]).max() < 1e-6  # TCP on the CAD point
    assert np.all(g[:, 3] > np.cos(np.radians(0.01)))  # orientation equal to the demo


def test_waypoint_function_cone_measure_is_the_cosine_of_the_deviation(irb4600, straight_tool, kin):
    f = waypoint_function(irb4600, np.eye(4), straight_tool, axisymmetric=False)
    q = np.array([0.1, 0.2, -0.1, 0.3, -0.8, 0.4])
    T = kin.pose(q)
    tilt = np.radians(5.0)
    R_demo = T[:3, :3] @ np.array(
        [[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]]
    )
    g, cost = f(q, T[:3, 3], R_demo.ravel(order="F"))
    assert float(g[3]) == pytest.approx(np.cos(tilt), abs=1e-12)
    assert float(cost) == pytest.approx(1 - np.cos(tilt), abs=1e-12)


def test_axisymmetric_tool_ignores_spin_about_the_tool_axis(irb4600, straight_tool, kin):
    f = waypoint_function(irb4600, np.eye(4), straight_tool, axisymmetric=True)
    q = np.array([0.1, 0.2, -0.1, 0.3, -0.8, 0.4])
    T = kin.pose(q)
    spin = np.radians(40.0)
    R_demo = T[:3, :3] @ np.array(
        [[np.cos(spin), -np.sin(spin), 0], [np.sin(spin), np.cos(spin), 0], [0, 0, 1]]
    )
    g, _ = f(q, T[:3, 3], R_demo.ravel(order="F"))
    assert float(g[3]) == pytest.approx(1.0, abs=1e-12)


def test_problem_size_grows_linearly_with_the_number_of_waypoints(irb4600, straight_tool):
    sizes = {}
    for n in (50, 200):
        nlp = build_refinement(irb4600, wave_path(n), np.eye(4), straight_tool, Tolerances())
        jac = ca.jacobian(nlp.nlp["g"], nlp.nlp["x"])
        sizes[n] = jac.sparsity().nnz()
    assert sizes[200] / sizes[50] == pytest.approx(4.0, rel=0.02)


def test_bad_settings_are_rejected_with_the_field_named(irb4600, straight_tool):
    with pytest.raises(InputError, match="at least 3 waypoints"):
        build_refinement(
            irb4600,
            wave_path(3).__class__(
                s=np.array([0.0, 0.1]),
                positions=np.zeros((2, 3)),
                rotations=np.stack([np.eye(3)] * 2),
                speed=np.ones(2),
                t_demo=np.array([0.0, 1.0]),
                residual=np.zeros(2),
            ),
            np.eye(4),
            straight_tool,
            Tolerances(),
        )
    with pytest.raises(InputError, match="joint_margin_deg"):
        build_refinement(irb4600, wave_path(10), np.eye(4), straight_tool, Tolerances(joint_margin_deg=500))
    with pytest.raises(InputError, match="Weights.velocity"):
        Weights(velocity=-1.0)
    with pytest.raises(InputError, match="singular segment point"):
        build_refinement(
            irb4600,
            wave_path(10),
            np.eye(4),
            straight_tool,
            Tolerances(),
            active=ActiveSet(singular_segments=((3, 1.5),)),
        )
