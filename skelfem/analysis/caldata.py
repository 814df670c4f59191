"""The calibration data contract: a measurement CSV read and checked against a design, before any meshing.

One row per measured state. Columns:

- **conditions**: a column named by a live ``--set`` key (``cables.flexor.contraction``,
  ``loads.pull.force.y``, ``pins.base.move.x``, ``gravity.acceleration.y``...) is that
  row's value of the key; a vector key is given per component (``.x``, ``.y``, ``.z``);
  a component without a column keeps the design's value;
- **measurements**: ``markers.<m>.x|y|z`` (position, mm), ``cables.<c>.tension`` (N),
  ``grounds.<g>.force.x|y|z`` and ``pins.<p>.reaction.x|y|z`` (N); an empty cell is a
  value not measured in that row;
- ``experiment`` (optional): rows with the same label form one load path, solved in
  the order of the file from rest; without it every row is one path.

Fitted parameters (``fit``) are live keys (or a vector key's component); a fitted key
that is also a condition column is fitted as an *offset* added to every row's value
(e.g. a tendon's contraction zero). A key with wildcards (``cables.lig*.stiffness``,
fnmatch) fits *one* value shared by every live key it matches (they must start equal). ``sigma`` gives a
column's (or an fnmatch pattern of columns') measurement standard deviation; ``bounds`` a parameter's box.

Everything here reads the Design only (no DOLFINx), so a command can refuse bad data
with one line before meshing. The outcome of a fit, :class:`Calibration`, is here too. ``live_keys`` lists what
a built model's
``parameters()`` will list (checked against it in the tests).
"""
from __future__ import annotations

import csv
import fnmatch
import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

MAX_BYTES = 20_000_000      # a larger CSV is refused (a calibration needs rows, not a log)
MAX_ROWS = 100_000
AXES = "xyz"
EXPERIMENT = "experiment"
# positive quantities: fitted in log theta (intervals exp(log theta +- q s), always positive) when they start > 0;
# kept >= 0 when they start at 0 (then fitted linearly)
POSITIVE = ("E", "stiffness", "density", "pretension", "friction", "friction_static")
LOG_RANGE = 1e6               # a positive quantity's default box: its start / LOG_RANGE to its start * LOG_RANGE
NU_BOUNDS = (-0.999, 0.4999)
SIGMA_RANGE = 1e9             # a sigma within [1/SIGMA_RANGE, SIGMA_RANGE] x its column's largest |value|
# a number in a CSV cell, a sigma or a bound: ASCII digits, one optional sign, point and exponent (no "1_000",
# no other scripts' digits, no "nan" or "inf"; a bound may say inf or -inf in words)
NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


class DataError(ValueError):
    """Bad calibration input: one line naming the problem."""


# -- what the design makes live -----------------------------------------------------------------
def live_keys(design) -> dict:
    """{key: value} of the live parameters a model of design exposes (scalars or 1D arrays)."""
    out: dict = {}
    used = [b.material for b in design.bodies] + [b.material for b in design.bones]   # rigid ones too (inert)
    for name in dict.fromkeys(used):
        m = design.materials[name]
        out[f"materials.{name}.E"] = float(m.E)
        out[f"materials.{name}.nu"] = float(m.nu)
    for pin in design.pins:
        move = pin.move if pin.move is not None else np.zeros(design.dim)
        out[f"pins.{pin.name}.move"] = np.asarray(move, float).copy()
        if pin.kind == "spring":
            out[f"pins.{pin.name}.stiffness"] = float(pin.stiffness)
    for c in design.cables:
        which = "contraction" if c.kind == "tendon" else "pretension"
        out[f"cables.{c.name}.{which}"] = float(getattr(c, which))
        out[f"cables.{c.name}.stiffness"] = float(c.stiffness)
        out[f"cables.{c.name}.friction"] = float(c.friction)
    for load in design.loads:
        out[f"loads.{load.name}.force"] = np.asarray(load.force, float).copy()
    for t in design.tractions:
        out[f"tractions.{t.name}.traction"] = np.asarray(t.traction, float).copy()
    friction = getattr(design, "friction", None)
    for g in design.grounds:
        out[f"grounds.{g.name}.point"] = np.asarray(g.point, float).copy()
        out[f"grounds.{g.name}.stiffness"] = float(g.stiffness)
        if friction is not None:                     # Coulomb coefficients: the ground's own or [contact]'s
            c = friction.ground(g.name)
            out[f"grounds.{g.name}.friction"] = float(c.kinetic)
            out[f"grounds.{g.name}.friction_static"] = float(c.static)
            if g.name not in friction.grounds:
                out["contact.friction"] = float(c.kinetic)
                out["contact.friction_static"] = float(c.static)
    objects = getattr(design, "objects", ())
    if objects:                                      # free rigid objects: their densities, [contact]'s friction
        assert friction is not None                  # read with the objects
        out["contact.friction"] = float(friction.default.kinetic)
        out["contact.friction_static"] = float(friction.default.static)
        for o in objects:
            if design.materials[o.material].density is not None:
                out[f"materials.{o.material}.density"] = float(design.materials[o.material].density)
    dens = design.gravity is not None or design.dynamics is not None
    if design.gravity is not None:
        out["gravity.acceleration"] = np.asarray(design.gravity, float).copy()
    if dens:
        allm = [b.material for b in design.bodies] + [b.material for b in design.bones]
        for name in dict.fromkeys(allm):
            if design.materials[name].density is not None:
                out[f"materials.{name}.density"] = float(design.materials[name].density)
    return out


