"""Typed reading of one TOML table at a time (unknown keys are errors), --set overrides, cached geometry checks.
"""
from __future__ import annotations

import math
import re
import tomllib

import numpy as np

from .spec import DesignError, MAX_COORDINATE, MAX_NAME, SECTIONS_BY_NAME


# -- reading typed values -------------------------------------------------------------------------
_REQUIRED = object()


class Table:
    """Keys of one TOML table, taken one at a time; leftovers are unknown keys."""

    def __init__(self, data, where: str, source: str):
        self.source, self.where = source, where
        if not isinstance(data, dict):
            self.fail("", "must be a table")
        self.data = dict(data)

    def key(self, name: str) -> str:
        return f"{self.where}.{name}" if self.where else name

    def fail(self, name: str, message: str):
        where = self.key(name) if name else self.where
        text = f"{self.source}: {where}: {message}" if where else f"{self.source}: {message}"
        raise DesignError(re.sub(r"[\x00-\x1f\x7f]", lambda m: repr(m.group())[1:-1], text))

    def has(self, name: str) -> bool:
        return name in self.data

    def take(self, name: str, kind: str, default=_REQUIRED, dim: int | None = None):
        if name not in self.data:
            if default is _REQUIRED:
                self.fail(name, "missing (required)")
            return default
        value = self.data.pop(name)
        return convert_value(value, kind, dim, lambda msg: self.fail(name, msg))

    def done(self) -> None:
        if self.data:
            self.fail(sorted(self.data)[0], "unknown key")


def is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def show_value(value, width: int = 60) -> str:
    """repr of a value for a one-line message, shortened."""
    try:
        text = repr(value)
    except Exception:           # e.g. an integer too long to print
        text = f"<{type(value).__name__}>"
    return text if len(text) <= width else text[:width - 3] + "..."


def is_finite(value) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:       # an integer beyond float range
        return False


def convert_value(value, kind: str, dim, fail):
    """value as kind: "number", "int", "str", "bool", "table", "tables", "list"; "vector" (dim numbers:
    a force, a normal, a move), "point" (dim coordinates) and "points" (a list of them). Every coordinate
    of every section obeys one rule here: finite and within +-MAX_COORDINATE mm."""
    if kind == "number":
        if not is_number(value):
            fail(f"must be a number, got {show_value(value)}")
        if not is_finite(value):
            fail(f"must be a finite number, got {show_value(value)}")
        return float(value)
    if kind == "int":
        if not isinstance(value, int) or isinstance(value, bool):
            fail(f"must be an integer, got {show_value(value)}")
        return int(value)
    if kind == "str":
        if not isinstance(value, str):
            fail(f"must be a string, got {show_value(value)}")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            fail(f"must be true or false, got {show_value(value)}")
        return value
    if kind in ("vector", "point", "points"):
        shape = (None, dim) if kind == "points" else (dim,)
        ok = isinstance(value, list) and (kind != "points" or all(isinstance(v, list) for v in value))
        if ok:
            flat = [x for v in value for x in v] if kind == "points" else value
            ok = all(is_number(x) for x in flat)
        if ok:
            if not all(is_finite(x) for x in flat):
                fail("must be finite")
            try:
                a = np.asarray(value, dtype=float)
            except (ValueError, TypeError, OverflowError):
                ok = False
        if not ok or a.ndim != len(shape) or a.shape[-1] != dim:
            what = f"a list of points with {dim} coordinates each" if kind == "points" else f"{dim} numbers"
            fail(f"must be {what}")
        if kind != "vector" and a.size and np.abs(a).max() > MAX_COORDINATE:
            fail(f"coordinates must lie within +-{MAX_COORDINATE:g} mm (got {np.abs(a).max():g})")
        return a
    if kind == "table":
        if not isinstance(value, dict):
            fail("must be a table")
        return value
    if kind == "tables":
        if not isinstance(value, list) or not all(isinstance(x, dict) for x in value):
            fail("must be an array of tables ([[...]])")
        return value
    if kind == "list":
        if not isinstance(value, list):
            fail("must be a list")
        return value
    raise AssertionError(kind)


def positive(t: Table, name: str, value: float, strict: bool = True) -> float:
    if value < 0 or (strict and value == 0):
        t.fail(name, f"must be {'>' if strict else '>='} 0, got {value:g}")
    return value


