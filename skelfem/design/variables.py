"""Design variables: the keys that name a number a 2D design can be moved by, read before meshing.

=================================  ==================================================================
``body.outline[i].x|y``            a body outline vertex (mm); ``bodies.NAME.outline[i]`` with [[bodies]]
``body.holes[k][i].x|y``           a hole vertex (mm); ``bodies.NAME.holes[k][i]``
``bones.B.outline[i].x|y``         a bone vertex (mm)
``bones.B.offset.x|y``             the bone's translation (mm, from where it is: starts at 0)
``bones.B.angle``                  the bone's rotation about its outline's area centroid (degrees,
                                   counter-clockwise, starts at 0)
``cables.C.path[i].x|y``           a cable's sketch vertex (mm)
``cables.C.stiffness``              a cable's spring constant k (N/mm)
``cables.C.pretension``             a ligament's pretension (mm: its rest length L0 - pretension)
``materials.M.E``                  a material's Young's modulus (MPa)
=================================  ==================================================================

``parse_variable`` resolves a key against a design (ValueError naming what is wrong);
``start_value`` is the variable's value in that design.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

_POINT = re.compile(r"^(?P<base>.+?)\[(?P<i>\d+)\]\.(?P<axis>[xy])$")
_HOLE = re.compile(r"^(?P<base>.+?)\.holes\[(?P<k>\d+)\]\[(?P<i>\d+)\]\.(?P<axis>[xy])$")

KINDS_TEXT = ("body.outline[i].x, body.holes[k][i].x, bones.B.outline[i].x, bones.B.offset.x, bones.B.angle, "
              "cables.C.path[i].x, cables.C.stiffness, cables.C.pretension, materials.M.E; .y likewise")
CABLE_PARAMETERS = ("stiffness", "pretension")


@dataclass(frozen=True)
class Variable:
    key: str
    kind: str              # "body", "hole", "bone_vertex", "offset", "angle", "path", "modulus", "stiffness",
    #                        "pretension"
    owner: str = ""        # body ("" for [body]), bone, cable or material name
    hole: int = -1         # "hole": which hole of the body
    index: int = -1        # vertex index
    axis: int = 0          # 0 x, 1 y


def _body(design, base: str):
    """The Body a key's base names ("body" or "bodies.NAME"), or None."""
    several = "bodies" in design.data
    if base == "body" and not several:
        return design.bodies[0]
    if several and base.startswith("bodies."):
        return next((b for b in design.bodies if b.name == base[len("bodies."):]), None)
    return None


def parse_variable(design, key) -> Variable:
    """The variable a key names in a 2D design; ValueError that names the problem."""
    if not isinstance(key, str) or not key:
        raise ValueError(f"{key!r}: a design variable is a dotted key ({KINDS_TEXT})")
    if design.dim != 2:
        raise ValueError(f"{key}: design variables are 2D")
    parts = key.split(".")
    if len(parts) == 3 and parts[0] == "materials" and parts[2] == "E":
        if parts[1] not in design.materials:
            raise ValueError(f"{key}: no material {parts[1]!r}")
        return Variable(key, "modulus", owner=parts[1])
    if len(parts) == 3 and parts[0] == "cables" and parts[2] in CABLE_PARAMETERS:
        cable = next((c for c in design.cables if c.name == parts[1]), None)
        if cable is None:
            raise ValueError(f"{key}: no cable {parts[1]!r}")
        if cable.friction > 0.0 or getattr(cable, "friction_by_material", ()):
            raise ValueError(f"{key}: design gradients do not cover cable friction")
        if parts[2] == "pretension" and cable.kind != "ligament":
            raise ValueError(f"{key}: a tendon has no pretension (its contraction is a load: set it per target)")
        return Variable(key, parts[2], owner=parts[1])
    bones = {b.name: b for b in design.bones}
    if len(parts) in (3, 4) and parts[0] == "bones" and parts[2] in ("offset", "angle"):
        if parts[1] not in bones:
            raise ValueError(f"{key}: no bone {parts[1]!r}")
        if parts[2] == "angle" and len(parts) == 3:
            return Variable(key, "angle", owner=parts[1])
        if parts[2] == "offset" and len(parts) == 4 and parts[3] in ("x", "y"):
            return Variable(key, "offset", owner=parts[1], axis="xy".index(parts[3]))
        raise ValueError(f"{key}: a bone's pose is bones.B.offset.x, bones.B.offset.y or bones.B.angle")
    hole = _HOLE.match(key)
    if hole:
        body = _body(design, hole["base"])
        k, i = int(hole["k"]), int(hole["i"])
        if body is None:
            raise ValueError(f"{key}: no body {hole['base']!r}")
        if k >= len(body.holes) or i >= len(body.holes[k]):
            raise ValueError(f"{key}: no such vertex (index out of range)")
        return Variable(key, "hole", owner=body.name or "", hole=k, index=i, axis="xy".index(hole["axis"]))
    m = _POINT.match(key)
    if m:
        base, i, axis = m["base"], int(m["i"]), "xy".index(m["axis"])
        if base.endswith(".outline"):
            owner = base[:-len(".outline")]
            body = _body(design, owner)
            if body is not None:
                if i >= len(body.outline):
                    raise ValueError(f"{key}: no such vertex (index out of range)")
                return Variable(key, "body", owner=body.name or "", index=i, axis=axis)
            if owner.startswith("bones.") and owner[len("bones."):] in bones:
                if i >= len(bones[owner[len("bones."):]].outline):
                    raise ValueError(f"{key}: no such vertex (index out of range)")
                return Variable(key, "bone_vertex", owner=owner[len("bones."):], index=i, axis=axis)
        if base.startswith("cables.") and base.endswith(".path"):
            name = base[len("cables."):-len(".path")]
            cables = {c.name: c for c in design.cables}
            if name not in cables:
                raise ValueError(f"{key}: no cable {name!r}")
            if i >= len(cables[name].path):
                raise ValueError(f"{key}: no such vertex (index out of range)")
            return Variable(key, "path", owner=name, index=i, axis=axis)
    raise ValueError(f"{key}: not a design variable ({KINDS_TEXT})")


def start_value(design, v: Variable) -> float:
    """The variable's value in design (0 for a bone's offset and angle)."""
    if v.kind in ("offset", "angle"):
        return 0.0
    if v.kind == "modulus":
        return float(design.materials[v.owner].E)
    if v.kind in CABLE_PARAMETERS:
        return float(getattr(design.cable(v.owner), v.kind))
    if v.kind == "path":
        return float(design.cable(v.owner).path[v.index][v.axis])
    if v.kind == "bone_vertex":
        return float(next(b for b in design.bones if b.name == v.owner).outline[v.index][v.axis])
    body = next(b for b in design.bodies if (b.name or "") == v.owner)
    poly = body.outline if v.kind == "body" else body.holes[v.hole]
    return float(poly[v.index][v.axis])