def scalar_keys(design) -> dict:
    """live_keys with every vector split into components: {"loads.pull.force.y": value, ...}."""
    out = {}
    for key, value in live_keys(design).items():
        if np.ndim(value) == 0:
            out[key] = float(value)
        else:
            out.update({f"{key}.{AXES[i]}": float(v) for i, v in enumerate(value)})
    return out


def is_path_parameter(key: str) -> bool:
    """A cable's friction coefficient: its measurements depend on the whole load path (hysteresis), so a
    calibration differences them over the path re-solved, not at one row's equilibrium."""
    return key.startswith("cables.") and key.endswith(".friction")


def split_key(key: str) -> tuple[str, int | None]:
    """("loads.pull.force", 1) for "loads.pull.force.y"; (key, None) for a scalar key."""
    base, _, last = key.rpartition(".")
    if last in AXES and base.count(".") >= 1 and not base.endswith((".E", ".nu")):
        return base, AXES.index(last)
    return key, None


def measurement_columns(design) -> list[str]:
    """Every measurement column the design can answer."""
    ax = AXES[:design.dim]
    cols = [f"markers.{m}.{a}" for m in design.markers for a in ax]
    cols += [f"cables.{c.name}.tension" for c in design.cables]
    cols += [f"grounds.{g.name}.force.{a}" for g in design.grounds for a in ax]
    cols += [f"pins.{p.name}.reaction.{a}" for p in design.pins for a in ax]
    return cols


# -- the problem --------------------------------------------------------------------------------
@dataclass
class Parameter:
    """One fitted scalar: a live key (and component), its start and box; an offset if a condition column."""
    key: str                   # as given to fit (component included: "gravity.acceleration.y")
    base: str                  # the live key ("gravity.acceleration")
    component: int | None
    initial: float
    lower: float
    upper: float
    offset: bool = False       # added to the condition column of the same name
    targets: list = field(default_factory=list)   # [(base, component)] it sets: several when tied (a pattern)

    def __post_init__(self):
        if not self.targets:
            self.targets = [(self.base, self.component)]

    log: bool = False          # a positive quantity: fitted in log(value)

    @property
    def scale(self) -> float:
        """The size the optimiser measures steps in."""
        return abs(self.initial) if self.initial != 0.0 else 1.0

    # the optimiser's coordinate z, 0 at the start: log(value / start) for a positive quantity,
    # (value - start) / scale for the others
    def to_z(self, value):
        if self.log:
            return np.log(np.asarray(value, float) / self.initial)
        return (np.asarray(value, float) - self.initial) / self.scale

    def from_z(self, z):
        if self.log:
            return self.initial * np.exp(z)
        return self.initial + np.asarray(z, float) * self.scale

    def dvalue_dz(self, value):
        """d value / d z at value: the value itself in log coordinates, the scale otherwise."""
        return value if self.log else self.scale

    def z_bounds(self) -> tuple[float, float]:
        with np.errstate(divide="ignore"):
            return float(self.to_z(self.lower)), float(self.to_z(self.upper))


