"""skelfem: simulation and control of cable-driven soft robots with embedded skeletons."""

__version__ = "0.1.0"
