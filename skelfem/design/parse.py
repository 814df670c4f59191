"""The entry points: read a TOML file, apply --set overrides, validate every section; flatten and diff designs.

Design files: load a TOML design, apply ``--set`` overrides, validate.

The contract is the design format (docs/guide/design-files.md). Every
problem is raised as a :class:`DesignError` whose message names the file and
the offending key, e.g. ``finger.toml: cables.flexor.stiffness: must be > 0``;
the CLI prints it as one ``error:`` line. Nothing here imports DOLFINx, so a
bad design is rejected before any heavy import or meshing.
"""
from __future__ import annotations

import copy
import dataclasses
import tomllib
from pathlib import Path

import numpy as np


from . import polygons
from .objects import take as take_objects
from .sections import (check_bodies_held, check_body_scale, read_cables, read_contact, read_dynamics,
                       check_energy_line_search, read_fabrication, read_gravity, read_grounds, read_loads, read_markers,
                       read_pins, read_solver, read_tractions)
from .stages import read_stages
from .relations import check_piece_names, check_pinned_objects, check_schedules
from .shapes import named_entries, read_body, read_bones, read_materials, read_solids
from .spec import Design, DesignError, FORMAT, MeshSpec, SECTIONS_BY_NAME, force_scale
from .table import Table, plain_name, positive, apply_override, raw_value  # noqa: F401 (raw_value re-exported)
from .text import check_text


# -- entry points -----------------------------------------------------------------------------------------

def used_materials(bodies, bones) -> tuple:
    """The materials a cable can run through: the bodies' and the bones', in that order."""
    return tuple(dict.fromkeys([b.material for b in bodies] + [b.material for b in bones]))

def parse_design(data: dict, source: str = "<design>", overrides=(), poses_of: Design | None = None) -> Design:
    """Validate a design given as parsed TOML (a dict); overrides are ``KEY=VALUE`` strings.

    poses_of: a checked 3D Design that data differs from in its bones' poses only (the editor's drafts of a
    dragged bone): the OpenCASCADE check of the solids is not run again and its volume is kept, so the bones'
    new places are NOT checked here; the caller must (the editor: the moved mesh's tetrahedra keep their
    orientation, else the design is parsed again without poses_of)."""
    data = _copied(data)
    check_text(data, source)
    for assignment in overrides:
        apply_override(data, assignment, source)
    if overrides:
        check_text(data, source)
    top = Table(data, "", source)
    fmt = top.take("format", "int")
    if fmt != FORMAT:
        top.fail("format", f"unsupported format {fmt} (this version reads format = {FORMAT})")
    name = plain_name(top, "name", top.take("name", "str", Path(source).stem if source != "<design>" else "design"),
                       "the design name (it names the output folder)")
    dim = top.take("dim", "int", 2)
    if dim not in (2, 3):
        top.fail("dim", f"must be 2 or 3, got {dim}")
    thickness = 1.0
    if dim == 2:
        thickness = positive(top, "thickness", top.take("thickness", "number", 1.0))
    elif top.has("thickness"):
        top.fail("thickness", "is for dim = 2 only")
    mt = Table(top.take("mesh", "table", {}), "mesh", source)
    mesh = MeshSpec(positive(mt, "size", mt.take("size", "number", MeshSpec.size)),
                    mt.take("degree", "int", MeshSpec.degree))
    if mesh.degree not in (1, 2):
        mt.fail("degree", f"must be 1 or 2, got {mesh.degree}")
    mt.done()
    materials = read_materials(top)
    bodies, region, tol, body_tables = read_body(top, dim, materials)
    body = bodies[0]
    check_body_scale(str(source), bodies, dim, thickness)
    bones = read_bones(top, dim, materials, tol, body_tables)
    soft = used_materials(bodies, bones)
    cables = read_cables(top, dim, region, tol, soft)
    pins = read_pins(top, dim)
    check_bodies_held(str(source), bodies, pins, tol)
    loads = read_loads(top, dim, region)
    # [[objects]], friction keys
    friction, objects = take_objects(top, dim, materials, bodies, read_solids, named_entries)
    grounds = read_grounds(top, dim, bodies, tol, objects)
    contact = read_contact(top, dim, mesh.size, (*bodies, *objects))
    markers = read_markers(top, dim, region, objects)
    solver = read_solver(top)
    check_energy_line_search(top, solver, bones, contact, len(bodies) + len(objects))
    gravity = read_gravity(top, dim, materials, list(soft))
    tractions = read_tractions(top, dim)
    fabrication = read_fabrication(top, dim, thickness, bodies)
    dynamics = read_dynamics(top, materials, list(dict.fromkeys([*soft, *(o.material for o in objects)])), mesh.size)
    stage_tables = named_entries(top, "stages")
    top.done()
    check_piece_names(str(source), [(t.where, b.name) for (t, _), b in zip(body_tables, bodies)]
                      + [(f"{section}.{e.name}", e.name) for section, entries in (("objects", objects),
                                                                                ("grounds", grounds)) for e in entries])
    check_schedules(str(source), cables, dynamics)
    check_pinned_objects(str(source), dim, pins, objects, tol)
    if dim == 2:
        loops = polygons.loops_of(bodies)
        measure = sum(abs(polygons.signed_area(b.outline)) - sum(abs(polygons.signed_area(h)) for h in b.holes)
                      for b in bodies)
        vertices = sum(len(loop) for loop in loops) + sum(len(b.outline) for b in bones)
    else:
        from . import solids
        from .objects import inside
        in_body = {k: X for k, X in markers.items() if not any(inside(o, X) for o in objects)}
        every = tuple(s for b in bodies for s in b.solids)        # several bodies: the parts the pins must hold
        if poses_of is not None and poses_of.dim == 3:
            result = solids.Check(poses_of.measure)
        else:
            result = solids.check(every, [(b.name, b.solids) for b in bones], [(c.name, c.path) for c in cables],
                                  in_body, [(ld.name, ld.at) for ld in loads], [(p.name, p.region) for p in pins],
                                  tol)
        if result.error is not None:
            key, message = result.error
            raise DesignError(f"{source}: {key}: {message}")
        measure = result.volume
        vertices = sum(len(next(iter(s.values())).get("outline", ())) + 8 for s in every) \
            + sum(len(next(iter(s.values())).get("outline", ())) + 8 for b in bones for s in b.solids)
    design = Design(
        source=str(source), name=name, dim=dim, thickness=thickness, mesh=mesh,
        materials=materials, body=body, bodies=bodies, bones=bones, cables=cables, pins=pins, loads=loads,
        grounds=grounds, contact=contact, markers=markers, solver=solver, gravity=gravity,
        tractions=tractions, fabrication=fabrication, dynamics=dynamics, friction=friction, objects=objects, data=data,
        measure=float(measure), vertices=int(vertices),
    )
    check_tolerances(design)
    if stage_tables:            # each stage's design validated like this one (read_stages parses it)
        design = dataclasses.replace(design, stages=read_stages(stage_tables, design, parse_design))
    return design