@dataclass
class Data:
    """A checked calibration problem: conditions, measurements, weights, the fitted parameters."""
    columns: list                       # measurement column names
    values: np.ndarray                  # (rows, columns), NaN where not measured
    sigma: np.ndarray                   # (columns,) standard deviations
    sigma_given: np.ndarray             # (columns,) bool: from --sigma (else 1 in the column's unit)
    conditions: dict                    # {scalar key: (rows,) values}
    experiments: list                   # (rows,) labels
    parameters: list                    # [Parameter]
    train: np.ndarray                   # (rows,) bool: fitted; the others are held out
    source: str = "<data>"
    header: list = field(default_factory=list)

    @property
    def rows(self) -> int:
        return len(self.values)

    @property
    def keys(self) -> list:
        return [p.key for p in self.parameters]

    def starts(self) -> np.ndarray:
        """(rows,) bool: the first row of each load path."""
        out = np.zeros(self.rows, bool)
        for i in range(self.rows):
            out[i] = i == 0 or self.experiments[i] != self.experiments[i - 1]
        return out


def read_table(source, max_bytes: int | None = None) -> tuple[list, list]:
    """(header, rows of strings) of a CSV path or text; DataError if unreadable or over max_bytes (MAX_BYTES)."""
    name = str(source)
    max_bytes = MAX_BYTES if max_bytes is None else int(max_bytes)
    if isinstance(source, (str, Path)) and not (isinstance(source, str) and "\n" in source):
        path = Path(source)
        try:
            size = path.stat().st_size
        except OSError as exc:
            raise DataError(f"{name}: cannot read ({exc.strerror or exc})") from None
        if not path.is_file():
            raise DataError(f"{name}: not a file")
        if size > max_bytes:
            raise DataError(f"{name}: {size} bytes, over the limit of {max_bytes} for a calibration CSV")
        try:
            text = path.read_text(encoding="utf-8-sig")
        except (OSError, UnicodeDecodeError) as exc:
            raise DataError(f"{name}: cannot read as UTF-8 text ({exc})") from None
    else:
        text, name = str(source), "<data>"
        if len(text.encode()) > max_bytes:
            raise DataError(f"{name}: over the limit of {max_bytes} bytes for a calibration CSV")
    try:
        rows = [r for r in csv.reader(io.StringIO(text)) if any(c.strip() for c in r)]
    except csv.Error as exc:
        raise DataError(f"{name}: not CSV ({exc})") from None
    if not rows:
        raise DataError(f"{name}: empty (expected a header and one row per measured state)")
    header = [h.strip() for h in rows[0]]
    if len(rows) - 1 > MAX_ROWS:
        raise DataError(f"{name}: {len(rows) - 1} rows, over the limit of {MAX_ROWS}")
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise DataError(f"{name}: column {dup[0]!r} appears twice")
    for i, r in enumerate(rows[1:], start=2):
        if len(r) != len(header):
            raise DataError(f"{name}: line {i}: {len(r)} cells, the header has {len(header)}")
    return header, [[c.strip() for c in r] for r in rows[1:]]


def _number(text: str, where: str, allow_empty: bool) -> float:
    """A finite number in the strict grammar NUMBER (what float() takes beyond it, e.g. '1_000', is refused)."""
    if text == "" and allow_empty:
        return math.nan
    if not NUMBER.fullmatch(text):
        raise DataError(f"{where}: {text!r} is not a number (digits 0-9 with an optional sign, point "
                        "and exponent, e.g. -1.5e3)")
    v = float(text)
    if not math.isfinite(v):
        raise DataError(f"{where}: {text!r} is not a finite number")
    return v


def parse_pairs(items, what: str) -> dict:
    """{"A": "B"} of ["A=B", ...]; DataError on a malformed item."""
    out = {}
    for item in items or ():
        if isinstance(item, tuple):
            key, value = item
        elif "=" in str(item):
            key, value = str(item).split("=", 1)
        else:
            raise DataError(f"{what} {item!r}: expected KEY=VALUE")
        out[key.strip()] = value.strip() if isinstance(value, str) else value
    return out


