"""Single-process printing: the whole robot, body and bones, as one multi-material 3MF.

The paper casts a silicone body around printed bones; a printer with several
extruders can instead print both at once, a flexible filament (TPU) for the
body and a rigid one (PLA) for the bones. The printed robot is

- **the body**: the design's body minus every bone minus the cable channels;
- **each bone**: the bone minus the cable channels;
- **the cable channels**, open for threading after printing: along each
  cable's whole path (``channel_diameter`` for tendons, ``anchor_diameter``
  for ligaments); a tendon's spool end runs on straight out of the body (the
  casting mould's exit), and every cable end that lies in a bone gets a hole
  straight up through bone and body, where the maker knots or glues the
  cable's end.

The parts are exact complements: the volume of the body with its channels
open equals that of the printed body plus the printed bones (no overlap, no
gap), checked to 1e-5 (a gap or an overlap is at least a piece of a channel, 1e-4
of the body or more).
Every part lies in one print pose, the one the body's outside needs least
support in (``orientation``; the channels' ceilings are bridged), so that
the assembly stays together on the bed.

The 3MF holds one object whose mesh is every part's triangles in turn;
PrusaSlicer reads the parts as the volumes of ``Metadata/Slic3r_PE_model.config``
(their triangle ranges, names and extruders: 1 for the body, 2 for the
bones), other readers the core spec's ``basematerials`` (one per part kind,
named after the design's materials).
"""
from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
from .build import cut_solids, tool_shapes, total_mass
from .meshing import generate_surface_mesh, triangle_surface
from .orientation import PrintPose, best_pose
from .parts import Plan, Tool, cable_points, cable_radius
from .surfaces import CURVATURE, Surface, orient

BODY_EXTRUDER, BONE_EXTRUDER = 1, 2
COMPLEMENT_TOLERANCE = 1e-5       # relative: body with open channels = printed body + printed bones (OCC's
                                  # volumes of nearly tangent cylinders are good to a few 1e-6)
COLOURS = {"body": "#E8A33DFF", "bone": "#F2F2EAFF"}


@dataclass
class PrintedPart:
    """One volume of the multi-material print, in design coordinates."""

    name: str            # "body" or "bone_<name>"
    kind: str            # "body" or "bone"
    material: str        # the design's material name
    surface: Surface
    cad_volume: float


def cable_tools(plan: Plan, up: np.ndarray) -> list[Tool]:
    """The open channels of the print: each cable's whole path, its tendon's spool exit, and a hole
    straight up (``up``: the print's vertical in design coordinates) out of the body from every cable end
    that lies in a bone: a hole that opens upward has no ceiling, so nothing in it needs support."""
    design, spec = plan.design, plan.spec
    reach = 2.0 * plan.scale                        # past the top of the body
    tools = []
    for cable in design.cables:
        r, p = cable_radius(spec, cable), cable_points(design, cable)
        tools.append(Tool("channel", p, r, cable=cable.name))
        for end in (p[0], p[-1]):
            if any(_ends_in(plan, bone.name, end) for bone in design.bones):
                tools.append(Tool("anchor", np.vstack([end - r * up, end + reach * up]), r, cable=cable.name))
    tools += [t for t in plan.mould_tools if t.kind == "exit"]          # the spool ends, straight out
    return tools


def _ends_in(plan: Plan, bone: str, point: np.ndarray) -> bool:
    """Does a cable end lie in this bone? (a tendon's channel in it ends there, or a ligament's anchor
    hole in it passes through there)"""
    return any(np.allclose(t.points[1], point) if t.kind == "anchor" else
               np.allclose(t.points[0], point) or np.allclose(t.points[-1], point)
               for t in plan.bone_tools.get(bone, []))


