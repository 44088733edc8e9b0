"""Benchmark suites: named lists of problems, read from a TOML data file.

A suite names bundled problem folders (``problems``) and generated path families (``generated``,
built at each of ``sizes`` waypoints). A generated family is a horizontal sine wave
(:func:`refine.synthetic.wave_path`) in front of a robot with the tool pointing down, optionally
with boxes beside the path that are checked for clearance like a cell. Every problem becomes a
:class:`BenchProblem`: everything a contender needs and the verification all contenders share.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from refine.errors import InputError
from refine.paths import FusedPath
from refine.settings import Tolerances
from refine.types import Array

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_SUITES = ROOT / "benchmarks" / "suites.toml"
"""The suites file of the repository."""


@dataclass
class BenchProblem:
    """One benchmark problem, as every contender sees it.

    Attributes:
        suite: the suite it came from.
        name: unique name in the suite, e.g. ``glass_adhesive`` or ``irb4600_obstacles-1600``.
        robot: the loaded robot.
        fused: CAD points with demonstrated orientations.
        base_in_world: T_F_R (4, 4).
        tcp_in_flange: T_flange_TCP (4, 4).
        tolerances: the problem's tolerances.
        axisymmetric: only the tool axis is constrained.
        home: preferred first configuration [rad], or None.
        sources: constraint sources (clearance) for refine and for the verification.
        repair_max_slack_deg: the problem's repair setting (None: no repair).
        max_rounds: outer rounds of the refinement.
        weights: refine's cost weights for the problem.
        expected: for the unreachable family, the outcome the problem states (else empty).
        expected_s_range_m: the arc-length range [m] the problem states its infeasibility or repair
            to be in (``[expected] s_range_m``), or None.
        solver_options: solver options of the run (``refine bench run --solver-option``), keyed with
            the solver's prefix (``ipopt.max_iter``, ``fatrop.tol``); a contender uses those of its
            solver and records what it used (:attr:`refine.bench.contenders.Answer.solver_options`).
        tool_in_world: T_F_TCP of a stationary tool (the robot holds the part; ``tcp_in_flange``
            then places the part's frame on the flange and the path is in the part's frame), or
            None (see :class:`refine.robot.kinematics.TcpKinematics`).
        time_limit_s: wall time one run of a contender may take [s] (``refine bench run
            --time-limit``); refine's contenders stop their solve at it themselves (status
            ``timeout``), the runner's watchdog stops any other (:mod:`refine.bench.watchdog`).
    """

    suite: str
    name: str
    robot: Any
    fused: FusedPath
    base_in_world: Array
    tcp_in_flange: Array
    tolerances: Tolerances
    axisymmetric: bool
    home: Array | None = None
    sources: tuple = ()
    repair_max_slack_deg: float | None = None
    max_rounds: int = 8
    weights: Any = None
    expected: str = ""
    expected_s_range_m: tuple[float, float] | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    tool_in_world: Array | None = None
    solver_options: dict[str, Any] = field(default_factory=dict)
    time_limit_s: float | None = None

    @property
    def n_waypoints(self) -> int:
        """Number of waypoints."""
        return len(self.fused)

    def refinement(self, derivative_mode: str = "assembled", solver: str = "ipopt", **options: Any) -> Any:
        """The refinement NLP of this problem, built as the pipeline builds it, for ``solver``.

        No joint-step rows at first: the solve adds those near their bound, as in ``refine run``.
        ``options``: other arguments of :func:`refine.optimise.problem.build_refinement` (an active
        set, ``joint_steps``, ``elastic_deg``, ...), which replace the pipeline's.
        """
        from refine.optimise.problem import build_refinement

        return build_refinement(
            self.robot,
            self.fused,
            self.base_in_world,
            self.tcp_in_flange,
            self.tolerances,
            axisymmetric=self.axisymmetric,
            weights=self.weights,
            derivative_mode=derivative_mode,
            solver=solver,
            tool_in_world=self.tool_in_world,
            **{"joint_steps": (), **options},
        )


def load_suites(path: Path = DEFAULT_SUITES) -> dict[str, Any]:
    """The parsed suites file, checked for the keys the runner uses."""
    try:
        data = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise InputError(f"suites file {path}: {e}") from e
    unknown = set(data) - set(TOP_KEYS)
    if unknown:
        raise InputError(
            f"suites file {path}: unknown table(s) {sorted(unknown)}; the tables are {', '.join(TOP_KEYS)}"
        )
    suites, generated = data.get("suite", {}), data.get("generated", {})
    for name, suite in suites.items():
        unknown = set(suite) - {"problems", "generated", "sizes", "tesseract"}
        if unknown:
            raise InputError(f"suites file {path}: [suite.{name}] has unknown keys {sorted(unknown)}")
        for family in suite.get("generated", []):
            if family not in generated:
                raise InputError(
                    f"suites file {path}: [suite.{name}] names [generated.{family}], not defined"
                )
        if suite.get("generated") and not suite.get("sizes"):
            raise InputError(f"suites file {path}: [suite.{name}] has generated paths but no sizes")
    for name, family in generated.items():
        check_family(f"suites file {path}: [generated.{name}]", family)
    for name, spec in data.get("instances", {}).items():
        unknown = set(spec) - {"problems"}
        if unknown or not isinstance(spec.get("problems"), list):
            raise InputError(
                f"suites file {path}: [instances.{name}] takes one key, problems (a list of SUITE/NAME or "
                f"problem folders); it has {sorted(spec)}"
            )
    return data


FAMILY_KEYS: dict[str, Any] = {
    "robot": None,
    "centre_m": None,
    "shape": "wave",
    "length_m": 1.0,
    "width_m": 0.3,
    "corner_radius_m": 0.05,
    "tool_length_m": 0.3,
    "amplitude_m": 0.05,
    "wavelength_m": 0.5,
    "tilt_deg": 12.0,
    "speed_m_s": 0.1,
    "noise_deg": 0.0,
    "noise_seed": 0,
    "boxes": [],
}
"""The keys of a ``[generated.NAME]`` family and their defaults (None: required); docs/bench.md
says what each means."""

SHAPES = ("wave", "loop")
"""The shapes of a generated family: a sine wave (:func:`refine.synthetic.wave_path`) or a closed
rounded rectangle (:func:`loop_path`)."""

BOX_KEYS = ("name", "centre_m", "size_m")
"""The keys of one of a family's ``boxes``."""


