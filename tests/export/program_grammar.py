"""Read robot programs with a grammar (lark, grammars in ``grammars/``) and compare them to trajectory.csv.

Independent of the writers' own read-back parsers: every program is parsed whole by its language's
grammar (a statement the grammar does not know fails the parse), the parse tree is walked for the
path targets in execution order, and each target becomes a TCP pose in the world frame {F} with only
what the program and ``result.json`` say (ABB: ``base_in_world · wobj uframe · robtarget``; KRL:
``E6POS`` in ``BASE_DATA[n]``, which the program requires to be the world {F}; URScript:
``base_in_world · p[...]``; Sunrise: ``Frame`` in the base frame). Run as a script to print the
figures for output folders: ``python3 tests/export/program_grammar.py out/glass_adhesive ...``.
"""

from __future__ import annotations

import csv
import json
import sys
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np
from lark import Lark, Token, Tree
from scipy.spatial.transform import Rotation

GRAMMARS = Path(__file__).resolve().parent / "grammars"


@cache
def parser(name: str) -> Lark:
    """The LALR parser of ``grammars/<name>.lark``."""
    return Lark((GRAMMARS / f"{name}.lark").read_text(encoding="utf-8"), parser="lalr")


@dataclass
class ParsedPass:
    """The path targets of one pass, in execution order, as TCP poses in {F}."""

    poses: list[np.ndarray] = field(default_factory=list)


@dataclass
class ParsedProgram:
    """What the grammar walk found in a program."""

    language: str
    files: tuple[str, ...]
    passes: list[ParsedPass]
    statements: list[str]  # the executed statements' names, in order (calls expanded)
    facts: dict = field(default_factory=dict)


# ---- values -------------------------------------------------------------------------------------


def _value(node) -> object:
    """Numbers, nested lists, strings, names of an expression tree (RAPID and URScript)."""
    if isinstance(node, Token):
        return str(node)
    kind = node.data
    if kind == "number":
        return float(node.children[0])
    if kind == "neg":
        return -_value(node.children[0])
    if kind in ("aggregate", "list", "pose"):
        items = [c for c in node.children if not (isinstance(c, Token) and c.type == "POSE_OPEN")]
        return [_value(c) for c in items]
    if kind == "string":
        return str(node.children[0])[1:-1]
    if kind in ("true", "false"):
        return kind == "true"
    if kind == "name":
        return str(node.children[0])
    return node


