"""plush_opt: optimisation-centric control of tendon-driven plush robots.

The public API (docs/api.md)::

    import plush_opt
    p = plush_opt.load("problems/gripper.yaml")        # scene -> mesh -> model -> targets
    eq = p.equilibrium({"left": 10.0})                 # .x, .converged, .status
    result = p.control(method="reparam")               # a ControlResult
    result.contractions, result.objective, result.x
    result.save("r.json")                              # the spec's result file
    q = p.with_targets([{"at": [78, 122], "to": [60, 100]}])   # the problem file's target format
    plush_opt.plot(p, result, "pose.png")              # the picture of `plush-opt solve --plot`
    plush_opt.export(p, result, "vtk")                 # pose.vtu (+ trace.pvd), as `solve --vtk`

Everything else lives in the modules named in docs/architecture.md.
"""

__version__ = "0.1.0"

# The names are imported on first use (PEP 562): importing a submodule, the
# command line's parser for one, stays free of numpy, CasADi and the solvers.
_API = {
    "BilevelOptions": "control", "ControlIterate": "control", "ControlOptions": "control",
    "ControlResult": "control", "ControlStats": "control",
    "Equilibrium": "solve.equilibrium", "EquilibriumOptions": "solve.equilibrium",
    "HardwareError": "base.errors", "PlushError": "base.errors", "SceneError": "base.errors",
    "SolverError": "base.errors",
    "Problem": "problem", "from_scene": "problem", "load": "problem",
    "plot": "apps.plot", "export": "apps.export",
}

__all__ = sorted(_API) + ["__version__"]


def __getattr__(name):
    if name in _API:
        import importlib
        value = getattr(importlib.import_module(f".{_API[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'plush_opt' has no attribute {name!r}")


def __dir__():
    return __all__