def check_family(where: str, family: dict[str, Any]) -> None:
    """Raise :class:`InputError` for a family with an unknown or missing key, naming it and the allowed ones."""
    unknown = sorted(set(family) - set(FAMILY_KEYS))
    if unknown:
        raise InputError(
            f"{where}: unknown key(s) {unknown}; the keys are {', '.join(FAMILY_KEYS)}",
            key=unknown[0],
            value=family[unknown[0]],
            expected=", ".join(FAMILY_KEYS),
        )
    missing = [k for k, v in FAMILY_KEYS.items() if v is None and k not in family]
    if missing:
        raise InputError(f"{where}: {', '.join(missing)} missing (required: robot, centre_m)", key=missing[0])
    for k, box in enumerate(family.get("boxes", [])):
        if not isinstance(box, dict) or set(box) != set(BOX_KEYS):
            raise InputError(
                f"{where}: boxes[{k}] has keys {sorted(box) if isinstance(box, dict) else box!r}; "
                f"a box has exactly {', '.join(BOX_KEYS)}",
                key=f"boxes[{k}]",
                expected=", ".join(BOX_KEYS),
            )
    if family.get("shape", "wave") not in SHAPES:
        raise InputError(
            f"{where}: shape = {family['shape']!r}; the shapes are {', '.join(SHAPES)}",
            key="shape",
            value=family["shape"],
            expected=", ".join(SHAPES),
        )
    if family.get("shape") == "loop":
        r = family.get("corner_radius_m", FAMILY_KEYS["corner_radius_m"])
        for key in ("length_m", "width_m"):
            if not family.get(key, FAMILY_KEYS[key]) > 2 * r:
                raise InputError(
                    f"{where}: a loop's {key} must exceed twice corner_radius_m ({2 * r:g} m)", key=key
                )
    numbers = [k for k, v in FAMILY_KEYS.items() if isinstance(v, float)] + ["noise_seed"]
    for key in numbers:
        value = family.get(key, FAMILY_KEYS[key])
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise InputError(f"{where}: {key} = {value!r} is not a number", key=key, value=value)
        positive = ("length_m", "tool_length_m", "wavelength_m", "speed_m_s", "width_m", "corner_radius_m")
        if value < 0 or (value == 0 and key in positive):
            raise InputError(
                f"{where}: {key} = {value!r} must be > 0 (>= 0 for amplitude, tilt, noise)",
                key=key,
                value=value,
            )


