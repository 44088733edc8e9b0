"""The settings of a problem file, one frozen, self-checking dataclass per table.

``refine.problem`` reads ``problem.toml`` into these; every key is documented in
``docs/problem-file.md``. Each ``__post_init__`` rejects a bad value with a message naming the table,
the key, the value and what is allowed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from refine.errors import InputError
from refine.frames import check_transform

Matrix4 = np.ndarray

CAD_FORMATS = ("csv", "dxf", "gcode", "mesh", "pathml")
DEMO_FORMATS = ("liberty_ascii", "liberty_binary", "csv")
PROGRAM_FORMATS = ("rapid", "krl", "urscript", "sunrise")
URSCRIPT_MODES = ("program", "script_node")
SHAPES = ("box", "cylinder", "sphere", "mesh")
CAUSES = ("reach", "joint limit", "joint wrap", "singularity", "collision", "self-collision", "orientation")

# ---- documented ranges that bound the work (docs/problem-file.md, "Ranges and limits")
MIN_SPACING_M = 1e-4
"""Finest waypoint spacing [m]: 0.1 mm, a tenth of the finest tracker resolution that matters."""
MAX_HAMPEL_WINDOW = 50
"""Widest Hampel half-window [samples]: 0.2 s at 240 Hz; wider windows only blur real motion."""
MAX_SMOOTHING_S = 1.0
"""Heaviest demonstration smoothing [s]: more would flatten every bend of a hand-held path."""
MAX_WAYPOINTS = 20_000
"""Most waypoints a path may be resampled to (path length / ``cad.spacing_m``): the refinement's
memory and time grow linearly with it (docs/problem-file.md, "Ranges and limits")."""
MAX_CHECK_STEPS = 2_000_000
"""Most poses of the dense collision check, counted as path length / ``collision.check_step_m``
(a lower bound: joint sweeps add more)."""
MIN_CHECK_STEP_M = 1e-4
"""Finest step of the dense collision check [m]."""
MIN_ORIENTATION_DEG = 0.01
"""Narrowest orientation cone [deg]: well above the verifier's accuracy (1e-6 deg)."""


