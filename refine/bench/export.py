"""Exported instances: one fixed refinement NLP written for any NLP solver (``refine bench export``).

An instance is the last round of refine's outer loop on a benchmark problem, as ``refine bench run``
solves it with the ``refine`` contender: the problem with every constraint the rounds added
(singularity bounds, clearance rows linearised at the previous round's answer, joint-step rows),
whose optimum is refine's answer. It is rebuilt with CasADi differentiating the whole problem (the
``"casadi"`` derivative mode: no compiled kernels), so exact first and second derivatives of every
function are available to whoever loads it. A folder holds three files:

- ``nlp.casadi``: the CasADi Function ``nlp: (x, p) -> (f, g)``, saved with ``Function.save``;
- ``bounds.json``: ``x0`` (refine's cold start: its IK seed, slacks at 0), ``lbx``, ``ubx``, ``lbg``,
  ``ubg`` and ``p``, as lists of numbers, an infinite bound written as ``null``;
- ``instance.json``: what the instance is (problem, round, sizes, refine's answer, objective,
  status, iterations and IPOPT options, versions).

A named test set of instances is a ``[instances.NAME]`` table of the suites file
(:func:`refine.bench.suites.load_suites`); :func:`solve_instance` solves one with plain IPOPT.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, replace
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from refine.bench.suites import BenchProblem, bundled_problem, generated_problem, problems
from refine.errors import InputError
from refine.types import Array

FORMAT_VERSION = 1
"""Version of the instance folder's layout, written in ``instance.json`` (``format``)."""

FILES = ("nlp.casadi", "bounds.json", "instance.json")
"""The files of an instance folder."""

BOUND_KEYS = ("x0", "lbx", "ubx", "lbg", "ubg", "p")
"""The keys of ``bounds.json``."""


@dataclass(frozen=True)
class Exported:
    """An instance written by :func:`export_instance`.

    Attributes:
        folder: where its files are.
        name: the problem's name.
        round: which solve of refine's outer loop it is (1 = the first; strict and elastic rounds
            counted together).
        objective: the NLP's objective at refine's answer [deg²-scaled cost, as the refinement's].
        status: refine's verdict (``ok``, ``repaired``, ``infeasible``).
        iterations: refine's IPOPT iterations over all its rounds.
    """

    folder: Path
    name: str
    round: int
    objective: float
    status: str
    iterations: int


def _list(values: Array) -> list[float | None]:
    """Numbers for JSON, an infinite bound as None (``null``)."""
    return [None if math.isinf(v) else float(v) for v in np.asarray(values, dtype=float).ravel()]


def _array(values: list[float | None], infinity: float) -> Array:
    """A ``bounds.json`` list back to numbers, ``null`` as ``infinity``."""
    return np.array([infinity if v is None else v for v in values], dtype=float)