TOP_KEYS = ("suite", "generated", "instances")
"""The tables of a suites file: suites, generated families, and test sets of exported instances."""


def problems(data: dict[str, Any], suite: str, *, root: Path = ROOT) -> Iterator[BenchProblem]:
    """The problems of ``suite``, built one at a time (large paths cost memory)."""
    if suite not in data.get("suite", {}):
        raise InputError(f"no suite {suite!r}; suites: {', '.join(sorted(data.get('suite', {})))}")
    spec = data["suite"][suite]
    for folder in spec.get("problems", []):
        yield bundled_problem(suite, root / folder)
    for name in spec.get("tesseract", []):
        if name != "puzzle_piece":
            raise InputError(f"[suite.{suite}] tesseract = {name!r}: the one known is 'puzzle_piece'")
        yield tesseract_puzzle(suite, root.parent / "shared" / "peers" / "tesseract_support")
    for family in spec.get("generated", []):
        for n in spec["sizes"]:
            yield generated_problem(suite, family, data["generated"][family], int(n))


def bundled_problem(suite: str, folder: Path) -> BenchProblem:
    """A problem folder as the pipeline would refine it (its first pass)."""
    from refine.problem import load_problem
    from refine.robot.registry import load_robot
    from refine.run.stages import constraint_sources, fused_path, weights_for

    problem = load_problem(folder)
    robot = load_robot(problem.robot.model)
    toml_file = folder / "problem.toml" if folder.is_dir() else folder
    stated = tomllib.loads(toml_file.read_text()).get("expected", {})
    expected = str(stated.get("status", ""))
    s_range = stated.get("s_range_m")
    return BenchProblem(
        suite=suite,
        name=problem.name,
        robot=robot,
        fused=fused_path(problem),
        base_in_world=problem.robot.base_in_world,
        tcp_in_flange=problem.tool.tcp_in_flange,
        tool_in_world=problem.tool.tcp_in_world,
        tolerances=problem.tolerances,
        axisymmetric=problem.tool.axisymmetric,
        home=None if problem.robot.home_deg is None else np.radians(problem.robot.home_deg),
        sources=constraint_sources(problem, robot),
        repair_max_slack_deg=problem.repair.max_slack_deg if problem.repair.enabled else None,
        max_rounds=problem.collision.max_outer_iterations,
        weights=weights_for(problem, robot),
        expected=expected,
        expected_s_range_m=None if s_range is None else (float(s_range[0]), float(s_range[1])),
    )


def generated_problem(suite: str, family: str, spec: dict[str, Any], n: int) -> BenchProblem:
    """The family's path of ``n`` waypoints (a sine wave or a loop) in front of its robot, with its boxes if any.

    The cost weights are the ones ``refine run`` gives the robot: the defaults, with the mid-range
    cost of :data:`refine.run.stages.REDUNDANT_MID_RANGE_WEIGHT` for an arm of more than six joints.
    """
    from refine.collision import CollisionModel
    from refine.frames import make_transform
    from refine.optimise.clearance import ClearanceSource
    from refine.optimise.problem import Weights
    from refine.robot.kinematics import TcpKinematics
    from refine.robot.registry import load_robot
    from refine.run.stages import REDUNDANT_MID_RANGE_WEIGHT
    from refine.settings import CollisionSettings, Shape
    from refine.synthetic import wave_path

    check_family(f"[generated.{family}]", spec)
    value = {**FAMILY_KEYS, **spec}
    robot = load_robot(spec["robot"])
    tool = float(value["tool_length_m"])
    tcp = make_transform(p=[0.0, 0.0, tool])
    common = {"centre": tuple(spec["centre_m"]), "length_m": float(value["length_m"])}
    common |= {"tilt_deg": float(value["tilt_deg"]), "speed_m_s": float(value["speed_m_s"])}
    if value["shape"] == "loop":
        loop = {"width_m": float(value["width_m"]), "corner_radius_m": float(value["corner_radius_m"])}
        fused = loop_path(n, **common, **loop)
    else:
        wave = {"amplitude_m": float(value["amplitude_m"]), "wavelength_m": float(value["wavelength_m"])}
        fused = wave_path(n, **common, **wave)
    if value["noise_deg"] > 0:
        fused = with_orientation_noise(fused, float(value["noise_deg"]), int(value["noise_seed"]))
    sources: tuple = ()
    boxes = spec.get("boxes", [])
    if boxes:
        settings = CollisionSettings()
        nozzle = Shape(
            "nozzle",
            "cylinder",
            pose=make_transform(p=[0.0, 0.0, 0.5 * (tool - 0.02)]),
            radius_m=0.02,
            length_m=tool - 0.02,
        )
        cell = tuple(
            Shape(b["name"], "box", pose=make_transform(p=b["centre_m"]), size_m=tuple(b["size_m"]))
            for b in boxes
        )
        model = CollisionModel(
            robot,
            np.eye(4),
            tcp,
            (nozzle,),
            cell,
            margin_m=settings.margin_m,
            self_margin_m=settings.self_margin_m,
        )
        sources = (ClearanceSource(model, TcpKinematics(robot, np.eye(4), tcp), settings.check_step_m),)
    return BenchProblem(
        suite=suite,
        name=f"{family}-{n}",
        robot=robot,
        fused=fused,
        base_in_world=np.eye(4),
        tcp_in_flange=tcp,
        tolerances=Tolerances(),
        axisymmetric=False,
        sources=sources,
        repair_max_slack_deg=None,
        weights=Weights(mid_range=REDUNDANT_MID_RANGE_WEIGHT if robot.nq > 6 else 0.0),
        extra={
            "family": family,
            "length_m": float(value["length_m"]),
            "obstacles": bool(boxes),
            "noise_deg": float(value["noise_deg"]),
        },
    )


