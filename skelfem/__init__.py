"""skelfem: simulation and control of cable-driven soft robots with embedded skeletons.

The public surface is ``__all__``; everything else is internal and may change.
Importing skelfem changes no global state (no signal handlers, PETSc options,
matplotlib backend or environment variable): the command line
(``skelfem.cli``) does that for itself. Names that need DOLFINx or PETSc are
imported on first use (nothing at all is imported by ``import skelfem`` itself, so the
command line installs its signal handlers at once)::

    from skelfem import Session
    with Session("geometry/finger.toml") as s:
        r = s.solve()
        print(r.marker("tip"), r.tension("flexor"))
"""
__version__ = "0.1.0"

__all__ = [
    "Design", "DesignError", "load_design", "parse_design",        # design files
    "Session", "Result", "Status",                                  # solving
    "Linearization", "SoftIK", "IKResult", "track", "line_targets",  # control
    "optimize_schedules", "OptimizeResult",                         # trajectory optimisation
    "calibrate", "Calibration",                                     # fitting to measurements
    "Term", "Context", "BUILDERS",                                  # the energy-term contract
    "SolveError", "SessionError", "MeshingError", "FabricationError",   # failures beyond bad input
]

_LAZY = {
    "Design": "design", "DesignError": "design", "load_design": "design", "parse_design": "design",
    "Result": "result", "Status": "result",
    "Session": "session", "Linearization": "analysis.sensitivity", "SoftIK": "analysis.control",
    "IKResult": "analysis.control", "track": "analysis.control", "line_targets": "analysis.control",
    "optimize_schedules": "analysis.optimize", "OptimizeResult": "analysis.optimize",
    "calibrate": "analysis.calibrate", "Calibration": "analysis.calibrate",
    "Term": "terms", "Context": "terms", "BUILDERS": "terms", "SolveError": "fem.newton", "SessionError": "session",
    "MeshingError": "design.occ", "FabricationError": "fabricate",
}


def __getattr__(name):
    """The public names that import DOLFINx/PETSc, on first use."""
    if name in _LAZY:
        import importlib
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'skelfem' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
