"""The tables of what a run must keep and make: tolerances, process, output, cell, optimiser.

The tables of what the run must keep and make: ``[tolerances]``, ``[process]``, ``[output]``, the
cell's shapes (``[[obstacles]]``), ``[collision]`` and ``[optimise]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from refine.errors import InputError
from refine.frames import check_transform
from refine.settings.limits import (
    MIN_CHECK_STEP_M,
    MIN_ORIENTATION_DEG,
    PROGRAM_FORMATS,
    SHAPES,
    URSCRIPT_MODES,
    Matrix4,
    check_solver,
    in_range,
    integer_in,
    non_negative,
    one_of,
    positive,
)


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
        in_range("tolerances", "position_m", self.position_m, 1e-8, 1.0, "m")
        in_range("tolerances", "orientation_deg", self.orientation_deg, MIN_ORIENTATION_DEG, 89.0, "deg")
        in_range("tolerances", "joint_margin_deg", self.joint_margin_deg, 0.0, 45.0, "deg")
        in_range("tolerances", "singularity_margin", self.singularity_margin, 0.0, 0.9)
        positive("tolerances", "joint_step_deg", self.joint_step_deg)
        in_range("tolerances", "joint_step_deg", self.joint_step_deg, 0.0, 1000.0, "deg")


@dataclass(frozen=True)
class ProcessParameter:
    """One process value with its unit, e.g. the glue flow rate in ``ml/s``."""

    name: str
    value: float
    unit: str


PATH_TOLERANCE_M = {"glue": 0.0005, "seal": 0.0005, "weld": 0.0003, "other": 0.0005}
"""Default ``[process] path_tolerance_m`` per process kind [m]: half a millimetre for a glue or
sealant bead, 0.3 mm for a weld (a fillet seam's joint)."""


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
        path_tolerance_m: largest deviation from the programmed path a blend zone may allow [m];
            None (the default) for the process kind's (:data:`PATH_TOLERANCE_M`). Where a program's
            zone would allow more, it writes a smaller zone or an exact stop.
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
    path_tolerance_m: float | None = None

    def __post_init__(self) -> None:
        one_of("process", "kind", self.kind, ("glue", "weld", "seal", "other"))
        if self.path_tolerance_m is None:
            object.__setattr__(self, "path_tolerance_m", PATH_TOLERANCE_M[self.kind])
        in_range("process", "path_tolerance_m", self.path_tolerance_m, 1e-6, 0.05, "m")
        for i, p in enumerate(self.parameters):
            in_range(f"process.parameters[{i}]", "value", p.value, -1e9, 1e9, p.unit)
        for name in ("lead_s", "preflow_s", "crater_fill_s", "postflow_s"):
            non_negative("process", name, getattr(self, name))
        positive("process", "arc_timeout_s", self.arc_timeout_s)
        if self.lead_m is not None:
            non_negative("process", "lead_m", self.lead_m)
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
        speed_levels: RAPID: at most this many ``speeddata`` for the path moves, raised where
            ``speed_share`` needs more.
        speed_share: largest shortfall of a segment's programmed speed below its planned speed, as
            a share of it [-]: a program whose speed levels would leave a segment slower writes
            more levels.
        moves_per_routine: RAPID: path moves per ``PROC`` (longer paths are split into several).
        air_speed_share: joint speed of the air moves (home, links, via points, return: RAPID
            ``MoveAbsJ``, KRL and FANUC ``PTP``/``J``, INFORM ``MOVJ``, URScript ``movej``, Sunrise
            ``ptp``) as a share of each joint's maximum speed, in whole percent [-]; the planned
            durations and the programs use the same.
        circular_moves: write the CAD's arcs as circular moves (RAPID ``MoveC``, KRL ``CIRC``,
            URScript ``movec``) where the controller's circle passes its checks; the other
            formats, and every arc piece that fails, keep straight moves. On by default.
    """

    programs: tuple[str, ...] | None = None
    urscript_mode: str = "program"
    speed_levels: int = 5
    speed_share: float = 0.02
    moves_per_routine: int = 500
    air_speed_share: float = 0.2
    circular_moves: bool = True

    def __post_init__(self) -> None:
        for p in self.programs or ():
            one_of("output", "programs[]", p, PROGRAM_FORMATS)
        one_of("output", "urscript_mode", self.urscript_mode, URSCRIPT_MODES)
        integer_in("output", "speed_levels", self.speed_levels, 1, 100)
        in_range("output", "speed_share", self.speed_share, 1e-4, 0.5)
        integer_in("output", "moves_per_routine", self.moves_per_routine, 10, 100000)
        in_range("output", "air_speed_share", self.air_speed_share, 0.01, 1.0)
        if abs(self.air_speed_share * 100.0 - round(self.air_speed_share * 100.0)) > 1e-9:
            raise InputError(
                f"output.air_speed_share must be a whole percent (0.01 steps), got {self.air_speed_share!r}",
                key="output.air_speed_share",
                value=self.air_speed_share,
                expected="0.01, 0.02, ..., 1.0",
            )


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
        one_of(owner, "shape", self.shape, SHAPES)
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
                positive(owner, key, getattr(self, key))
                in_range(owner, key, getattr(self, key), 0.0, 100.0, "m")
        for v in self.size_m or ():
            positive(owner, "size_m[]", v)
            in_range(owner, "size_m[]", v, 0.0, 100.0, "m")
        one_of(owner, "units", self.units, ("m", "mm", "in"))


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
        in_range("collision", "margin_m", self.margin_m, 0.0, 1.0, "m")
        in_range("collision", "self_margin_m", self.self_margin_m, 0.0, 0.5, "m")
        in_range("collision", "check_step_m", self.check_step_m, MIN_CHECK_STEP_M, 0.1, "m")
        in_range("collision", "max_outer_iterations", self.max_outer_iterations, 1, 50)


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
            in_range("optimise", key, getattr(self, key), 0.0, 1e6)
        if self.mid_range_weight is not None:
            in_range("optimise", "mid_range_weight", self.mid_range_weight, 0.0, 1e6)