def prepare_data(design, data, fit, sigma=None, bounds=None, holdout: float = 0.0,
                 seed: int = 0, max_bytes: int | None = None) -> Data:
    """Read and check data (a CSV path, CSV text, or {column: values}) against design; DataError if bad.

    fit: live keys to fit; sigma: {column or pattern: std} or ["COL=VALUE"]; bounds:
    {key: (lo, hi)} or ["KEY=LO,HI"]; holdout: the fraction of rows kept out of the fit.
    """
    header, rows, source = _rows(data, max_bytes)
    names, values, conds, experiments = _columns(design, header, rows, source)
    _check_condition_values(design, conds, source)
    keys, targets_of = _fitted_keys(design, fit, conds)
    params = _parameters(design, keys, targets_of, conds, bounds)
    sig, given = _weights(names, values, sigma)
    train = _training_rows(len(rows), holdout, seed)
    count = int(np.isfinite(values[train]).sum())
    if count < len(params) or train.sum() < 1:
        raise DataError(f"{source}: {int(train.sum())} fitted rows hold {count} measurements, fewer than the "
                        f"{len(params)} parameters to fit")
    return Data(names, values, sig, given, conds, experiments, params, train, source, header)


def _rows(data, max_bytes: int | None) -> tuple[list, list, str]:
    """(header, rows of strings, source name) of a CSV path, CSV text or {column: values}."""
    if isinstance(data, dict):
        header = list(data)
        n = len(next(iter(data.values()))) if data else 0
        rows = [[("" if (isinstance(data[h][i], float) and math.isnan(data[h][i])) else str(data[h][i]))
                 if not isinstance(data[h][i], str) else data[h][i] for h in header] for i in range(n)]
        source = "<data>"
    else:
        header, rows = read_table(data, max_bytes)
        source = str(data) if not (isinstance(data, str) and "\n" in data) else "<data>"
    if not rows:
        raise DataError(f"{source}: no rows (expected one row per measured state)")
    return header, rows, source


def _columns(design, header: list, rows: list, source: str) -> tuple[list, np.ndarray, dict, list]:
    """(measurement column names, their values (rows, columns), {condition key: values}, experiment
    label of each row); DataError on a column that names nothing or an experiment split in two."""
    live = scalar_keys(design)
    vectors = {k for k, v in live_keys(design).items() if np.ndim(v) > 0}
    measures = measurement_columns(design)
    cols: list = []
    conds: dict = {}
    for j, h in enumerate(header):
        if h == EXPERIMENT:
            continue
        column = [_number(r[j], f"{source}: row {i + 1}, column {h!r}", h in measures)
                  for i, r in enumerate(rows)]
        if h in measures:
            cols.append((h, column))
        elif h in live:
            conds[h] = np.array(column)
        elif h in vectors:
            raise DataError(f"{source}: column {h!r}: a vector; give its components ({h}.x, {h}.y...)")
        else:
            raise DataError(f"{source}: column {h!r} names no marker, cable, ground, pin or live parameter "
                            f"of {design.name} (measurements: {', '.join(measures) or 'none'})")
    if not cols:
        raise DataError(f"{source}: no measurement column (markers.<m>.x, cables.<c>.tension, ...)")
    experiments = [r[header.index(EXPERIMENT)] for r in rows] if EXPERIMENT in header else ["1"] * len(rows)
    for lab in dict.fromkeys(experiments):
        at = [i for i, e in enumerate(experiments) if e == lab]
        if at != list(range(at[0], at[-1] + 1)):
            raise DataError(f"{source}: experiment {lab!r}: its rows must be consecutive (one load path)")
    names = [c for c, _ in cols]
    values = np.array([v for _, v in cols], float).T
    return names, values, conds, experiments


