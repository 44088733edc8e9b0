"""The tables of a run's inputs: robot, tool, frames, CAD and demonstration.

The tables of a run's inputs: ``[robot]``, ``[tool]``, ``[frames]``, ``[cad]`` and
``[demonstration]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from refine.errors import InputError
from refine.frames import check_transform
from refine.settings.limits import (
    CAD_FORMATS,
    DEMO_FORMATS,
    MAX_HAMPEL_WINDOW,
    MAX_SMOOTHING_S,
    MIN_CHORD_TOLERANCE_M,
    MIN_SPACING_M,
    Matrix4,
    in_range,
    integer_in,
    one_of,
    positive,
)
from refine.settings.process import Shape


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
        urdf: a robot outside the registry: its URDF or xacro file (absolute path), or None.
        packages: with ``urdf``: ROS package name -> folder (absolute path), for the packages its
            ``$(find pkg)`` and ``package://pkg/`` name that are not found beside it.
        flange_frame: with ``urdf``: the frame the tool is mounted on.
        controller: with ``urdf``: the controller family (``"abb"``, ``"kuka"``, ``"ur"``,
            ``"fanuc"``, ``"yaskawa"``).
        reach_m: with ``urdf``: the reach [m] scaling the singularity measure (default: the
            chain from the second joint to the flange, stretched).
        joint_lower_deg: per-joint lower limits [deg] in place of the robot's, or None.
        joint_upper_deg: per-joint upper limits [deg] in place of the robot's, or None.
        joint_velocity_deg_s: per-joint speed limits [deg/s] in place of the robot's, or None.
        base_link: with ``urdf``: the link the arm stands on (its base frame), or None for the
            URDF's root.
        locked_joints_deg: with ``urdf``: joints held still, as (name, value [deg]) pairs.
    """

    model: str = ""
    base_in_world: Matrix4 = field(default_factory=lambda: np.eye(4))
    joint_acceleration_deg_s2: tuple[float, ...] | None = None
    velocity_scale: float = 1.0
    home_deg: tuple[float, ...] | None = None
    urdf: Path | None = None
    packages: tuple[tuple[str, Path], ...] = ()
    flange_frame: str = "tool0"
    controller: str | None = None
    reach_m: float | None = None
    joint_lower_deg: tuple[float, ...] | None = None
    joint_upper_deg: tuple[float, ...] | None = None
    joint_velocity_deg_s: tuple[float, ...] | None = None
    base_link: str | None = None
    locked_joints_deg: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        if self.urdf is None and not self.model:
            raise InputError("[robot] needs model (a registry robot) or urdf (a robot's URDF file)")
        if self.urdf is not None and self.controller is None:
            raise InputError(
                '[robot] a robot from its URDF needs controller ("abb", "kuka", "ur", "fanuc" or "yaskawa")'
            )
        if self.urdf is None and (self.controller is not None or self.reach_m is not None or self.packages):
            raise InputError(
                "[robot] controller, reach_m and packages go with urdf (a registry robot has its own)"
            )
        if self.urdf is None and (self.base_link is not None or self.locked_joints_deg):
            raise InputError("[robot] base_link and locked_joints_deg go with urdf (a registry robot has its own chain)")
        if self.reach_m is not None:
            positive("robot", "reach_m", self.reach_m)
        for a in self.joint_velocity_deg_s or ():
            positive("robot", "joint_velocity_deg_s[]", a)
        check_transform(self.base_in_world, "robot.base_in_world")
        if not (math.isfinite(self.velocity_scale) and 0.0 < self.velocity_scale <= 1.0):
            raise InputError(f"robot.velocity_scale must be in (0, 1], got {self.velocity_scale}")
        for a in self.joint_acceleration_deg_s2 or ():
            positive("robot", "joint_acceleration_deg_s2[]", a)
            in_range("robot", "joint_acceleration_deg_s2[]", a, 0.0, 1e5, "deg/s^2")
        for a in self.home_deg or ():
            in_range("robot", "home_deg[]", a, -720.0, 720.0, "deg")


