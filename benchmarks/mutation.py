"""Mutation score of the modules that decide what reaches a robot (run before a release, not in CI).

A small AST mutator plants one realistic bug at a time in a temporary copy of the repository and runs
only the tests that cover the module (``GROUPS``); a mutant the tests fail on is killed, one they
pass on survives. Operators: comparison flipped (``<`` to ``<=`` or ``>``, ``==`` to ``!=``),
arithmetic swapped (``+``/``-``, ``*``/``/``), a sign dropped, a number off by one (integers) or ten
times larger (floats), ``and``/``or`` swapped, ``not`` dropped, ``min``/``max`` swapped, the first
two arguments of a call swapped, and a statement dropped (an expression statement, an ``if`` block,
a ``raise``, an augmented assignment). Log calls, f-strings and docstrings are not mutated.

Mutation runs are CPU-heavy: a seeded sample of the sites per group is run (``--sample``), with the
tests under ``nice``. Each group's tests are first run on the unmutated copy; a group whose tests
fail there is reported as such and not scored.

Usage::

    nice -n 10 python3 benchmarks/mutation.py --sample 40 --seed 1 --out /tmp/mutation
    python3 benchmarks/mutation.py --group verify --sample 10        # one group
    python3 benchmarks/mutation.py --tests-ref <commit> ...         # the tests of an older commit
    python3 benchmarks/mutation.py --recheck /tmp/mutation/report.json --out /tmp/recheck
                                  # only that run's survivors, against the tests as they are now

The report (``report.md`` and ``report.json`` in ``--out``) gives per group the mutants run, killed,
the score, and every survivor with its file, line and change.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

GROUPS: dict[str, tuple[list[str], list[str]]] = {
    "verify": (
        ["refine/optimise/verify.py"],
        ["tests/optimise/test_verify.py", "tests/optimise/test_solve.py"],
    ),
    "problem": (
        ["refine/optimise/problem.py"],
        [
            "tests/optimise/test_nlp_values.py",
            "tests/optimise/test_problem.py",
            "tests/optimise/test_solve.py",
            "tests/test_api.py::test_a_reused_problem_equals_a_fresh_build_for_the_new_path_and_tolerances",
        ],
    ),
    "timing": (["refine/timing.py"], ["tests/test_timing.py"]),
    "export": (
        [
            "refine/export/rapid.py",
            "refine/export/krl.py",
            "refine/export/urscript.py",
            "refine/export/pathml.py",
            "refine/cad/pathml_read.py",
            "refine/export/trajectory_csv.py",
            "refine/export/writers.py",
            "refine/export/sunrise.py",
        ],
        ["tests/export"],
    ),
    "liberty": (
        ["refine/demo/liberty.py", "refine/demo/liberty_binary.py"],
        [
            "tests/demo/test_liberty.py",
            "tests/demo/test_liberty_binary.py",
            "tests/demo/test_liberty_device_records.py",
            "tests/demo/test_liberty_records.py",
            "tests/demo/test_limits.py",
        ],
    ),
    "frames": (["refine/frames.py"], ["tests/test_frames.py"]),
}
"""Group name -> (modules mutated, tests run on each mutant: files, folders or ``file::test`` ids).
Files that do not exist are ignored."""

COMPARE_SWAPS = {
    ast.Lt: (ast.LtE, ast.Gt),
    ast.LtE: (ast.Lt, ast.GtE),
    ast.Gt: (ast.GtE, ast.Lt),
    ast.GtE: (ast.Gt, ast.LtE),
    ast.Eq: (ast.NotEq,),
    ast.NotEq: (ast.Eq,),
    ast.Is: (ast.IsNot,),
    ast.IsNot: (ast.Is,),
    ast.In: (ast.NotIn,),
    ast.NotIn: (ast.In,),
}
BINOP_SWAPS = {
    ast.Add: ast.Sub,
    ast.Sub: ast.Add,
    ast.Mult: ast.Div,
    ast.Div: ast.Mult,
    ast.FloorDiv: ast.Mult,
}
DROPPABLE = (ast.Expr, ast.If, ast.Raise, ast.AugAssign)
NAME_SWAPS = {
    "min": "max",
    "max": "min",
    "argmin": "argmax",
    "argmax": "argmin",
    "minimum": "maximum",
    "maximum": "minimum",
    "any": "all",
    "all": "any",
}


@dataclass(frozen=True)
class Site:
    """One mutation: the n-th visited node of a file and what is done to it."""

    file: str
    node_index: int
    kind: str
    option: int
    line: int
    description: str


def _skip(node: ast.AST) -> bool:
    """Subtrees not mutated: f-strings, log calls, annotations are handled by the walker."""
    if isinstance(node, ast.JoinedStr):
        return True
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
        owner = node.func.value
        if isinstance(owner, ast.Name) and owner.id in ("log", "logger", "logging", "warnings"):
            return True
    return False


def _is_docstring(body: list[ast.stmt], i: int) -> bool:
    s = body[i]
    return (
        i == 0
        and isinstance(s, ast.Expr)
        and isinstance(s.value, ast.Constant)
        and isinstance(s.value.value, str)
    )


def _walk(tree: ast.AST):
    """Nodes in a fixed order with their index, skipping annotations, docstrings and ``_skip`` subtrees."""
    index = 0
    stack = [tree]
    while stack:
        node = stack.pop()
        if _skip(node):
            continue
        yield index, node
        index += 1
        children = []
        for name, value in ast.iter_fields(node):
            if name in ("annotation", "returns", "decorator_list", "type_comment"):
                continue
            if isinstance(value, list):
                children.extend(v for v in value if isinstance(v, ast.AST))
            elif isinstance(value, ast.AST):
                children.append(value)
        if isinstance(node, ast.ImportFrom | ast.Import):
            continue
        stack.extend(reversed(children))


def sites_of(file: str, source: str) -> list[Site]:
    """Every mutation site of one module."""
    tree = ast.parse(source)
    out: list[Site] = []

    def add(i, node, kind, option, what):
        out.append(Site(file, i, kind, option, getattr(node, "lineno", 0), what))

    for i, node in _walk(tree):
        if isinstance(node, ast.Compare):
            for opt, new in enumerate(COMPARE_SWAPS.get(type(node.ops[0]), ())):
                add(i, node, "compare", opt, f"{type(node.ops[0]).__name__} -> {new.__name__}")
        elif isinstance(node, ast.BinOp) and type(node.op) in BINOP_SWAPS:
            add(i, node, "binop", 0, f"{type(node.op).__name__} -> {BINOP_SWAPS[type(node.op)].__name__}")
        elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            add(i, node, "unary", 0, "sign dropped")
        elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            add(i, node, "not", 0, "not dropped")
        elif isinstance(node, ast.BoolOp):
            add(
                i,
                node,
                "boolop",
                0,
                f"{type(node.op).__name__} -> {'Or' if isinstance(node.op, ast.And) else 'And'}",
            )
        elif (
            isinstance(node, ast.Constant)
            and type(node.value) in (int, float)
            and not isinstance(node.value, bool)
        ):
            if isinstance(node.value, int):
                add(i, node, "const", 0, f"{node.value} -> {node.value + 1}")
            elif node.value != 0.0:
                add(i, node, "const", 0, f"{node.value} -> {node.value * 10}")
            else:
                add(i, node, "const", 0, f"{node.value} -> 1.0")
        elif isinstance(node, ast.Name | ast.Attribute):
            name = node.id if isinstance(node, ast.Name) else node.attr
            if name in NAME_SWAPS and isinstance(node.ctx, ast.Load):
                add(i, node, "name", 0, f"{name} -> {NAME_SWAPS[name]}")
        if (
            isinstance(node, ast.Call)
            and len(node.args) >= 2
            and not any(isinstance(a, ast.Starred) for a in node.args[:2])
        ):
            add(i, node, "swapargs", 0, "first two arguments swapped")
        for field in ("body", "orelse", "finalbody"):
            body = getattr(node, field, None)
            if isinstance(body, list) and body and isinstance(body[0], ast.stmt):
                for j, stmt in enumerate(body):
                    if isinstance(stmt, DROPPABLE) and not _is_docstring(body, j):
                        what = f"{type(stmt).__name__} at line {stmt.lineno} dropped"
                        out.append(Site(file, i, f"drop:{field}:{j}", 0, stmt.lineno, what))
    return out


def mutate(source: str, site: Site) -> str:
    """The module source with ``site`` applied."""
    tree = ast.parse(source)
    for i, node in _walk(tree):
        if i != site.node_index:
            continue
        if site.kind == "compare":
            node.ops[0] = COMPARE_SWAPS[type(node.ops[0])][site.option]()
        elif site.kind == "binop":
            node.op = BINOP_SWAPS[type(node.op)]()
        elif site.kind in ("unary", "not"):
            _replace(tree, node, node.operand)
        elif site.kind == "boolop":
            node.op = ast.Or() if isinstance(node.op, ast.And) else ast.And()
        elif site.kind == "const":
            v = node.value
            node.value = v + 1 if isinstance(v, int) else (v * 10 if v != 0.0 else 1.0)
        elif site.kind == "name":
            if isinstance(node, ast.Name):
                node.id = NAME_SWAPS[node.id]
            else:
                node.attr = NAME_SWAPS[node.attr]
        elif site.kind == "swapargs":
            node.args[0], node.args[1] = node.args[1], node.args[0]
        elif site.kind.startswith("drop:"):
            _, field, j = site.kind.split(":")
            getattr(node, field)[int(j)] = ast.Pass()
        break
    else:
        raise RuntimeError(f"site not found: {site}")
    return ast.unparse(ast.fix_missing_locations(tree))


def _replace(tree: ast.AST, old: ast.AST, new: ast.AST) -> None:
    for parent in ast.walk(tree):
        for name, value in ast.iter_fields(parent):
            if value is old:
                setattr(parent, name, new)
                return
            if isinstance(value, list):
                for k, v in enumerate(value):
                    if v is old:
                        value[k] = new
                        return


PRELOAD = (
    "numpy",
    "scipy.spatial.transform",
    "scipy.interpolate",
    "scipy.optimize",
    "casadi",
    "pinocchio",
    "fcl",
    "trimesh",
    "lxml.etree",
    "ezdxf",
    "networkx",
    "toppra",
    "pytest",
    "hypothesis",
)
"""Third-party modules imported once in this process; each mutant's tests run in a fork of it."""