def loop_path(
    n: int,
    *,
    length_m: float,
    width_m: float,
    corner_radius_m: float,
    centre: tuple[float, float, float],
    tilt_deg: float,
    speed_m_s: float,
) -> FusedPath:
    """A closed horizontal rounded rectangle of ``n`` waypoints, the tool down and dragged along it.

    ``width_m`` along world x, ``length_m`` along y, quarter-circle corners of ``corner_radius_m``
    (:func:`refine.synthetic.rounded_rectangle`), counter-clockwise from the middle of the edge
    nearer the robot, at equal arc length; the tool's z axis points down, leaned back against the
    travel by ``tilt_deg``, its x axis along the travel (:func:`refine.synthetic.tool_rotations`).
    The tool turns once about the vertical over the lap.
    """
    from refine.synthetic import rounded_rectangle, tool_rotations

    a, b, da, db, _, perimeter = rounded_rectangle(0.5 * length_m, 0.5 * width_m, corner_radius_m, n)
    # the footprint turned by -90 deg: (a, b) -> (x, y) = (b, -a), so the lap starts in the middle
    # of the edge nearer the robot and runs counter-clockwise seen from above
    positions = np.column_stack([centre[0] + b, centre[1] - a, np.full(n, centre[2])])
    tangents = np.column_stack([db, -da, np.zeros(n)])
    up = np.tile([0.0, 0.0, 1.0], (n, 1))
    s = np.arange(n) * perimeter / n
    speed = np.full(n, speed_m_s)
    return FusedPath(
        s=s,
        positions=positions,
        rotations=tool_rotations(tangents, up, np.full(n, math.radians(tilt_deg))),
        speed=speed,
        t_demo=s / speed_m_s,
        residual=np.zeros(n),
    )


def with_orientation_noise(fused: FusedPath, noise_deg: float, seed: int) -> FusedPath:
    """``fused`` with each demonstrated orientation turned by a random rotation, as a hand's jitter.

    Each waypoint's rotation vector has three independent normal components of standard deviation
    ``noise_deg`` [deg] (in the tool frame), drawn from ``numpy.random.default_rng(seed)``, so a
    family's paths are the same in every run; the CAD points stay exact.
    """
    from dataclasses import replace

    from refine.frames import matrix_from_rotvec

    rng = np.random.default_rng(seed)
    turns = matrix_from_rotvec(np.radians(rng.normal(0.0, noise_deg, size=(len(fused), 3))))
    return replace(fused, rotations=fused.rotations @ turns)


PUZZLE_SPACING_M = 0.0025
"""Waypoint spacing of the puzzle piece's toolpath [m] (its points are about 2.5 mm apart)."""

PUZZLE_SPEED_M_S = 0.02
"""The puzzle piece's grinding speed [m/s] (the example states none)."""


