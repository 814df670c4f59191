"""Writing an edited design back into its TOML file, keeping the user's comments and layout.

``render(text, new)`` parses the file as it is (tomlkit keeps comments,
spacing and the order of keys) and changes only the values that differ from
what the file says: an unchanged line stays byte for byte, a changed value
keeps the comment after it. Entries of ``bones``, ``cables``, ... are matched
by name; added, removed or reordered entries rewrite that section. A number
keeps its kind where it can (a float stays a float: ``E = 2500.0``).

``target(folder, own, name)`` confines saving to the design's own file or a
plain ``NAME.toml`` in the same folder.
"""
from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

from ..design.text import is_text

MAX_NAME = 100


class SaveError(Exception):
    """A save that is refused; status is the HTTP status to answer with."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.message, self.status = message, status


def _value(new, old=None):
    """new as a TOML value, of old's kind where both are numbers."""
    if isinstance(new, bool):
        return new
    if isinstance(new, int) and isinstance(old, float):
        return float(new)
    if isinstance(new, float) and isinstance(old, int) and not isinstance(old, bool) \
            and math.isfinite(new) and new.is_integer():
        return int(new)
    if isinstance(new, list):
        olds = old if isinstance(old, list) and len(old) == len(new) else [None] * len(new)
        return [_value(v, o) for v, o in zip(new, olds)]
    if isinstance(new, dict):
        return {k: _value(v, old.get(k) if isinstance(old, dict) else None) for k, v in new.items()}
    return new


def _named(entries) -> list | None:
    if isinstance(entries, list) and all(isinstance(e, dict) and isinstance(e.get("name"), str) for e in entries):
        return [e["name"] for e in entries]
    return None


def _merge(node, old: dict, new: dict) -> None:
    """Make the tomlkit container node (holding old) hold new, touching only what differs."""
    import tomlkit
    for key in [k for k in old if k not in new]:
        del node[key]
    for key, value in new.items():
        if key not in old:
            node[key] = _value(value)
            continue
        was = old[key]
        if was == value:                     # 3000.0 == 3000: the file's spelling stays
            continue
        if isinstance(value, dict) and isinstance(was, dict):
            _merge(node[key], was, value)
        elif (isinstance(value, list) and isinstance(was, list) and _named(value) is not None
              and _named(value) == _named(was) and isinstance(node[key], tomlkit.items.AoT)):
            for item, e_old, e_new in zip(node[key], was, value):
                _merge(item, e_old, e_new)
        elif isinstance(value, list) and value and all(isinstance(e, dict) for e in value) \
                and not isinstance(node[key], tomlkit.items.Array):
            aot = tomlkit.aot()
            for e in value:
                aot.append(_value(e))
            node[key] = aot
        elif was != value:
            node[key] = _value(value, was)


def render(text: str, new: dict, default_name: str | None = None) -> str:
    """The TOML text of design new, written over the file text (comments and layout kept)."""
    import tomlkit
    doc = tomlkit.parse(text)
    old = tomllib.loads(text)
    new = dict(new)
    if "name" not in old and "name" in new and new["name"] == default_name:
        new.pop("name")                        # the loader's default: do not write it in
    _merge(doc, old, new)
    out = tomlkit.dumps(doc)
    if tomllib.loads(out) != new:               # never write a file that says something else
        raise SaveError("internal error: the written TOML would not read back as the design", 500)
    return out


def target(folder: Path, own: Path, name: str | None) -> Path:
    """Where to save: own (the design's file) when name is None, else folder/name checked.

    name must be a plain file name ending in .toml (no folders, no '..', not hidden),
    and an existing file there must be a regular file (not a link).
    """
    folder = Path(folder).resolve()
    if name is None:
        path = Path(own)
    else:
        if not isinstance(name, str) or not name:
            raise SaveError(f"name: must be a file name of 1 to {MAX_NAME} bytes")
        if not is_text(name):
            raise SaveError(f"name: {name!r}: must be valid UTF-8 text (it holds a lone surrogate)")
        if len(name.encode()) > MAX_NAME:
            raise SaveError(f"name: must be a file name of 1 to {MAX_NAME} bytes")
        if "/" in name or "\\" in name or name in (".", "..") or name.startswith(".") \
                or re.search(r"[\x00-\x1f\x7f]", name):
            raise SaveError(f"name: {name!r}: must be a plain file name in the design's folder "
                            "(no folders, not hidden)", 403)
        if not name.endswith(".toml") or name == ".toml":
            raise SaveError(f"name: {name!r}: must end in .toml")
        path = folder / name
    if path.is_symlink() or (path.exists() and not path.is_file()):
        raise SaveError(f"{path.name}: exists and is not a plain file; choose another name", 403)
    if path.resolve().parent != folder:
        raise SaveError(f"{path.name}: outside the design's folder", 403)
    return path