def _copied(value):
    """A deep copy of TOML-like data (dicts, lists and scalars copied directly; anything else by deepcopy)."""
    if isinstance(value, dict):
        return {k: _copied(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copied(v) for v in value]
    if value is None or isinstance(value, (str, int, float)):
        return value
    return copy.deepcopy(value)


MAX_RTOL = 1e-3          # a looser relative tolerance ends Newton before it has solved anything
MAX_ATOL_RELATIVE = 1e-3  # ... and an absolute one above this share of the design's force scale


def check_tolerances(design) -> None:
    """[solver] rtol and atol must ask for an equilibrium: rtol = 1e300 or atol = 1e300 N reported the
    unsolved start as "converged" (exit 0)."""
    s = design.solver
    if s.rtol > MAX_RTOL:
        raise DesignError(f"{design.source}: solver.rtol: must be at most {MAX_RTOL:g} (relative to the first "
                          f"residual), got {s.rtol:g}")
    limit = MAX_ATOL_RELATIVE * force_scale(design)
    if s.atol is not None and s.atol > limit:
        raise DesignError(f"{design.source}: solver.atol: must be at most {limit:.3g} N for this design "
                          f"({MAX_ATOL_RELATIVE:g} x its force scale, E x cross-section), got {s.atol:g}")


MAX_FILE = 64 * 2 ** 20      # bytes: a design is text, not a data set


def read_toml(path, what: str = "design file") -> dict:
    """Parse a TOML file; DesignError (one line) for anything that is not a readable TOML table."""
    source = str(path)
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_FILE + 1)
        if len(raw) > MAX_FILE:
            raise DesignError(f"{source}: larger than {MAX_FILE // 2 ** 20} MB; not a {what}")
        return tomllib.loads(raw.decode("utf-8"))
    except FileNotFoundError:
        raise DesignError(f"{source}: no such file") from None
    except IsADirectoryError:
        raise DesignError(f"{source}: is a folder, not a {what}") from None
    except PermissionError:
        raise DesignError(f"{source}: permission denied") from None
    except UnicodeDecodeError:
        raise DesignError(f"{source}: not a text (UTF-8) file") from None
    except tomllib.TOMLDecodeError as exc:
        raise DesignError(f"{source}: malformed TOML: {exc}") from None
    except RecursionError:
        raise DesignError(f"{source}: malformed TOML: nested too deeply") from None
    except OSError as exc:
        raise DesignError(f"{source}: cannot read ({exc.strerror or exc})") from None
    except ValueError as exc:          # e.g. an embedded NUL in the path
        raise DesignError(f"{source}: cannot read ({exc})") from None


def load_design(path, overrides=()) -> Design:
    """Read, override and validate a design file; raises DesignError for any problem."""
    path = Path(path)
    data = read_toml(path)
    data.setdefault("name", path.stem)
    return parse_design(data, str(path), overrides)


def flatten(raw: dict, prefix: str = "") -> dict:
    """{dotted key: value}: the --set keys of a design dict; named entries by name (order kept as a key)."""
    out = {}
    for key, value in raw.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, path + "."))
        elif (not prefix and key in SECTIONS_BY_NAME and isinstance(value, list)
              and all(isinstance(e, dict) and isinstance(e.get("name"), str) for e in value)
              and len({e["name"] for e in value}) == len(value)):
            out[f"{path}.#order"] = tuple(e["name"] for e in value)
            for e in value:
                out.update(flatten(e, f"{path}.{e['name']}."))
        else:
            out[path] = value
    return out


def changed_keys(old: dict, new: dict) -> set:
    """The keys whose values differ between two flattened designs (present in one only included)."""
    missing = object()
    return {k for k in old.keys() | new.keys() if old.get(k, missing) != new.get(k, missing)}


def live_value(raw: dict, key: str, held):
    """The value of key in raw if it has the form of held, a live parameter's value (a number, or a vector of
    its shape); None if raw has no such key or holds another form (a table of coefficients by material
    where the parameter is one coefficient): such a change is not live."""
    try:
        value = raw_value(raw, key)
    except KeyError:
        return None
    if isinstance(value, (bool, str, dict)):
        return None
    try:
        given, shape = np.asarray(value, dtype=float), np.shape(held)
    except (TypeError, ValueError, OverflowError):
        return None
    return value if given.shape == shape and np.all(np.isfinite(given)) else None