def check_print(plan: Plan) -> None:
    """Every cable's channel through the printed body keeps fabrication.min_wall of body between it and the
    body's surface (its spool exit excepted); raises FabricationError naming the cable and the point."""
    from .parts import where_text
    from .plan import path_samples
    from .surfaces import FabricationError, inside, point_triangle_distance
    design, spec = plan.design, plan.spec
    exits = {t.cable: t.points[0] for t in plan.mould_tools if t.kind == "exit"}
    tol = 1e-7 * plan.scale
    for cable in design.cables:
        r = cable_radius(spec, cable)
        x, _ = path_samples(cable_points(design, cable), r / 2)
        free = ~np.any([inside(x, s, tol) for s in plan.bone_surfaces.values()], axis=0) if plan.bone_surfaces \
            else np.ones(len(x), bool)
        if cable.name in exits:                 # the spool exit opens the channel on purpose
            free &= np.linalg.norm(x - exits[cable.name], axis=1) > r + spec.min_wall + r
        if not free.any():
            continue
        d = point_triangle_distance(x[free], plan.body_surface.corners).min(axis=1)
        worst = int(np.argmin(d))
        if d[worst] - r < spec.min_wall:
            key = "fabrication.channel_diameter" if cable.kind == "tendon" else "fabrication.anchor_diameter"
            raise FabricationError(f"cables.{cable.name}.path",
                                   f"printed, its {2 * r:g} mm channel ({key}) leaves {max(d[worst] - r, 0):.2g} mm "
                                   f"of body at {where_text(x[free][worst])}, less than fabrication.min_wall "
                                   f"({spec.min_wall:g} mm): move the cable inward or thin its channel")


def build_print(plan: Plan) -> tuple[list[PrintedPart], PrintPose, dict]:
    """Every volume of the print (body first, then the bones in design order), their common print pose
    and the complement check."""
    from ..runtime.interrupts import import_gmsh
    gmsh = import_gmsh()

    from ..design.occ import gmsh_model
    from ..mesh.geometry import add_design_solids
    design = plan.design
    materials = {b.name: b.material for b in design.bones}
    with gmsh_model("skelfem-fabricate-3mf"):
        occ = gmsh.model.occ
        body, bones = add_design_solids(occ, design, plan.spec.bone_depth or None)
        occ.synchronize()
        body_volume = float(sum(occ.getMass(3, t) for t in body))
        generate_surface_mesh(gmsh, plan.scale / 6, CURVATURE)      # the body's outside chooses the pose
        outside = triangle_surface(gmsh, body)
        outside.tris = orient(outside.points, outside.tris)
        pose = best_pose(outside.points, outside.tris)
        gmsh.model.mesh.clear()
        tools = cable_tools(plan, pose.rotation.T @ np.array([0.0, 0.0, 1.0]))

        def channels():
            return [s for t in tools for s in tool_shapes(occ, t)]
        body_open = cut_solids(occ, [(3, t) for t in body], channels())   # the body, channels open
        open_volume = total_mass(occ, body_open)
        every_bone = [(3, t) for tags in bones.values() for t in tags]
        printed_body = cut_solids(occ, body_open, occ.copy(every_bone) if every_bone else [])
        printed_bones = {name: cut_solids(occ, [(3, t) for t in tags], channels())
                         for name, tags in bones.items()}
        occ.synchronize()
        volumes = {"body": printed_body, **{f"bone_{n}": v for n, v in printed_bones.items()}}
        for name, v in volumes.items():
            if len(v) != 1:
                raise RuntimeError(f"{name}: the geometry kernel made {len(v)} solids instead of one")
        generate_surface_mesh(gmsh, plan.scale / 6, CURVATURE)
        parts = []
        for name, v in volumes.items():
            s = triangle_surface(gmsh, [v[0][1]])
            s.tris = orient(s.points, s.tris)
            kind = "body" if name == "body" else "bone"
            parts.append(PrintedPart(name, kind, design.body.material if kind == "body" else materials[name[5:]],
                                     s, float(occ.getMass(*v[0]))))
    total = sum(p.cad_volume for p in parts)
    check = {"body_volume": body_volume, "channels_volume": body_volume - open_volume, "parts_volume": total,
             "relative_error": (total - open_volume) / open_volume}
    check["complement"] = abs(check["relative_error"]) <= COMPLEMENT_TOLERANCE
    return parts, pose, check


