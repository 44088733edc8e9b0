"""refine: optimisation-based refinement of demonstrated robot paths.

The package is built in floors, each importing only from the ones below (``docs/design.md``)::

    base         errors, frames (SE(3), every angle convention), paths (the data between
                 stages), settings/ (the problem file's tables)
    robot/       spec, URDF reading, Robot, the registry, numeric kinematics and IK
    inputs       problem, cad/ (CAD/CAM readers), demo/ (tracker readers), collision/ (FCL),
                 timing (TOPPRA)
    fuse/        the demonstration aligned to the CAD path; the tracker-frame check
    optimise/    every optimisation problem: the refinement NLP, its solve and repair, the
                 verifier, the diagnosis, the placement search (CasADi; IPOPT or fatrop)
    outputs      export/ (PathML, programs, trajectory CSV, result JSON), report/
    application  run/ (a problem from file to outputs), calibrate/, bench/
    interfaces   api, cli

The library API (``docs/api.md``): :func:`load_problem`, :func:`solve`, :func:`refine_path`,
:class:`Result`, :class:`Robot`. They are imported on first use, so ``import refine`` stays light.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from refine.errors import ArgumentError, Cancelled, InputError, NotExecutable, RefineError, SolverError
from refine.lazy import lazy_names
from refine.version import __version__

if TYPE_CHECKING:
    from refine.api import PassArrays, Result, load_problem, refine_path, solve
    from refine.control import Progress
    from refine.problem import Problem
    from refine.robot.model import Robot
    from refine.run.typed import Diagnosis, DiagnosisCause, Metrics
    from refine.settings import CollisionSettings, Shape, Tolerances

_LAZY = {
    "load_problem": "refine.api",
    "Problem": "refine.problem",
    "solve": "refine.api",
    "refine_path": "refine.api",
    "Result": "refine.api",
    "PassArrays": "refine.api",
    "Robot": "refine.robot.model",
    "Shape": "refine.settings",
    "Tolerances": "refine.settings",
    "CollisionSettings": "refine.settings",
    "Progress": "refine.control",
    "Metrics": "refine.run.typed",
    "Diagnosis": "refine.run.typed",
    "DiagnosisCause": "refine.run.typed",
}

__all__ = [
    "__version__",
    "ArgumentError",
    "Cancelled",
    "CollisionSettings",
    "Diagnosis",
    "DiagnosisCause",
    "InputError",
    "Metrics",
    "NotExecutable",
    "PassArrays",
    "Problem",
    "Progress",
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


logging.getLogger("refine").addHandler(logging.NullHandler())  # a library logs only where the host says

__getattr__, __dir__ = lazy_names("refine", _LAZY, globals())  # the API's names, imported on first use
