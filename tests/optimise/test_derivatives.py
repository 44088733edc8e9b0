"""The hand-assembled derivatives of the refinement NLP against CasADi's own differentiation, and the
on-disk cache of compiled kernels."""

import dataclasses
import os

import casadi as ca
import numpy as np
import pytest

from refine.errors import InputError
from refine.optimise import compiled as compiled_module
from refine.optimise.compiled import compiled, compiler
from refine.optimise.derivatives import waypoint_kernels
from refine.optimise.kkt import Evaluator
from refine.optimise.problem import ActiveSet, LinearRow, Weights, build_refinement
from refine.problem import Tolerances
from refine.synthetic import wave_path


def _problem(robot, tool, *, elastic: bool, singularity_hessian: bool = True, joint_steps="all"):
    rng = np.random.default_rng(3)
    N = 12
    active = ActiveSet(
        singular_waypoints=(2, 5),
        singular_segments=((7, 0.3), (10, 0.8)),
        linear_rows=(
            LinearRow(3, 0.0, rng.normal(size=6), 0.1, "a"),
            LinearRow(8, 0.6, rng.normal(size=6), -0.2, "b"),
            LinearRow(8, 0.6, rng.normal(size=6), 0.0, "c"),
        ),
    )
    return build_refinement(
        robot,
        wave_path(N),
        np.eye(4),
        tool,
        Tolerances(),
        weights=Weights(mid_range=0.3, acceleration=1e-3),
        active=active,
        elastic_deg=2.0 if elastic else None,
        singularity_hessian=singularity_hessian,
        joint_steps=joint_steps,
    )


@pytest.mark.parametrize("elastic", [False, True])
@pytest.mark.parametrize("singularity_hessian", [True, False])
@pytest.mark.parametrize("joint_steps", ["all", (0, 7, 20, 65), ()])
def test_assembled_derivatives_equal_casadi_differentiation(
    irb4600, straight_tool, monkeypatch, elastic, singularity_hessian, joint_steps
):
    """Exact everywhere, with all, some or none of the joint-step rows; without the singularity
    Hessian, the Hessian is the exact one of a Lagrangian whose singularity rows have zero multipliers."""
    # in the virtual machine, CasADi can differentiate the symbolic problem twice itself
    monkeypatch.setenv("REFINE_COMPILE", "0")
    nlp = _problem(
        irb4600,
        straight_tool,
        elastic=elastic,
        singularity_hessian=singularity_hessian,
        joint_steps=joint_steps,
    )
    assert nlp.nlp["g"].shape[0] == 4 * 12 + (6 * 11 if joint_steps == "all" else len(joint_steps)) + 4 + 3
    x, p, f, g = (nlp.nlp[k] for k in ("x", "p", "f", "g"))
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.shape[0])
    reference = ca.Function(
        "reference",
        [x, p, lam_f, lam_g],
        [f, ca.gradient(f, x), g, ca.jacobian(g, x), ca.triu(ca.hessian(lam_f * f + ca.dot(lam_g, g), x)[0])],
    )
    rng = np.random.default_rng(7)
    xv = np.concatenate(
        [
            rng.uniform(nlp.lbx[: nlp.n_waypoints * 6], nlp.ubx[: nlp.n_waypoints * 6]) * 0.5,
            rng.uniform(0.0, 0.01, x.shape[0] - nlp.n_waypoints * 6),
        ]
    )
    lf, lg = 0.7, rng.normal(size=g.shape[0])
    f_ref, grad_ref, g_ref, jac_ref, hess_ref = (
        np.array(ca.densify(v)) for v in reference(xv, nlp.params, lf, lg)
    )
    if not singularity_hessian:
        # the 4 singularity rows (2 waypoints, 2 segment points) follow the path and step rows
        first = 4 * nlp.n_waypoints + (
            6 * (nlp.n_waypoints - 1) if joint_steps == "all" else len(joint_steps)
        )
        lg_no_singular = lg.copy()
        lg_no_singular[first : first + 4] = 0.0
        hess_exact = np.array(ca.densify(reference(xv, nlp.params, lf, lg)[4]))
        hess_ref = np.array(ca.densify(reference(xv, nlp.params, lf, lg_no_singular)[4]))
        assert np.abs(hess_exact - hess_ref).max() > 1e-3  # the singularity rows do add curvature
    f_val, grad = nlp.derivatives["grad_f"](xv, nlp.params)
    g_val, jac = nlp.derivatives["jac_g"](xv, nlp.params)
    hess = nlp.derivatives["hess_lag"](xv, nlp.params, lf, lg)
    np.testing.assert_allclose(float(f_val), f_ref.item(), rtol=1e-12)
    np.testing.assert_allclose(np.array(g_val).ravel(), g_ref.ravel(), atol=1e-12)
    np.testing.assert_allclose(np.array(grad).ravel(), grad_ref.ravel(), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.array(ca.densify(jac)), jac_ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.array(ca.densify(hess)), hess_ref, rtol=1e-8, atol=1e-8)
    assert np.abs(hess_ref).max() > 1.0  # the comparison is not of zeros


