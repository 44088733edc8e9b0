"""The package's layering, read from every module's imports (docs/design.md, "The wings").

Each module of ``refine/`` belongs to one floor; a module may import from its own floor and the
floors below, never from a floor above, and no chain of imports may lead back to where it started.
Every import counts: at the top of a module, inside a function, and under ``TYPE_CHECKING``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "refine"

#: The longest a module may grow [lines].
MAX_MODULE_LINES = 600

#: The floors, lowest first: each a list of module-name prefixes (a prefix names a module or a
#: package and everything in it).
FLOORS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "base",
        (
            "refine.errors",
            "refine.lazy",
            "refine.version",
            "refine.types",
            "refine.frames",
            "refine.names",
            "refine.paths",
            "refine.plausible",
            "refine.interrupt",
            "refine.control",
            "refine.arguments",
            "refine.stopwatch",
            "refine.settings",
            "refine.pathml_format",
            "refine.native",
        ),
    ),
    ("robot", ("refine.robot",)),
    ("inputs", ("refine.problem", "refine.problem_toml", "refine.cad", "refine.demo", "refine.collision", "refine.timing", "refine.timing_passes")),
    ("fusion", ("refine.fuse",)),
    ("optimise", ("refine.optimise",)),
    ("plan", ("refine.plan",)),
    ("outputs", ("refine.run.result", "refine.run.evaluate", "refine.run.outputs", "refine.export", "refine.report")),
    ("application", ("refine.run", "refine.calibrate", "refine.synthetic", "refine.bench", "refine.serve")),
    ("interfaces", ("refine.api", "refine.cli", "refine")),
)


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def floor_of(module: str) -> int:
    """The floor of the longest prefix that names the module."""
    best, floor = -1, None
    for index, (_, prefixes) in enumerate(FLOORS):
        for prefix in prefixes:
            inside = module == prefix or (prefix != "refine" and module.startswith(prefix + "."))
            if inside and len(prefix) > best:
                best, floor = len(prefix), index
    if floor is None:
        raise AssertionError(f"module {module} is on no floor: add it to FLOORS and docs/design.md")
    return floor


def imported_modules(path: Path, known: set[str]) -> set[str]:
    """Every refine module ``path`` imports (the longest known module prefix of each name)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
        elif isinstance(node, ast.ImportFrom) and node.level:
            raise AssertionError(f"{path}: relative import; write the module's full name")
        for name in names:
            if not name.startswith("refine"):
                continue
            parts = name.split(".")
            for k in range(len(parts), 0, -1):
                candidate = ".".join(parts[:k])
                if candidate in known:
                    out.add(candidate)
                    break
    return out


def import_graph() -> nx.DiGraph:
    mods = modules()
    graph = nx.DiGraph()
    graph.add_nodes_from(mods)
    for name, path in mods.items():
        for target in imported_modules(path, set(mods)):
            # a package's own __init__ is imported with any of its modules: not an arrow of its own
            if target != name and not (name.startswith(target + ".") and target != "refine"):
                graph.add_edge(name, target)
    return graph


def upward(graph: nx.DiGraph) -> list[str]:
    return [
        f"{a} ({FLOORS[floor_of(a)][0]}) imports {b} ({FLOORS[floor_of(b)][0]})"
        for a, b in graph.edges
        if floor_of(b) > floor_of(a)
    ]


def test_every_module_is_on_a_floor():
    for name in modules():
        floor_of(name)


def test_no_module_imports_from_a_floor_above():
    assert upward(import_graph()) == []


def test_no_import_circle():
    circles = [sorted(c) for c in nx.strongly_connected_components(import_graph()) if len(c) > 1]
    assert circles == []


def test_a_planted_upward_import_and_circle_are_caught(tmp_path):
    """The checks themselves: a robot module importing the optimiser, inside a function, is found,
    and so is the circle it closes with the optimiser's import of the robot."""
    planted = tmp_path / "planted.py"
    planted.write_text("def f():\n    from refine.optimise.problem import build_refinement\n")
    assert imported_modules(planted, {"refine.optimise.problem", "refine.robot.model"}) == {
        "refine.optimise.problem"
    }
    graph = import_graph()
    assert graph.has_edge("refine.optimise.problem", "refine.robot.model")
    graph.add_edge("refine.robot.model", "refine.optimise.problem")
    assert upward(graph) == [
        "refine.robot.model (robot) imports refine.optimise.problem (optimise)"
    ]
    assert any(len(c) > 1 for c in nx.strongly_connected_components(graph))


def test_modules_stay_a_few_hundred_lines():
    lines = {n: len(p.read_text().splitlines()) for n, p in modules().items()}
    assert {n: k for n, k in lines.items() if k > MAX_MODULE_LINES} == {}
