"""Problem files: ``problems/<name>/problem.toml`` loaded into frozen, self-checking dataclasses.

Every key is documented in ``docs/problem-file.md``. Unknown keys and missing files are errors that
name the key or the path. Paths in the file are relative to the problem file. Poses are written
``{ xyz = [x, y, z], rpy_deg = [rx, ry, rz] }``: metres, and fixed-axis X-Y-Z angles in degrees.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from refine.errors import InputError
from refine.frames import transform_from_xyz_rpy
from refine.settings import (
    CadSettings,
    CollisionSettings,
    DemoSettings,
    ExpectedOutcome,
    FrameSettings,
    MultipassSettings,
    OptimiseSettings,
    OutputSettings,
    ProcessParameter,
    ProcessSettings,
    RepairSettings,
    RobotSettings,
    Shape,
    Tolerances,
    ToolSettings,
)

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

Matrix4 = np.ndarray

__all__ = [
    "CadSettings",
    "DemoSettings",
    "FrameSettings",
    "OutputSettings",
    "Problem",
    "ProcessParameter",
    "ProcessSettings",
    "RobotSettings",
    "Tolerances",
    "ToolSettings",
    "load_problem",
]


@dataclass(frozen=True)
class Problem:
    """A whole problem file.

    Attributes:
        name: problem name (defaults to the folder name).
        root: folder of the problem file; relative paths are resolved against it.
        demonstration: the tracker log settings; None when the path and its orientations and
            speeds come from a PathML document.
        cell: ``[[cell.objects]]``: the cell's collision objects in the world frame.
        multipass: ``[multipass]``: the passes of a multi-layer weld, or None for one pass.
        expected: ``[expected]``: the outcome a test problem is built to produce, or None.
        description: free text.
    """

    name: str
    root: Path
    robot: RobotSettings
    tool: ToolSettings
    cad: CadSettings
    demonstration: DemoSettings | None
    frames: FrameSettings = field(default_factory=FrameSettings)
    tolerances: Tolerances = field(default_factory=Tolerances)
    process: ProcessSettings = field(default_factory=ProcessSettings)
    output: OutputSettings = field(default_factory=OutputSettings)
    cell: tuple[Shape, ...] = ()
    collision: CollisionSettings = field(default_factory=CollisionSettings)
    optimise: OptimiseSettings = field(default_factory=OptimiseSettings)
    repair: RepairSettings = field(default_factory=RepairSettings)
    multipass: MultipassSettings | None = None
    expected: ExpectedOutcome | None = None
    description: str = ""

    def __post_init__(self) -> None:
        if self.demonstration is None and self.cad.format != "pathml":
            raise InputError(
                'missing required table [demonstration] (only a PathML path, [cad] format = "pathml", may go without)'
            )


def load_problem(path: str | Path) -> Problem:
    """Load ``problem.toml`` (or the folder holding it) into a :class:`Problem`.

    Raises:
        InputError: unknown or missing keys, bad values, missing files; the message names them.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "problem.toml"
    if not path.is_file():
        raise InputError(f"problem file not found: {path}")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{path}: not valid TOML: {e}") from e
    root = path.parent.resolve()
    _check_keys(data, "", _TOP_KEYS, path)
    for table in ("robot", "tool", "cad"):
        if table not in data:
            raise InputError(f"{path}: missing required table [{table}]")
    try:
        return Problem(
            name=str(data.get("name", root.name)),
            root=root,
            description=str(data.get("description", "")),
            robot=_robot(_table(data, "robot"), path),
            tool=_tool(_table(data, "tool"), path),
            frames=_frames(_table(data, "frames"), path),
            cad=_cad(_table(data, "cad"), root, path),
            demonstration=_demo(_table(data, "demonstration"), root, path)
            if "demonstration" in data
            else None,
            tolerances=_build(Tolerances, _table(data, "tolerances"), "tolerances", path),
            process=_process(_table(data, "process"), path),
            output=_output(_table(data, "output"), path),
            cell=_cell(_table(data, "cell"), root, path),
            collision=_build(CollisionSettings, _table(data, "collision"), "collision", path),
            optimise=_build(OptimiseSettings, _table(data, "optimise"), "optimise", path),
            repair=_build(RepairSettings, _table(data, "repair"), "repair", path),
            multipass=_multipass(_table(data, "multipass"), path) if "multipass" in data else None,
            expected=_expected(_table(data, "expected"), path) if "expected" in data else None,
        )
    except InputError as e:
        raise InputError(f"{path}: {e}") from e


# ---- loader internals ---------------------------------------------------------------------------

_TOP_KEYS = {
    "cell",
    "collision",
    "optimise",
    "repair",
    "multipass",
    "expected",
    "name",
    "description",
    "robot",
    "tool",
    "frames",
    "cad",
    "demonstration",
    "tolerances",
    "process",
    "output",
}


def _table(data: dict[str, Any], key: str) -> dict[str, Any]:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise InputError(f"[{key}] must be a table, got {type(value).__name__}")
    return value


