"""``[[stages]]``: a static scenario as a sequence of live parameter changes, each validated before meshing.

    [[stages]]
    name = "close"
    set = { "cables.left_flexor.contraction" = 4.0, "cables.right_flexor.contraction" = 4.0 }
    [[stages]]
    name = "weigh"
    set = { "gravity.acceleration" = [0.0, -9.81] }
    steps = 4                       # optional: this stage's change in 4 equal steps

A stage changes only parameters that a Session changes live (no re-mesh:
contractions, pretensions, stiffnesses, pin moves, loads, tractions, ground
points, gravity, densities, E and nu, Coulomb coefficients), so the state and
friction's history carry from one stage to the next. Each stage's values are
absolute and the design after every stage is validated like the design
itself: a bad stage is one DesignError naming ``stages.NAME`` before
anything is meshed.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

from .spec import DesignError, MAX_STEPS, SECTIONS_BY_NAME
from .table import Table, is_number, raw_value, set_key

MAX_STAGES = 100          # a scenario, not a sweep: each stage's design is validated in full
VECTOR_FIELDS = ("move", "force", "point", "acceleration", "traction", "centre", "axis")   # live vectors


@dataclass(frozen=True, eq=False)
class StageSpec:
    name: str
    changes: dict                 # {live --set key: value} as written (absolute values)
    steps: int | None = None      # the change in this many equal steps; None: at once, halved on failure
    design: object = field(default=None, repr=False)    # the validated design after this stage


def live_keys(design) -> list:
    """The --set keys of design that a Session changes live (the terms' parameters), in design order."""
    keys = []
    for c in design.cables:
        keys += [f"cables.{c.name}.{'contraction' if c.kind == 'tendon' else 'pretension'}",
                 f"cables.{c.name}.stiffness", f"cables.{c.name}.friction"]
    for p in design.pins:
        keys += [f"pins.{p.name}.move"]
        if p.centre is not None:                   # a pin the design turns (rotate = {angle, centre})
            keys += [f"pins.{p.name}.rotate.angle", f"pins.{p.name}.rotate.centre"]
            keys += [f"pins.{p.name}.rotate.axis"] if design.dim == 3 else []
        keys += [f"pins.{p.name}.stiffness"] if p.kind == "spring" else []
    keys += [f"loads.{ld.name}.force" for ld in design.loads]
    keys += [f"tractions.{t.name}.traction" for t in design.tractions]
    for g in design.grounds:
        keys += [f"grounds.{g.name}.{k}" for k in ("point", "stiffness", "friction", "friction_static")]
    strained = list(dict.fromkeys([b.material for b in design.bodies] + [b.material for b in design.bones]
                                  + [o.material for o in design.objects if not o.rigid]))
    keys += [f"materials.{m}.{k}" for m in strained for k in ("E", "nu")]
    weighed = strained if design.gravity is not None else []
    if len(design.bodies) + len(design.objects) > 1:            # objects weigh, pieces rub
        weighed = weighed + [o.material for o in design.objects]
    keys += [f"materials.{m}.density" for m in dict.fromkeys(weighed)]
    if design.gravity is not None:
        keys.append("gravity.acceleration")
    if len(design.bodies) + len(design.objects) > 1 or any(g.name not in design.friction.grounds
                                                            for g in design.grounds):
        keys += ["contact.friction", "contact.friction_static"]
    return keys


def _flat(table: dict, prefix: str = "") -> dict:
    """{dotted key: value} of a stage's set table: quoted dotted keys and nested tables alike."""
    out = {}
    for key, value in table.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _patterns(keys: list) -> str:
    """The live keys with entry and material names as NAME, each form once: cables.NAME.contraction, ..."""
    named = (*SECTIONS_BY_NAME, "materials")
    forms = [".".join([p[0], "NAME", *p[2:]]) if p[0] in named and len(p) > 2 else ".".join(p)
             for p in (k.split(".") for k in keys)]
    return ", ".join(dict.fromkeys(forms))


def read_stages(tables: list, design, parse) -> tuple:
    """The StageSpecs of the [[stages]] entries (Tables from named_entries), each stage's design validated
    by parse(data, source) from the design's data with every change up to it; () if there are none."""
    if not tables:
        return ()
    source = design.source
    if design.dynamics is not None:
        raise DesignError(f"{source}: stages: stages are a static scenario; a run in time ([dynamics]) "
                          "follows its schedules")
    if len(tables) > MAX_STAGES:
        raise DesignError(f"{source}: stages: at most {MAX_STAGES} stages, got {len(tables)}")
    live = live_keys(design)
    data = {k: copy.deepcopy(v) for k, v in design.raw.items() if k != "stages"}
    before: dict = {}
    out = []
    for t in tables:
        name = t.where.split(".", 1)[1]
        changes = _flat(t.take("set", "table"))
        steps = t.take("steps", "int", None)
        t.done()
        if not changes:
            t.fail("set", "a stage changes at least one live parameter (none given)")
        if steps is not None and not 1 <= steps <= MAX_STEPS:
            t.fail("steps", f"must be 1 to {MAX_STEPS}, got {steps}")
        for key, value in changes.items():
            where = Table({}, f"{t.where}.set", source)
            if key not in live:
                turned = key.split(".")[0] == "pins" and ".rotate." in key
                where.fail(key, "not a parameter a stage can change" + (
                    " (a stage turns a pin that the design gives rotate = {angle = 0.0, centre = [...]})"
                    if turned else f" (this design's live ones: {_patterns(live)})"))
            vector = key.rsplit(".", 1)[1] in VECTOR_FIELDS
            if not (isinstance(value, list) if vector else is_number(value)):
                where.fail(key, f"must be {'a list of numbers' if vector else 'a number'} to change live")
            set_key(data, key, copy.deepcopy(value), lambda message: where.fail(key, message))
        try:
            staged = parse(copy.deepcopy(data), source)
        except DesignError as exc:
            text = str(exc)
            text = text[len(source) + 2:] if text.startswith(f"{source}: ") else text
            raise DesignError(f"{source}: {t.where}: {text}") from None
        values = {k: _value(staged, k) for k in changes}
        unset = object()        # a key no earlier stage set changes (the design's own value may be --set)
        if all(before.get(k, unset) == v for k, v in values.items()):
            t.fail("set", "changes nothing: an earlier stage set every value to this already")
        before.update(values)
        out.append(StageSpec(name, changes, steps, staged))
    return tuple(out)


def _value(design, key: str):
    """The value of a live key in a validated design, comparable with ==: a tuple of floats or a float
    (a key not written: None)."""
    try:
        v = raw_value(design.raw, key)
    except KeyError:
        return None
    return tuple(float(x) for x in v) if isinstance(v, list) else float(v) if is_number(v) else v
