"""Problem files: ``problems/<name>/problem.toml`` loaded into frozen, self-checking dataclasses.

Every key is documented in ``docs/problem-file.md``. Unknown keys and missing files are errors that
name the key or the path. Paths in the file are relative to the problem file. Poses are written
``{ xyz = [x, y, z], rpy_deg = [rx, ry, rz] }``: metres, and fixed-axis X-Y-Z angles in degrees.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from refine.arguments import typed
from refine.errors import InputError, option
from refine.frames import transform_from_xyz_rpy
from refine.names import comment_text, file_stem
from refine.problem_toml import read_problem_toml
from refine.settings import (
    CadSettings,
    CollisionSettings,
    DemoSettings,
    ExpectedOutcome,
    FrameSettings,
    MultipassSettings,
    OptimiseSettings,
    OutputSettings,
    PlacementSettings,
    ProcessParameter,
    ProcessSettings,
    RepairSettings,
    RobotSettings,
    Shape,
    Tolerances,
    ToolSettings,
)

if TYPE_CHECKING:
    from refine.settings import CalibrationSettings

Matrix4 = np.ndarray
MAX_POSE_M = 100.0
"""Largest pose translation accepted [m]: a robot cell fits in 100 m."""
MAX_INPUT_FILE_BYTES = 1 << 30
"""Largest data file a problem may name [bytes] (1 GiB; a 2-million-line Liberty log is 130 MB)."""

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
        cad: the CAD/CAM path file; None when the path is given in memory (``refine.refine_path``).
        demonstration: the tracker log settings; None when the path and its orientations and
            speeds come from a PathML document.
        cell: ``[[cell.objects]]``: the cell's collision objects in the world frame.
        multipass: ``[multipass]``: the passes of a multi-layer weld, or None for one pass.
        expected: ``[expected]``: the outcome a test problem is built to produce, or None.
        calibration: ``[calibration]``: the frames' standard deviations, or None.
        description: free text.
        source: the problem file it was loaded from, for messages (None when built in code).
    """

    name: str
    root: Path
    robot: RobotSettings
    tool: ToolSettings
    cad: CadSettings | None
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
    calibration: CalibrationSettings | None = None
    description: str = ""
    source: Path | None = None

    def __post_init__(self) -> None:
        if self.demonstration is None and self.cad is not None and self.cad.format not in ("pathml", "toolpath"):
            raise InputError(
                "missing required table [demonstration] (only a PathML path or a CAM toolpath, "
                '[cad] format = "pathml" or "toolpath", may go without)'
            )
        if self.tool.stationary:
            from refine.settings.stationary import check_stationary

            check_stationary(self)

    @property
    def file_stem(self) -> str:
        """The stem of the output files named after the problem (:func:`refine.names.file_stem`)."""
        return file_stem(self.name)

    @property
    def input_files(self) -> tuple[Path, ...]:
        """Every data file the problem reads (resolved paths), for the outputs-never-overwrite check."""
        files = [self.cad.file] if self.cad is not None else []
        if self.demonstration is not None:
            files += [
                self.demonstration.file,
                *([self.demonstration.truth] if self.demonstration.truth else []),
            ]
        files += [s.file for s in (*self.cell, *self.tool.collision) if s.file is not None]
        files += [self.robot.urdf] if self.robot.urdf is not None else []
        return tuple(files)


def load_problem(path: str | Path, *, allow_outside: bool = False) -> Problem:
    """Load ``problem.toml`` (or the folder holding it) into a :class:`Problem`.

    Args:
        path: the problem file or its folder.
        allow_outside: accept data files outside the problem folder (by default a path that
            leaves the folder, by ``..``, an absolute path or a symbolic link, is an error).

    Raises:
        InputError: unknown or missing keys, bad values, missing files, files outside the problem
            folder; the message names the file and the key (and the line for TOML syntax).
    """
    typed(path, "path", (str, Path), "the path of a problem folder or its problem.toml")
    path = Path(path)
    if path.is_dir():
        path = path / "problem.toml"
    if not path.is_file():
        raise InputError(
            f"problem file not found: {path}", key="path", value=str(path), expected="a problem folder or file"
        )
    return problem_from_data(read_problem_toml(path), path, allow_outside=allow_outside)


