"""TEMPORARY minimal loader (replaced by the full validating module)."""
from __future__ import annotations
import copy, tomllib
from dataclasses import dataclass, field
from pathlib import Path
import numpy as np


class DesignError(ValueError):
    pass


@dataclass(frozen=True, eq=False)
class Material:
    name: str; E: float; nu: float


def _ns(**kw):
    from types import SimpleNamespace
    return SimpleNamespace(**kw)


def apply_override(data, assignment, source):
    if "=" not in assignment:
        raise DesignError(f"{source}: {assignment}: expected KEY=VALUE")
    key, value = assignment.split("=", 1)
    try:
        value = tomllib.loads("v = " + value)["v"]
    except tomllib.TOMLDecodeError:
        pass
    parts = key.split(".")
    node = data
    for part in parts[:-1]:
        if isinstance(node, list):
            node = next(e for e in node if e.get("name") == part)
        else:
            node = node.setdefault(part, {})
    node[parts[-1]] = value


def parse_design(data, source="<design>", overrides=()):
    data = copy.deepcopy(data)
    for o in overrides:
        apply_override(data, o, source)
    dim = data.get("dim", 2)
    A = lambda v: np.asarray(v, float)
    mats = {k: Material(k, float(v["E"]), float(v["nu"])) for k, v in data["materials"].items()}
    b = data["body"]
    body = _ns(outline=A(b["outline"]) if "outline" in b else None, holes=tuple(A(h) for h in b.get("holes", [])),
               solids=tuple(b.get("solids", [])), material=b["material"])
    bones = tuple(_ns(name=x["name"], outline=A(x["outline"]) if "outline" in x else None,
                      solids=tuple(x.get("solids", [])), material=x["material"]) for x in data.get("bones", []))
    cables = tuple(_ns(name=c["name"], kind=c["kind"], path=A(c["path"]), stiffness=float(c["stiffness"]),
                       contraction=float(c.get("contraction", 0.0)), pretension=float(c.get("pretension", 0.0)))
                   for c in data.get("cables", []))
    pins = tuple(_ns(name=p["name"], region=A(p["region"]), kind=p.get("kind", "fixed"),
                     stiffness=float(p.get("stiffness", 0.0)), move=A(p.get("move", [0.0] * dim))) for p in data["pins"])
    loads = tuple(_ns(name=l["name"], at=A(l["at"]), force=A(l["force"])) for l in data.get("loads", []))
    grounds = tuple(_ns(name=g["name"], point=A(g["point"]), normal=A(g["normal"]) / np.linalg.norm(g["normal"]),
                        stiffness=float(g["stiffness"])) for g in data.get("grounds", []))
    s = data.get("solver", {})
    m = data.get("mesh", {})
    return _ns(source=str(source), format=1, name=data.get("name", "design"), dim=dim,
               thickness=float(data.get("thickness", 1.0)), mesh=_ns(size=float(m.get("size", 2.0)), degree=int(m.get("degree", 1))),
               materials=mats, body=body, bones=bones, cables=cables, pins=pins, loads=loads, grounds=grounds,
               contact=_ns(self_contact=False, dhat=0.3), markers={k: A(v) for k, v in data.get("markers", {}).items()},
               solver=_ns(steps=int(s.get("steps", 1)), max_iterations=int(s.get("max_iterations", 50)), rtol=1e-9, atol=1e-10, line_search="energy"), raw=data)


def load_design(path, overrides=()):
    path = Path(path)
    with open(path, "rb") as f:
        data = tomllib.load(f)
    data.setdefault("name", path.stem)
    return parse_design(data, str(path), overrides)
