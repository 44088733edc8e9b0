"""refine: optimisation-based refinement of demonstrated robot paths.

The pipeline (one module per stage, see ``docs/design.md``)::

    demo/  parse, filter and smooth the tracker log
    cad/   read and resample the CAD/CAM path
    fuse   align the demonstration to the CAD path
    frames SE(3) helpers and every orientation convention
    robot  robot models (Pinocchio) and the registry of robots/
    optimise/  the joint-path NLP (CasADi; IPOPT, or fatrop stage by stage)
    timing TOPPRA time parameterisation
    export/    PathML, robot programs, trajectory CSV, result JSON

The library API (``docs/api.md``): :func:`load_problem`, :func:`solve`, :func:`refine_path`,
:class:`Result`, :class:`Robot`. They are imported on first use, so ``import refine`` stays light.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from refine.errors import InfeasibleError, InputError, RefineError, SolverError
from refine.lazy import lazy_names
from refine.version import __version__

if TYPE_CHECKING:
    from refine.api import PassArrays, Result, refine_path, solve
    from refine.problem import Problem, load_problem
    from refine.robot.model import Robot
    from refine.settings import CollisionSettings, Shape, Tolerances

_LAZY = {
    "load_problem": "refine.problem",
    "Problem": "refine.problem",
    "solve": "refine.api",
    "refine_path": "refine.api",
    "Result": "refine.api",
    "PassArrays": "refine.api",
    "Robot": "refine.robot.model",
    "Shape": "refine.settings",
    "Tolerances": "refine.settings",
    "CollisionSettings": "refine.settings",
}

__all__ = [
    "__version__",
    "CollisionSettings",
    "InfeasibleError",
    "InputError",
    "PassArrays",
    "Problem",
    "RefineError",
    "Result",
    "Robot",
    "Shape",
    "SolverError",
    "Tolerances",
    "load_problem",
    "refine_path",
    "solve",
]


__getattr__, __dir__ = lazy_names("refine", _LAZY, globals())  # the API's names, imported on first use