# -- the 3MF package ---------------------------------------------------------------------------------------
CONTENT_TYPES = """<?xml version="1.0" encoding="UTF-8"?>
<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">
 <Default Extension="rels" ContentType="application/vnd.openxmlformats-package.relationships+xml"/>
 <Default Extension="model" ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/>
 <Default Extension="config" ContentType="text/xml"/>
</Types>
"""
RELS = """<?xml version="1.0" encoding="UTF-8"?>
<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">
 <Relationship Target="/3D/3dmodel.model" Id="rel0" Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/>
</Relationships>
"""
CORE = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
SLIC3RPE = "http://schemas.slic3r.org/3mf/2017/06"


def _numbers(a: np.ndarray, fmt: str) -> list[str]:
    return [fmt % tuple(row) for row in a]


def write_3mf(path: Path, name: str, parts: list[PrintedPart], pose: PrintPose) -> dict:
    """The print as one 3MF (see the module doc); returns each part's triangle range and extruder."""
    kinds = sorted({p.kind for p in parts}, key=["body", "bone"].index)
    materials = {k: next(p.material for p in parts if p.kind == k) for k in kinds}
    vertices, triangles, ranges, offset, first = [], [], [], 0, 0
    for p in parts:
        x = pose.apply(p.surface.points)
        vertices += _numbers(x, '   <vertex x="%.6f" y="%.6f" z="%.6f"/>')
        t = p.surface.tris + offset
        pindex = kinds.index(p.kind)
        triangles += [f'   <triangle v1="{a}" v2="{b}" v3="{c}" pid="1" p1="{pindex}"/>' for a, b, c in t]
        ranges.append({"name": p.name, "first": first, "last": first + len(t) - 1,
                       "extruder": BODY_EXTRUDER if p.kind == "body" else BONE_EXTRUDER})
        offset, first = offset + len(x), first + len(t)
    base = "\n".join(f'  <base name={quoteattr(f"{materials[k]} ({k})")} displaycolor="{COLOURS[k]}"/>'
                     for k in kinds)
    model = (f'<?xml version="1.0" encoding="UTF-8"?>\n'
             f'<model unit="millimeter" xml:lang="en-US" xmlns="{CORE}" xmlns:slic3rpe="{SLIC3RPE}">\n'
             f' <metadata name="Title">{name}</metadata>\n'
             f' <metadata name="Application">skelfem</metadata>\n'
             f' <metadata name="slic3rpe:Version3mf">1</metadata>\n'
             f' <resources>\n <basematerials id="1">\n{base}\n </basematerials>\n'
             f' <object id="2" type="model" pid="1" pindex="0">\n  <mesh>\n   <vertices>\n'
             + "\n".join(vertices) + "\n   </vertices>\n   <triangles>\n" + "\n".join(triangles)
             + '\n   </triangles>\n  </mesh>\n </object>\n </resources>\n'
             ' <build>\n  <item objectid="2"/>\n </build>\n</model>\n')
    volumes = "".join(
        f'  <volume firstid="{r["first"]}" lastid="{r["last"]}">\n'
        f'   <metadata type="volume" key="name" value={quoteattr(r["name"])}/>\n'
        f'   <metadata type="volume" key="volume_type" value="ModelPart"/>\n'
        f'   <metadata type="volume" key="extruder" value="{r["extruder"]}"/>\n'
        f'  </volume>\n' for r in ranges)
    config = ('<?xml version="1.0" encoding="UTF-8"?>\n<config>\n <object id="2" instances_count="1">\n'
              f'  <metadata type="object" key="name" value={quoteattr(name)}/>\n{volumes} </object>\n</config>\n')
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("[Content_Types].xml", CONTENT_TYPES)
        z.writestr("_rels/.rels", RELS)
        z.writestr("3D/3dmodel.model", model)
        z.writestr("Metadata/Slic3r_PE_model.config", config)
    return {r["name"]: {"triangles": [r["first"], r["last"]], "extruder": r["extruder"]} for r in ranges}