def preload() -> None:
    """Import the heavy third-party modules before forking (never ``refine`` itself)."""
    for name in PRELOAD:
        try:
            importlib.import_module(name)
        except ImportError:
            pass


def run_tests(copy_root: Path, tests: list[str], timeout_s: float) -> tuple[str, float]:
    """``"passed"``, ``"failed"`` or ``"timeout"`` and the wall time [s].

    The tests run in a forked child that imports ``refine`` from ``copy_root`` (the parent never
    imports it), so every mutant starts from a fresh package without paying for the third-party
    imports again.
    """
    start = time.perf_counter()
    pid = os.fork()
    if pid == 0:  # child
        try:
            os.setsid()
            os.chdir(copy_root)
            os.environ.pop("CI", None)
            os.environ["PYTHONPATH"] = str(copy_root)
            sys.path.insert(0, str(copy_root))
            sys.dont_write_bytecode = True
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            os.dup2(devnull, 2)
            import pytest

            rc = pytest.main(["-x", "-q", "-p", "no:cacheprovider", "--no-header", *tests])
            os._exit(int(rc))
        except BaseException:  # noqa: BLE001 - any error in the child is a failed run
            os._exit(99)
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            rc = os.waitstatus_to_exitcode(status)
            return ("passed" if rc == 0 else "failed"), time.perf_counter() - start
        if time.perf_counter() - start > timeout_s:
            try:
                os.killpg(pid, 9)
            except ProcessLookupError:
                pass
            os.waitpid(pid, 0)
            return "timeout", time.perf_counter() - start
        time.sleep(0.05)


