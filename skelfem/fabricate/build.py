"""The build pass: each part in its own OCC model (cuts and fuses, in micrometres: micrometres.py), volume
measured, STL and STEP written and checked.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from .meshing import generate_surface_mesh, triangle_surface, write_file
from .micrometres import Z, MicrometreOCC, in_millimetres, largest_tolerance, scratch_file
from .orientation import PrintPose, best_pose, move_into_pose
from .parts import Frame, Plan, Tool
from .surfaces import CURVATURE, Surface, orient, signed_volume

# Triangles per turn of a curved face, tried in turn until a part's STL volume is within STL_VOLUME_TOLERANCE
# of its CAD volume (an inscribed polygon of n sides loses about (2 pi / n)^2 / 6 of a round part: 0.4 % at
# 40, 0.05 % at 120): flat parts and thin channels stay at CURVATURE, round bones and moulds get finer.
CURVATURES = (CURVATURE, 2 * CURVATURE, 3 * CURVATURE)
STL_VOLUME_TOLERANCE = 5e-4


# -- the build pass --------------------------------------------------------------------------------------------
@dataclass
class Part:
    """One printed part: its file stem, kind, oriented surface and exact (CAD) volume."""

    name: str
    kind: str                    # "bone" or "mould"
    surface: Surface             # in design coordinates (the exploded view); pose.apply for print ones
    cad_volume: float
    info: dict = field(default_factory=dict)
    pose: PrintPose | None = None    # how it lies on the print bed (STL and STEP are written so)
    step_tolerance: float | None = None   # mm: the largest tolerance of the STEP file's shape (if written)


def tool_shapes(occ, tool: Tool) -> list:
    """OCC solids of a tool: a cylinder per segment of its axis (the ends extended), a ball at each bend."""
    p = tool.points.copy()
    p[0], p[-1] = tool.ends()
    out = []
    for a, b in zip(p[:-1], p[1:]):
        out.append((3, occ.addCylinder(*a, *(b - a), tool.radius)))
    for x in tool.points[1:-1]:
        out.append((3, occ.addSphere(*x, tool.radius)))
    return out


def total_mass(occ, dimtags) -> float:
    occ.synchronize()
    return float(sum(occ.getMass(*v) for v in dimtags))


def _volumes(out) -> list[int]:
    return [t for d, t in out if d == 3]


def clean_solids(occ, out) -> list:
    """The volumes of a boolean's result without the empty slivers OpenCASCADE sometimes leaves
    (a solid of zero volume where a plane touches a sphere, say); those are removed from the model."""
    occ.synchronize()
    vols = [(3, t) for t in _volumes(out)]
    mass = np.array([occ.getMass(*v) for v in vols])
    empty = [v for v, m in zip(vols, mass) if m <= 1e-9 * max(mass.max(initial=0.0), 1.0)]
    if empty:
        occ.remove(empty, recursive=True)
    return [v for v in vols if v not in empty]


def cut_solids(occ, objects: list, tools: list) -> list:
    """The volumes of objects minus tools (clean_solids), the objects themselves when there is nothing to cut:
    OpenCASCADE refuses a boolean with an empty list of tools (a design without bones or cables)."""
    if not tools:
        return clean_solids(occ, list(objects))
    return clean_solids(occ, occ.cut(objects, tools)[0])


def write_step(gmsh, path: Path) -> None:
    """The current model as a STEP file (meshing.write_file: a full disk is the file's OSError)."""
    write_file(gmsh, path)


def _finish(gmsh, name: str, kind: str, volumes: list[int], plan: Plan, folder: Path | None, info: dict) -> Part:
    """Bring the part in the current model (built in micrometres) to millimetres, measure and triangulate it,
    choose how it lies on the print bed, and (if folder) write its STEP file so, with the largest tolerance
    of its shape."""
    occ = gmsh.model.occ
    with scratch_file(folder, f"{name}.brep") as scratch:
        volumes = in_millimetres(gmsh, scratch)          # the model holds the part alone: all of it
    if len(volumes) != 1:
        raise RuntimeError(f"{name}: the geometry kernel made {len(volumes)} solids instead of one")
    cad = float(occ.getMass(3, volumes[0]))
    for curvature in CURVATURES:             # round parts: finer until the STL's volume is the CAD volume's
        gmsh.model.mesh.clear()
        generate_surface_mesh(gmsh, plan.scale / 6, curvature)
        surface = triangle_surface(gmsh, volumes)
        surface.tris = orient(surface.points, surface.tris)
        if abs(signed_volume(surface.points, surface.tris) - cad) <= STL_VOLUME_TOLERANCE * cad:
            break
    pose = best_pose(surface.points, surface.tris)
    tolerance = None
    if folder is not None:
        move_into_pose(occ, [(3, volumes[0])], pose)
        occ.synchronize()
        write_step(gmsh, folder / f"{name}.step")
        tolerance = largest_tolerance(gmsh, folder / f".{name}.brep")
    return Part(name, kind, surface, cad, info, pose, tolerance)


def build_bone(plan: Plan, bone, folder: Path | None = None, pole_axis=Z) -> Part:
    """A bone with its sheaths (sheaths.py) minus its channels, anchor holes and sockets.

    The added and removed volumes are measured on their own (the sheaths'
    volume outside the bone; the OCC intersection of the fused cutting tools
    with an un-cut copy of the bone and its sheaths), so that the bone's
    volume can be checked against (un-cut volume) + (added) - (removed).
    pole_axis: where balls have their poles (micrometres.py).
    """
    from ..runtime.interrupts import import_gmsh
    gmsh = import_gmsh()

    from ..design.occ import gmsh_model
    from ..mesh.geometry import add_design_solids
    design = plan.design
    with gmsh_model(f"skelfem-fabricate-bone-{bone.name}"):
        occ = MicrometreOCC(gmsh.model.occ, pole_axis)
        _, tags = add_design_solids(occ, design, plan.spec.bone_depth or None, bones=[bone.name], body=False)
        solid = [(3, t) for t in tags[bone.name]]
        added = 0.0
        covers = [s for tool in plan.bone_tools[bone.name] if tool.kind == "sheath" for s in tool_shapes(occ, tool)]
        if covers:
            solid = clean_solids(occ, occ.fuse(solid, covers)[0])
            added = total_mass(occ, solid) - plan.bone_volumes[bone.name]
        tools = [s for tool in plan.bone_tools[bone.name] if tool.kind != "sheath" for s in tool_shapes(occ, tool)]
        removed = 0.0
        if tools:
            copies = occ.copy(tools)
            if len(copies) > 1:
                copies, _ = occ.fuse(copies[:1], copies[1:])
            common, _ = occ.intersect(occ.copy(solid), copies)
            occ.synchronize()
            removed = float(sum(occ.getMass(3, t) for t in _volumes(common)))
            occ.remove(common, recursive=True)
            solid = clean_solids(occ, occ.cut(solid, tools)[0])
        kinds = [t.kind for t in plan.bone_tools[bone.name]]
        info = {"uncut_volume": plan.bone_volumes[bone.name], "removed_volume": removed, "sheath_volume": added,
                "sheaths": kinds.count("sheath"),
                "channels": kinds.count("channel"), "anchor_holes": kinds.count("anchor"),
                "sockets": kinds.count("socket")}
        return _finish(gmsh, f"bone_{bone.name}", "bone", _volumes(solid), plan, folder, info)


def _block(occ, frame: Frame, n0: float, n1: float) -> tuple[int, float]:
    """The block's slab between n0 and n1 (frame coordinates) as an OCC box; (tag, volume).

    When the frame's axes are the coordinate axes (2D, and 3D planes normal
    to an axis) the box is made in place; otherwise it is made in frame
    coordinates and rotated rigidly (an affine map would turn its faces into
    general surfaces, which the boolean operations handle badly).
    """
    lo, hi = frame.lo.copy(), frame.hi.copy()
    lo[2], hi[2] = n0, n1
    M = frame.matrix
    if np.allclose(np.abs(M), np.round(np.abs(M)), atol=1e-12):
        corners = frame.world(np.array([lo, hi]))
        a, b = corners.min(axis=0), corners.max(axis=0)
        return occ.addBox(*a, *(b - a)), float(np.prod(hi - lo))
    from scipy.spatial.transform import Rotation
    tag = occ.addBox(*lo, *(hi - lo))
    rv = Rotation.from_matrix(M).as_rotvec()
    angle = float(np.linalg.norm(rv))
    if angle > 0:
        occ.rotate([(3, tag)], 0.0, 0.0, 0.0, *(rv / angle), angle)
    return tag, float(np.prod(hi - lo))


def build_half(plan: Plan, side: str, folder: Path | None = None, pole_axis=Z) -> Part:
    """One mould half: its slab of the block minus the body, with pins or pin holes, its pegs and guide
    posts, the tendon exits, the pry slots, the removable rods' holes, the clamp bolts' holes and (top) the
    pour hole and vents. pole_axis: where balls have their poles (micrometres.py)."""
    from ..runtime.interrupts import import_gmsh
    gmsh = import_gmsh()

    from ..design.occ import gmsh_model
    from ..mesh.geometry import add_design_solids
    f = plan.frame
    with gmsh_model(f"skelfem-fabricate-mould-{side}"):
        occ = MicrometreOCC(gmsh.model.occ, pole_axis)
        body, _ = add_design_solids(occ, plan.design, bones=[])
        n0, n1 = (f.lo[2], f.c) if side == "bottom" else (f.c, f.hi[2])
        box, block = _block(occ, f, n0, n1)
        half = clean_solids(occ, occ.cut([(3, box)], [(3, t) for t in body])[0])
        mass = [total_mass(occ, half)]                     # the slab minus the body
        adds = [t for t in plan.pegs + plan.posts if t.side == side] + [t for t in plan.mould_tools
                                                                         if t.kind == "pin" and side == "bottom"]
        if adds:
            half = clean_solids(occ, occ.fuse(half, [s for t in adds for s in tool_shapes(occ, t)])[0])
        mass.append(total_mass(occ, half))
        cuts = [t for t in plan.mould_tools
                if t.kind in ("exit", "pry", "rod_hole", "clamp")
                or (side == "top" and t.kind in ("pin_hole", "pour", "vent"))]
        half = cut_solids(occ, half, [s for t in cuts for s in tool_shapes(occ, t)])
        mass.append(total_mass(occ, half))
        info = {"block_volume": block, "pegs": sum(t.side == side for t in plan.pegs),
                "added_volume": mass[1] - mass[0], "cut_volume": mass[1] - mass[2]}
        return _finish(gmsh, f"mould_{side}", "mould", _volumes(half), plan, folder, info)