def read_3mf(path: Path) -> dict:
    """A 3MF written by write_3mf, read back: {part name: (points, triangles)} (each part's own vertices)."""
    import xml.etree.ElementTree as ET
    with zipfile.ZipFile(path) as z:
        model = ET.fromstring(z.read("3D/3dmodel.model"))
        config = ET.fromstring(z.read("Metadata/Slic3r_PE_model.config"))
    ns = {"m": CORE}
    v = np.array([[float(e.get(k)) for k in "xyz"] for e in model.iterfind(".//m:vertex", ns)])
    t = np.array([[int(e.get(k)) for k in ("v1", "v2", "v3")] for e in model.iterfind(".//m:triangle", ns)])
    out = {}
    for vol in config.iter("volume"):
        name = next(m.get("value") for m in vol.iter("metadata") if m.get("key") == "name")
        tris = t[int(vol.get("firstid")):int(vol.get("lastid")) + 1]
        used, inv = np.unique(tris, return_inverse=True)
        out[name] = (v[used], inv.reshape(-1, 3))
    return out


# -- everything, into a folder -------------------------------------------------------------------------------
MESH_TOLERANCE = 0.01        # relative: each part's triangulated volume (read back from the 3MF) against its CAD one


def write(plan: Plan, folder: Path, picture_file: bool = True) -> dict:
    """Build the print, write <name>.3mf into folder, read it back and check every part (closed, oriented,
    one piece, volume), write fabrication.json (and fabrication.png); returns the report."""
    from ..io.files import write_json
    from .picture import picture
    from .surfaces import FORMAT, check_mesh

    folder = Path(folder)
    design, spec = plan.design, plan.spec
    parts, pose, complement = build_print(plan)
    path = folder / f"{design.name}.3mf"
    ranges = write_3mf(path, design.name, parts, pose)
    back = read_3mf(path)
    report = {"format": FORMAT, "design": design.name, "dim": design.dim, "output": "3mf", "file": path.name,
              "print": pose.to_dict(), "parts": {}, "channels": [], "checks": {"complement": complement},
              "notes": []}              # the plan's notes are the casting's (pegs, posts, pour): not for a print
    meshes = report["checks"]["meshes"] = {}
    for p in parts:
        m = meshes[p.name] = check_mesh(*back[p.name])
        report["parts"][p.name] = {"kind": p.kind, "material": p.material, "extruder": ranges[p.name]["extruder"],
                                   "triangles": ranges[p.name]["triangles"], "volume": p.cad_volume,
                                   "mesh_volume": m["volume"],
                                   "relative_error": (m["volume"] - p.cad_volume) / p.cad_volume}
    for cable in design.cables:
        report["channels"].append({"cable": cable.name, "kind": cable.kind,
                                   "diameter": spec.channel_diameter if cable.kind == "tendon"
                                   else spec.anchor_diameter})
    checks = report["checks"]
    checks["parts_closed_and_oriented"] = all(m["oriented"] and m["degenerate"] == 0 and m["outer_shells"] == 1
                                              for m in meshes.values())       # a body may hold bone cavities
    checks["part_volumes"] = all(abs(p["relative_error"]) <= MESH_TOLERANCE for p in report["parts"].values())
    checks["complement_exact"] = bool(complement["complement"])
    checks["passed"] = bool(checks["complement_exact"] and checks["parts_closed_and_oriented"]
                            and checks["part_volumes"])
    report["notes"].append(
        f"the body prints in a flexible filament (extruder {BODY_EXTRUDER}) in place of the cast "
        f"{design.body.material!r}: simulate with that filament's stiffness (materials.{design.body.material}.E) "
        "for a robot printed so")
    report["by_hand"] = ["thread each cable through its channel after printing (tendons from their spool exit)",
                         "knot or glue each cable's end in the hole above it"]
    if picture_file:
        picture(folder / "fabrication.png", parts, plan,
                title=f"{design.name}: one print, body (translucent) and bones")
    write_json(folder / "fabrication.json", report)
    return report
