"""Observables: every scalar a user reads from a result, named once.

The names are result.json's keys joined by dots, with a vector's component
as its axis letter (x, y, z):

=======================================  ==========================================================
``markers.M.x|y|z``                      marker M's position, mm
``cables.C.tension``                     cable C's tension (the pulled end's), N
``pins.P.reaction.x|y|z``                the force pin P exerts on the body, N
``grounds.G.force.x|y|z``                the force the body (and objects on it) exert on ground G, N
``grounds.G.friction_force.x|y|z``       its tangential part, N (grounds with friction)
``objects.O.position.x|y|z``             object O's centroid, mm
``objects.O.rotation``                   2D: object O's angle, rad; 3D: ``objects.O.rotation.x|y|z``
``contacts.A|B.normal_magnitude``        the pair's sum of nodal normal force magnitudes, N
``contacts.A|B.normal_force.x|y|z``      the normal force on A, N
``contacts.A|B.friction_force.x|y|z``    the friction force on A, N (pairs with friction)
=======================================  ==========================================================

Calibration's CSV columns use the same names (skelfem.analysis.caldata.measurement_columns).
"""
from __future__ import annotations

import math

AXES = "xyz"

# (section, read-out key): the vectors whose components are observables, and the scalars
VECTORS = {"markers": ("position",), "pins": ("reaction",), "grounds": ("force", "friction_force"),
           "objects": ("position", "rotation"), "contacts": ("normal_force", "friction_force")}
SCALARS = {"cables": ("tension",), "objects": ("rotation",), "contacts": ("normal_magnitude",)}
PATTERNS = ("markers.M.x|y|z", "cables.C.tension", "pins.P.reaction.x|y|z", "grounds.G.force.x|y|z",
            "grounds.G.friction_force.x|y|z", "objects.O.position.x|y|z", "objects.O.rotation",
            "contacts.A|B.normal_magnitude", "contacts.A|B.normal_force.x|y|z",
            "contacts.A|B.friction_force.x|y|z")


def _entries(data: dict):
    """(section, name, read-outs) of every named read-out of a result dict (contacts by 'A|B')."""
    for section in ("markers", "cables", "pins", "grounds", "objects"):
        for name, entry in (data.get(section) or {}).items():
            if isinstance(entry, dict):
                yield section, name, entry
    for entry in data.get("contacts") or []:
        if isinstance(entry, dict) and len(entry.get("between", ())) == 2:
            yield "contacts", "|".join(entry["between"]), entry


def observables(data: dict) -> dict[str, float]:
    """{name: value} of every observable of a result dict (result.json, ``Result.to_dict()``)."""
    out = {}
    for section, name, entry in _entries(data):
        for key in SCALARS.get(section, ()):
            value = entry.get(key)
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                out[f"{section}.{name}.{key}"] = float(value)
        for key in VECTORS.get(section, ()):
            value = entry.get(key)
            if isinstance(value, (list, tuple)) and all(isinstance(v, (int, float)) for v in value):
                stem = f"{section}.{name}" if section == "markers" else f"{section}.{name}.{key}"
                out.update({f"{stem}.{AXES[i]}": float(v) for i, v in enumerate(value)})
    return {k: v for k, v in out.items() if math.isfinite(v)}