def _transform(p, q_wxyz) -> np.ndarray:
    T = np.eye(4)
    w, x, y, z = q_wxyz
    T[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
    T[:3, 3] = p
    return T


# ---- RAPID --------------------------------------------------------------------------------------


def read_rapid(path: Path, base_in_world: np.ndarray) -> ParsedProgram:
    """Parse a RAPID module and list its ``MoveL``/``TriggL``/``MoveC`` targets as TCP poses in {F}."""
    tree = parser("rapid").parse(path.read_text(encoding="utf-8"))
    module = tree.children[0]
    data, procs = {}, {}
    for item in module.children[1:]:
        if item.data == "data_decl":
            storage, typ, name, *value = item.children
            data[str(name)] = (str(typ), _value(value[0]) if value and value[0] is not None else None)
        elif item.data == "proc":
            procs[str(item.children[0])] = item.children[1:]
    statements: list[tuple[str, list]] = []

    def walk(body, depth=0):
        for st in body:
            if st.data == "call":
                name, args = str(st.children[0]), st.children[1]
                if name in procs:
                    walk(procs[name], depth + 1)
                else:
                    statements.append((name, [] if args is None else args.children))
            elif st.data == "if_stmt":
                statements.append(("IF", []))

    walk(procs["main"])
    wobj = [v for t, v in data.values() if t == "wobjdata"]
    uframe = _transform(np.array(wobj[0][3][0]) / 1000.0, wobj[0][3][1])
    oframe = _transform(np.array(wobj[0][4][0]) / 1000.0, wobj[0][4][1])
    T_world_uframe = base_in_world @ uframe @ oframe
    poses = []
    for name, args in statements:
        points = {"MoveL": 1, "TriggL": 1, "MoveC": 2}.get(name, 0)  # MoveC: the circle point, then the end
        for arg in args[:points]:
            if arg.data != "argitem":
                continue
            target = _value(arg.children[0])
            if isinstance(target, str) and data.get(target, ("",))[0] == "robtarget":
                trans, rot = data[target][1][0], data[target][1][1]
                poses.append(T_world_uframe @ _transform(np.array(trans) / 1000.0, rot))
    speeds = {n: v[0] for n, (t, v) in data.items() if t == "speeddata"}
    facts = {
        "speeddata": speeds,
        "routines": sorted(procs),
        "home": [n for n, (t, _) in data.items() if t == "jointtarget"],
    }
    return ParsedProgram("rapid", (path.name,), [ParsedPass(poses)], [n for n, _ in statements], facts)


# ---- KRL ----------------------------------------------------------------------------------------


def _struct(node) -> dict:
    out = {}
    for f in node.children:
        key, val = str(f.children[0]), f.children[1]
        if val.data == "struct":
            out[key] = _struct(val)
        else:
            out[key] = float(val.children[0]) * (-1.0 if val.data == "neg_number" else 1.0)
    return out


def read_krl(src: Path, dat: Path) -> ParsedProgram:
    """Parse a KRL ``.src`` + ``.dat`` pair; each pass's ``LIN`` path points as TCP poses in {F}.

    A pass is the ``LIN`` moves between a ``PTP`` to a point and the next ``PTP``, without its last
    move (the retract) and from the move the process output switches on at.
    """
    dtree = parser("krl_dat").parse(dat.read_text(encoding="utf-8"))
    decl = {str(d.children[1]): (str(d.children[0]), _struct(d.children[2])) for d in dtree.find_data("decl")}
    stree = parser("krl_src").parse(src.read_text(encoding="utf-8"))
    body = next(stree.find_data("def_block")).children[1:]
    statements, passes, current = [], [], None

    def walk(sts):
        nonlocal current
        for st in sts:
            statements.append(st.data)
            if st.data == "motion":
                kind, name = str(st.children[0]), str(st.children[1])
                if kind == "PTP":
                    current = {"moves": [], "on": None}
                    passes.append(current)
                elif current is not None:
                    current["moves"].append(name)
            elif st.data == "circ" and current is not None:  # the via point, then the end point
                current["moves"] += [str(st.children[0]), str(st.children[1])]
            elif st.data == "trigger" and current is not None:
                statements[-1] = "trigger:" + str(st.children[0])
                current.setdefault("triggers", []).append(len(current["moves"]))
                if current["on"] is None:
                    current["on"] = len(current["moves"])
            elif st.data == "if_stmt":
                walk(st.children[1:])

    walk(body)
    parsed = []
    for p in passes:
        if not p["moves"]:
            continue  # the home moves
        start = p["on"] if p["on"] is not None else 0
        poses = []
        for name in p["moves"][start:-1]:
            e = decl[name][1]
            R = Rotation.from_euler("ZYX", [e["A"], e["B"], e["C"]], degrees=True).as_matrix()
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R, np.array([e["X"], e["Y"], e["Z"]]) / 1000.0
            poses.append(T)
        parsed.append(ParsedPass(poses))
    facts = {"axis_decls": [n for n, (t, _) in decl.items() if t == "E6AXIS"]}
    return ParsedProgram("krl", (src.name, dat.name), parsed, statements, facts)


# ---- URScript -----------------------------------------------------------------------------------


def read_urscript(path: Path, base_in_world: np.ndarray) -> ParsedProgram:
    """Parse a URScript file; each pass's ``movel`` poses (without the retract) as TCP poses in {F}.

    A pass starts at the ``movej`` after the home ``movej``; its path starts at the move a
    ``run process_on()`` precedes or that a ``set_digital_out(.., True)`` of the arc follows.
    """
    tree = parser("urscript").parse(path.read_text(encoding="utf-8"))
    statements, calls = [], []

    def walk(node):
        for st in node.children:
            if not isinstance(st, Tree):
                continue
            if st.data in ("def_block", "thread_block"):
                if st.data == "def_block":
                    walk_body = [c for c in st.children[1:] if isinstance(c, Tree) and c.data != "params"]
                    for c in walk_body:
                        walk(Tree("body", [c]))
                continue  # a thread body runs beside the program
            if st.data == "call":
                name = str(st.children[0])
                args = [] if st.children[1] is None else st.children[1].children
                calls.append((name, args))
                statements.append(name)
            elif st.data == "run_thread":
                calls.append(("run:" + str(st.children[0]), []))
                statements.append("run:" + str(st.children[0]))
            elif st.data in ("if_block", "while_block"):
                statements.append(st.data)
            else:
                statements.append(st.data)

    walk(tree)
    passes, current, pending_on = [], None, False
    movej = 0
    for name, args in calls:
        if name == "movej":
            movej += 1
            if movej >= 2:
                current = {"moves": [], "on": None}
                passes.append(current)
        elif name == "movel" and current is not None:
            if pending_on and current["on"] is None:
                current["on"], pending_on = len(current["moves"]), False
            current["moves"].append(_value(args[0]))
        elif name == "run:process_on":
            pending_on = True
        elif name == "set_digital_out" and current is not None and _value(args[1]) is True:
            if current["on"] is None and current["moves"]:
                current["on"] = len(current["moves"]) - 1
    parsed = []
    for p in passes:
        if not p["moves"]:
            continue
        poses = []
        for v in p["moves"][p["on"] or 0 : -1]:
            T = np.eye(4)
            T[:3, :3] = Rotation.from_rotvec(v[3:]).as_matrix()
            T[:3, 3] = v[:3]
            poses.append(base_in_world @ T)
        parsed.append(ParsedPass(poses))
    return ParsedProgram("urscript", (path.name,), parsed, statements, {})


# ---- Sunrise (Java) -----------------------------------------------------------------------------


def _java_number(node) -> float:
    if node.data == "neg":
        return -_java_number(node.children[0])
    if node.data == "number":
        return float(str(node.children[0]).rstrip("dDfFlL"))
    raise AssertionError(f"not a number literal: {node.data}")


def read_sunrise(path: Path, base_in_world: np.ndarray) -> ParsedProgram:
    """Parse a Sunrise application; each pass's rows (in ``run()`` order) as TCP poses in {F}.

    Rows ``{x, y, z, a, b, c, e1, status, turn, v}`` come from the ``new double[][] {...}`` returned
    by the methods that ``run()`` hands to ``runPass``; x y z [mm] and a b c [rad] about z, y', x''
    are in the robot base frame.
    """
    tree = parser("java").parse(path.read_text(encoding="utf-8"))
    methods = {}
    for m in tree.find_data("method"):
        name = next(c for c in m.children if isinstance(c, Token) and c.type == "NAME")
        methods[str(name)] = m
    rows_of = {}
    for name, m in methods.items():
        inits = list(m.find_data("new_array_init"))
        if inits and name.startswith("pass"):
            table = inits[0].children[-1]
            rows_of[name] = [[_java_number(v) for v in row.children] for row in table.children]
    run_calls = [t for t in methods["run"].iter_subtrees_topdown() if t.data == "call"]
    statements = [str(c.children[0]) for c in run_calls]
    passes = []
    for c in run_calls:
        if str(c.children[0]) != "runPass":
            continue
        join_call = c.children[1].children[0]
        parts = [str(p.children[0]) for p in join_call.children[1].children]
        rows = [r for part in parts for r in rows_of[part]]
        poses = []
        for r in rows:
            T = np.eye(4)
            T[:3, :3] = Rotation.from_euler("ZYX", r[3:6]).as_matrix()
            T[:3, 3] = np.array(r[:3]) / 1000.0
            poses.append(base_in_world @ T)
        passes.append(ParsedPass(poses))
    facts = {"methods": sorted(methods), "rows": {k: len(v) for k, v in rows_of.items()}}
    return ParsedProgram("sunrise", (path.name,), passes, statements, facts)


# ---- FANUC TP and Yaskawa INFORM ---------------------------------------------------------------


def _fixed_xyz_pose(xyz_mm, angles_deg) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", angles_deg, degrees=True).as_matrix()  # Rz·Ry·Rx
    T[:3, 3] = np.asarray(xyz_mm, dtype=float) / 1000.0
    return T


def read_tp(path: Path) -> ParsedProgram:
    """Parse a TP program; each pass's ``L`` path positions (in the user frame, the world {F}).

    A pass starts at the ``J`` move to an approach point; its path is the ``L`` moves after it
    without the last (the retract).
    """
    tree = parser("tp").parse(path.read_text(encoding="ascii"))
    positions = {}
    for p in tree.find_data("pdef"):
        body = p.children[3]
        if body.data == "cartesian":
            xyz = [float(v) for v in body.children[1].children]
            wpr = [float(v) for v in body.children[2].children]
            positions[int(p.children[0])] = _fixed_xyz_pose(xyz, wpr)
    passes, current, statements = [], None, []
    for line in tree.find_data("line"):
        st = line.children[1]
        if isinstance(st, Token):
            continue
        statements.append(st.data)
        if st.data == "motion":
            kind, index = str(st.children[0]), int(st.children[1].children[0])
            if kind == "J" and index in positions:
                current = []
                passes.append(current)
            elif kind == "L" and current is not None:
                current.append(positions[index])
    parsed = [ParsedPass(moves[:-1]) for moves in passes if moves]
    return ParsedProgram("tp", (path.name,), parsed, statements, {})


def read_inform(path: Path, base_in_world: np.ndarray, controller_in_base: np.ndarray) -> ParsedProgram:
    """Parse an INFORM job; each pass's ``MOVL`` positions (ROBOT frame) as TCP poses in {F}.

    A pass starts at a ``MOVJ`` to a point other than the first (home); its path is the ``MOVL``
    moves after it without the last (the retract).
    """
    tree = parser("inform").parse(path.read_text(encoding="ascii"))
    T_world_robot = base_in_world @ controller_in_base
    positions = {}
    for c in tree.find_data("cvar"):
        v = [float(x) for x in c.children[1:]]
        positions[str(c.children[0])] = T_world_robot @ _fixed_xyz_pose(v[:3], v[3:])
    body = next(tree.find_data("body"))
    passes, current, statements, home = [], None, [], None
    for st in body.children:
        if isinstance(st, Token):
            continue
        statements.append(st.data)
        if st.data == "movj":
            name = str(st.children[0])
            home = home or name
            if name != home:
                current = []
                passes.append(current)
        elif st.data == "movl" and current is not None:
            current.append(positions[str(st.children[0])])
    parsed = [ParsedPass(moves[:-1]) for moves in passes if moves]
    return ParsedProgram("inform", (path.name,), parsed, statements, {})


# ---- against trajectory.csv ---------------------------------------------------------------------


def trajectory_poses(path: Path) -> np.ndarray:
    """TCP poses in {F} of a trajectory.csv (x, y, z, qw, qx, qy, qz columns), shape (N, 4, 4)."""
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    return np.array(
        [
            _transform(
                [float(r[k]) for k in ("x", "y", "z")], [float(r[k]) for k in ("qw", "qx", "qy", "qz")]
            )
            for r in rows
        ]
    )


def pose_errors(parsed: list[np.ndarray], expected: np.ndarray) -> tuple[float, float]:
    """Largest position error [mm] and orientation error [deg] between two pose lists of equal length."""
    if len(parsed) != len(expected):
        raise AssertionError(f"{len(parsed)} targets in the program, {len(expected)} rows in trajectory.csv")
    P = np.array(parsed)
    dp = np.linalg.norm(P[:, :3, 3] - expected[:, :3, 3], axis=1).max() * 1000.0
    R_rel = np.swapaxes(P[:, :3, :3], 1, 2) @ expected[:, :3, :3]
    dr = np.degrees(np.linalg.norm(Rotation.from_matrix(R_rel).as_rotvec(), axis=1)).max()
    return float(dp), float(dr)


def read_programs(out: Path) -> list[tuple[ParsedProgram, list[tuple[float, float]]]]:
    """Parse every program a run wrote into ``out`` and compare each pass to its trajectory CSV."""
    doc = json.loads((out / "result.json").read_text())
    outputs = doc["outputs"]
    base = np.array(doc["robot"]["base_in_world"])
    csvs = [out / outputs[k] for k in sorted(outputs) if k.startswith("trajectory")]
    csvs = sorted(csvs, key=lambda p: p.name)
    expected = [trajectory_poses(c) for c in csvs]
    # a circular move's targets are its via and end point: the waypoints between are not written
    for i, p in enumerate(doc["passes"][: len(expected)]):
        arcs = (p.get("circular_moves") or {}).get("written", [])
        inside = {k for a, via, b in arcs for k in range(a + 1, b) if k != via}
        if inside and any(out.glob(g) for g in ("*.mod", "*.src", "*.script")):
            expected[i] = expected[i][[k for k in range(len(expected[i])) if k not in inside]]
    programs = []
    for kind, name in outputs.items():
        f = out / name
        if kind.startswith("rapid"):
            programs.append(read_rapid(f, base))
        elif kind == "krl_src":
            programs.append(read_krl(f, out / outputs["krl_dat"]))
        elif kind == "urscript":
            programs.append(read_urscript(f, base))
        elif kind == "sunrise":
            programs.append(read_sunrise(f, base))
        elif kind == "tp":
            programs.append(read_tp(f))
        elif kind == "inform":
            programs.append(read_inform(f, base, np.array(doc["robot"]["controller_in_base"])))
    results = []
    rapid_k = 0
    for prog in programs:
        if prog.language == "rapid":  # one module per pass
            exp = [expected[rapid_k]]
            rapid_k += 1
        else:
            exp = expected
        if len(prog.passes) != len(exp):
            raise AssertionError(f"{prog.files}: {len(prog.passes)} passes, {len(exp)} trajectories")
        results.append((prog, [pose_errors(p.poses, e) for p, e in zip(prog.passes, exp, strict=True)]))
    return results


def main(argv: list[str]) -> int:
    """Print, per output folder, each program's parse result and its largest pose errors."""
    for folder in argv:
        out = Path(folder)
        for prog, errors in read_programs(out):
            dp = max(e[0] for e in errors)
            dr = max(e[1] for e in errors)
            n = sum(len(p.poses) for p in prog.passes)
            print(
                f"{out.name:16s} {prog.language:8s} {'+'.join(prog.files):34s} parsed: 0 errors, "
                f"{len(prog.passes)} pass(es), {n} targets; max |dp| {dp:.2e} mm, max |dR| {dr:.2e} deg"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