def tesseract_puzzle(suite: str, support: Path) -> BenchProblem:
    """Tesseract's puzzle piece as Tesseract poses it: the iiwa holds the part, the grinder stands in the world.

    From the example's files in ``support`` (``tesseract_support``): the workcell URDF read with
    its arm's chain (``base_link`` to ``tool0``, the grinder's two joints locked at zero), the part's
    frame on the flange (``tcp_in_flange`` = T_tool0_part), the grinder's TCP (``grinder_frame``)
    as a stationary tool, and the toolpath (positions and tool axes in the part's frame) with the
    spin about the tool axis free. The URDF's ``package://`` mesh paths are written out absolute
    into a copy beside a temporary folder. No clearance is checked: refine's URDF reader takes each
    link's convex hull, and the concave part's hull reaches into the grinder at the grinding point;
    the contenders are told so and check none either. refine's cost weights are those ``refine run``
    gives a redundant arm: the defaults with the mid-range cost of
    :data:`refine.run.stages.REDUNDANT_MID_RANGE_WEIGHT`.
    """
    import tempfile

    from refine.cad.toolpath import fused_from_toolpath
    from refine.optimise.problem import Weights
    from refine.robot.model import robot_from_urdf
    from refine.run.stages import REDUNDANT_MID_RANGE_WEIGHT

    urdf = support / "urdf" / "puzzle_piece_workcell.urdf"
    if not urdf.is_file():
        raise InputError(
            f"the puzzle piece's files are not at {support} (tesseract_support of Tesseract's example)"
        )
    folder = Path(tempfile.mkdtemp(prefix="refine-puzzle-"))
    text = urdf.read_text().replace("package://tesseract_support/", f"{support.resolve()}/")
    (folder / urdf.name).write_text(text)
    robot = robot_from_urdf(
        folder / urdf.name,
        controller="kuka",
        flange_frame="tool0",
        base_link="base_link",
        locked_joints_deg={"joint_aux1": 0.0, "joint_aux2": 0.0},
    )
    model = robot.model
    data = model.createData()
    import pinocchio as pin

    pin.framesForwardKinematics(model, data, pin.neutral(model))
    T_base = {
        name: data.oMf[model.getFrameId(name)].homogeneous for name in ("tool0", "part", "grinder_frame")
    }
    base_in_world = np.eye(4)
    base_in_world[2, 3] = 0.5  # world -> table -> base_link
    fused = fused_from_toolpath(
        support / "urdf" / "puzzle_bent.csv", "mm", PUZZLE_SPACING_M, PUZZLE_SPEED_M_S, np.eye(4)
    )
    return BenchProblem(
        suite=suite,
        name="puzzle_piece_tesseract",
        robot=robot,
        fused=fused,
        base_in_world=base_in_world,
        tcp_in_flange=np.linalg.inv(T_base["tool0"]) @ T_base["part"],
        tolerances=Tolerances(),
        axisymmetric=True,
        weights=Weights(mid_range=REDUNDANT_MID_RANGE_WEIGHT if robot.nq > 6 else 0.0),
        tool_in_world=base_in_world @ T_base["grinder_frame"],
        extra={
            "tesseract_files": {
                "urdf": folder / urdf.name,
                "srdf": support / "urdf" / "puzzle_piece_workcell.srdf",
                "tcp_frame": "grinder_frame",
                "working_frame": "part",
                "tip_link": "part",
            }
        },
    )


def describe(data: dict[str, Any]) -> list[str]:
    """One line per suite (its problems and generated families), then one per test set of exported instances."""
    lines = []
    for name, suite in sorted(data.get("suite", {}).items()):
        count = len(suite.get("problems", [])) + len(suite.get("generated", [])) * len(suite.get("sizes", []))
        parts = [f"{len(suite.get('problems', []))} problem folder(s)"]
        if suite.get("generated"):
            sizes = suite["sizes"]
            parts.append(
                f"{len(suite['generated'])} generated famil{'y' if len(suite['generated']) == 1 else 'ies'} "
                f"at {sizes[0]}-{sizes[-1]} waypoints"
            )
        lines.append(f"{name:12s} {count:3d} problems: {', '.join(parts)}")
    for name, spec in sorted(data.get("instances", {}).items()):
        lines.append(f"{name:12s} {len(spec['problems']):3d} exported instances (bench export --set {name})")
    return lines


def growth_exponent(n: Array, t: Array) -> float:
    """Slope of log t against log n (least squares): 1 for time linear in n."""
    n, t = np.asarray(n, float), np.asarray(t, float)
    ok = (n > 0) & (t > 0)
    if ok.sum() < 2:
        return math.nan
    return float(np.polyfit(np.log(n[ok]), np.log(t[ok]), 1)[0])
