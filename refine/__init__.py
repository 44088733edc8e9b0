"""refine: optimisation-based refinement of demonstrated robot paths.

The pipeline (one module per stage, see ``docs/design.md``)::

    demo/  parse, filter and smooth the tracker log
    cad/   read and resample the CAD/CAM path
    fuse   align the demonstration to the CAD path
    frames SE(3) helpers and every orientation convention
    robot  robot models (Pinocchio) and the registry of robots/
    optimise/  the joint-path NLP (CasADi + IPOPT)
    timing TOPPRA time parameterisation
    export/    PathML, robot programs, trajectory CSV, result JSON
"""

from refine.errors import InfeasibleError, InputError, RefineError, SolverError

__all__ = ["InfeasibleError", "InputError", "RefineError", "SolverError"]
__version__ = "0.1.0"
