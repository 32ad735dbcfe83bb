"""plush_opt: optimisation-centric control of tendon-driven plush robots.

The public API (docs/api.md)::

    import plush_opt
    p = plush_opt.load("problems/gripper.yaml")        # scene -> mesh -> model -> targets
    eq = p.equilibrium({"left": 10.0})                 # .x, .converged, .status
    result = p.control(method="reparam")               # a ControlResult
    result.contractions, result.objective, result.x
    result.save("r.json")                              # the spec's result file

Everything else lives in the modules named in docs/architecture.md.
"""

__version__ = "0.1.0"

from .control import (BilevelOptions, ControlIterate, ControlOptions, ControlResult,  # noqa: E402
                      ControlStats)
from .equilibrium import Equilibrium, EquilibriumOptions  # noqa: E402
from .errors import HardwareError, PlushError, SceneError, SolverError  # noqa: E402
from .problem import Problem, from_scene, load  # noqa: E402

__all__ = [
    "BilevelOptions", "ControlIterate", "ControlOptions", "ControlResult", "ControlStats",
    "Equilibrium", "EquilibriumOptions", "HardwareError", "PlushError", "Problem", "SceneError",
    "SolverError", "__version__", "from_scene", "load",
]
