"""Every string of a design is text: one rule for every section, every name and every string value.

A TOML file cannot hold a lone surrogate (U+D800 to U+DFFF on its own), but
JSON can ("\\ud800"), and so can a dict handed to ``parse_design``: such a
string cannot be written as UTF-8, so it broke later, far from its key (a
material name in a saved file, an object name in Gmsh). :func:`check_text`
walks the whole design, keys and values, before any section is read, and
names the first string that is not text.
"""
from __future__ import annotations

import json

from .spec import DesignError


def is_text(s: str) -> bool:
    """s can be written as UTF-8 (it holds no lone surrogate)."""
    try:
        s.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def shown(s: str) -> str:
    """s printable on one line whatever it holds: lone surrogates as \\udXXX escapes."""
    return s.encode("utf-8", "backslashreplace").decode("utf-8")


def _label(entry, index: int) -> str:
    """How a key names entry index of a list: by its name (named entries), else [index]."""
    name = entry.get("name") if isinstance(entry, dict) else None
    return f".{name}" if isinstance(name, str) and name and is_text(name) else f"[{index}]"


def check_text(data, source: str) -> None:
    """DesignError ``source: KEY: must be valid UTF-8 text ...`` for the first key or string value of data
    (a parsed design: dicts, lists, scalars) that is not text."""
    try:                    # the common case at once: everything encodes (the walk below names what does not)
        json.dumps(data, ensure_ascii=False, check_circular=False).encode("utf-8")
        return
    except (TypeError, ValueError, UnicodeEncodeError, RecursionError):
        pass
    stack = [(data, "")]
    while stack:
        node, where = stack.pop()
        if isinstance(node, dict):
            items = []
            for key, value in node.items():
                name = shown(key) if isinstance(key, str) else str(key)
                path = f"{where}.{name}" if where else name
                if isinstance(key, str) and not is_text(key):
                    _fail(source, path, key)
                items.append((value, path))
            stack.extend(reversed(items))
        elif isinstance(node, list):
            stack.extend(reversed([(v, f"{where}{_label(v, i)}") for i, v in enumerate(node)]))
        elif isinstance(node, str) and not is_text(node):
            _fail(source, where, node)


def _fail(source: str, where: str, value: str) -> None:
    where = f"{where}: " if where else ""
    text = repr(value)
    raise DesignError(f"{shown(source)}: {where}must be valid UTF-8 text (it holds a lone surrogate: "
                      f"{text if len(text) <= 60 else text[:57] + '...'})")