def _fitted_keys(design, fit, conds: dict) -> tuple[list, dict]:
    """(the fitted keys, {key: the live keys it sets}): plain keys, vectors by component, patterns tied."""
    live = scalar_keys(design)
    vectors = {k for k, v in live_keys(design).items() if np.ndim(v) > 0}
    fit = list(fit or [])
    if not fit:
        raise DataError("fit: no parameter to fit (give --fit KEY)")
    keys, tied = [], {}
    for key in fit:
        if any(ch in key for ch in "*?["):
            hits = [k for k in live if fnmatch.fnmatchcase(k, key)]
            if not hits:
                raise DataError(f"fit: {key!r} matches no live parameter of {design.name}")
            if len({live[k] for k in hits}) > 1:
                raise DataError(f"fit: {key!r} ties parameters that start at different values "
                                f"({', '.join(f'{k}={live[k]:g}' for k in hits)})")
            if any(k in conds for k in hits):
                raise DataError(f"fit: {key!r} matches a condition column")
            tied[key] = hits
            keys.append(key)
        elif key in vectors:
            keys += [f"{key}.{AXES[i]}" for i in range(len(live_keys(design)[key]))]
        elif key in live:
            keys.append(key)
        else:
            raise DataError(f"fit: {key!r} is not a live parameter of {design.name} "
                            f"(live: {', '.join(live) or 'none'})")
    targets_of = {k: tied.get(k, [k]) for k in keys}
    flat = [t for k in keys for t in targets_of[k]]
    frictionless = [t for t in flat if is_path_parameter(t) and not scalar_keys(design)[t] > 0.0]
    if frictionless:
        raise DataError(f"fit: {frictionless[0]!r}: starts at 0, a cable without friction; start it above 0 "
                        f"(--set {frictionless[0]}=0.1)")
    if len(set(flat)) != len(flat):
        raise DataError("fit: a parameter is named twice")
    return keys, targets_of


def _parameters(design, keys: list, targets_of: dict, conds: dict, bounds) -> list:
    """A Parameter per fitted key: its start, bounds (defaults, or given and checked) and log scaling."""
    live = scalar_keys(design)
    bounds = parse_pairs(bounds.items() if isinstance(bounds, dict) else bounds, "bounds")
    for b in bounds:
        if b not in keys:
            raise DataError(f"bounds: {b!r} is not a fitted parameter (fitted: {', '.join(keys)})")
    params = []
    vector_keys = live_keys(design)
    for key in keys:
        targets = [(t, None) if t in vector_keys else split_key(t) for t in targets_of[key]]
        base, comp = targets[0]
        offset = key in conds
        initial = 0.0 if offset else live[targets_of[key][0]]
        last = targets_of[key][0].rsplit(".", 1)[-1]
        positive = not offset and last in POSITIVE
        log = positive and initial > 0
        lo, hi = -math.inf, math.inf
        if log:
            lo, hi = initial / LOG_RANGE, initial * LOG_RANGE
        elif positive:
            lo = 0.0
        if not offset and last == "nu":
            lo, hi = NU_BOUNDS
        if key in bounds:
            lo, hi = _bounds(key, bounds[key])
            if log and not lo > 0:
                raise DataError(f"bounds: {key}={lo:g},{hi:g}: a positive quantity (fitted in log) needs a "
                                "lower bound > 0")
            if not lo <= initial <= hi:
                raise DataError(f"bounds: {key}={lo:g},{hi:g} excludes the start {initial:g}")
            if not offset:
                _check_bound_values(design, key, targets, lo, hi, vector_keys)
        params.append(Parameter(key, base, comp, float(initial), float(lo), float(hi), offset, targets, log))
    return params


def _weights(names: list, values: np.ndarray, sigma) -> tuple[np.ndarray, np.ndarray]:
    """(each column's sigma, whether it was given) from {column or pattern: std} or ["COL=VALUE"]."""
    sig = np.ones(len(names))
    given = np.zeros(len(names), bool)
    for pattern, text in parse_pairs(sigma.items() if isinstance(sigma, dict) else sigma, "sigma").items():
        v = _number(str(text), f"sigma {pattern}", False)
        if not v > 0:
            raise DataError(f"sigma {pattern}={text}: must be > 0")
        hit = [j for j, c in enumerate(names) if fnmatch.fnmatchcase(c, pattern)]
        if not hit:
            raise DataError(f"sigma {pattern}: names no measurement column (have: {', '.join(names)})")
        for j in hit:               # against the data's scale: the weighted residuals stay far from overflow
            scale = _column_scale(values[:, j])
            if not scale / SIGMA_RANGE <= v <= scale * SIGMA_RANGE:
                raise DataError(f"sigma {pattern}={text}: column {names[j]!r} has values up to {scale:g}; a sigma "
                                f"must lie within {1 / SIGMA_RANGE:g} and {SIGMA_RANGE:g} times that")
        sig[hit], given[hit] = v, True
    return sig, given


def _training_rows(n_rows: int, holdout: float, seed: int) -> np.ndarray:
    """Which rows the fit uses: all but a random fraction holdout (at least one row if holdout > 0)."""
    if not 0.0 <= float(holdout) < 1.0:
        raise DataError(f"holdout {holdout}: must be a fraction in [0, 1)")
    train = np.ones(n_rows, bool)
    k = int(round(float(holdout) * n_rows))
    if holdout > 0 and k == 0:
        k = 1
    if k:
        train[np.random.default_rng(seed).choice(n_rows, size=k, replace=False)] = False
    return train