@dataclass(frozen=True)
class ToolSettings:
    """``[tool]``: the process tool on the flange and the tracker sensor on the hand tool.

    Attributes:
        name: tool name, used for RAPID tooldata / KRL tool names.
        tcp_in_flange: T_flange_TCP, (4, 4); the TCP z axis points along the nozzle/torch. With a
            stationary tool, T_flange_part: the held part's frame, the path's frame (TOML key
            ``part_in_flange``).
        tcp_in_world: T_F_TCP of a stationary tool (the tool stands in the world and the robot
            holds the part: glazing, sealing or grinding a small part), or None for a tool on the
            flange. The path is then given in the held part's frame.
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
    tcp_in_world: Matrix4 | None = None

    @property
    def stationary(self) -> bool:
        """The tool stands in the world and the robot holds the part (``tcp_in_world`` given)."""
        return self.tcp_in_world is not None

    def __post_init__(self) -> None:
        check_transform(self.tcp_in_flange, "tool.tcp_in_flange")
        if self.tcp_in_world is not None:
            check_transform(self.tcp_in_world, "tool.tcp_in_world")
        check_transform(self.sensor_in_tcp, "tool.sensor_in_tcp")
        positive("tool", "mass_kg", self.mass_kg)
        in_range("tool", "mass_kg", self.mass_kg, 0.0, 2000.0, "kg")
        for v in self.cog_in_flange_m:
            in_range("tool", "cog_in_flange_m[]", v, -5.0, 5.0, "m")
        integer_in("tool", "number", self.number, 1, 16)


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
        integer_in("frames", "base_number", self.base_number, 1, 32)


@dataclass(frozen=True)
class CadSettings:
    """``[cad]``: the CAD/CAM path file.

    Attributes:
        file: absolute path of the file.
        format: ``"csv"``, ``"dxf"``, ``"gcode"``, ``"mesh"`` (STL, OBJ, PLY), ``"pathml"`` or
            ``"toolpath"`` (a CAM toolpath with tool axes, CSV) (from the extension when not given).
        units: length unit of the file: ``"m"``, ``"mm"`` or ``"in"``.
        spacing_m: largest waypoint spacing along the path after resampling [m].
        chord_tolerance_m: largest distance of the CAD geometry from the straight moves between
            waypoints [m].
        layer: DXF layer holding the path, or None for the only/first path entity.
        reverse: run the path in the opposite direction.
        section_origin: a point of the cutting plane [file units] (mesh: plane section).
        section_normal: the cutting plane's normal (mesh: plane section).
        boundary: take the mesh's open boundary instead of a section (mesh).
        start_near: start a closed contour at its point nearest to this [file units], or None.
        track: the track to read: its 1-based number (DXF, G-code), ``"layer/track"`` (PathML), or
            None for every track (DXF, G-code) or the first (PathML).
        speed_m_s: the tool's speed along a CAM toolpath [m/s] (toolpath; required there).
    """

    file: Path
    format: str = "csv"
    units: str = "mm"
    spacing_m: float = 0.005
    chord_tolerance_m: float = 1e-4
    layer: str | None = None
    reverse: bool = False
    section_origin: tuple[float, float, float] | None = None
    section_normal: tuple[float, float, float] | None = None
    boundary: bool = False
    start_near: tuple[float, float, float] | None = None
    track: str | None = None
    speed_m_s: float | None = None

    def __post_init__(self) -> None:
        one_of("cad", "format", self.format, CAD_FORMATS)
        if (self.format == "toolpath") != (self.speed_m_s is not None):
            raise InputError(
                "cad: speed_m_s [m/s] goes with format = 'toolpath' (a CAM toolpath's speed), and only with it"
            )
        if self.format == "mesh" and self.boundary == (self.section_normal is not None):
            raise InputError(
                "cad: a mesh path needs either boundary = true or section_origin + section_normal"
            )
        if (self.section_origin is None) != (self.section_normal is None):
            raise InputError("cad: section_origin and section_normal go together")
        one_of("cad", "units", self.units, ("m", "mm", "in"))
        in_range("cad", "spacing_m", self.spacing_m, MIN_SPACING_M, 1.0, "m")
        in_range("cad", "chord_tolerance_m", self.chord_tolerance_m, MIN_CHORD_TOLERANCE_M, 0.01, "m")
        for key in ("section_origin", "section_normal", "start_near"):
            for v in getattr(self, key) or ():
                in_range("cad", f"{key}[]", v, -1e6, 1e6, "file units")


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
        one_of("demonstration", "format", self.format, DEMO_FORMATS)
        if self.angle_units is not None:
            one_of("demonstration", "angle_units", self.angle_units, ("deg", "rad"))
        one_of("demonstration", "units", self.units, ("in", "cm", "m", "mm"))
        in_range("demonstration", "station", self.station, 1, 32)
        positive("demonstration", "rate_hz", self.rate_hz)
        in_range("demonstration", "rate_hz", self.rate_hz, 1.0, 10_000.0, "Hz")
        in_range("demonstration", "hampel_window", self.hampel_window, 1, MAX_HAMPEL_WINDOW, "samples")
        positive("demonstration", "hampel_sigmas", self.hampel_sigmas)
        in_range("demonstration", "hampel_sigmas", self.hampel_sigmas, 0.5, 100.0)
        in_range("demonstration", "smoothing_s", self.smoothing_s, 0.0, MAX_SMOOTHING_S, "s")
        positive("demonstration", "pause_speed_m_s", self.pause_speed_m_s)
        in_range("demonstration", "pause_speed_m_s", self.pause_speed_m_s, 0.0, 1.0, "m/s")
