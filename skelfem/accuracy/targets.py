"""What ``--tol`` bounds: every marker (a bare ``--tol MM``), or named observables, each with its tolerance.

    --tol 0.5                                  every marker's position within 0.5 mm (as always)
    --tol cables.flexor.tension=0.05           the flexor's tension within 0.05 N
    --tol markers.tip=0.1 --tol pins.base.reaction=0.01
                                               a marker's position (its distance), a vector's magnitude of
                                               error, or one component (``markers.tip.x``)

The ladder (skelfem.accuracy.ladder) measures one quantity per row: the
answers of the targets on each mesh, ``rows(result)`` (n_rows, dim). A
bare tolerance keeps the markers' positions in mm and ``tol`` in mm; with
named targets each row is divided by its own tolerance, so the ladder's
change, estimate and ``tol`` (1) are in units of the tolerances: a row
meets its target when its Richardson estimate is below 1, and the ladder
stops when every row does (the largest decides). Names are checked
against the design before any meshing (``check``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..observables import AXES, SCALARS, VECTORS

PIECE_SECTIONS = ("bodies", "objects")          # pieces that can touch: contacts.A|B


def _entries(design, section: str) -> list[str]:
    if section == "markers":
        return list(design.markers)
    return [e.name for e in getattr(design, section, ())]


def check(design, name: str) -> str | None:
    """Why `name` is not an observable of `design` (one line), or None if it is one.

    An observable, or a vector of them without its component: ``markers.M``,
    ``pins.P.reaction``, ``grounds.G.force``, ``objects.O.position``,
    ``contacts.A|B.normal_force`` (skelfem.observables' table)."""
    parts = name.split(".")
    section = parts[0]
    if section not in VECTORS and section not in SCALARS:
        return (f"{name!r} is not an observable (one of markers.M[.x], cables.C.tension, pins.P.reaction[.x], "
                "grounds.G.force[.x], objects.O.position[.x], objects.O.rotation, contacts.A|B.normal_magnitude ...)")
    if len(parts) < 2 or not parts[1]:
        return f"{name!r}: which {section[:-1]}? ({section}.NAME...)"
    entry = parts[1]
    if section == "contacts":
        pieces = ["body"] + [b.name for b in design.bodies if b.name != "body"] + [o.name for o in design.objects]
        pair = entry.split("|")
        if len(pair) != 2 or pair[0] == pair[1] or not all(p in pieces for p in pair):
            return f"{name!r}: contacts are named A|B by two pieces of the design ({', '.join(pieces)})"
    elif entry not in _entries(design, section):
        have = _entries(design, section)
        return f"{name!r}: no {section[:-1]} named {entry!r} (the design has {', '.join(have) or 'none'})"
    rest = parts[2:]
    dim = design.dim
    keys: tuple[str, ...]
    if section == "markers":
        keys, rest = ("position",), (["position"] + rest)
    else:
        keys = VECTORS.get(section, ()) + SCALARS.get(section, ())
    if not rest or rest[0] not in keys:
        return f"{name!r}: {section} have {', '.join(keys)}"
    key, comp = rest[0], rest[1:]
    vector = key in VECTORS.get(section, ()) and not (section == "objects" and key == "rotation" and dim == 2)
    if comp and (not vector or len(comp) != 1 or comp[0] not in AXES[:dim]):
        return f"{name!r}: {'no components' if not vector else 'the component is one of ' + ', '.join(AXES[:dim])}"
    if len(comp) > 1:
        return f"{name!r}: too many parts"
    return None


@dataclass(frozen=True)
class Targets:
    """The --tol targets: ((name or None for every marker, tolerance), ...), in the design's dimension."""
    items: tuple
    dim: int

    @classmethod
    def markers(cls, tol: float, dim: int) -> "Targets":
        return cls(((None, float(tol)),), dim)

    @property
    def bare(self) -> bool:
        """Only a bare tolerance: rows in mm, tol in mm (today's --tol)."""
        return all(name is None for name, _ in self.items)

    @property
    def tol(self) -> float:
        """The tolerance the ladder compares its estimate with: mm for a bare one, else 1 (rows scaled)."""
        return self.items[0][1] if self.bare else 1.0

    @property
    def unit(self) -> str:
        return "mm" if self.bare else "tolerances"

    def spec(self):
        """result.json's ``accuracy.tol``: the number of a bare tolerance, else {name: tolerance}."""
        if self.bare:
            return self.items[0][1]
        return {("markers" if name is None else name): tol for name, tol in self.items}

    def _values(self, result, name: str | None) -> np.ndarray:
        data = result.to_dict()
        if name is None:
            return np.array([m["position"] for m in (data.get("markers") or {}).values()], dtype=float)
        section, entry, *rest = name.split(".")
        if section == "markers":
            pos = np.asarray(data["markers"][entry]["position"], dtype=float)
            return pos[None, :] if not rest else np.array([[pos[AXES.index(rest[0])]]])
        if section == "contacts":
            hit = [c for c in data.get("contacts") or [] if set(c.get("between", ())) == set(entry.split("|"))]
            value = hit[0].get(rest[0]) if hit else None
            if value is not None and hit[0]["between"] != entry.split("|") and rest[0] != "normal_magnitude":
                value = -np.asarray(value, dtype=float)          # the force on the other piece
            value = 0.0 if value is None else value              # no contact (yet): no force
        else:
            value = data[section][entry][rest[0]]
        value = np.atleast_1d(np.asarray(value, dtype=float))
        if len(rest) == 2:
            value = value[AXES.index(rest[1]):AXES.index(rest[1]) + 1]
        return value[None, :]

    def rows(self, result) -> np.ndarray:
        """(n_rows, dim): each target's answer (a vector's components in a row, a scalar in the first
        column), divided by its tolerance unless the tolerance is bare."""
        out = []
        for name, tol in self.items:
            v = self._values(result, name)
            v = v if self.bare else v / tol
            row = np.zeros((len(v), self.dim))
            row[:, :v.shape[1]] = v
            out.append(row)
        return np.concatenate(out) if out else np.zeros((0, self.dim))

    def owner(self, row: int, n_markers: int) -> tuple[str | None, int]:
        """(the target's name, or None for the bare markers, and the marker's index there) of a row."""
        for name, _ in self.items:
            n = n_markers if name is None else 1
            if row < n:
                return name, row
            row -= n
        raise IndexError(row)

    def per_target(self, estimate: float | None) -> dict:
        """{name: {"tol", "estimated_error"}}: the ladder's estimate (the largest over its rows, in units of
        the tolerances) as a bound on each target's error in its own unit."""
        if estimate is None or self.bare:
            return {}
        return {("markers" if n is None else n): {"tol": t, "estimated_error": estimate * t} for n, t in self.items}