def _positive(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise InputError(f"{owner}.{name} must be a finite number > 0, got {value!r}")


def _non_negative(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
        raise InputError(f"{owner}.{name} must be a finite number >= 0, got {value!r}")


def check_waypoint_count(length_m: float, spacing_m: float, where: str) -> None:
    """Refuse a path that would be resampled to more than :data:`MAX_WAYPOINTS` waypoints."""
    count = length_m / spacing_m
    if not math.isfinite(count) or count > MAX_WAYPOINTS:
        raise InputError(
            f"{where}: a {length_m:.3f} m path at cad.spacing_m = {spacing_m:g} m gives {count:.0f} "
            f"waypoints, more than the limit of {MAX_WAYPOINTS}; use a larger spacing "
            f"(at least {length_m / MAX_WAYPOINTS:.2g} m)"
        )


SOLVERS = ("ipopt", "fatrop")
"""The NLP solvers a refinement can be built for (``[optimise] solver``)."""


def check_solver(name: str) -> str:
    """``name`` if it is one of :data:`SOLVERS`, else an :class:`InputError` listing them."""
    if name not in SOLVERS:
        raise InputError(f"optimise.solver must be one of {', '.join(map(repr, SOLVERS))}, got {name!r}")
    return name


def _in_range(owner: str, name: str, value: float, lo: float, hi: float, unit: str = "") -> None:
    """Reject a value that is not a finite number in [lo, hi] (the documented range)."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not (ok and lo <= value <= hi):
        u = f" {unit}" if unit else ""
        raise InputError(f"{owner}.{name} must be a finite number in [{lo:g}, {hi:g}]{u}, got {value!r}")


def _integer_in(owner: str, name: str, value: int, low: int, high: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise InputError(f"{owner}.{name} must be an integer in {low}..{high}, got {value!r}")


def _one_of(owner: str, name: str, value: str, allowed: tuple[str, ...]) -> None:
    if value not in allowed:
        raise InputError(f"{owner}.{name} = {value!r} is not one of {', '.join(allowed)}")


@dataclass(frozen=True)
class RobotSettings:
    """``[robot]``: which robot, where it stands, optional limit overrides.

    Attributes:
        model: registry name, a folder of ``robots/`` (e.g. ``"abb_irb4600_60_205"``); with
            ``urdf``, the robot's name in outputs (default: the URDF's robot name).
        base_in_world: T_F_R, the robot base in the world frame {F}, (4, 4).
        joint_acceleration_deg_s2: per-joint acceleration limits [deg/s^2] overriding the
            robot's default, or None.
        velocity_scale: fraction of the data-sheet joint speeds the plan may use, in (0, 1].
        home_deg: a preferred joint configuration [deg] to start the IK seed from, or None.
        urdf: a robot outside the registry: its URDF file (absolute path), or None.
        flange_frame: with ``urdf``: the frame the tool is mounted on.
        controller: with ``urdf``: the controller family (``"abb"``, ``"kuka"``, ``"ur"``).
        reach_m: with ``urdf``: the reach [m] scaling the singularity measure (default: the
            chain from the second joint to the flange, stretched).
        joint_lower_deg: per-joint lower limits [deg] in place of the robot's, or None.
        joint_upper_deg: per-joint upper limits [deg] in place of the robot's, or None.
        joint_velocity_deg_s: per-joint speed limits [deg/s] in place of the robot's, or None.
    """

    model: str = ""
    base_in_world: Matrix4 = field(default_factory=lambda: np.eye(4))
    joint_acceleration_deg_s2: tuple[float, ...] | None = None
    velocity_scale: float = 1.0
    home_deg: tuple[float, ...] | None = None
    urdf: Path | None = None
    flange_frame: str = "tool0"
    controller: str | None = None
    reach_m: float | None = None
    joint_lower_deg: tuple[float, ...] | None = None
    joint_upper_deg: tuple[float, ...] | None = None
    joint_velocity_deg_s: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.urdf is None and not self.model:
            raise InputError("[robot] needs model (a registry robot) or urdf (a robot's URDF file)")
        if self.urdf is not None and self.controller is None:
            raise InputError('[robot] a robot from its URDF needs controller ("abb", "kuka" or "ur")')
        if self.urdf is None and (self.controller is not None or self.reach_m is not None):
            raise InputError("[robot] controller and reach_m go with urdf (a registry robot has its own)")
        if self.reach_m is not None:
            _positive("robot", "reach_m", self.reach_m)
        for a in self.joint_velocity_deg_s or ():
            _positive("robot", "joint_velocity_deg_s[]", a)
        check_transform(self.base_in_world, "robot.base_in_world")
        if not (math.isfinite(self.velocity_scale) and 0.0 < self.velocity_scale <= 1.0):
            raise InputError(f"robot.velocity_scale must be in (0, 1], got {self.velocity_scale}")
        for a in self.joint_acceleration_deg_s2 or ():
            _positive("robot", "joint_acceleration_deg_s2[]", a)
            _in_range("robot", "joint_acceleration_deg_s2[]", a, 0.0, 1e5, "deg/s^2")
        for a in self.home_deg or ():
            _in_range("robot", "home_deg[]", a, -720.0, 720.0, "deg")


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
        collision: the tool's collision shapes, poses in the flange frame.
        number: the tool's number on controllers that number their tools (KRL ``TOOL_DATA[n]``,
            1..16).
    """

    name: str
    tcp_in_flange: Matrix4
    sensor_in_tcp: Matrix4 = field(default_factory=lambda: np.eye(4))
    axisymmetric: bool = False
    mass_kg: float = 5.0
    cog_in_flange_m: tuple[float, float, float] = (0.0, 0.0, 0.1)
    collision: tuple[Shape, ...] = ()
    number: int = 1

    def __post_init__(self) -> None:
        check_transform(self.tcp_in_flange, "tool.tcp_in_flange")
        check_transform(self.sensor_in_tcp, "tool.sensor_in_tcp")
        _positive("tool", "mass_kg", self.mass_kg)
        _in_range("tool", "mass_kg", self.mass_kg, 0.0, 2000.0, "kg")
        for v in self.cog_in_flange_m:
            _in_range("tool", "cog_in_flange_m[]", v, -5.0, 5.0, "m")
        _integer_in("tool", "number", self.number, 1, 16)


@dataclass(frozen=True)
class FrameSettings:
    """``[frames]``: where the tracker receiver and the CAD frame sit in the world {F}.

    Attributes:
        source_in_world: T_F_S, the tracker receiver (source) in {F}.
        cad_in_world: T_F_CAD, the frame the CAD/CAM coordinates are given in.
        base_number: the number under which the world {F} is calibrated as a base on controllers
            that number their bases (KRL ``BASE_DATA[n]``, 1..32).
    """

    source_in_world: Matrix4 = field(default_factory=lambda: np.eye(4))
    cad_in_world: Matrix4 = field(default_factory=lambda: np.eye(4))
    base_number: int = 1

    def __post_init__(self) -> None:
        check_transform(self.source_in_world, "frames.source_in_world")
        check_transform(self.cad_in_world, "frames.cad_in_world")
        _integer_in("frames", "base_number", self.base_number, 1, 32)


@dataclass(frozen=True)
class CadSettings:
    """``[cad]``: the CAD/CAM path file.

    Attributes:
        file: absolute path of the file.
        format: ``"csv"``, ``"dxf"``, ``"gcode"``, ``"mesh"`` (STL, OBJ, PLY) or ``"pathml"``
            (from the extension when not given).
        units: length unit of the file: ``"m"``, ``"mm"`` or ``"in"``.
        spacing_m: waypoint spacing along the path after resampling [m].
        layer: DXF layer holding the path, or None for the only/first path entity.
        reverse: run the path in the opposite direction.
        section_origin: a point of the cutting plane [file units] (mesh: plane section).
        section_normal: the cutting plane's normal (mesh: plane section).
        boundary: take the mesh's open boundary instead of a section (mesh).
        start_near: start a closed contour at its point nearest to this [file units], or None.
        track: PathML track to read, as ``"layer/track"`` names, or None for the first (pathml).
    """

    file: Path
    format: str = "csv"
    units: str = "mm"
    spacing_m: float = 0.005
    layer: str | None = None
    reverse: bool = False
    section_origin: tuple[float, float, float] | None = None
    section_normal: tuple[float, float, float] | None = None
    boundary: bool = False
    start_near: tuple[float, float, float] | None = None
    track: str | None = None

    def __post_init__(self) -> None:
        _one_of("cad", "format", self.format, CAD_FORMATS)
        if self.format == "mesh" and self.boundary == (self.section_normal is not None):
            raise InputError(
                "cad: a mesh path needs either boundary = true or section_origin + section_normal"
            )
        if (self.section_origin is None) != (self.section_normal is None):
            raise InputError("cad: section_origin and section_normal go together")
        _one_of("cad", "units", self.units, ("m", "mm", "in"))
        _in_range("cad", "spacing_m", self.spacing_m, MIN_SPACING_M, 1.0, "m")
        for key in ("section_origin", "section_normal", "start_near"):
            for v in getattr(self, key) or ():
                _in_range("cad", f"{key}[]", v, -1e6, 1e6, "file units")


@dataclass(frozen=True)
class DemoSettings:
    """``[demonstration]``: the tracker log and how to clean it.

    Attributes:
        file: absolute path of the log.
        format: ``"liberty_ascii"``, ``"liberty_binary"`` or ``"csv"``.
        units: position unit of the log: ``"in"`` or ``"cm"`` (Liberty), ``"m"``/``"mm"`` (CSV).
        station: tracker station (sensor) number to read.
        rate_hz: sample rate [Hz] for logs without timestamps.
        hampel_window: half-width of the Hampel outlier filter [samples].
        hampel_sigmas: threshold of the Hampel filter [robust standard deviations].
        smoothing_s: standard deviation of the Gaussian smoothing of positions and orientations [s].
        pause_speed_m_s: below this speed the tool counts as still (start pause) [m/s].
        truth: absolute path of a ``truth.csv`` (simulated demonstrations only), or None.
        angle_units: angle unit of a CSV log, ``"deg"`` or ``"rad"``; None: degrees, and a log whose
            angles look like radians stops (:func:`refine.plausible.check_demo_units`).
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
    angle_units: str | None = None

    def __post_init__(self) -> None:
        _one_of("demonstration", "format", self.format, DEMO_FORMATS)
        if self.angle_units is not None:
            _one_of("demonstration", "angle_units", self.angle_units, ("deg", "rad"))
        _one_of("demonstration", "units", self.units, ("in", "cm", "m", "mm"))
        _in_range("demonstration", "station", self.station, 1, 32)
        _positive("demonstration", "rate_hz", self.rate_hz)
        _in_range("demonstration", "rate_hz", self.rate_hz, 1.0, 10_000.0, "Hz")
        _in_range("demonstration", "hampel_window", self.hampel_window, 1, MAX_HAMPEL_WINDOW, "samples")
        _positive("demonstration", "hampel_sigmas", self.hampel_sigmas)
        _in_range("demonstration", "hampel_sigmas", self.hampel_sigmas, 0.5, 100.0)
        _in_range("demonstration", "smoothing_s", self.smoothing_s, 0.0, MAX_SMOOTHING_S, "s")
        _positive("demonstration", "pause_speed_m_s", self.pause_speed_m_s)
        _in_range("demonstration", "pause_speed_m_s", self.pause_speed_m_s, 0.0, 1.0, "m/s")


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
        joint_step_deg: largest change of any joint between consecutive waypoints [deg]; keeps
            the path continuous (no IK branch jump, no full turn of a wrist between two waypoints).
    """

    position_m: float = 1e-6
    orientation_deg: float = 3.0
    joint_margin_deg: float = 2.0
    singularity_margin: float = 0.02
    joint_step_deg: float = 20.0

    def __post_init__(self) -> None:
        _in_range("tolerances", "position_m", self.position_m, 1e-8, 1.0, "m")
        _in_range("tolerances", "orientation_deg", self.orientation_deg, MIN_ORIENTATION_DEG, 89.0, "deg")
        _in_range("tolerances", "joint_margin_deg", self.joint_margin_deg, 0.0, 45.0, "deg")
        _in_range("tolerances", "singularity_margin", self.singularity_margin, 0.0, 0.9)
        _positive("tolerances", "joint_step_deg", self.joint_step_deg)
        _in_range("tolerances", "joint_step_deg", self.joint_step_deg, 0.0, 1000.0, "deg")


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
        output: name of the digital output that switches the process on and off (the arc of a weld).
        parameters: process values (flow rate, current, ...), written to PathML and programs.
        lead_s: the output switches this long before the robot reaches the first and the last
            path point, on the move [s] (the dispenser's opening and closing delay).
        lead_m: instead of ``lead_s``, this distance before those points [m].
        gas_output: weld: the shielding-gas valve output.
        arc_ok_input: weld: the power source's "arc established" input.
        preflow_s: weld: gas pre-flow before the arc is started [s].
        arc_timeout_s: weld: how long to wait for the arc signal before stopping with an error [s].
        crater_fill_s: weld: dwell with the arc on at the end point, filling the crater [s].
        postflow_s: weld: gas post-flow after the arc is off [s].
    """

    kind: str = "other"
    output: str = "doProcess"
    parameters: tuple[ProcessParameter, ...] = ()
    lead_s: float = 0.0
    lead_m: float | None = None
    gas_output: str = "doGas"
    arc_ok_input: str = "diArcOk"
    preflow_s: float = 0.5
    arc_timeout_s: float = 2.0
    crater_fill_s: float = 0.5
    postflow_s: float = 3.0

    def __post_init__(self) -> None:
        _one_of("process", "kind", self.kind, ("glue", "weld", "seal", "other"))
        for i, p in enumerate(self.parameters):
            _in_range(f"process.parameters[{i}]", "value", p.value, -1e9, 1e9, p.unit)
        for name in ("lead_s", "preflow_s", "crater_fill_s", "postflow_s"):
            _non_negative("process", name, getattr(self, name))
        _positive("process", "arc_timeout_s", self.arc_timeout_s)
        if self.lead_m is not None:
            _non_negative("process", "lead_m", self.lead_m)
            if self.lead_s:
                raise InputError(
                    f"process: give lead_s ({self.lead_s} s) or lead_m ({self.lead_m} m), not both"
                )


@dataclass(frozen=True)
class OutputSettings:
    """``[output]``: which programs to write.

    Attributes:
        programs: program formats, from :data:`PROGRAM_FORMATS`; None (the default) for the one the
            robot's controller runs (``RobotSpec.default_program``: RAPID for ABB, KRL for the KR arms,
            Sunrise for the LBR iiwa, URScript for UR); an empty tuple for none.
        urscript_mode: ``"program"`` (a ``def`` ... ``end`` function called at the end of the file)
            or ``"script_node"`` (the body alone, for a PolyScope Script node).
        speed_levels: RAPID: at most this many ``speeddata`` for the path moves.
        moves_per_routine: RAPID: path moves per ``PROC`` (longer paths are split into several).
    """

    programs: tuple[str, ...] | None = None
    urscript_mode: str = "program"
    speed_levels: int = 5
    moves_per_routine: int = 500

    def __post_init__(self) -> None:
        for p in self.programs or ():
            _one_of("output", "programs[]", p, PROGRAM_FORMATS)
        _one_of("output", "urscript_mode", self.urscript_mode, URSCRIPT_MODES)
        _integer_in("output", "speed_levels", self.speed_levels, 1, 100)
        _integer_in("output", "moves_per_routine", self.moves_per_routine, 10, 100000)


@dataclass(frozen=True)
class Shape:
    """A collision shape: ``[[cell.objects]]`` in the world, or ``[[tool.collision]]`` on the flange.

    Attributes:
        name: object name, used in messages and repair reports.
        shape: one of :data:`SHAPES`.
        pose: pose of the shape's frame (world {F} for cell objects, flange for tool shapes), (4, 4);
            boxes, cylinders and spheres are centred on it, cylinders along its z axis.
        size_m: box edge lengths [m].
        radius_m: cylinder or sphere radius [m].
        length_m: cylinder length [m].
        file: mesh file (STL, OBJ, PLY), absolute path.
        units: length unit of the mesh file.
        workpiece: the process is meant to touch it (the tool's own shapes are not checked against
            it; the links are).
    """

    name: str
    shape: str
    pose: Matrix4 = field(default_factory=lambda: np.eye(4))
    size_m: tuple[float, float, float] | None = None
    radius_m: float | None = None
    length_m: float | None = None
    file: Path | None = None
    units: str = "m"
    workpiece: bool = False

    def __post_init__(self) -> None:
        owner = f"shape {self.name!r}"
        _one_of(owner, "shape", self.shape, SHAPES)
        check_transform(self.pose, f"{owner}.pose")
        need = {
            "box": ("size_m",),
            "cylinder": ("radius_m", "length_m"),
            "sphere": ("radius_m",),
            "mesh": ("file",),
        }
        for key in need[self.shape]:
            if getattr(self, key) is None:
                raise InputError(f"{owner}: a {self.shape} needs {key}")
        for key in ("radius_m", "length_m"):
            if getattr(self, key) is not None:
                _positive(owner, key, getattr(self, key))
                _in_range(owner, key, getattr(self, key), 0.0, 100.0, "m")
        for v in self.size_m or ():
            _positive(owner, "size_m[]", v)
            _in_range(owner, "size_m[]", v, 0.0, 100.0, "m")
        _one_of(owner, "units", self.units, ("m", "mm", "in"))


@dataclass(frozen=True)
class CollisionSettings:
    """``[collision]``: clearance to the cell and between the robot's own links.

    Attributes:
        enabled: check and keep clearance (needs ``[[cell.objects]]`` or a tool with shapes).
        margin_m: smallest distance kept between robot or tool and the cell [m].
        self_margin_m: smallest distance kept between non-adjacent links [m].
        check_step_m: largest TCP travel between two poses of the dense final check [m].
        max_outer_iterations: rounds of linearise -> solve -> check before giving up.
    """

    enabled: bool = True
    margin_m: float = 0.01
    self_margin_m: float = 0.005
    check_step_m: float = 0.001
    max_outer_iterations: int = 8

    def __post_init__(self) -> None:
        _in_range("collision", "margin_m", self.margin_m, 0.0, 1.0, "m")
        _in_range("collision", "self_margin_m", self.self_margin_m, 0.0, 0.5, "m")
        _in_range("collision", "check_step_m", self.check_step_m, MIN_CHECK_STEP_M, 0.1, "m")
        _in_range("collision", "max_outer_iterations", self.max_outer_iterations, 1, 50)


@dataclass(frozen=True)
class OptimiseSettings:
    """``[optimise]``: cost weights of the refinement (see ``refine.optimise.problem.Weights``) and its solver.

    Attributes:
        orientation_weight: weight of the squared deviation from the demonstration.
        velocity_weight: weight of the squared joint step per metre of path.
        acceleration_weight: weight of the squared second difference per metre².
        mid_range_weight: weight of the squared distance of each joint from the middle of its range
            (normalised by the range); the secondary cost that resolves a redundant arm's extra
            freedom. Default: 0 for 6-axis arms, 2.0 when the robot has more than 6 joints.
        solver: the NLP solver, ``"ipopt"`` (default, the faster by measurement) or ``"fatrop"``
            (the problem posed stage by stage; at most 2,000 waypoints per pass; see
            ``refine.optimise.stagewise``).
    """

    orientation_weight: float = 1.0
    velocity_weight: float = 5e-3
    acceleration_weight: float = 5e-8
    mid_range_weight: float | None = None
    solver: str = "ipopt"

    def __post_init__(self) -> None:
        check_solver(self.solver)
        for key in ("orientation_weight", "velocity_weight", "acceleration_weight"):
            _in_range("optimise", key, getattr(self, key), 0.0, 1e6)
        if self.mid_range_weight is not None:
            _in_range("optimise", "mid_range_weight", self.mid_range_weight, 0.0, 1e6)


MAX_PLACEMENT_TRANSLATE_M = 1.0
"""Largest workpiece shift the placement repair may search [m]: beyond it the cell is laid out anew."""
MAX_PLACEMENT_ROTATE_DEG = 45.0
"""Largest workpiece turn the placement repair may search [deg]."""
PLACEMENT_FREEDOMS = ("plane", "all")
"""``[repair] placement.free``: in the support plane only, or any rigid move."""


@dataclass(frozen=True)
class PlacementSettings:
    """``[repair] placement``: the bounds of the workpiece move the placement repair may propose.

    The move is a rigid transform of the workpiece (the CAD frame, the demonstration recorded on it
    and the cell objects marked ``workpiece``): a turn about the path's centroid and a shift, both
    in the world frame {F}. The smallest move is the one with the least
    ``sqrt((|t| / translate_m)² + (angle / rotate_deg)²)`` (see :mod:`refine.placement`).

    Attributes:
        translate_m: largest shift of the workpiece [m] (0: no shift).
        rotate_deg: largest turn of the workpiece about the path's centroid [deg] (0: no turn).
        free: ``"plane"``: the workpiece only slides in the plane it rests on and turns about that
            plane's normal; ``"all"``: any rigid move (kept out of the cell's other objects).
    """

    translate_m: float = 0.0
    rotate_deg: float = 0.0
    free: str = "plane"

    def __post_init__(self) -> None:
        _in_range("repair.placement", "translate_m", self.translate_m, 0.0, MAX_PLACEMENT_TRANSLATE_M, "m")
        _in_range("repair.placement", "rotate_deg", self.rotate_deg, 0.0, MAX_PLACEMENT_ROTATE_DEG, "deg")
        if self.translate_m == 0.0 and self.rotate_deg == 0.0:
            raise InputError(
                "repair.placement needs translate_m > 0 m or rotate_deg > 0 deg "
                "(leave placement out to search no workpiece move)"
            )
        if self.free not in PLACEMENT_FREEDOMS:
            raise InputError(
                f"repair.placement.free must be one of {', '.join(map(repr, PLACEMENT_FREEDOMS))}, got {self.free!r}"
            )


@dataclass(frozen=True)
class RepairSettings:
    """``[repair]``: what to do when the strict problem is infeasible.

    Attributes:
        enabled: look for the smallest extra orientation slack per waypoint that makes it feasible.
        max_slack_deg: the largest extra slack [deg] on top of the orientation tolerance.
        time_limit_s: wall-time budget of one pass's refinement (IK seed, solves, repair) [s];
            when it runs out before a verdict the pass is ``infeasible`` and says so.
        placement: the bounds of a workpiece move to search when the strict problem has no
            answer (:mod:`refine.placement`), or None for no placement search.
    """

    enabled: bool = True
    max_slack_deg: float = 15.0
    time_limit_s: float = 120.0
    placement: PlacementSettings | None = None

    def __post_init__(self) -> None:
        _in_range("repair", "max_slack_deg", self.max_slack_deg, 0.0, 90.0, "deg")
        _in_range("repair", "time_limit_s", self.time_limit_s, 0.1, 86400.0, "s")


@dataclass(frozen=True)
class MultipassSettings:
    """``[multipass]``: the passes of a multi-layer weld, generated from the demonstrated first pass.

    Attributes:
        layers: number of layers (the first is the demonstrated root pass).
        layer_height_m: height of each layer above the previous, along the seam's bisector [m].
        lateral_offsets_m: per layer, the lateral offset of each pass from the seam line [m];
            layer 1 must be ``[0.0]``.
        work_angle_change_deg: per layer and pass, the change of the work angle (tilt about the
            seam tangent) from the demonstrated one [deg]; zeros when absent.
    """

    layers: int = 1
    layer_height_m: float = 0.0
    lateral_offsets_m: tuple[tuple[float, ...], ...] = ((0.0,),)
    work_angle_change_deg: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        _in_range("multipass", "layers", self.layers, 1, 50)
        _in_range("multipass", "layer_height_m", self.layer_height_m, 0.0, 0.1, "m")
        for key, bound, unit in (("lateral_offsets_m", 0.2, "m"), ("work_angle_change_deg", 90.0, "deg")):
            for row in getattr(self, key) or ():
                for v in row:
                    _in_range("multipass", f"{key}[][]", v, -bound, bound, unit)
        if len(self.lateral_offsets_m) != self.layers:
            raise InputError(
                f"multipass.lateral_offsets_m needs one list per layer ({self.layers}), got {len(self.lateral_offsets_m)}"
            )
        if self.work_angle_change_deg is not None and [len(x) for x in self.work_angle_change_deg] != [
            len(x) for x in self.lateral_offsets_m
        ]:
            raise InputError("multipass.work_angle_change_deg must have the shape of lateral_offsets_m")


@dataclass(frozen=True)
class ExpectedOutcome:
    """``[expected]``: what a test problem is built to produce (checked by the test suite).

    Attributes:
        status: ``"ok"``, ``"repaired"`` or ``"infeasible"``.
        reason: a text the repair or infeasibility reason must contain (e.g. ``"joint limit"``).
        max_slack_deg: for a repaired problem, the largest slack it may use [deg].
        s_range_m: arc-length range [m] the reported segment must overlap, or None.
        cause: the cause the diagnosis must name first for that segment (``"reach"``,
            ``"joint limit"``, ``"joint wrap"``, ``"singularity"``, ``"collision"``,
            ``"self-collision"``, ``"orientation"``), or ``""`` for no check.
    """

    status: str
    reason: str = ""
    max_slack_deg: float | None = None
    s_range_m: tuple[float, float] | None = None
    cause: str = ""

    def __post_init__(self) -> None:
        _one_of("expected", "status", self.status, ("ok", "repaired", "infeasible"))
        if self.cause:
            _one_of("expected", "cause", self.cause, CAUSES)