def _check_keys(table: dict[str, Any], where: str, allowed: set[str], path: Path) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        prefix = f"[{where}] " if where else ""
        raise InputError(
            f"{path}: {prefix}unknown key(s) {', '.join(map(repr, unknown))}; "
            f"allowed: {', '.join(sorted(allowed))}"
        )


def _number(value: Any, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{key} must be a number, got {value!r}")
    return float(value)


def _numbers(value: Any, key: str, count: int | None = None) -> tuple[float, ...]:
    if not isinstance(value, list) or (count is not None and len(value) != count):
        size = "a list of numbers" if count is None else f"a list of {count} numbers"
        raise InputError(f"{key} must be {size}, got {value!r}")
    return tuple(_number(v, f"{key}[{i}]") for i, v in enumerate(value))


def _pose(value: Any, key: str) -> Matrix4:
    form = f"{key} must be a table {{ xyz = [m, m, m], rpy_deg = [deg, deg, deg] }}"
    if not isinstance(value, dict):
        raise InputError(f"{form}, got {value!r}")
    unknown = sorted(set(value) - {"xyz", "rpy_deg"})
    if unknown:
        raise InputError(f"{form}; unknown key(s) {', '.join(map(repr, unknown))}")
    xyz = _numbers(value.get("xyz", [0.0, 0.0, 0.0]), f"{key}.xyz", 3)
    rpy = _numbers(value.get("rpy_deg", [0.0, 0.0, 0.0]), f"{key}.rpy_deg", 3)
    return transform_from_xyz_rpy(xyz, rpy)


_SCALAR_TYPES: dict[str, tuple[type, ...]] = {
    "float": (int, float),
    "int": (int,),
    "bool": (bool,),
    "str": (str,),
}


def _check_types(cls: type, table: dict[str, Any], where: str) -> None:
    """Reject TOML values whose type does not match the field's annotation (bools are not numbers)."""
    for key, value in table.items():
        annotation = str(cls.__dataclass_fields__[key].type).replace(" | None", "")  # type: ignore[attr-defined]
        allowed = _SCALAR_TYPES.get(annotation)
        if allowed is None:
            continue
        if (isinstance(value, bool) and bool not in allowed) or not isinstance(value, allowed):
            kind = {"float": "a number", "int": "an integer", "bool": "true or false", "str": "a string"}[
                annotation
            ]
            raise InputError(f"{where}.{key} must be {kind}, got {value!r}")


def _file(root: Path, value: Any, key: str) -> Path:
    if not isinstance(value, str) or not value:
        raise InputError(f"{key} must be a file name relative to the problem folder, got {value!r}")
    f = (root / value).resolve()
    if not f.is_file():
        raise InputError(f"{key} = {value!r}: file not found at {f}")
    return f


def _fields(cls: type) -> set[str]:
    return set(cls.__dataclass_fields__)  # type: ignore[attr-defined]


def _build(cls: type, table: dict[str, Any], where: str, path: Path, **overrides: Any) -> Any:
    _check_keys(table, where, _fields(cls), path)
    _check_types(cls, {k: v for k, v in table.items() if k not in overrides}, where)
    kwargs = {**table, **overrides}
    try:
        return cls(**kwargs)
    except TypeError as e:
        raise InputError(f"[{where}] {e}") from e


def _robot(t: dict[str, Any], path: Path) -> RobotSettings:
    _check_keys(t, "robot", _fields(RobotSettings), path)
    if "model" not in t:
        raise InputError("[robot] missing required key 'model'")
    out: dict[str, Any] = {"model": str(t["model"])}
    if "base_in_world" in t:
        out["base_in_world"] = _pose(t["base_in_world"], "robot.base_in_world")
    for key in ("joint_acceleration_deg_s2", "home_deg"):
        if key in t:
            out[key] = _numbers(t[key], f"robot.{key}")
    if "velocity_scale" in t:
        out["velocity_scale"] = _number(t["velocity_scale"], "robot.velocity_scale")
    return RobotSettings(**out)


def _tool(t: dict[str, Any], path: Path) -> ToolSettings:
    _check_keys(t, "tool", _fields(ToolSettings), path)
    for key in ("name", "tcp_in_flange"):
        if key not in t:
            raise InputError(f"[tool] missing required key {key!r}")
    _check_types(
        ToolSettings, {k: v for k, v in t.items() if k in ("name", "axisymmetric", "mass_kg")}, "tool"
    )
    out: dict[str, Any] = dict(t)
    out["tcp_in_flange"] = _pose(t["tcp_in_flange"], "tool.tcp_in_flange")
    if "sensor_in_tcp" in t:
        out["sensor_in_tcp"] = _pose(t["sensor_in_tcp"], "tool.sensor_in_tcp")
    if "cog_in_flange_m" in t:
        out["cog_in_flange_m"] = _numbers(t["cog_in_flange_m"], "tool.cog_in_flange_m", 3)
    if "collision" in t:
        out["collision"] = tuple(
            _shape(item, f"tool.collision[{i}]", None, path)
            for i, item in enumerate(_list(t["collision"], "tool.collision"))
        )
    return ToolSettings(**out)


def _frames(t: dict[str, Any], path: Path) -> FrameSettings:
    _check_keys(t, "frames", _fields(FrameSettings), path)
    return FrameSettings(**{k: _pose(v, f"frames.{k}") for k, v in t.items()})


def _cad(t: dict[str, Any], root: Path, path: Path) -> CadSettings:
    if "file" not in t:
        raise InputError("[cad] missing required key 'file'")
    f = _file(root, t["file"], "cad.file")
    fmt = t.get("format", _CAD_SUFFIXES.get(f.suffix.lower(), f.suffix))
    overrides: dict[str, Any] = {"file": f, "format": fmt}
    for key in ("section_origin", "section_normal", "start_near"):
        if key in t:
            overrides[key] = _numbers(t[key], f"cad.{key}", 3)
    return _build(CadSettings, t, "cad", path, **overrides)


_CAD_SUFFIXES = {
    ".dxf": "dxf",
    ".csv": "csv",
    ".nc": "gcode",
    ".ngc": "gcode",
    ".gcode": "gcode",
    ".tap": "gcode",
    ".stl": "mesh",
    ".obj": "mesh",
    ".ply": "mesh",
    ".aml": "pathml",
}


def _list(value: Any, key: str) -> list[Any]:
    if not isinstance(value, list):
        raise InputError(f"{key} must be a list of tables ([[{key}]]), got {value!r}")
    return value


def _shape(t: Any, key: str, root: Path | None, path: Path) -> Shape:
    if not isinstance(t, dict):
        raise InputError(f"{key} must be a table, got {t!r}")
    _check_keys(t, key, _fields(Shape), path)
    out: dict[str, Any] = dict(t)
    if "pose" in t:
        out["pose"] = _pose(t["pose"], f"{key}.pose")
    if "size_m" in t:
        out["size_m"] = _numbers(t["size_m"], f"{key}.size_m", 3)
    if "file" in t:
        if root is None:
            raise InputError(f"{key}: mesh files are for cell objects only")
        out["file"] = _file(root, t["file"], f"{key}.file")
    try:
        return Shape(**out)
    except TypeError as e:
        raise InputError(f"{key}: {e}") from e


def _cell(t: dict[str, Any], root: Path, path: Path) -> tuple[Shape, ...]:
    _check_keys(t, "cell", {"objects"}, path)
    return tuple(
        _shape(o, f"cell.objects[{i}]", root, path)
        for i, o in enumerate(_list(t.get("objects", []), "cell.objects"))
    )


def _multipass(t: dict[str, Any], path: Path) -> MultipassSettings:
    _check_keys(t, "multipass", _fields(MultipassSettings), path)
    out: dict[str, Any] = dict(t)
    for key in ("lateral_offsets_m", "work_angle_change_deg"):
        if key in t:
            out[key] = tuple(
                _numbers(row, f"multipass.{key}[{i}]")
                for i, row in enumerate(_list(t[key], f"multipass.{key}"))
            )
    return _build(
        MultipassSettings,
        {k: v for k, v in t.items() if k not in out or k in ("layers", "layer_height_m")},
        "multipass",
        path,
        **{k: v for k, v in out.items() if k in ("lateral_offsets_m", "work_angle_change_deg")},
    )


def _expected(t: dict[str, Any], path: Path) -> ExpectedOutcome:
    overrides = {"s_range_m": _numbers(t["s_range_m"], "expected.s_range_m", 2)} if "s_range_m" in t else {}
    return _build(ExpectedOutcome, t, "expected", path, **overrides)


def _demo(t: dict[str, Any], root: Path, path: Path) -> DemoSettings:
    if "file" not in t:
        raise InputError("[demonstration] missing required key 'file'")
    overrides: dict[str, Any] = {"file": _file(root, t["file"], "demonstration.file")}
    if "truth" in t:
        overrides["truth"] = _file(root, t["truth"], "demonstration.truth")
    return _build(DemoSettings, t, "demonstration", path, **overrides)


def _process(t: dict[str, Any], path: Path) -> ProcessSettings:
    _check_keys(t, "process", _fields(ProcessSettings), path)
    params = []
    for i, p in enumerate(t.get("parameters", [])):
        _check_keys(p, f"process.parameters[{i}]", {"name", "value", "unit"}, path)
        if set(p) != {"name", "value", "unit"}:
            raise InputError(f"[[process.parameters]] #{i + 1} needs name, value and unit, got {p}")
        value = _number(p["value"], f"process.parameters[{i}].value")
        params.append(ProcessParameter(str(p["name"]), value, str(p["unit"])))
    return ProcessSettings(
        kind=str(t.get("kind", "other")),
        output=str(t.get("output", "doProcess")),
        parameters=tuple(params),
    )


def _output(t: dict[str, Any], path: Path) -> OutputSettings:
    _check_keys(t, "output", _fields(OutputSettings), path)
    if "programs" in t:
        programs = t["programs"]
        if not isinstance(programs, list) or not all(isinstance(p, str) for p in programs):
            raise InputError(f'output.programs must be a list of strings such as ["rapid"], got {programs!r}')
        return OutputSettings(programs=tuple(programs))
    return OutputSettings()
