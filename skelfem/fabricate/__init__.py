"""skelfem fabricate: printable bones and a two-part mould from a design.

``plan`` finds every problem on triangulations before anything is written
(``surfaces``: triangle surfaces, rays, STL; ``meshing``: Gmsh surfaces;
``plan``: the plan), ``build`` makes each part with OpenCASCADE, ``picture``
draws the exploded view and ``files`` writes a checked folder; ``multimaterial``
writes the whole robot as one multi-material 3MF instead (``write_print``); ``bodies``
splits a design of several soft bodies into one design per body (``split_bodies``).
"""
from .bodies import split as split_bodies
from .files import build, write
from .multimaterial import check_print, write as write_print
from .parts import Plan
from .plan import plan
from .surfaces import FabricationError, check_mesh, orient, read_stl, write_stl

__all__ = ["FabricationError", "Plan", "build", "check_print", "check_mesh", "orient", "plan", "read_stl",
           "split_bodies", "write", "write_print", "write_stl"]
