"""Everything into a folder: build every part, check volumes against their references, write fabrication.json.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from .build import Part, build_bone, build_half
from .micrometres import READER_TOLERANCE, Z
from .picture import picture
from .sequence import STEPS, casting_sequence
from .parts import Plan
from .surfaces import FORMAT, check_mesh, read_stl, write_stl


# -- everything, into a folder -------------------------------------------------------------------------------------
TOLERANCE = 0.01       # relative: bone volumes and the mould's cavity against their references


def build(plan: Plan, folder: Path | None = None) -> list[Part]:
    """Every part of the plan: the bones in design order, then mould_bottom and mould_top (STEP files
    into folder if given, each built again with its balls' poles on z if its STEP file's tolerances are
    beyond a reader's: micrometres.py)."""
    from ..runtime.interrupts import interruptible        # OCC's booleans ignore signals: off the main thread

    def part(make, *args):
        first = interruptible(make, plan, *args, folder, plan.frame.n)
        if folder is None or first.step_tolerance <= READER_TOLERANCE:
            return first
        return interruptible(make, plan, *args, folder, Z)
    parts = [part(build_bone, b) for b in plan.design.bones]
    return parts + [part(build_half, side) for side in ("bottom", "top")]


def _plain(x) -> list:
    return [round(float(v), 6) for v in np.ravel(x)]


def _rod(t, f) -> dict:
    """A removable rod: where it enters the block's outside, its direction in, how deep, how thick."""
    tip = t.points[0]
    out = (t.points[-1] - tip) / np.linalg.norm(t.points[-1] - tip)
    entry = tip + f.reach(tip, out) * out            # out along the rod from its tip to the block's face
    return {"cable": t.cable, "diameter": 2 * t.radius, "entry": _plain(entry), "tip": _plain(tip),
            "direction": _plain(-out), "depth": float(np.linalg.norm(tip - entry))}


def write(plan: Plan, folder: Path, picture_file: bool = True) -> dict:
    """Build every part into folder (STL, STEP), check the STL files as written, and write
    fabrication.json, fabrication.png (the exploded view) and casting.png (the casting sequence); returns
    the report (fabrication.json's content)."""
    from ..design import polygons
    from ..io.files import write_json

    folder = Path(folder)
    design, spec, f = plan.design, plan.spec, plan.frame
    parts = build(plan, folder)
    report = {"format": FORMAT, "design": design.name, "dim": design.dim,
              "bone_depth": spec.bone_depth if design.dim == 2 else None,
              "fabrication": {k: (_plain(v) if isinstance(v, np.ndarray) else v)
                              for k, v in vars(spec).items() if k not in ("split_point", "split_normal")},
              "parts": {}, "bones": {}, "mould": {}, "checks": {}, "notes": list(plan.notes)}
    report["fabrication"]["split"] = {"point": _plain(f.c * f.n if spec.split_point is None else spec.split_point),
                                      "normal": _plain(f.n), "chosen": spec.split_point is None}
    if design.dim == 3:
        report["fabrication"].pop("bone_depth")
    stl = {}
    for part in parts:
        path = folder / f"{part.name}.stl"
        write_stl(path, part.pose.apply(part.surface.points), part.surface.tris, part.name)   # as printed
        stl[part.name] = check_mesh(*read_stl(path))
        report["parts"][part.name] = {"kind": part.kind, "stl": path.name, "step": f"{part.name}.step",
                                      "step_tolerance": part.step_tolerance,
                                      "volume": part.cad_volume, "stl_volume": stl[part.name]["volume"],
                                      "triangles": stl[part.name]["triangles"], "print": part.pose.to_dict()}
    checks = report["checks"]
    checks["stl"] = stl
    for bone, part in zip(design.bones, parts):
        info = part.info
        uncut = abs(polygons.signed_area(bone.outline)) * spec.bone_depth if design.dim == 2 else info["uncut_volume"]
        expected = uncut + info["sheath_volume"] - info["removed_volume"]
        got = stl[part.name]["volume"]
        report["bones"][bone.name] = {
            "file": f"{part.name}.stl", "uncut_volume": uncut, "removed_volume": info["removed_volume"],
            "sheath_volume": info["sheath_volume"], "sheaths": info["sheaths"],
            "expected_volume": expected, "volume": part.cad_volume, "stl_volume": got,
            "relative_error": (got - expected) / expected, "channels": info["channels"],
            "anchor_holes": info["anchor_holes"], "pegs": info["sockets"],
            "cables": sorted({t.cable for t in plan.bone_tools[bone.name] if t.cable})}
    halves = {p.name: p for p in parts if p.kind == "mould"}
    block = sum(p.info["block_volume"] for p in halves.values())
    cavity = block - sum(stl[name]["volume"] for name in halves)
    cavity_cad = block - sum(p.cad_volume for p in halves.values())
    cut = sum(p.info["cut_volume"] for p in halves.values())
    added = sum(p.info["added_volume"] for p in halves.values())
    closed = cavity - cut + added
    report["mould"] = {
        "split": report["fabrication"]["split"], "axes": {"u": _plain(f.u), "v": _plain(f.v), "n": _plain(f.n)},
        "block": {"min": _plain(f.lo), "max": _plain(f.hi), "volume": block},
        "body_volume": plan.body_volume, "cavity_volume": cavity, "cavity_volume_cad": cavity_cad,
        "relative_error": (cavity - plan.body_volume) / plan.body_volume,
        "openings_volume": cut, "pegs_and_pins_volume": added, "closed_cavity_volume": closed,
        "closed_relative_error": (closed - plan.body_volume) / plan.body_volume,
        "pins": [{"at": _plain(t.points[0]), "diameter": 2 * t.radius} for t in plan.mould_tools if t.kind == "pin"],
        "pour": [{"from": _plain(t.points[-1]), "to": _plain(t.points[0]), "diameter": 2 * t.radius}
                 for t in plan.mould_tools if t.kind == "pour"],
        "vents": [{"from": _plain(t.points[-1]), "to": _plain(t.points[0]), "diameter": 2 * t.radius}
                  for t in plan.mould_tools if t.kind == "vent"],
        "exits": {t.cable: {"from": _plain(t.points[0]), "to": _plain(t.points[-1])}
                  for t in plan.mould_tools if t.kind == "exit"},
        "pegs": [{"bone": t.bone, "half": t.side, "tip": _plain(t.points[0]), "diameter": 2 * t.radius}
                 for t in plan.pegs],
        "posts": [{"cable": t.cable, "half": t.side, "tip": _plain(t.points[0]), "diameter": 2 * t.radius}
                  for t in plan.posts if t.kind == "post"],
        "rods": [_rod(t, f) for t in plan.posts if t.kind == "rod"],
        "pry_slots": [{"from": _plain(t.points[0]), "to": _plain(t.points[-1]), "diameter": 2 * t.radius}
                      for t in plan.mould_tools if t.kind == "pry"],
        "clamps": [{"at": _plain(t.points[0]), "to": _plain(t.points[-1]), "bolt": t.side, "diameter": 2 * t.radius}
                   for t in plan.mould_tools if t.kind == "clamp"]}
    report["routes"] = plan.routes
    report["mould"]["flow"] = plan.flow
    checks["stl_closed_and_oriented"] = all(r["oriented"] and r["degenerate"] == 0 and r["parts"] == 1
                                            for r in stl.values())
    checks["bone_volumes"] = all(abs(b["relative_error"]) <= TOLERANCE for b in report["bones"].values())
    # the cavity (block minus both halves, from the STL files) holds the body plus what the pour hole,
    # vents, exits and pin holes take out of the halves, minus what the pegs and pins put in
    checks["cavity_is_body"] = abs(report["mould"]["closed_relative_error"]) <= TOLERANCE
    # every cable cast within route_tolerance of its sketch (the plan refuses a route it cannot hold)
    checks["routes_held"] = all(r["deviation"] <= spec.route_tolerance for r in plan.routes.values())
    checks["tolerance"] = TOLERANCE
    # a STEP file cannot hold a tolerance: a reader gives every edge READER_TOLERANCE, which must cover how far
    # each edge's curves lie off its faces (micrometres.py), or a CAD program's check flags the edge
    loose = [p.name for p in parts if p.step_tolerance > READER_TOLERANCE]
    checks["step_tolerances"] = {"largest": max(p.step_tolerance for p in parts), "reader": READER_TOLERANCE,
                                 "within": not loose}
    if loose:
        report["notes"].append(f"the STEP file(s) of {', '.join(loose)} hold edges further than "
                               f"{READER_TOLERANCE:g} mm off their faces: a CAD program's check may flag them "
                               f"(its shape healing's tolerance fix clears that); the STL files are not affected")
    checks["passed"] = (checks["stl_closed_and_oriented"] and checks["bone_volumes"] and checks["cavity_is_body"]
                        and checks["routes_held"])
    report["casting_steps"] = list(STEPS)
    if picture_file:
        picture(folder / "fabrication.png", parts, plan)
        casting_sequence(folder / "casting.png", parts, plan)
    write_json(folder / "fabrication.json", report)
    return report