def export_instance(
    problem: BenchProblem, folder: Path, *, solver_options: dict[str, Any] | None = None
) -> Exported:
    """Solve ``problem`` as the ``refine`` contender does and write its last round to ``folder``.

    ``solver_options``: IPOPT options (``ipopt.`` prefix) for refine's solve, recorded in
    ``instance.json`` with the ones the engine sets itself.

    Raises:
        InputError: refine solved no NLP for the problem (it was found out of reach before any
            solve), or the problem is one refine's refinement does not state (a stationary tool).
    """
    import casadi as ca

    from refine.bench.contenders import solve_as_refine

    if problem.tool_in_world is not None:
        raise InputError(
            f"{problem.name}: refine's refinement does not state a stationary tool, nothing to export"
        )
    result, _, _, _ = solve_as_refine(problem, "assembled", "ipopt", solver_options)
    if result.problem is None:
        raise InputError(
            f"{problem.name}: refine answered {result.status} before solving any NLP "
            f"({result.reason[:160]}), so there is no instance to export"
        )
    last = result.problem
    symbolic = replace(last, derivative_mode="casadi").rebuilt(
        active=last.active, elastic_deg=last.elastic_deg, joint_steps=last.joint_steps
    )
    x, p = symbolic.nlp["x"], symbolic.nlp["p"]
    function = ca.Function("nlp", [x, p], [symbolic.nlp["f"], symbolic.nlp["g"]], ["x", "p"], ["f", "g"])
    n_q = symbolic.n_waypoints * symbolic.dof
    answer = np.zeros(x.numel())
    answer[:n_q] = np.asarray(result.q, dtype=float).ravel()
    if symbolic.elastic_deg is not None:
        bounds_now = {"lbx": symbolic.lbx, "ubx": symbolic.ubx, "lbg": symbolic.lbg, "p": symbolic.params}
        answer = least_slacks(function, bounds_now, symbolic.n_waypoints, symbolic.dof, answer)
    x0 = np.zeros(x.numel())
    x0[:n_q] = np.asarray(result.q_seed, dtype=float).ravel()
    objective = float(function(answer, symbolic.params)[0])

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    function.save(str(folder / "nlp.casadi"))
    bounds = {
        "x0": _list(x0),
        "lbx": _list(symbolic.lbx),
        "ubx": _list(symbolic.ubx),
        "lbg": _list(symbolic.lbg),
        "ubg": _list(symbolic.ubg),
        "p": _list(symbolic.params),
    }
    (folder / "bounds.json").write_text(json.dumps(bounds) + "\n")
    options = {k: v for k, v in last.solver_options.items() if k.startswith("ipopt.")}
    info = {
        "format": FORMAT_VERSION,
        "problem": problem.name,
        "suite": problem.suite,
        "robot": problem.robot.spec.name,
        "n_waypoints": symbolic.n_waypoints,
        "dof": symbolic.dof,
        "n_x": int(x.numel()),
        "n_g": int(symbolic.nlp["g"].numel()),
        "n_p": int(p.numel()),
        "round": int(result.outer_iterations),
        "elastic": symbolic.elastic_deg is not None,
        "elastic_max_slack_deg": symbolic.elastic_deg,
        "rows": {
            "path": 4 * symbolic.n_waypoints,
            "joint_steps": len(symbolic.step_rows()),
            "singularity": len(last.active.singular_waypoints) + len(last.active.singular_segments),
            "linear": len(last.active.linear_rows),
        },
        "x_layout": "joints of waypoint 0 (rad), joints of waypoint 1, ...; then one slack per waypoint "
        "(cosine units) when elastic",
        "p_layout": "CAD points (3 per waypoint, m), then demonstrated rotation matrices (9 per waypoint, "
        "column-major)",
        "refine": {
            "status": result.status,
            "solver_status": result.solver_status,
            "objective": objective,
            "iterations": int(result.iterations),
            "rounds": int(result.outer_iterations),
            "x": _list(answer),
            "ipopt_options": options,
        },
        "versions": {name: _version(name) for name in ("refine", "casadi")},
    }
    (folder / "instance.json").write_text(json.dumps(info, indent=1) + "\n")
    return Exported(folder, problem.name, info["round"], objective, result.status, int(result.iterations))


def least_slacks(function: Any, bounds: dict[str, Array], n_waypoints: int, dof: int, x: Array) -> Array:
    """``x`` of an elastic instance with each slack the least its cone row needs at ``x``'s joints.

    At the optimum the penalised slack rests on its cone row, so this is the answer's own slack,
    computed exactly (one converted back from degrees loses digits). It also puts two answers on
    the same footing: with a slack weight of 1e4, a cone row broken by IPOPT's constraint
    tolerance (1e-10) on each of N rows changes the objective by about N·1e-6.
    """
    x = np.array(x, dtype=float)
    n_q, N = n_waypoints * dof, n_waypoints
    x[n_q:] = 0.0
    cone = np.asarray(function(x, bounds["p"])[1]).ravel()[3 : 4 * N : 4]
    x[n_q:] = np.clip(bounds["lbg"][3 : 4 * N : 4] - cone, bounds["lbx"][n_q:], bounds["ubx"][n_q:])
    return x


def _version(name: str) -> str:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return ""


def load_instance(folder: Path) -> tuple[Any, dict[str, Array], dict[str, Any]]:
    """The instance in ``folder``: the loaded Function, its bounds as arrays (±inf restored), ``instance.json``.

    Raises:
        InputError: a file is missing, or ``bounds.json`` lacks a key or has one of the wrong length.
    """
    import casadi as ca

    folder = Path(folder)
    missing = [name for name in FILES if not (folder / name).is_file()]
    if missing:
        raise InputError(
            f"instance folder {folder}: missing {', '.join(missing)} (expected {', '.join(FILES)})"
        )
    function = ca.Function.load(str(folder / "nlp.casadi"))
    raw = json.loads((folder / "bounds.json").read_text())
    lacking = [k for k in BOUND_KEYS if k not in raw]
    if lacking:
        raise InputError(
            f"{folder / 'bounds.json'}: no {', '.join(lacking)} (expected keys {', '.join(BOUND_KEYS)})"
        )
    infinity = {"lbx": -math.inf, "lbg": -math.inf}
    bounds = {k: _array(raw[k], infinity.get(k, math.inf)) for k in BOUND_KEYS}
    sizes = {"x0": function.size1_in(0), "lbx": function.size1_in(0), "ubx": function.size1_in(0),
             "p": function.size1_in(1), "lbg": function.size1_out(1), "ubg": function.size1_out(1)}  # fmt: skip
    for key, size in sizes.items():
        if len(bounds[key]) != size:
            raise InputError(
                f"{folder / 'bounds.json'}: {key} has {len(bounds[key])} values, the NLP needs {size}"
            )
    return function, bounds, json.loads((folder / "instance.json").read_text())


