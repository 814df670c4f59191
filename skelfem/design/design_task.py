"""The task file of ``skelfem optimize-design``, validated against its design before anything is meshed.

```toml
[[variables]]                   # design variables (skelfem.design.variables) and their bounds
key = "bones.distal.offset.x"   # offsets and angles start at 0; vertices and E at the design's values
bounds = [-2.0, 2.0]            # must hold the start value

[[objectives]]                  # summed
kind = "reach"                  # weight * |marker - at|^2 over the targets (mm^2)
marker = "tip"
weight = 1.0
targets = [{ set = { "cables.flexor.contraction" = 8.0 }, at = [-8.0, 76.0] }]

[[objectives]]
kind = "tension"                # weight * the cable's tension over the targets (N): tendon effort
cable = "flexor"
weight = 0.01
targets = [{ set = { "cables.flexor.contraction" = 8.0 } }]   # default: one target, the design as it is

[constraints]                   # fabrication clearances, mm (skelfem.design.clearances); optional
min_wall = 1.5                  # silicone between every bone and the body's outline and holes
min_gap = 3.0                   # between any two bones
min_cable_wall = 1.5            # between a cable's sketch vertices in the silicone and the outline
min_cable_gap = 2.0             # between any two cables' sketches
min_entry_angle = 30.0          # degrees: a tendon's channel into a bone, against the bone's edge

[optimizer]
max_evaluations = 30            # forward solves (each with its gradient), 1 to 1000
```

Every problem is one DesignError naming the task file and the key: a variable that does not exist,
bounds that exclude the start, a task with no objective, a marker or cable the design lacks, a
``set`` the design refuses, a constraint the start design does not meet, and a design whose
ingredients the design gradient does not cover.
"""
from __future__ import annotations

import math
import re

import numpy as np
from dataclasses import dataclass

from .clearances import ANGLES, KEYS as CONSTRAINT_KEYS, Clearances, cable_gap_floor, start_points
from .parse import parse_design, read_toml
from .spec import DesignError
from .variables import Variable, parse_variable, start_value

KINDS = ("reach", "tension")
TARGET_SETTING = re.compile(r"^(cables\.[^.]+\.(contraction|pretension)|pins\.[^.]+\.move|gravity\.acceleration)$")
MAX_EVALUATIONS = 1000


@dataclass(frozen=True)
class TaskVariable:
    variable: Variable
    start: float
    lower: float
    upper: float

    @property
    def key(self) -> str:
        return self.variable.key


@dataclass(frozen=True)
class TaskTarget:
    set: tuple             # ((--set key, value), ...) applied to the design for this target
    at: tuple | None       # reach: the marker's target (mm)


@dataclass(frozen=True)
class TaskObjective:
    kind: str
    name: str              # the marker (reach) or the cable (tension)
    weight: float
    targets: tuple


@dataclass(frozen=True)
class Task:
    source: str
    variables: tuple
    objectives: tuple
    max_evaluations: int = 30
    constraints: tuple = ()     # ((key, mm), ...) of [constraints]: skelfem.design.clearances


def uncovered(design) -> str | None:
    """'KEY: why' for a design ingredient the design gradient does not cover, or None (design level)."""
    if design.dim != 2:
        return "dim: optimize-design takes 2D designs (3D bone poses: skelfem.analysis.design_gradient)"
    if design.dynamics is not None:
        return "dynamics: design gradients cover static equilibria"
    for b in design.bones:
        if b.rigid:
            return f"bones.{b.name}.rigid: design gradients do not cover rigid bones yet"
    for c in design.cables:
        if c.friction > 0.0 or getattr(c, "friction_by_material", ()):
            return f"cables.{c.name}.friction: design gradients do not cover cable friction"
    for section in ("objects", "loads"):
        if getattr(design, section):
            return f"{section}: design gradients do not cover this ingredient yet"
    if design.grounds:
        return "grounds: optimize-design does not take grounds yet (skelfem.analysis.design_gradient does)"
    for pin in design.pins:
        if getattr(pin, "angle", 0.0):
            return (f"pins.{pin.name}.rotate: design gradients do not cover turned pins (their displacement "
                    "depends on the nodes)")
    if design.contact.self_contact:
        return "contact.self: design gradients do not cover contact"
    return None


