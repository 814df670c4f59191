"""Values made once per DOLFINx object and kept beside it: a mesh's bounding-box tree of cells and its
facets' corners, a space's global DOF numbers. They are keyed by the object's identity and a name, and
dropped when the object is collected or when asked (a mesh whose nodes moved, a big mesh's tree once
its points are located); nothing is stored on DOLFINx's own objects.
"""
from __future__ import annotations

import weakref
from typing import Any, Callable

_KEPT: dict[tuple[int, str], Any] = {}


def kept(obj, name: str, make: Callable[[], Any]) -> Any:
    """obj's value `name`, made by make() the first time it is asked for."""
    key = (id(obj), name)
    if key not in _KEPT:
        _KEPT[key] = make()
        weakref.finalize(obj, _KEPT.pop, key, None)     # gone with the object (its id may be reused)
    return _KEPT[key]


def peek(obj, name: str) -> Any:
    """obj's value `name` if it is kept, else None (nothing is made)."""
    return _KEPT.get((id(obj), name))


def forget(obj, *names: str) -> None:
    """Drop obj's values `names`, or all of them if none is named."""
    for key in [k for k in _KEPT if k[0] == id(obj) and (not names or k[1] in names)]:
        del _KEPT[key]