def solve_instance(folder: Path, options: dict[str, Any] | None = None) -> dict[str, Any]:
    """Solve the instance in ``folder`` with plain IPOPT (exact Hessian) from its ``x0``.

    ``options``: CasADi nlpsol options (IPOPT's with the ``ipopt.`` prefix); by default IPOPT's own
    defaults, quiet. Returns the objective (of an elastic instance with the least slacks at IPOPT's
    joints, :func:`least_slacks`, as refine's in ``instance.json``; IPOPT's own is
    ``solver_objective``), IPOPT's iterations and status, the largest bound or constraint
    violation, the CPU time [s] and ``x``.
    """
    import casadi as ca

    function, b, info = load_instance(folder)
    x = ca.MX.sym("x", function.size1_in(0))
    p = ca.MX.sym("p", function.size1_in(1))
    f, g = function(x, p)
    settings = {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": False, **(options or {})}
    solver = ca.nlpsol("instance", "ipopt", {"x": x, "p": p, "f": f, "g": g}, settings)
    c0 = time.process_time()
    sol = solver(x0=b["x0"], p=b["p"], lbx=b["lbx"], ubx=b["ubx"], lbg=b["lbg"], ubg=b["ubg"])
    cpu = time.process_time() - c0
    stats = solver.stats()
    xs, gs = np.asarray(sol["x"]).ravel(), np.asarray(sol["g"]).ravel()
    violation = max(
        float(np.max(np.maximum(b["lbx"] - xs, 0.0), initial=0.0)),
        float(np.max(np.maximum(xs - b["ubx"], 0.0), initial=0.0)),
        float(np.max(np.maximum(b["lbg"] - gs, 0.0), initial=0.0)),
        float(np.max(np.maximum(gs - b["ubg"], 0.0), initial=0.0)),
    )
    objective = float(sol["f"])
    if info["elastic"]:
        objective = float(
            function(least_slacks(function, b, info["n_waypoints"], info["dof"], xs), b["p"])[0]
        )
    return {
        "objective": objective,
        "solver_objective": float(sol["f"]),
        "iterations": int(stats.get("iter_count", 0)),
        "status": str(stats.get("return_status", "")),
        "max_violation": violation,
        "cpu_s": cpu,
        "x": xs,
    }


def find_problem(data: dict[str, Any], reference: str, *, root: Path | None = None) -> BenchProblem:
    """The benchmark problem ``reference`` names: a problem folder (or its ``problem.toml``), or ``SUITE/NAME``.

    ``NAME`` is a problem's name in the suite, e.g. ``glass/glass_adhesive`` or ``quick/irb4600-100``.

    Raises:
        InputError: no such folder, suite or problem (the message lists the suite's problems).
    """
    from refine.bench.suites import ROOT

    root = ROOT if root is None else root
    path = Path(reference)
    if path.exists():
        return bundled_problem("export", path)
    suite, _, name = reference.partition("/")
    if not name:
        raise InputError(
            f"problem {reference!r}: neither a problem folder nor SUITE/NAME (e.g. glass/glass_adhesive)"
        )
    spec = data.get("suite", {}).get(suite, {})
    family, _, size = name.rpartition("-")
    if family in spec.get("generated", []) and size.isdigit() and int(size) in spec.get("sizes", []):
        return generated_problem(suite, family, data["generated"][family], int(size))
    for folder in spec.get("problems", []):
        if Path(folder).name == name:
            return bundled_problem(suite, root / folder)
    seen = []
    for problem in problems(data, suite, root=root):
        if problem.name == name:
            return problem
        seen.append(problem.name)
    raise InputError(
        f"problem {reference!r}: suite {suite!r} has no problem {name!r}; it has {', '.join(seen)}"
    )


def export_set(
    data: dict[str, Any], name: str, folder: Path, *, solver_options: dict[str, Any] | None = None, echo=print
) -> list[Exported]:
    """Export every problem of the test set ``[instances.NAME]`` into ``folder/<problem>/``.

    Also writes ``folder/index.json``: the set's name and, per instance, its folder, round,
    refine's objective, status and iterations.
    """
    sets = data.get("instances", {})
    if name not in sets:
        raise InputError(
            f"no test set {name!r} of exported instances; sets: {', '.join(sorted(sets)) or 'none'}"
        )
    out = []
    for reference in sets[name]["problems"]:
        problem = find_problem(data, reference)
        done = export_instance(problem, Path(folder) / problem.name, solver_options=solver_options)
        echo(
            f"{reference}: round {done.round}, {done.status}, objective {done.objective:.13g} -> {done.folder}"
        )
        out.append(done)
    index = {
        "set": name,
        "instances": [
            {"name": e.name, "folder": e.folder.name, "round": e.round, "objective": e.objective,
             "status": e.status, "iterations": e.iterations}
            for e in out
        ],
    }  # fmt: skip
    (Path(folder) / "index.json").write_text(json.dumps(index, indent=1) + "\n")
    return out