def _number(source, key, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise DesignError(f"{source}: {key}: expected a finite number, got {value!r}")
    return float(value)


def _table(source, key, value, allowed) -> dict:
    if not isinstance(value, dict):
        raise DesignError(f"{source}: {key}: expected a table, got {type(value).__name__}")
    unknown = sorted(set(value) - set(allowed))
    if unknown:
        raise DesignError(f"{source}: {key}.{unknown[0]}: unknown key (allowed: {', '.join(allowed)})")
    return value


def _list(source, key, value) -> list:
    if not isinstance(value, list) or not value:
        raise DesignError(f"{source}: {key}: expected a non-empty list")
    return value


def _variables(source, design, items) -> tuple:
    out, seen = [], set()
    for i, item in enumerate(_list(source, "variables", items)):
        where = f"variables[{i}]"
        item = _table(source, where, item, ("key", "bounds"))
        if "key" not in item:
            raise DesignError(f"{source}: {where}.key: missing")
        try:
            v = parse_variable(design, item["key"])
        except ValueError as exc:
            raise DesignError(f"{source}: {where}.key: {exc}") from None
        if v.key in seen:
            raise DesignError(f"{source}: {where}.key: {v.key} is named twice")
        seen.add(v.key)
        bounds = item.get("bounds")
        if not isinstance(bounds, list) or len(bounds) != 2:
            raise DesignError(f"{source}: {where}.bounds: expected [lower, upper]")
        lo, hi = (_number(source, f"{where}.bounds", b) for b in bounds)
        start = start_value(design, v)
        if not lo < hi:
            raise DesignError(f"{source}: {where}.bounds: lower {lo:g} must be below upper {hi:g}")
        if not lo <= start <= hi:
            raise DesignError(f"{source}: {where}.bounds: [{lo:g}, {hi:g}] exclude the start value {start:g} "
                              f"of {v.key}")
        if v.kind in ("modulus", "stiffness") and lo <= 0.0:
            raise DesignError(f"{source}: {where}.bounds: {v.key} must stay > 0 (lower bound {lo:g})")
        out.append(TaskVariable(v, start, lo, hi))
    return tuple(out)


def _setting(source, where, design, key, value) -> tuple:
    if not TARGET_SETTING.match(key):
        raise DesignError(f"{source}: {where}.{key}: a target sets loads only (cables.C.contraction, "
                          "cables.C.pretension, pins.P.move, gravity.acceleration): the design variables and the "
                          "mesh stay the optimiser's")
    if isinstance(value, list):
        text = "[" + ", ".join(repr(_number(source, f"{where}.{key}", v)) for v in value) + "]"
    else:
        text = repr(_number(source, f"{where}.{key}", value))
    try:
        parse_design(design.raw, design.source, [f"{key}={text}"])
    except DesignError as exc:
        raise DesignError(f"{source}: {where}.{key}: {str(exc).split(': ', 1)[-1]}") from None
    return key, value


def _objectives(source, design, items) -> tuple:
    out = []
    for i, item in enumerate(_list(source, "objectives", items)):
        where = f"objectives[{i}]"
        kind = item.get("kind") if isinstance(item, dict) else None
        if kind not in KINDS:
            raise DesignError(f"{source}: {where}.kind: expected one of {', '.join(KINDS)}, got {kind!r}")
        name_key = "marker" if kind == "reach" else "cable"
        item = _table(source, where, item, ("kind", name_key, "weight", "targets"))
        name = item.get(name_key)
        names = list(design.markers) if kind == "reach" else [c.name for c in design.cables]
        if name not in names:
            raise DesignError(f"{source}: {where}.{name_key}: {name!r} not in the design "
                              f"(have: {', '.join(names) or 'none'})")
        weight = _number(source, f"{where}.weight", item.get("weight", 1.0))
        if not weight > 0.0:
            raise DesignError(f"{source}: {where}.weight: must be > 0, got {weight:g}")
        raw_targets = item.get("targets", [{}] if kind == "tension" else None)
        if raw_targets is None:
            raise DesignError(f"{source}: {where}.targets: missing (a reach objective needs targets: at = [x, y])")
        targets = []
        for j, t in enumerate(_list(source, f"{where}.targets", raw_targets)):
            tw = f"{where}.targets[{j}]"
            t = _table(source, tw, t, ("set", "at") if kind == "reach" else ("set",))
            given = t.get("set", {})
            given = _table(source, f"{tw}.set", given, list(given) if isinstance(given, dict) else ())
            settings = tuple(_setting(source, f"{tw}.set", design, k, v) for k, v in given.items())
            at = None
            if kind == "reach":
                if not isinstance(t.get("at"), list) or len(t["at"]) != 2:
                    raise DesignError(f"{source}: {tw}.at: expected [x, y] (mm)")
                at = tuple(_number(source, f"{tw}.at", v) for v in t["at"])
            targets.append(TaskTarget(settings, at))
        out.append(TaskObjective(kind, str(name), weight, tuple(targets)))     # name is in names: a str
    return tuple(out)


def _constraints(source, design, value) -> tuple:
    """[constraints] as ((key, mm), ...), each met by the start design."""
    table = _table(source, "constraints", value, CONSTRAINT_KEYS)
    extent = float(max(max(p[:, i].max() - p[:, i].min() for i in (0, 1))
                       for p in (np.asarray(loop, dtype=float) for loop in design.body_loops)))
    out = {}
    for key, v in table.items():
        v = _number(source, f"constraints.{key}", v)
        if key in ANGLES and not 0.0 < v < 90.0:
            raise DesignError(f"{source}: constraints.{key}: expected an angle in (0, 90) degrees, got {v:g}")
        if key not in ANGLES and not 0.0 < v <= extent:
            raise DesignError(f"{source}: constraints.{key}: expected a length in (0, {extent:.4g}] mm (the body's "
                              f"extent), got {v:g}")
        out[key] = v
    floor = cable_gap_floor(design)
    if out.get("min_cable_gap", floor) < floor:
        raise DesignError(f"{source}: constraints.min_cable_gap: {out['min_cable_gap']:g} mm is less than the "
                          f"{floor:g} mm skelfem fabricate needs between two cables' holes in a bone (their radii + "
                          "fabrication.min_wall)")
    if out:
        clear = Clearances(design, out)
        bad = clear.worst(start_points(design))
        if bad:
            group, least = bad[0]
            raise DesignError(f"{source}: constraints.{group.asked_by}: {group.shortfall(least)}: the optimiser "
                              "starts from a design that meets its constraints")
    return tuple(out.items())


def parse_task(data: dict, source: str, design) -> Task:
    """The Task of a task file's data, for design; DesignError for any problem (nothing meshed)."""
    _table(source, "task", data, ("variables", "objectives", "constraints", "optimizer"))
    why = uncovered(design)
    if why:
        raise DesignError(f"{design.source}: {why}")
    if "variables" not in data:
        raise DesignError(f"{source}: variables: missing (at least one [[variables]] with key and bounds)")
    if "objectives" not in data:
        raise DesignError(f"{source}: objectives: missing (a task needs at least one [[objectives]])")
    variables = _variables(source, design, data["variables"])
    objectives = _objectives(source, design, data["objectives"])
    optimizer = _table(source, "optimizer", data.get("optimizer", {}), ("max_evaluations",))
    n = optimizer.get("max_evaluations", 30)
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_EVALUATIONS:
        raise DesignError(f"{source}: optimizer.max_evaluations: expected an integer from 1 to "
                          f"{MAX_EVALUATIONS}, got {n!r}")
    constraints = _constraints(source, design, data.get("constraints", {}))
    return Task(source, variables, objectives, int(n), constraints)


def load_task(path, design) -> Task:
    return parse_task(read_toml(path, "task file"), str(path), design)