def problem_from_data(data: dict[str, Any], path: Path, *, allow_outside: bool = False) -> Problem:
    """A :class:`Problem` from the parsed tables of ``path`` (what :func:`load_problem` reads).

    The checks and messages are those of :func:`load_problem`; data files are looked up beside
    ``path``. An editor that holds the file's tables in memory (``refine serve``) checks a change
    through this before it is saved.

    Raises:
        InputError: as :func:`load_problem`.
    """
    root = path.parent.resolve()
    _check_keys(data, "", _TOP_KEYS, path)
    for table in ("robot", "tool", "cad"):
        if table not in data:
            raise InputError(f"{path}: missing required table [{table}]")
    try:
        inside = None if allow_outside else root
        return Problem(
            name=_name(data.get("name", root.name)),
            root=root,
            description=comment_text(_string(data.get("description", ""), "description"), 2000),
            robot=_robot(_table(data, "robot"), path, inside),
            tool=_tool(_table(data, "tool"), path, root, inside),
            frames=_frames(_table(data, "frames"), path),
            cad=_cad(_table(data, "cad"), root, path, inside),
            demonstration=_demo(_table(data, "demonstration"), root, path, inside)
            if "demonstration" in data
            else None,
            tolerances=_build(Tolerances, _table(data, "tolerances"), "tolerances", path),
            process=_process(_table(data, "process"), path),
            output=_output(_table(data, "output"), path),
            cell=_cell(_table(data, "cell"), root, path, inside),
            collision=_build(CollisionSettings, _table(data, "collision"), "collision", path),
            optimise=_build(OptimiseSettings, _table(data, "optimise"), "optimise", path),
            repair=_repair(_table(data, "repair"), path),
            multipass=_multipass(_table(data, "multipass"), path) if "multipass" in data else None,
            expected=_expected(_table(data, "expected"), path) if "expected" in data else None,
            calibration=_calibration(_table(data, "calibration")) if "calibration" in data else None,
            source=path,
        )
    except InputError as e:
        raise InputError(f"{path}: {e}", key=e.key, value=e.value, expected=e.expected, file=str(path)) from e


# ---- loader internals ---------------------------------------------------------------------------


def _string(value: Any, key: str) -> str:
    if not isinstance(value, str):
        raise InputError(f"{key} must be a string, got {type(value).__name__}")
    return value


def _name(value: Any) -> str:
    """The problem name as one printable line (see :mod:`refine.names`); empty names are refused."""
    name = comment_text(_string(value, "name"), 200)
    if name != value:
        logging.getLogger(__name__).warning("name %r made printable: %r", value, name)
    if not name.strip("._- "):
        raise InputError(f"name must have at least one letter or digit, got {value!r}")
    return name


_TOP_KEYS = {
    "calibration",
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


def _calibration(t: dict[str, Any]) -> CalibrationSettings:
    from refine.settings import calibration_settings

    return calibration_settings(t)


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
    if not math.isfinite(value):
        raise InputError(f"{key} must be a finite number, got {value!r}")
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
    if max(abs(v) for v in xyz) > MAX_POSE_M or max(abs(v) for v in rpy) > 720.0:
        raise InputError(
            f"{key}: xyz must lie within ±{MAX_POSE_M:g} m and rpy_deg within ±720 deg, got {value!r}"
        )
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
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"{where}.{key} must be a finite number, got {value!r}")
        if isinstance(value, str) and comment_text(value, 10_000) != value:
            raise InputError(f"{where}.{key} must be one line of printable ASCII text, got {value!r}")


def _file(root: Path, value: Any, key: str, inside: Path | None) -> Path:
    """The resolved data file named by ``key``; it must lie in ``inside`` unless that is None."""
    if not isinstance(value, str) or not value or "\0" in value:
        raise InputError(f"{key} must be a file name relative to the problem folder, got {value!r}")
    f = (root / value).resolve()
    if inside is not None and not f.is_relative_to(inside):
        raise InputError(
            f"{key} = {value!r} lies outside the problem folder {inside} (resolved to {f}); "
            "copy the file into the folder, or "
            + option("pass --allow-outside", "load it with refine.load_problem(path, allow_outside=True)"),
            key=key,
            value=value,
            expected=f"a file inside the problem folder {inside}",
        )
    if not f.is_file():
        raise InputError(f"{key} = {value!r}: not a regular file at {f}")
    size = f.stat().st_size
    if size > MAX_INPUT_FILE_BYTES:
        raise InputError(f"{key} = {value!r}: {size} bytes exceeds the limit of {MAX_INPUT_FILE_BYTES} bytes")
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


