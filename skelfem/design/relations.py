"""Checks between sections, once each is read: names that share result.json's keys, schedules and
[dynamics], fixed pins and rigid objects.
"""
from __future__ import annotations

import numpy as np

from . import polygons
from .spec import DesignError

PAIR_SEPARATOR = "|"      # contacts are keyed "A|B" in result.json and in the observables
HELD_STRETCH = 10.0       # x tol: a shorter stretch of an object's boundary in a pin's box is a touching corner


def check_piece_names(source: str, named: list) -> None:
    """Bodies ([body] is named "body"), objects and grounds name the two sides of a contact (result.json's
    contacts, "between" and the observables contacts.A|B...): their names are distinct across the three
    sections and hold no PAIR_SEPARATOR. named: (where, name) of each, where as "body", "bodies.NAME",
    "objects.NAME", "grounds.NAME". An object named "body" reported a contact ["body", "body"]."""
    seen: dict = {}
    for where, name in named:
        key = where if where == "body" else f"{where}.name"
        if PAIR_SEPARATOR in name:
            raise DesignError(f"{source}: {key}: must not contain {PAIR_SEPARATOR!r} (it separates the two "
                              f"sides of a contact in result.json); got {name!r}")
        if name in seen:
            other = seen[name]
            what = "the body's name ([body] is named \"body\")" if other == "body" else f"the name of {other}"
            raise DesignError(f"{source}: {key}: {name!r} is {what} already; bodies, objects and grounds need "
                              "distinct names (result.json's contacts name them side by side)")
        seen[name] = where


def check_schedules(source: str, cables: tuple, dynamics) -> None:
    """A tendon's schedule (contraction against time) drives a run in time: without [dynamics] it would
    be ignored in silence."""
    if dynamics is not None:
        return
    for c in cables:
        if c.schedule is not None:
            raise DesignError(f"{source}: cables.{c.name}.schedule: a schedule needs a [dynamics] section (it "
                              "gives the contraction against time; a static run would ignore it): add [dynamics] "
                              "or use contraction")


def check_pinned_objects(source: str, dim: int, pins: tuple, objects: tuple, tol: float) -> None:
    """A fixed pin holds the boundary inside its region; a rigid object's nodes follow its rigid motion,
    which a Dirichlet condition cannot hold too (the model refused it after meshing, naming no real key).
    A spring pin may hold a rigid object."""
    for p in pins:
        if p.kind != "fixed":
            continue
        for o in objects:
            if o.rigid and _holds(p.region, o, dim, tol):
                raise DesignError(f"{source}: objects.{o.name}.rigid: a rigid object cannot be held by a fixed "
                                  f"pin (pins.{p.name}.region reaches its boundary): make the pin kind = "
                                  "\"spring\", the object rigid = false, or move the region off it")


def _holds(region: np.ndarray, obj, dim: int, tol: float) -> bool:
    """Whether the box region holds a stretch of the object's boundary (2D: an edge clipped to the box has
    length; 3D: the box, grown by tol, shares volume with the object)."""
    lo, hi = np.asarray(region[0], float) - tol, np.asarray(region[1], float) + tol
    box = obj.box
    if np.any(hi < box[0]) or np.any(lo > box[1]):
        return False
    if dim == 3:
        from .solids import common_volume
        return common_volume([{"box": {"min": lo, "max": hi}}], obj.solids) > 0
    p, q = polygons.edges(np.asarray(obj.outline, float))
    d = q - p
    t0, t1 = np.zeros(len(p)), np.ones(len(p))
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(2):                 # Liang-Barsky: clip each edge to the box, axis by axis
            a, b = (lo[k] - p[:, k]) / d[:, k], (hi[k] - p[:, k]) / d[:, k]
            flat = d[:, k] == 0
            inside = (p[:, k] >= lo[k]) & (p[:, k] <= hi[k])
            t0 = np.where(flat, np.where(inside, t0, 1.0), np.maximum(t0, np.minimum(a, b)))
            t1 = np.where(flat, np.where(inside, t1, 0.0), np.minimum(t1, np.maximum(a, b)))
    return bool(np.any((t1 - t0) * np.linalg.norm(d, axis=1) > HELD_STRETCH * tol))
