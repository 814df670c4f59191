"""A design of several soft bodies (``[[bodies]]``) fabricated one body at a time.

Each body is cast in a mould of its own, around its own bones, with its own
cables: the design splits into one design per body (named
``<design>_<body>``), each planned and built as a one-body design into a
sub-folder ``<body>/`` of the output. A bone belongs to the body that holds
most of its volume (an OpenCASCADE intersection: bones lie strictly inside
one body, which the design checks already require); a cable to the body its
first point lies in or on (a cable never runs from one body into another).
Loads, grounds, tractions, markers and objects play no part in fabrication
and are left out; so are pins (a mould does not hold the body).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from .meshing import generate_surface_mesh, triangle_surface
from .surfaces import PROBE_CURVATURE, FabricationError, inside, point_triangle_distance

ON_BODY = 1e-6        # relative to the body's extent: a point this close to a body is on it


def split(design) -> list:
    """One design per body (the design itself if it has one body); raises FabricationError for a bone or a
    cable that no body holds."""
    if len(design.bodies) == 1:
        return [design]
    from ..runtime.interrupts import interruptible
    bones, cables = interruptible(_owners, design)            # Gmsh ignores signals: off the main thread
    out = []
    for b in design.bodies:
        out.append(replace(design, name=f"{design.name}_{b.name}", body=b, bodies=(b,),
                           bones=tuple(x for x in design.bones if bones[x.name] == b.name),
                           cables=tuple(c for c in design.cables if cables[c.name] == b.name),
                           pins=(), loads=(), grounds=(), tractions=(), markers={}, objects=()))
    return out


def _owners(design) -> tuple[dict, dict]:
    """({bone: body}, {cable: body}): bones by their OpenCASCADE volume in each body, cables by their first
    point against the bodies' triangulated surfaces."""
    from ..runtime.interrupts import import_gmsh
    gmsh = import_gmsh()

    from ..design.occ import gmsh_model
    from ..mesh.geometry import add_design_solids
    from .parts import cable_points
    with gmsh_model("skelfem-fabricate-bodies"):
        occ = gmsh.model.occ
        bodies = {b.name: add_design_solids(occ, replace(design, body=b, bodies=(b,)), bones=[])[0]
                  for b in design.bodies}
        _, bone_tags = add_design_solids(occ, design, design.fabrication.bone_depth or None, body=False)
        occ.synchronize()
        scale = max(float(np.ptp(np.reshape(occ.getBoundingBox(3, t), (2, 3)), axis=0).max())
                    for tags in bodies.values() for t in tags)
        bones = {}
        for name, tags in bone_tags.items():
            share = {}
            for body, btags in bodies.items():
                common, _ = occ.intersect(occ.copy([(3, t) for t in tags]), occ.copy([(3, t) for t in btags]))
                occ.synchronize()
                share[body] = sum(occ.getMass(*v) for v in common if v[0] == 3)
                occ.remove(common, recursive=True)
            best = max(share, key=share.get)
            if share[best] <= 0.0:
                raise FabricationError(f"bones.{name}", "lies in no body")
            bones[name] = best
        generate_surface_mesh(gmsh, scale / 8, PROBE_CURVATURE)
        surfaces = {body: triangle_surface(gmsh, btags) for body, btags in bodies.items()}
    cables = {}
    for cable in design.cables:
        p = cable_points(design, cable)[:1]
        near = {body: 0.0 if inside(p, s, ON_BODY * scale)[0] else float(point_triangle_distance(p, s.corners).min())
                for body, s in surfaces.items()}
        best = min(near, key=near.get)
        if near[best] > 0.05 * scale:           # the probe's triangles cut round surfaces' chords
            raise FabricationError(f"cables.{cable.name}.path", "its first point lies in no body")
        cables[cable.name] = best
    return bones, cables
