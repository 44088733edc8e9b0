"""Problem files: ``problems/<name>/problem.toml`` loaded into frozen, self-checking dataclasses.

Every key is documented in ``docs/problem-file.md``. Unknown keys and missing files are errors that
name the key or the path. Paths in the file are relative to the problem file. Poses are written
``{ xyz = [x, y, z], rpy_deg = [rx, ry, rz] }``: metres, and fixed-axis X-Y-Z angles in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from refine.errors import InputError
from refine.frames import check_transform, transform_from_xyz_rpy

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

Matrix4 = np.ndarray


def _positive(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise InputError(f"{owner}.{name} must be a finite number > 0, got {value!r}")


def _non_negative(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
        raise InputError(f"{owner}.{name} must be a finite number >= 0, got {value!r}")


def _one_of(owner: str, name: str, value: str, allowed: tuple[str, ...]) -> None:
    if value not in allowed:
        raise InputError(f"{owner}.{name} = {value!r} is not one of {', '.join(allowed)}")


@dataclass(frozen=True)
class RobotSettings:
    """``[robot]``: which robot, where it stands, optional limit overrides.

    Attributes:
        model: registry name, a folder of ``robots/`` (e.g. ``"abb_irb4600_60_205"``).
        base_in_world: T_F_R, the robot base in the world frame {F}, (4, 4).
        joint_acceleration_deg_s2: per-joint acceleration limits [deg/s^2] overriding the
            robot's default, or None.
        velocity_scale: fraction of the data-sheet joint speeds the plan may use, in (0, 1].
        home_deg: a preferred joint configuration [deg] to start the IK seed from, or None.
    """

    model: str
    base_in_world: Matrix4 = field(default_factory=lambda: np.eye(4))
    joint_acceleration_deg_s2: tuple[float, ...] | None = None
    velocity_scale: float = 1.0
    home_deg: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        check_transform(self.base_in_world, "robot.base_in_world")
        if not 0.0 < self.velocity_scale <= 1.0:
            raise InputError(f"robot.velocity_scale must be in (0, 1], got {self.velocity_scale}")
        for a in self.joint_acceleration_deg_s2 or ():
            _positive("robot", "joint_acceleration_deg_s2[]", a)


@dataclass(frozen=True)
class ToolSettings:
    """``[tool]``: the process tool on the flange and the tracker sensor on the hand tool.

    Attributes:
        name: tool name, used for RAPID tooldata / KRL tool names.
        tcp_in_flange: T_flange_TCP, (4, 4); the TCP z axis points along the nozzle/torch.
        sensor_in_tcp: T_TCP_E, pose of the tracker sensor {E} in the TCP frame of the hand
            tool the worker used, (4, 4).
        axisymmetric: the spin about the TCP z axis is free (it is not constrained to the demo).
        mass_kg: tool mass [kg] for the program's tooldata.
        cog_in_flange_m: tool centre of gravity in the flange frame [m].
    """

    name: str
    tcp_in_flange: Matrix4
    sensor_in_tcp: Matrix4 = field(default_factory=lambda: np.eye(4))
    axisymmetric: bool = False
    mass_kg: float = 5.0
    cog_in_flange_m: tuple[float, float, float] = (0.0, 0.0, 0.1)

    def __post_init__(self) -> None:
        check_transform(self.tcp_in_flange, "tool.tcp_in_flange")
        check_transform(self.sensor_in_tcp, "tool.sensor_in_tcp")
        _positive("tool", "mass_kg", self.mass_kg)


@dataclass(frozen=True)
class FrameSettings:
    """``[frames]``: where the tracker receiver and the CAD frame sit in the world {F}.

    Attributes:
        source_in_world: T_F_S, the tracker receiver (source) in {F}.
        cad_in_world: T_F_CAD, the frame the CAD/CAM coordinates are given in.
    """

    source_in_world: Matrix4 = field(default_factory=lambda: np.eye(4))
    cad_in_world: Matrix4 = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        check_transform(self.source_in_world, "frames.source_in_world")
        check_transform(self.cad_in_world, "frames.cad_in_world")


@dataclass(frozen=True)
class CadSettings:
    """``[cad]``: the CAD/CAM path file.

    Attributes:
        file: absolute path of the file.
        format: ``"csv"`` or ``"dxf"`` (from the extension when not given).
        units: length unit of the file: ``"m"``, ``"mm"`` or ``"in"``.
        spacing_m: waypoint spacing along the path after resampling [m].
        layer: DXF layer holding the path, or None for the only/first path entity.
        reverse: run the path in the opposite direction.
    """

    file: Path
    format: str = "csv"
    units: str = "mm"
    spacing_m: float = 0.005
    layer: str | None = None
    reverse: bool = False

    def __post_init__(self) -> None:
        _one_of("cad", "format", self.format, ("csv", "dxf"))
        _one_of("cad", "units", self.units, ("m", "mm", "in"))
        _positive("cad", "spacing_m", self.spacing_m)


@dataclass(frozen=True)
class DemoSettings:
    """``[demonstration]``: the tracker log and how to clean it.

    Attributes:
        file: absolute path of the log.
        format: ``"liberty_ascii"`` or ``"csv"``.
        units: position unit of the log: ``"in"`` or ``"cm"`` (Liberty), ``"m"``/``"mm"`` (CSV).
        station: tracker station (sensor) number to read.
        rate_hz: sample rate [Hz] for logs without timestamps.
        hampel_window: half-width of the Hampel outlier filter [samples].
        hampel_sigmas: threshold of the Hampel filter [robust standard deviations].
        smoothing_s: standard deviation of the Gaussian smoothing of positions and orientations [s].
        pause_speed_m_s: below this speed the tool counts as still (start pause) [m/s].
        truth: absolute path of a ``truth.csv`` (simulated demonstrations only), or None.
    """

    file: Path
    format: str = "liberty_ascii"
    units: str = "in"
    station: int = 1
    rate_hz: float = 240.0
    hampel_window: int = 7
    hampel_sigmas: float = 3.0
    smoothing_s: float = 0.03
    pause_speed_m_s: float = 0.01
    truth: Path | None = None

    def __post_init__(self) -> None:
        _one_of("demonstration", "format", self.format, ("liberty_ascii", "csv"))
        _one_of("demonstration", "units", self.units, ("in", "cm", "m", "mm"))
        _positive("demonstration", "rate_hz", self.rate_hz)
        _positive("demonstration", "hampel_window", self.hampel_window)
        _positive("demonstration", "hampel_sigmas", self.hampel_sigmas)
        _non_negative("demonstration", "smoothing_s", self.smoothing_s)
        _positive("demonstration", "pause_speed_m_s", self.pause_speed_m_s)


@dataclass(frozen=True)
class Tolerances:
    """``[tolerances]``: what the refined path must satisfy.

    Attributes:
        position_m: largest TCP position error against the CAD path accepted in verification [m].
        orientation_deg: half-angle of the cone around the demonstrated orientation [deg].
        joint_margin_deg: distance kept from every joint limit [deg].
        singularity_margin: lower bound on the singularity measure, the scaled manipulability
            ``sqrt(det(Js Jsᵀ))`` with Js the TCP Jacobian whose position rows are divided by the
            robot's reach [-].
    """

    position_m: float = 1e-6
    orientation_deg: float = 3.0
    joint_margin_deg: float = 2.0
    singularity_margin: float = 0.02

    def __post_init__(self) -> None:
        _positive("tolerances", "position_m", self.position_m)
        _positive("tolerances", "orientation_deg", self.orientation_deg)
        if self.orientation_deg >= 90.0:
            raise InputError(f"tolerances.orientation_deg must be < 90, got {self.orientation_deg}")
        _non_negative("tolerances", "joint_margin_deg", self.joint_margin_deg)
        _non_negative("tolerances", "singularity_margin", self.singularity_margin)


@dataclass(frozen=True)
class ProcessParameter:
    """One process value with its unit, e.g. the glue flow rate in ``ml/s``."""

    name: str
    value: float
    unit: str


@dataclass(frozen=True)
class ProcessSettings:
    """``[process]``: what the tool does along the path.

    Attributes:
        kind: ``"glue"``, ``"weld"``, ``"seal"`` or ``"other"``.
        output: name of the digital output that switches the process on and off.
        parameters: process values (flow rate, current, ...), written to PathML and programs.
    """

    kind: str = "other"
    output: str = "doProcess"
    parameters: tuple[ProcessParameter, ...] = ()

    def __post_init__(self) -> None:
        _one_of("process", "kind", self.kind, ("glue", "weld", "seal", "other"))


@dataclass(frozen=True)
class OutputSettings:
    """``[output]``: which programs to write.

    Attributes:
        programs: program formats, from ``"rapid"`` (more to come).
    """

    programs: tuple[str, ...] = ("rapid",)

    def __post_init__(self) -> None:
        for p in self.programs:
            _one_of("output", "programs[]", p, ("rapid",))


@dataclass(frozen=True)
class Problem:
    """A whole problem file.

    Attributes:
        name: problem name (defaults to the folder name).
        root: folder of the problem file; relative paths are resolved against it.
        description: free text.
    """

    name: str
    root: Path
    robot: RobotSettings
    tool: ToolSettings
    cad: CadSettings
    demonstration: DemoSettings
    frames: FrameSettings = field(default_factory=FrameSettings)
    tolerances: Tolerances = field(default_factory=Tolerances)
    process: ProcessSettings = field(default_factory=ProcessSettings)
    output: OutputSettings = field(default_factory=OutputSettings)
    description: str = ""


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
    for table in ("robot", "tool", "cad", "demonstration"):
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
            demonstration=_demo(_table(data, "demonstration"), root, path),
            tolerances=_build(Tolerances, _table(data, "tolerances"), "tolerances", path),
            process=_process(_table(data, "process"), path),
            output=_output(_table(data, "output"), path),
        )
    except InputError as e:
        raise InputError(f"{path}: {e}") from e


# ---- loader internals ---------------------------------------------------------------------------

_TOP_KEYS = {
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
    return ToolSettings(**out)


def _frames(t: dict[str, Any], path: Path) -> FrameSettings:
    _check_keys(t, "frames", _fields(FrameSettings), path)
    return FrameSettings(**{k: _pose(v, f"frames.{k}") for k, v in t.items()})


def _cad(t: dict[str, Any], root: Path, path: Path) -> CadSettings:
    if "file" not in t:
        raise InputError("[cad] missing required key 'file'")
    f = _file(root, t["file"], "cad.file")
    fmt = t.get("format", {".dxf": "dxf", ".csv": "csv"}.get(f.suffix.lower(), f.suffix))
    return _build(CadSettings, t, "cad", path, file=f, format=fmt)


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