def plain_name(t: Table, name: str, value: str, what: str) -> str:
    """A name that also names folders or columns: no separators, control characters or hidden names."""
    from ..io.outdir import check_name
    problem = check_name(value, what, MAX_NAME)
    if problem:
        t.fail(name, f"{problem}; got {show_value(value)}")
    return value


KEY_SEPARATORS = ".="      # a name is one part of a dotted --set key (cables.NAME.contraction=...)
MATERIAL_PAIR = ":"        # [contact.pairs] "a:b": two material names


def entry_name(t: Table, name: str, value: str, what: str = "a name", also: str = "") -> str:
    """The one rule for every name a design gives (entries of [[cables]], [[objects]], [[bodies]]...,
    materials, markers): a plain name (plain_name) that is one part of a dotted --set key, so without '.'
    or '='; also: more characters the name must not hold (a material's ':' separates a contact pair)."""
    if name == value and isinstance(value, str) and len(value) > MAX_NAME:   # the key is the name: one line
        name = value[:MAX_NAME // 4] + "..."
    bad = [c for c in KEY_SEPARATORS + also if isinstance(value, str) and c in value]
    if not isinstance(value, str) or not value or bad:
        seps = " or ".join(repr(c) for c in KEY_SEPARATORS + also)
        t.fail(name, f"must be a non-empty name without {seps}; got {show_value(value)}")
    return plain_name(t, name, value, what)


# -- overrides ------------------------------------------------------------------------------------------
def _parse_value(text: str):
    try:
        return tomllib.loads("v = " + text)["v"]
    except (tomllib.TOMLDecodeError, RecursionError, KeyError):
        return text.strip()


def apply_override(data: dict, assignment: str, source: str) -> None:
    """Apply ``KEY=VALUE`` (KEY dotted; named entries addressed by name) to data in place."""
    def fail(msg):
        raise DesignError(f"{source}: --set {assignment}: {msg}")
    if "=" not in assignment:
        fail("expected KEY=VALUE")
    key, text = assignment.split("=", 1)
    set_key(data, key, _parse_value(text), fail)


def set_key(data: dict, key: str, value, fail) -> None:
    """Set the dotted key (named entries addressed by name) to value in data, in place; fail(message) for
    a key that leads nowhere (an unknown entry, a value where a table is needed)."""
    parts = [p.strip() for p in key.strip().split(".")]
    if not all(parts):
        fail("empty key")
    node, walked = data, []
    for part in parts[:-1]:
        walked.append(part)
        if isinstance(node, list):
            match = [e for e in node if isinstance(e, dict) and e.get("name") == part]
            if not match:
                names = ", ".join(str(e.get("name")) for e in node if isinstance(e, dict))
                fail(f"no entry named {part!r} in {'.'.join(walked[:-1])} (have: {names or 'none'})")
            node = match[0]
        elif isinstance(node, dict):
            if part not in node:
                if parts[0] in SECTIONS_BY_NAME and len(walked) == 1:
                    fail(f"the design has no {part!r} section")
                node[part] = {}
            node = node[part]
        else:
            fail(f"{'.'.join(walked[:-1])} is a value, not a table")
    if isinstance(node, list):
        fail(f"address an entry of {'.'.join(parts[:-1])} by name")
    if not isinstance(node, dict):
        fail(f"{'.'.join(parts[:-1])} is a value, not a table")
    node[parts[-1]] = value


def raw_value(raw: dict, key: str):
    """The value of a dotted design key (named entries by name) in a design's raw dict; KeyError if none."""
    node = raw
    for part in key.split("."):
        if isinstance(node, list):
            node = next((e for e in node if isinstance(e, dict) and e.get("name") == part), None)
            if node is None:
                raise KeyError(key)
        elif isinstance(node, dict):
            node = node[part]
        else:
            raise KeyError(key)
    return node


# -- geometry checks (2D) --------------------------------------------------------------------------------
_MEMO: dict = {}     # results of pure geometry checks by their inputs: a re-parse after a live change repeats none


def memoised(kind: str, arrays, tol: float, check):
    """check() once per (kind, arrays, tol); a check that raises is not remembered."""
    key = (kind, tol, *((a.shape, a.tobytes()) for a in arrays))
    if key not in _MEMO:
        if len(_MEMO) > 4096:
            _MEMO.clear()
        _MEMO[key] = check()
    return _MEMO[key]


