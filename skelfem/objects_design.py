"""Design sections for touching the world: Coulomb friction coefficients (and, later, objects).

Keys read here (everything else of these sections is read by skelfem.design)::

    [contact]
    friction = 0.5            # kinetic Coulomb coefficient, default for every contact (>= 0; default 0)
    friction_static = 0.6     # static coefficient, >= friction (default: friction)

    [[grounds]]
    friction = 0.4            # this ground's coefficients (default: [contact]'s)
    friction_static = 0.5

:func:`take` runs before the sections it reads from are parsed: it removes
these keys from the tables that skelfem.design goes on to check (so they
are not unknown keys there), leaving the design's raw data untouched. It
needs only the ``_Table`` it is given (``take``, ``fail``, its class), so it
imports nothing from skelfem.design.
"""
from __future__ import annotations

from dataclasses import dataclass, field

FRICTION_KEYS = ("friction", "friction_static")


@dataclass(frozen=True)
class Coulomb:
    """Kinetic and static Coulomb coefficients (static >= kinetic >= 0)."""
    kinetic: float = 0.0
    static: float = 0.0

    @property
    def active(self) -> bool:
        return self.static > 0.0


@dataclass(frozen=True, eq=False)
class FrictionSpec:
    default: Coulomb = field(default_factory=Coulomb)     # [contact]
    grounds: dict = field(default_factory=dict)           # ground name -> Coulomb

    def ground(self, name: str) -> Coulomb:
        return self.grounds.get(name, self.default)

    @property
    def active(self) -> bool:
        return self.default.active or any(c.active for c in self.grounds.values())


def _coulomb(t, default: Coulomb | None) -> Coulomb | None:
    """The (friction, friction_static) pair of table t, or default if it has neither."""
    if not any(t.has(k) for k in FRICTION_KEYS):
        return default
    base = default or Coulomb()
    mu = t.take("friction", "number", base.kinetic if not t.has("friction_static") else None)
    if mu is None:
        t.fail("friction", "missing: friction_static needs friction (the kinetic coefficient) beside it")
    if mu < 0:
        t.fail("friction", f"must be >= 0, got {mu:g}")
    mu_s = t.take("friction_static", "number", mu)
    if mu_s < mu:
        t.fail("friction_static", f"must be >= friction ({mu:g}), got {mu_s:g}")
    return Coulomb(float(mu), float(mu_s))


def _stripped(top, section: str, kind: str):
    """A _Table over a copy of top's section (the original, shared with the raw data, stays)."""
    value = top.data.get(section)
    if value is None:
        return None
    Table = type(top)
    if kind == "table":
        if not isinstance(value, dict):
            return None                               # skelfem.design reports the type
        t = Table(dict(value), section, top.source)
        top.data[section] = t.data
        return t
    if not isinstance(value, list) or not all(isinstance(e, dict) for e in value):
        return None
    out = []
    for i, e in enumerate(value):
        name = e.get("name")
        label = name if isinstance(name, str) and name else str(i)
        out.append((name, Table(dict(e), f"{section}.{label}", top.source)))
    top.data[section] = [t.data for _, t in out]
    return out


def take(top, dim: int) -> tuple[FrictionSpec]:
    """Read (and remove from top's tables) the friction keys of [contact] and [[grounds]]."""
    contact = _stripped(top, "contact", "table")
    default = Coulomb()
    if contact is not None:
        default = _coulomb(contact, default)
    grounds = {}
    for name, t in _stripped(top, "grounds", "tables") or ():
        c = _coulomb(t, None)
        if c is not None and isinstance(name, str):
            grounds[name] = c
    return (FrictionSpec(default, grounds),)