def _robot(t: dict[str, Any], path: Path, inside: Path | None = None) -> RobotSettings:
    _check_keys(t, "robot", _fields(RobotSettings), path)
    out: dict[str, Any] = {}
    if "urdf" in t:
        out["urdf"] = _file(path.parent.resolve(), t["urdf"], "robot.urdf", inside)
        from refine.robot.urdf import urdf_robot_name

        out["model"] = _string(t["model"], "robot.model") if "model" in t else urdf_robot_name(out["urdf"])
        if not re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", out["model"]):
            raise InputError(
                f"robot.model = {out['model']!r}: a robot's name is 1 to 64 letters, digits, '_', '.' or '-'"
            )
        for key in ("flange_frame", "controller", "base_link"):
            if key in t:
                out[key] = _string(t[key], f"robot.{key}")
        if "locked_joints_deg" in t:
            locked = t["locked_joints_deg"]
            if not isinstance(locked, dict):
                raise InputError(
                    f"robot.locked_joints_deg must be a table of joint = value [deg], got {locked!r}"
                )
            out["locked_joints_deg"] = tuple(
                (str(k), _number(v, f"robot.locked_joints_deg.{k}")) for k, v in locked.items()
            )
        if "reach_m" in t:
            out["reach_m"] = _number(t["reach_m"], "robot.reach_m")
        if "packages" in t:
            from refine.robot.description import package_folders

            out["packages"] = package_folders(t["packages"], path.parent.resolve())
    elif "model" not in t:
        raise InputError("[robot] missing required key 'model' (a registry robot) or 'urdf' (a URDF file)")
    else:
        out["model"] = _robot_model(t["model"])
        extra = sorted({"flange_frame", "controller", "reach_m", "packages", "base_link", "locked_joints_deg"} & set(t))
        if extra:
            raise InputError(
                f"[robot] {', '.join(extra)} go with urdf; robot {t['model']!r} of the registry has its own"
            )
    for key in ("joint_lower_deg", "joint_upper_deg", "joint_velocity_deg_s"):
        if key in t:
            out[key] = _numbers(t[key], f"robot.{key}")
    if "base_in_world" in t:
        out["base_in_world"] = _pose(t["base_in_world"], "robot.base_in_world")
    for key in ("joint_acceleration_deg_s2", "home_deg"):
        if key in t:
            out[key] = _numbers(t[key], f"robot.{key}")
    if "velocity_scale" in t:
        out["velocity_scale"] = _number(t["velocity_scale"], "robot.velocity_scale")
    return RobotSettings(**out)


def _robot_model(value: Any) -> str:
    from refine.robot.registry import available_robots

    if not isinstance(value, str) or value not in (known := available_robots()):
        names = ", ".join(known)
        message = f"robot.model = {value!r} is not a robot of the registry; available: {names}"
        raise InputError(message, key="robot.model", value=value, expected=f"a robot of the registry: {names}")
    return value


def _tool(t: dict[str, Any], path: Path, root: Path, inside: Path | None) -> ToolSettings:
    _check_keys(t, "tool", _fields(ToolSettings) | {"part_in_flange"}, path)
    if "tcp_in_world" in t:  # a stationary tool: the robot holds the part, whose frame the path is in
        if "tcp_in_flange" in t or "part_in_flange" not in t:
            raise InputError(
                "[tool] tcp_in_world (a stationary tool) needs part_in_flange (the held part's frame on the "
                "flange, the frame the path is given in) instead of tcp_in_flange"
            )
        t = {**{k: v for k, v in t.items() if k != "part_in_flange"}, "tcp_in_flange": t["part_in_flange"]}
        t["tcp_in_world"] = _pose(t["tcp_in_world"], "tool.tcp_in_world")
    elif "part_in_flange" in t:
        raise InputError("[tool] part_in_flange is for a stationary tool: give tcp_in_world too, or tcp_in_flange")
    for key in ("name", "tcp_in_flange"):
        if key not in t:
            raise InputError(f"[tool] missing required key {key!r}")
    _check_types(
        ToolSettings,
        {k: v for k, v in t.items() if k in ("name", "axisymmetric", "mass_kg", "number")},
        "tool",
    )
    out: dict[str, Any] = dict(t)
    out["tcp_in_flange"] = _pose(t["tcp_in_flange"], "tool.tcp_in_flange")
    if "sensor_in_tcp" in t:
        out["sensor_in_tcp"] = _pose(t["sensor_in_tcp"], "tool.sensor_in_tcp")
    if "cog_in_flange_m" in t:
        out["cog_in_flange_m"] = _numbers(t["cog_in_flange_m"], "tool.cog_in_flange_m", 3)
    if "collision" in t:
        out["collision"] = tuple(
            _shape(item, f"tool.collision[{i}]", root, path, inside)
            for i, item in enumerate(_list(t["collision"], "tool.collision"))
        )
    return ToolSettings(**out)


def _frames(t: dict[str, Any], path: Path) -> FrameSettings:
    _check_keys(t, "frames", _fields(FrameSettings), path)
    _check_types(FrameSettings, {k: v for k, v in t.items() if k == "base_number"}, "frames")
    return FrameSettings(**{k: v if k == "base_number" else _pose(v, f"frames.{k}") for k, v in t.items()})