def _bounds(key: str, value) -> tuple[float, float]:
    if isinstance(value, str):
        parts = value.split(",")
        if len(parts) != 2:
            raise DataError(f"bounds: {key}={value}: expected LO,HI")
        lo, hi = (_number(p.strip(), f"bounds {key}", False) if p.strip() not in ("-inf", "inf")
                  else float(p) for p in parts)
    else:
        try:
            lo, hi = (float(v) for v in value)
        except (TypeError, ValueError):
            raise DataError(f"bounds: {key}: expected (LO, HI), got {value!r}") from None
        if math.isnan(lo) or math.isnan(hi):
            raise DataError(f"bounds: {key}: NaN is not a bound")
    if not lo < hi:
        raise DataError(f"bounds: {key}: lower {lo:g} is not below upper {hi:g}")
    return lo, hi


def _check_condition_values(design, conds: dict, source: str) -> None:
    """Every row's conditions must make a design the design file's rules accept (a contraction longer
    than the cable, E <= 0, ...), as `--set` would: one parse of the design per distinct row, before any
    meshing (a contraction of 1e9 mm was meshed and solved, then ended in exit 2 blaming the solve)."""
    from ..design.parse import parse_design
    from ..design.spec import DesignError
    if not conds:
        return
    vectors = {k: v for k, v in live_keys(design).items() if np.ndim(v) > 0}
    where = []                                     # (condition key, its design key, component or None)
    for key in conds:
        base, _, last = key.rpartition(".")
        where.append((key, base, AXES.index(last)) if base in vectors and last in AXES else (key, key, None))
    rows = np.array([conds[key] for key, _, _ in where], float).T
    for i in sorted({tuple(r): i for i, r in reversed(list(enumerate(rows)))}.values()):
        sets: dict = {}
        for (key, base, comp), value in zip(where, rows[i]):
            if comp is None:
                sets[base] = repr(float(value))
            else:
                vec = sets.setdefault(base, [float(v) for v in vectors[base]])
                vec[comp] = float(value)
        overrides = [f"{k}={v if isinstance(v, str) else '[' + ', '.join(repr(x) for x in v) + ']'}"
                     for k, v in sets.items()]
        try:
            parse_design(design.raw, design.source, overrides)
        except DesignError as exc:
            why = str(exc).split(": ", 1)[-1]
            raise DataError(f"{source}: row {i + 1}: its conditions make a design the design file's rules "
                            f"refuse ({why})") from None


def _check_bound_values(design, key: str, targets, lo: float, hi: float, vector_keys: dict) -> None:
    """Each finite end of a box must be a value the design accepts for every key it sets (E > 0, nu in
    (-1, 0.5), a stiffness > 0, ...): the design's own checks decide, before any meshing."""
    from ..design.parse import parse_design
    from ..design.spec import DesignError
    for end in (lo, hi):
        if not math.isfinite(end):
            continue
        for base, comp in targets:
            if comp is None:
                text = repr(float(end))
            else:
                vec = [float(v) for v in vector_keys[base]]
                vec[comp] = float(end)
                text = "[" + ", ".join(repr(v) for v in vec) + "]"
            try:
                parse_design(design.raw, design.source, [f"{base}={text}"])
            except DesignError as exc:
                why = str(exc).split(": ", 1)[-1]
                raise DataError(f"bounds: {key}={lo:g},{hi:g}: {end:g} is not a valid value ({why})") from None


def _column_scale(values: np.ndarray) -> float:
    """A measurement column's largest |value| (1 in its unit when it holds only zeros or nothing)."""
    v = np.abs(values[np.isfinite(values)])
    return float(v.max()) if len(v) and v.max() > 0 else 1.0