@pytest.mark.skipif(compiler() is None, reason="no C compiler: the kernels run in the virtual machine")
def test_compiled_kernels_give_the_virtual_machine_values(irb4600, straight_tool, monkeypatch):
    fast = waypoint_kernels(irb4600, np.eye(4), straight_tool, False)
    monkeypatch.setenv("REFINE_COMPILE", "0")
    slow = waypoint_kernels(irb4600, np.eye(4), straight_tool, False)
    assert "external" in str(fast["waypoint_h"]).lower() or fast["waypoint_h"].is_a("External")
    q = np.array([0.1, 0.2, -0.1, 0.3, -0.8, 0.4])
    args = (q, [1.0, 0.2, 0.5], np.eye(3).ravel(), [0.1, -0.2, 0.3, 0.5], 2.0)
    np.testing.assert_allclose(
        np.array(fast["waypoint_h"](*args)), np.array(slow["waypoint_h"](*args)), rtol=1e-12
    )
    for a, b in zip(fast["waypoint_d"](*args[:3]), slow["waypoint_d"](*args[:3]), strict=True):
        np.testing.assert_allclose(np.array(a), np.array(b), rtol=1e-12, atol=1e-12)


@pytest.mark.skipif(compiler() is None, reason="no C compiler: the kernels run in the virtual machine")
@pytest.mark.parametrize("elastic", [False, True])
def test_grad_f_and_jac_g_return_the_problems_own_objective_and_rows_bit_for_bit(
    irb4600, straight_tool, elastic
):
    """With compiled kernels, the objective and rows that grad_f and jac_g return (from the derivative
    kernel's outputs) are the very numbers of the problem's f and g (from the waypoint kernel), and the
    two functions call the waypoint kernel no more."""
    nlp = _problem(irb4600, straight_tool, elastic=elastic)
    x, p, f, g = (nlp.nlp[k] for k in ("x", "p", "f", "g"))
    own = ca.Function("own", [x, p], [f, g])
    rng = np.random.default_rng(5)
    for _ in range(3):
        xv = rng.uniform(nlp.lbx, nlp.ubx) * 0.7
        f_own, g_own = (np.array(v) for v in own(xv, nlp.params))
        f_val, _ = nlp.derivatives["grad_f"](xv, nlp.params)
        g_val, _ = nlp.derivatives["jac_g"](xv, nlp.params)
        assert float(f_val) == f_own.item()
        np.testing.assert_array_equal(np.array(g_val), g_own)
        assert np.abs(g_own).max() > 0.1  # the comparison is not of zeros
    for name in ("grad_f", "jac_g"):
        called = {
            nlp.derivatives[name].instruction_MX(k).which_function().name()
            for k in range(nlp.derivatives[name].n_instructions())
            if nlp.derivatives[name].instruction_MX(k).is_call()
        }
        assert not any(c.startswith("map") and "waypoint_d" not in c and "waypoint" in c for c in called), (
            called
        )


