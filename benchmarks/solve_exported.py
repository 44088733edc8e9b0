"""Solve exported refinement instances with plain IPOPT, outside refine (casadi and the standard library only).

    python benchmarks/solve_exported.py FOLDER [FOLDER ...]

Each FOLDER is an instance written by ``refine bench export`` (nlp.casadi, bounds.json,
instance.json) or a test set's folder (``refine bench export --set NAME``, with index.json). Every
instance is solved three times from its ``x0`` with the exact Hessian CasADi derives from the
loaded Function: with IPOPT's own defaults (tol 1e-8, constraint violation 1e-4); with refine's
two convergence tolerances only (``ipopt.tol``, ``ipopt.constr_viol_tol`` from instance.json,
everything else IPOPT's default); and with every IPOPT option refine used (its warm-start point
and MUMPS settings too). Printed per instance: refine's objective and iterations (all its rounds),
each solve's objective (of an elastic instance, with the least slacks its cone rows need at the
solve's joints, as refine's is taken), relative difference to refine's, largest |x - x_refine|, iterations and
status, and process CPU time [s]. Exit status 1 when the objective of a solve at refine's
tolerances is more than 1e-6 relative from refine's (with IPOPT's defaults a constraint met to
only 1e-8 can move the objective by more where clearance rows bind: that row is reported, not
judged).
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import casadi as ca

RELATIVE_TOLERANCE = 1e-6
"""The agreement asked of a solve's objective with refine's (relative), when it stops at refine's tolerances."""

TOLERANCES = ("ipopt.tol", "ipopt.constr_viol_tol")
"""The convergence tolerances of refine's IPOPT options, given alone to the cold solve that is judged."""


def bounds_of(folder: Path) -> dict[str, list[float]]:
    """bounds.json with ``null`` read as the infinite bound it stands for."""
    raw = json.loads((folder / "bounds.json").read_text())
    below = {"lbx", "lbg"}
    return {
        key: [(-math.inf if key in below else math.inf) if v is None else v for v in values]
        for key, values in raw.items()
    }


def least_slacks(nlp: ca.Function, b: dict, info: dict, x: list[float]) -> list[float]:
    """An elastic instance's ``x`` with each slack the least its cone row (4th of each waypoint) needs.

    refine's objective in instance.json is taken so; with the slack weight of 1e4, IPOPT's own
    objective can be lower by about N·1e4 times its constraint tolerance.
    """
    n_q, N = info["n_waypoints"] * info["dof"], info["n_waypoints"]
    x = list(x[:n_q]) + [0.0] * (len(x) - n_q)
    g = ca.DM(nlp(x, b["p"])[1]).full().ravel()
    slacks = [b["lbg"][4 * k + 3] - g[4 * k + 3] for k in range(N)]
    return x[:n_q] + [
        min(max(s, lo), hi) for s, lo, hi in zip(slacks, b["lbx"][n_q:], b["ubx"][n_q:], strict=True)
    ]


def solve(folder: Path, options: dict) -> dict:
    """Plain IPOPT on the instance in ``folder`` with CasADi ``options``."""
    nlp = ca.Function.load(str(folder / "nlp.casadi"))
    b = bounds_of(folder)
    x = ca.MX.sym("x", nlp.size1_in(0))
    p = ca.MX.sym("p", nlp.size1_in(1))
    f, g = nlp(x, p)
    solver = ca.nlpsol("plain", "ipopt", {"x": x, "p": p, "f": f, "g": g}, options)
    c0 = time.process_time()
    sol = solver(x0=b["x0"], p=b["p"], lbx=b["lbx"], ubx=b["ubx"], lbg=b["lbg"], ubg=b["ubg"])
    cpu = time.process_time() - c0
    stats = solver.stats()
    x_sol = [float(v) for v in ca.DM(sol["x"]).full().ravel()]
    objective = float(sol["f"])
    info = json.loads((folder / "instance.json").read_text())
    if info["elastic"]:
        objective = float(nlp(least_slacks(nlp, b, info, x_sol), b["p"])[0])
    return {
        "objective": objective,
        "x": x_sol,
        "iterations": int(stats["iter_count"]),
        "status": stats["return_status"],
        "cpu_s": cpu,
    }


def instances(paths: list[str]) -> list[Path]:
    """Instance folders: each path itself, or the folders its index.json lists."""
    out = []
    for path in map(Path, paths):
        if (path / "index.json").is_file():
            out += [
                path / item["folder"] for item in json.loads((path / "index.json").read_text())["instances"]
            ]
        else:
            out.append(path)
    return out


def main(paths: list[str]) -> int:
    quiet = {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": False}
    worst = 0.0
    print(f"casadi {ca.__version__}")
    for folder in instances(paths):
        info = json.loads((folder / "instance.json").read_text())
        ref = info["refine"]
        print(
            f"{info['problem']}: round {info['round']}, {info['n_x']} variables, {info['n_g']} constraints; "
            f"refine {ref['status']} objective {ref['objective']:.13g} in {ref['iterations']} iterations "
            f"({ref['rounds']} round(s), warm-started after the first)"
        )
        tolerances = {k: ref["ipopt_options"][k] for k in TOLERANCES if k in ref["ipopt_options"]}
        for label, options, judged in (
            ("IPOPT defaults", quiet, False),
            ("IPOPT, refine's tolerances", {**tolerances, **quiet}, True),
            ("IPOPT, all refine's options", {**ref["ipopt_options"], **quiet}, True),
        ):
            r = solve(folder, options)
            rel = abs(r["objective"] - ref["objective"]) / max(abs(ref["objective"]), 1e-300)
            dx = max(abs(a - b) for a, b in zip(r["x"], ref["x"], strict=True))
            worst = max(worst, rel) if judged else worst
            print(
                f"  {label:28s} objective {r['objective']:.13g} rel diff {rel:.1e} max|dx| {dx:.1e} "
                f"{r['iterations']:4d} iterations {r['status']} cpu {r['cpu_s']:.2f} s"
            )
    print(f"worst relative objective difference {worst:.1e} (asked: <= {RELATIVE_TOLERANCE:g})")
    return 0 if worst <= RELATIVE_TOLERANCE else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