def _cad(t: dict[str, Any], root: Path, path: Path, inside: Path | None) -> CadSettings:
    if "file" not in t:
        raise InputError("[cad] missing required key 'file'")
    f = _file(root, t["file"], "cad.file", inside)
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


def _shape(t: Any, key: str, root: Path, path: Path, inside: Path | None = None) -> Shape:
    if not isinstance(t, dict):
        raise InputError(f"{key} must be a table, got {t!r}")
    _check_keys(t, key, _fields(Shape), path)
    out: dict[str, Any] = dict(t)
    if "pose" in t:
        out["pose"] = _pose(t["pose"], f"{key}.pose")
    if "size_m" in t:
        out["size_m"] = _numbers(t["size_m"], f"{key}.size_m", 3)
    if "file" in t:
        out["file"] = _file(root, t["file"], f"{key}.file", inside)
    _check_types(Shape, {k: v for k, v in t.items() if k in ("name", "shape", "units", "workpiece")}, key)
    for k in ("radius_m", "length_m"):
        if k in t:
            out[k] = _number(t[k], f"{key}.{k}")
    try:
        return Shape(**out)
    except TypeError as e:
        raise InputError(f"{key}: {e}") from e


def _cell(t: dict[str, Any], root: Path, path: Path, inside: Path | None) -> tuple[Shape, ...]:
    _check_keys(t, "cell", {"objects"}, path)
    return tuple(
        _shape(o, f"cell.objects[{i}]", root, path, inside)
        for i, o in enumerate(_list(t.get("objects", []), "cell.objects"))
    )


def _repair(t: dict[str, Any], path: Path) -> RepairSettings:
    if "placement" not in t:
        return _build(RepairSettings, t, "repair", path)
    p = t["placement"]
    form = "repair.placement must be a table { translate_m = m, rotate_deg = deg }"
    if not isinstance(p, dict):
        raise InputError(f"{form}, got {p!r}")
    _check_keys(p, "repair.placement", _fields(PlacementSettings), path)
    values: dict[str, Any] = {
        k: _string(v, f"repair.placement.{k}") if k == "free" else _number(v, f"repair.placement.{k}")
        for k, v in p.items()
    }
    return _build(RepairSettings, t, "repair", path, placement=PlacementSettings(**values))


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


def _demo(t: dict[str, Any], root: Path, path: Path, inside: Path | None) -> DemoSettings:
    if "file" not in t:
        raise InputError("[demonstration] missing required key 'file'")
    overrides: dict[str, Any] = {"file": _file(root, t["file"], "demonstration.file", inside)}
    if "truth" in t:
        overrides["truth"] = _file(root, t["truth"], "demonstration.truth", inside)
    return _build(DemoSettings, t, "demonstration", path, **overrides)


def _process(t: dict[str, Any], path: Path) -> ProcessSettings:
    _check_keys(t, "process", _fields(ProcessSettings), path)
    params = []
    for i, p in enumerate(_list(t.get("parameters", []), "process.parameters")):
        if not isinstance(p, dict):
            raise InputError(f"process.parameters[{i}] must be a table {{ name, value, unit }}, got {p!r}")
        _check_keys(p, f"process.parameters[{i}]", {"name", "value", "unit"}, path)
        if set(p) != {"name", "value", "unit"}:
            raise InputError(f"[[process.parameters]] #{i + 1} needs name, value and unit, got {p}")
        _check_types(ProcessParameter, p, f"process.parameters[{i}]")
        value = _number(p["value"], f"process.parameters[{i}].value")
        params.append(ProcessParameter(p["name"], value, p["unit"]))
    _check_types(ProcessSettings, {k: v for k, v in t.items() if k != "parameters"}, "process")
    scalars = {k: v for k, v in t.items() if k not in ("kind", "output", "parameters")}
    return ProcessSettings(
        kind=t.get("kind", "other"),
        output=t.get("output", "doProcess"),
        parameters=tuple(params),
        **scalars,
    )


def _output(t: dict[str, Any], path: Path) -> OutputSettings:
    _check_keys(t, "output", _fields(OutputSettings), path)
    if "programs" in t:
        programs = t["programs"]
        if not isinstance(programs, list) or not all(isinstance(p, str) for p in programs):
            raise InputError(f'output.programs must be a list of strings such as ["rapid"], got {programs!r}')
    rest = {k: v for k, v in t.items() if k != "programs"}
    _check_types(OutputSettings, rest, "output")
    if "programs" in t:
        rest["programs"] = tuple(t["programs"])
    return OutputSettings(**rest)