def make_copy(work: Path, tests_ref: str | None) -> Path:
    """A copy of the repository (work tree without .git) next to a link to ``../shared``."""
    root = work / "repo"
    shutil.copytree(ROOT, root, ignore=shutil.ignore_patterns(".git", "__pycache__", "*.pyc", ".ruff_cache"))
    shared = ROOT.parent / "shared"
    if shared.exists():
        (work / "shared").symlink_to(shared)
    if tests_ref:
        shutil.rmtree(root / "tests")
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", tests_ref, "tests"], check=True, capture_output=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", str(root)], input=archive, check=True)
    return root


def _earlier_survivors(
    earlier: dict, files: list[str], sites: list[Site], root: Path
) -> tuple[list[Site], int]:
    """The survivors of an earlier run as sites of the current sources, and that run's kill count.

    Raises:
        SystemExit: a survivor is no longer a site of the current source, or a mutated file changed
            its number of sites (the earlier sample is then not the same set of mutants).
    """
    if sorted(earlier["files"]) != sorted(files) or earlier["sites"] != len(sites):
        raise SystemExit(
            f"{files}: the sources changed since the earlier run ({earlier['sites']} sites, now {len(sites)})"
        )
    current = {(s.file, s.node_index, s.kind, s.option): s for s in sites}
    out = []
    for d in earlier.get("survivors", []):
        site = current.get((d["file"], d["node_index"], d["kind"], d["option"]))
        line = (root / d["file"]).read_text().splitlines()[d["line"] - 1].strip() if d["line"] else ""
        if site is None or site.description != d["description"] or line != d["source"]:
            raise SystemExit(f"{d['file']}:{d['line']} {d['description']}: not a site of the current source")
        out.append(site)
    return out, int(earlier["killed"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--group", action="append", choices=sorted(GROUPS), help="groups to run (default: all)")
    ap.add_argument("--sample", type=int, default=40, help="mutants per group, seeded sample (0: all)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the sample")
    ap.add_argument("--tests-ref", help="take tests/ from this git commit (a before/after comparison)")
    ap.add_argument("--out", type=Path, default=Path("mutation-report"), help="report folder")
    ap.add_argument("--list", action="store_true", help="only print the number of sites per group")
    ap.add_argument(
        "--recheck",
        type=Path,
        help="run only the survivors of this earlier report.json against the current tests; the "
        "score counts its killed mutants and the survivors killed now (the sources must not have changed)",
    )
    args = ap.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))  # leave no temporary copy behind
    args.out.mkdir(parents=True, exist_ok=True)
    report: dict[str, dict] = {}
    previous = json.loads(args.recheck.read_text()) if args.recheck else None
    with tempfile.TemporaryDirectory(prefix="refine-mutation-") as tmp:
        root = make_copy(Path(tmp), args.tests_ref)
        preload()
        for group in args.group or (list(previous) if previous else list(GROUPS)):
            files, tests = GROUPS[group]
            files = [f for f in files if (root / f).is_file()]
            tests = [t for t in tests if (root / t.split("::")[0]).exists()]
            sites = [s for f in files for s in sites_of(f, (root / f).read_text())]
            if previous is not None:
                sample, earlier_killed = _earlier_survivors(previous[group], files, sites, root)
            else:
                sample, earlier_killed = (
                    (
                        sites
                        if not args.sample or args.sample >= len(sites)
                        else random.Random(f"{args.seed}:{group}").sample(sites, args.sample)
                    ),
                    0,
                )
            print(
                f"{group}: {len(sites)} sites in {len(files)} files, {len(sample)} "
                f"{'survivors of the earlier run' if previous else 'sampled'}; tests {tests}",
                flush=True,
            )
            if args.list:
                continue
            verdict, base_s = run_tests(root, tests, 1800.0)
            entry: dict = {
                "files": files,
                "tests": tests,
                "sites": len(sites),
                "sampled": len(sample),
                "baseline": verdict,
                "baseline_s": round(base_s, 1),
            }
            report[group] = entry
            if verdict != "passed":
                print(f"  the tests fail on the unmutated copy ({verdict}): group not scored", flush=True)
                continue
            killed, timeouts, survivors = 0, 0, []
            for k, site in enumerate(sorted(sample, key=lambda s: (s.file, s.line, s.node_index, s.kind))):
                path = root / site.file
                original = path.read_text()
                try:
                    path.write_text(mutate(original, site))
                    verdict, dt = run_tests(root, tests, 3.0 * base_s + 30.0)
                finally:
                    path.write_text(original)
                killed += verdict != "passed"
                timeouts += verdict == "timeout"
                if verdict == "passed":
                    line = original.splitlines()[site.line - 1].strip() if site.line else ""
                    survivors.append({**asdict(site), "source": line})
                print(
                    f"  [{k + 1}/{len(sample)}] {verdict:7s} {dt:5.1f} s  {site.file}:{site.line} {site.description}",
                    flush=True,
                )
            if previous is not None:  # the earlier run's sample, its kills and the survivors killed now
                entry.update(rechecked=len(sample), sampled=previous[group]["sampled"])
                killed += earlier_killed
            entry.update(
                killed=killed,
                timeouts=timeouts,
                score=round(100.0 * killed / max(1, entry["sampled"]), 1),
                survivors=survivors,
            )
            print(
                f"{group}: {killed}/{entry['sampled']} killed ({entry['score']} %), {timeouts} by timeout",
                flush=True,
            )
    (args.out / "report.json").write_text(json.dumps(report, indent=2))
    lines = ["| group | sites | sampled | killed | score |", "|---|---|---|---|---|"]
    for g, e in report.items():
        lines.append(
            f"| {g} | {e['sites']} | {e['sampled']} | {e.get('killed', '-')} | {e.get('score', e['baseline'])} |"
        )
    for g, e in report.items():
        for s in e.get("survivors", []):
            lines.append(f"- {g}: {s['file']}:{s['line']} {s['description']} (`{s['source']}`)")
    (args.out / "report.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
