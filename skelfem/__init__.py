"""skelfem: simulation and control of cable-driven soft robots with embedded skeletons."""

__version__ = "0.1.0"


def __getattr__(name):
    """``skelfem.Session`` without importing DOLFINx for ``import skelfem``."""
    if name in ("Session", "Result"):
        from . import session
        return getattr(session, name)
    raise AttributeError(name)
