"""Physical ingredients, one module each, all behind the contract of :mod:`.base`.

``BUILDERS`` lists every registered ingredient's ``build(ctx) -> [Term]``;
the model calls each on the design and sums what they return. Adding an
ingredient is one new module and one line here.
"""
from . import (cables, contact, elasticity, friction, gravity, grounds, objects, inertia, loads, markers, pins, rigid,
               tractions)
from .base import Context, Term

BUILDERS = [
    elasticity.build,
    pins.build,
    cables.build,
    loads.build,
    grounds.build,
    contact.build,
    markers.build,
    gravity.build,
    tractions.build,
    inertia.build,
    rigid.build,
    friction.build,
    objects.build,
]

__all__ = ["BUILDERS", "Context", "Term"]