# -- the outcome -------------------------------------------------------------------------------------
@dataclass
class Calibration:
    """The outcome of a calibration (``to_dict()`` is calibration.json)."""
    keys: list
    initial: np.ndarray
    values: np.ndarray
    std: np.ndarray                   # inf for a parameter in an unidentifiable group (first order for log ones)
    ci95: np.ndarray                  # (m, 2); a positive quantity's: value /÷ factor, always > 0
    covariance: np.ndarray
    correlation: np.ndarray
    singular_values: np.ndarray       # of the weighted Jacobian in the fit's coordinates (log for positive ones)
    unidentifiable: list              # [[key, ...], ...]: directions unseen at the start or at the estimate
    iterations: int
    converged: bool
    status: str
    cost: float                       # f = |r|^2 / 2 at the estimate
    history: list                     # cost at the start and after each accepted step
    columns: list
    rms: dict                         # {column: RMS of model - data over fitted rows}
    holdout: dict | None              # {"rows": n, "rms": {column: ...}, "weighted_rms": ...}
    model_values: np.ndarray          # (rows, columns) at the estimate
    data: Data
    offsets: list                     # keys fitted as offsets of a condition column
    s2: float                         # variance factor of the covariance
    solves: int = 0
    newton_iterations: int = 0
    time: float = 0.0
    timings: dict = field(default_factory=dict)
    factor: np.ndarray | None = None  # (m,) the 95 % interval as value x/÷ factor (NaN: a linear parameter)
    identified: list = field(default_factory=list)    # (m,) bool
    reasons: list = field(default_factory=list)       # (m,) why not identified ("" if it is)
    groups_start: list = field(default_factory=list)  # unidentifiable groups at the start, at the estimate
    groups_end: list = field(default_factory=list)
    identify_with: list = field(default_factory=list)  # per unidentifiable group: measurements that would fix it
    starts: list = field(default_factory=list)        # per start: its values, cost, iterations, converged
    model_error: dict | None = None   # the model's own error per column and what the fit did with it (calerror)
    model_errors: np.ndarray | None = None    # (rows, columns) its estimate e_ij at the estimate (NaN: none)

    def to_dict(self) -> dict:
        params = {}
        factor = self.factor if self.factor is not None else np.full(len(self.keys), math.nan)
        for i, k in enumerate(self.keys):
            finite = math.isfinite(self.std[i])
            log = bool(self.data.parameters[i].log)
            params[k] = {"value": float(self.values[i]), "initial": float(self.initial[i]),
                         "std": float(self.std[i]) if finite else None,
                         "ci95": [float(v) for v in self.ci95[i]] if finite else None,
                         "factor95": float(factor[i]) if finite and log else None,
                         "log": log, "offset": k in self.offsets,
                         "identified": bool(self.identified[i]) if self.identified else finite,
                         "reason": self.reasons[i] if self.reasons else ""}
        return {
            "parameters": params,
            "correlation": {"keys": list(self.keys), "matrix": [[float(v) if math.isfinite(v) else None
                                                                for v in row] for row in self.correlation]},
            "unidentifiable": self.unidentifiable,
            "unidentifiable_at_start": self.groups_start, "unidentifiable_at_end": self.groups_end,
            "identify_with": [{"group": g, "measurements": w} for g, w in zip(self.unidentifiable, self.identify_with)],
            "singular_values": [float(v) for v in self.singular_values],
            "iterations": int(self.iterations), "converged": bool(self.converged), "status": self.status,
            "cost": float(self.cost), "cost_history": [float(c) for c in self.history],
            "starts": self.starts,
            "residual_rms": {c: v for c, v in self.rms.items()},
            "holdout": self.holdout,
            "model_error": self.model_error,
            "variance_factor": float(self.s2),
            "rows": int(self.data.rows), "fitted_rows": int(self.data.train.sum()),
            "sigma": {c: float(s) for c, s in zip(self.columns, self.data.sigma)},
            "sigma_given": {c: bool(g) for c, g in zip(self.columns, self.data.sigma_given)},
            "solves": int(self.solves), "newton_iterations": int(self.newton_iterations),
            "time": round(float(self.time), 3),
        }

    def overrides(self, design) -> dict:
        """{--set key: value} of the fitted design parameters (offsets excluded), vectors merged."""
        base = {k: (np.array(v, float) if np.ndim(v) else float(v)) for k, v in live_keys(design).items()}
        out: dict = {}
        for p, v in zip(self.data.parameters, self.values):
            if p.offset:
                continue
            for b, comp in p.targets:
                if comp is None:
                    out[b] = float(v)
                else:
                    vec = out.get(b, base[b]).copy()
                    vec[comp] = float(v)
                    out[b] = vec
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in out.items()}