@pytest.mark.skipif(compiler() is None, reason="no C compiler")
def test_compiled_library_is_cached_on_disk_by_key(tmp_path, monkeypatch):
    monkeypatch.setenv("REFINE_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(compiled_module, "_loaded", compiled_module.BoundedCache(compiled_module.LOADED_MAX))
    made = []

    def make(scale):
        def build():
            made.append(scale)
            x = ca.SX.sym("x")
            return [ca.Function("twice", [x], [scale * x])]

        return build

    assert float(compiled("t", "key-a", make(2.0))["twice"](3.0)) == 6.0
    assert len(list(tmp_path.glob("t-*.so"))) == 1 and made == [2.0]
    monkeypatch.setattr(
        compiled_module, "_loaded", compiled_module.BoundedCache(compiled_module.LOADED_MAX)
    )  # a new process: only the disk remains
    assert float(compiled("t", "key-a", make(2.0))["twice"](3.0)) == 6.0
    assert made == [2.0]  # loaded from disk, not built again
    assert float(compiled("t", "key-b", make(5.0))["twice"](3.0)) == 15.0  # another key, another library
    assert len(list(tmp_path.glob("t-*.so"))) == 2


def test_without_compilation_the_functions_themselves_are_used(tmp_path, monkeypatch):
    monkeypatch.setenv("REFINE_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("REFINE_COMPILE", "0")
    x = ca.SX.sym("x")
    f = ca.Function("square", [x], [x * x])
    out = compiled("t", "key", lambda: [f])
    assert float(out["square"](4.0)) == 16.0
    assert not list(tmp_path.iterdir())


@pytest.mark.skipif(compiler() is None, reason="no C compiler")
def test_the_cache_folder_keeps_its_bound_dropping_the_least_recently_used(tmp_path, monkeypatch):
    monkeypatch.setenv("REFINE_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(compiled_module, "_loaded", compiled_module.BoundedCache(compiled_module.LOADED_MAX))

    def make(scale):
        x = ca.SX.sym("x")
        return lambda: [ca.Function("twice", [x], [scale * x])]

    compiled("t", "key-0", make(0.0))
    (first,) = tmp_path.glob("t-*.so")
    pair_bytes = first.stat().st_size + first.with_suffix(".names").stat().st_size
    # room for three libraries of this size, not four
    monkeypatch.setenv("REFINE_CACHE_MAX_MB", str(3.5 * pair_bytes / 1e6))
    libraries = [first]
    for k in range(1, 6):
        before = set(tmp_path.glob("t-*.so"))
        compiled("t", f"key-{k}", make(float(k)))
        (new,) = set(tmp_path.glob("t-*.so")) - before
        libraries.append(new)
        os.utime(new, (1e9 + k, 1e9 + k))  # distinct use times, in the order made
        if k == 3:  # the first library is used again: it becomes the most recent
            monkeypatch.setattr(
                compiled_module, "_loaded", compiled_module.BoundedCache(compiled_module.LOADED_MAX)
            )
            compiled("t", "key-0", make(0.0))
            os.utime(first, (1e9 + 3.5, 1e9 + 3.5))
    left = set(tmp_path.glob("t-*.so"))
    total = sum(p.stat().st_size + p.with_suffix(".names").stat().st_size for p in left)
    assert total <= 3.5 * pair_bytes
    # made in the order 0 1 2 3 (0 used again) 4 5: the three most recent are 5, 4 and 0
    assert left == {libraries[5], libraries[4], libraries[0]}
    assert not any(p.with_suffix(".names").exists() for p in set(libraries) - left)
    monkeypatch.setenv("REFINE_CACHE_MAX_MB", "lots")
    with pytest.raises(InputError, match="REFINE_CACHE_MAX_MB must be a number of megabytes"):
        compiled("t", "key-9", make(9.0))


@pytest.mark.parametrize(("singularity_hessian", "joint_steps"), [(True, (0, 7, 20, 65)), (False, "all")])
def test_the_newton_evaluation_gives_the_nlp_derivatives_at_once(
    irb4600, straight_tool, monkeypatch, singularity_hessian, joint_steps
):
    """The Newton correction's one-call evaluation gives CasADi's own gradient, rows, Jacobian and
    Hessian of the problem, and the values of the separate grad_f, jac_g and hess_lag to rounding."""
    monkeypatch.setenv("REFINE_COMPILE", "0")  # CasADi differentiates the problem twice itself
    nlp = _problem(
        irb4600,
        straight_tool,
        elastic=False,
        singularity_hessian=singularity_hessian,
        joint_steps=joint_steps,
    )
    assert "newton" in nlp.derivatives
    x, p, f, g = (nlp.nlp[k] for k in ("x", "p", "f", "g"))
    lam_g = ca.MX.sym("lam_g", g.shape[0])
    hessian = ca.triu(ca.hessian(f + ca.dot(lam_g, g), x)[0])
    reference = ca.Function("reference", [x, p, lam_g], [ca.gradient(f, x), g, ca.jacobian(g, x), hessian])
    rng = np.random.default_rng(11)
    xv = rng.uniform(nlp.lbx, nlp.ubx) * 0.5
    lg = rng.normal(size=g.shape[0])
    if not singularity_hessian:  # the four singularity rows follow the path and step rows
        first = 4 * nlp.n_waypoints + (
            6 * (nlp.n_waypoints - 1) if joint_steps == "all" else len(joint_steps)
        )
        lg[first : first + 4] = 0.0
    grad_ref, g_ref, jac_ref, hess_ref = (np.array(ca.densify(v)) for v in reference(xv, nlp.params, lg))
    _, grad_sep = nlp.derivatives["grad_f"](xv, nlp.params)
    g_sep, jac_sep = nlp.derivatives["jac_g"](xv, nlp.params)
    hess_sep = nlp.derivatives["hess_lag"](xv, nlp.params, 1.0, lg)

    ev = Evaluator(nlp)
    grad1, g1, jac1 = (np.array(v, copy=True) for v in ev.first_order(xv))
    grad0, g0, jac0 = ev.first_order(xv, lg)
    hess0 = ev.hessian(lg)
    assert jac0 is not jac1  # each evaluation has its own buffers
    for grad_ev, g_ev, jac_ev in ((grad1, g1, jac1), (grad0, g0, jac0)):
        np.testing.assert_allclose(grad_ev, grad_ref.ravel(), rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(g_ev, g_ref.ravel(), atol=1e-12)
        np.testing.assert_allclose(ev.jacobian(jac_ev).toarray(), jac_ref, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(grad_ev, np.array(grad_sep).ravel(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(g_ev, np.array(g_sep).ravel(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(
            ev.jacobian(jac_ev).toarray(), np.array(ca.densify(jac_sep)), rtol=1e-12, atol=1e-12
        )
    upper = np.triu(ev.hessian_matrix(hess0).toarray())
    np.testing.assert_allclose(upper, hess_ref, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(upper, np.array(ca.densify(hess_sep)), rtol=1e-12, atol=1e-12)
    # another point's Hessian is evaluated there, not the one kept from the first
    xv2 = xv + 1e-2
    ev.first_order(xv2)
    hess2 = np.triu(ev.hessian_matrix(ev.hessian(lg)).toarray())
    np.testing.assert_allclose(
        hess2,
        np.array(ca.densify(nlp.derivatives["hess_lag"](xv2, nlp.params, 1.0, lg))),
        rtol=1e-12,
        atol=1e-12,
    )
    assert np.abs(hess_ref).max() > 1.0 and np.abs(g_ref).max() > 1e-2  # the comparison is not of zeros
    # without them (an elastic problem has none) the separate functions give the same
    separate = Evaluator(
        dataclasses.replace(nlp, derivatives={k: v for k, v in nlp.derivatives.items() if k != "newton"})
    )
    for a, b in zip(separate.first_order(xv), (grad1, g1, jac1), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(separate.hessian(lg), hess0, rtol=1e-12, atol=1e-12)
