"""The settings of a problem file, one frozen, self-checking dataclass per table.

``refine.problem`` reads ``problem.toml`` into these; every key is documented in
``docs/problem-file.md``. Each ``__post_init__`` rejects a bad value with a message naming the table,
the key, the value and what is allowed. The tables live in the modules of this package
(:mod:`~refine.settings.limits`: the limits and checks every table shares; :mod:`~refine.settings.inputs`:
robot, tool, frames, CAD and demonstration; :mod:`~refine.settings.process`: tolerances, process,
output, cell and optimiser; :mod:`~refine.settings.repair`: repair, placement, multi-pass and the
expected outcome; :mod:`~refine.settings.calibration`: the frames' uncertainties); import them from here.
"""

from refine.settings.calibration import (  # noqa: F401
    FRAMES,
    CalibrationSettings,
    FrameUncertainty,
    calibration_settings,
)
from refine.settings.inputs import (  # noqa: F401
    CadSettings,
    DemoSettings,
    FrameSettings,
    RobotSettings,
    ToolSettings,
)
from refine.settings.limits import (  # noqa: F401
    CAD_FORMATS,
    CAUSES,
    DEMO_FORMATS,
    MAX_CHECK_STEPS,
    MAX_HAMPEL_WINDOW,
    MAX_SMOOTHING_S,
    MAX_WAYPOINTS,
    MIN_CHECK_STEP_M,
    MIN_CHORD_TOLERANCE_M,
    MIN_ORIENTATION_DEG,
    MIN_SPACING_M,
    PROGRAM_FORMATS,
    SHAPES,
    SOLVERS,
    URSCRIPT_MODES,
    check_solver,
    check_waypoint_count,
    in_range,
    integer_in,
    non_negative,
    one_of,
    positive,
)
from refine.settings.process import (  # noqa: F401
    CollisionSettings,
    OptimiseSettings,
    OutputSettings,
    ProcessParameter,
    ProcessSettings,
    Shape,
    Tolerances,
)
from refine.settings.repair import (  # noqa: F401
    MAX_PLACEMENT_ROTATE_DEG,
    MAX_PLACEMENT_TRANSLATE_M,
    PLACEMENT_FREEDOMS,
    ExpectedOutcome,
    MultipassSettings,
    PlacementSettings,
    RepairSettings,
)


def _checked_constructors() -> None:
    """Every table's constructor refuses an unknown field as a ``refine.errors.ArgumentError``."""
    import dataclasses

    from refine.errors import checked_call

    for value in list(globals().values()):
        if (
            isinstance(value, type)
            and dataclasses.is_dataclass(value)
            and value.__module__.startswith(__name__)
        ):
            value.__init__ = checked_call(value.__init__)  # type: ignore[method-assign]


_checked_constructors()
