"""One solve's outcome: result.json's keys as typed fields, numpy arrays and a plot for notebooks.

``Result.to_dict()`` is exactly result.json (a deep copy: mutating it changes
nothing here). The standard fields are typed properties; every other section a
term or a run adds (``dynamics``, ``accuracy``, ...) reads as an attribute too.
``displacement()`` and ``plot(ax)`` use the state captured when the Result was
made, so they stay true to that solve after the Session moves on.
"""
from __future__ import annotations

import copy
import math
from enum import StrEnum

import numpy as np

from .design.spec import FORMAT



class Status(StrEnum):
    """Why a solve ended (result.json ``status``); a StrEnum, so ``status == "converged"`` holds."""

    CONVERGED = "converged"
    NOT_STARTED = "not_started"
    MAX_ITERATIONS = "max_iterations"
    LINE_SEARCH_FAILED = "line_search_failed"
    LINEAR_SOLVE_FAILED = "linear_solve_failed"
    INVERTED_ELEMENTS = "inverted_elements"
    TRUST_REGION_COLLAPSED = "trust_region_collapsed"
    INNER_SOLVE_FAILED = "inner_solve_failed"
    LOCAL_MINIMUM_OF_RESIDUAL = "local_minimum_of_residual"
    FRICTION_NOT_CONVERGED = "friction_not_converged"
    NOT_HELD = "not_held"
    DIVERGED = "diverged"

    @classmethod
    def of(cls, text: str) -> "Status":
        """The status of result.json's text: "diverged (-3)" is DIVERGED, "no equilibrium: object X is
        not held" is NOT_HELD."""
        try:
            return cls(text)
        except ValueError:
            return cls.NOT_HELD if text.startswith("no equilibrium") else cls.DIVERGED


def plain(value):
    """JSON-ready: arrays to lists, numpy scalars to floats, non-finite floats to None."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [plain(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


STANDARD_SECTIONS = ("markers", "cables", "pins", "grounds")


def result_dict(design, model, report, timings: dict) -> dict:
    """result.json as the design-format contract defines it, from the terms' read-outs."""
    converged = bool(report.converged)
    res = {
        "format": FORMAT,
        "design": design.name,
        "converged": converged,
        "status": report.status,
        "newton_iterations": int(report.newton_iterations),
        "load_steps": int(report.load_steps),
        "energy": float(report.energy) if converged else None,
        "dofs": int(model.V.dofmap.index_map.size_global * model.bs),
        "cells": int(model.mesh.topology.index_map(model.mesh.topology.dim).size_global),
        "degree": int(design.mesh.degree),
        "min_jacobian": float(report.min_jacobian),
        "linear_solver": getattr(report, "linear_solver", "direct"),
    }
    if res["linear_solver"] == "iterative":      # Krylov iterations per Newton step, and MUMPS fallbacks
        res["linear_iterations"] = [[int(k) for k in step] for step in getattr(report, "linear_iterations", [])]
        res["linear_fallbacks"] = int(getattr(report, "linear_fallbacks", 0))
        res["linear_loose_steps"] = int(getattr(report, "linear_loose_steps", 0))
    readouts = model.readouts() if converged else {}
    for section in STANDARD_SECTIONS:
        res[section] = readouts.pop(section, {}) if converged else None
    res.update(readouts)
    if converged and len(design.bodies) + len(design.objects) > 1:
        res.setdefault("contacts", {})                       # pieces that can touch: the list, even if empty
    if isinstance(res.get("contacts"), dict):                # contacts between pieces: a list of pairs
        res["contacts"] = list(res["contacts"].values())
    res["attempts"] = list(report.attempts)           # a dynamics run keeps a bounded, evenly spaced part
    res["residual_history"] = [[float(r) for r in step] for step in report.residual_history]
    res["timings"] = {k: round(float(v), 4) for k, v in timings.items()}
    return plain(res)


class Result:
    """One solve's outcome (see the module doc).

    Typed fields: ``design`` (name), ``converged``, ``status`` (result.json's text, with the reason),
    ``outcome`` (the same as a :class:`Status`),
    ``newton_iterations``, ``load_steps``, ``energy`` (N mm, None unless
    converged), ``dofs``, ``cells``, ``degree``, ``min_jacobian``, ``markers``,
    ``cables``, ``pins``, ``grounds`` (dicts of read-outs, None unless
    converged), ``timings`` (s). ``report`` is the solver's own report.
    """

    def __init__(self, data: dict, report=None, state: tuple | None = None):
        self._data, self.report = data, report
        self._state = state          # (rest vertices X, their displacement u, cells), serial runs only

    # -- typed fields ---------------------------------------------------------------------------------
    @property
    def design(self) -> str:
        return self._data["design"]

    @property
    def converged(self) -> bool:
        return bool(self._data["converged"])

    @property
    def status(self) -> str:
        return self._data["status"]

    @property
    def outcome(self) -> Status:
        return Status.of(self._data["status"])

    @property
    def newton_iterations(self) -> int:
        return int(self._data["newton_iterations"])

    @property
    def load_steps(self) -> int:
        return int(self._data["load_steps"])

    @property
    def energy(self) -> float | None:
        return self._data["energy"]

    @property
    def dofs(self) -> int:
        return int(self._data["dofs"])

    @property
    def cells(self) -> int:
        return int(self._data["cells"])

    @property
    def degree(self) -> int:
        return int(self._data["degree"])

    @property
    def min_jacobian(self) -> float:
        return self._data["min_jacobian"]

    @property
    def markers(self) -> dict | None:
        return copy.deepcopy(self._data["markers"])

    @property
    def cables(self) -> dict | None:
        return copy.deepcopy(self._data["cables"])

    @property
    def pins(self) -> dict | None:
        return copy.deepcopy(self._data["pins"])

    @property
    def grounds(self) -> dict | None:
        return copy.deepcopy(self._data["grounds"])

    @property
    def timings(self) -> dict:
        return dict(self._data["timings"])

    def __getattr__(self, key):
        """Other sections of result.json (``dynamics``, ``accuracy``, ...), as copies."""
        try:
            return copy.deepcopy(self.__dict__["_data"][key])
        except KeyError:
            raise AttributeError(key) from None

    # -- numbers for notebooks ---------------------------------------------------------------------
    def marker(self, name: str) -> np.ndarray:
        """A marker's position (mm) as a numpy array; KeyError for an unknown marker."""
        if not self.converged:
            raise ValueError(f"{self.design}: not converged ({self._data['status']}): no marker positions")
        return np.asarray(self._data["markers"][name]["position"], dtype=float)

    def tension(self, cable: str) -> float:
        """A cable's tension (N)."""
        if not self.converged:
            raise ValueError(f"{self.design}: not converged ({self._data['status']}): no tensions")
        return float(self._data["cables"][cable]["tension"])

    def observables(self) -> dict[str, float]:
        """Every observable of this result, {name: value} (``markers.tip.x``, ``cables.flexor.tension``...:
        the names of skelfem.observables, as calibration's CSV columns use them)."""
        from .observables import observables
        return observables(self._data)

    def observable(self, name: str) -> float:
        """One observable by name; KeyError naming the ones there are for an unknown name."""
        values = self.observables()
        if name not in values:
            raise KeyError(f"{name!r}: not an observable of this result (there are: {', '.join(values)})")
        return values[name]

    def error(self, name: str) -> float | None:
        """The estimated error of one observable (the exact value's distance from the computed one), in its
        unit (``Session.solve(estimate=True)`` or ``--estimate``); None where it could not be estimated;
        ValueError without an estimate."""
        errors = self._data.get("errors")
        if errors is None:
            raise ValueError(f"{self.design}: no error estimate (solve with estimate=True, or --estimate)")
        self.observable(name)                                  # KeyError naming the observables there are
        entry = errors.get(name)
        return None if entry is None else entry["error"]

    def displacement(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rest vertex coordinates X, displacement u at them, cells), as numpy arrays (copies), mm.

        Captured when the solve ended; the mesh's vertices (P2's mid-edge nodes are left out).
        Serial sessions only: under MPI each rank holds part of the mesh (write solution.xdmf instead).
        """
        if self._state is None:
            raise RuntimeError("displacement(): the state is kept for serial sessions only; "
                               "under MPI read solution.xdmf")
        return tuple(a.copy() for a in self._state)

    def plot(self, ax=None, show_rest: bool = True):
        """Draw the deformed mesh (and the rest outline, markers) on ``ax``; returns the axes.

        With no ``ax`` a new matplotlib Figure is made without pyplot, so the
        backend is never switched (``ax.figure.savefig(...)`` saves it). 2D only.
        """
        X, u, cells = self.displacement()
        if X.shape[1] != 2:
            raise ValueError("plot(): 2D designs only (3D results: solution.xdmf in ParaView, or deformed.png)")
        if ax is None:
            from matplotlib.figure import Figure
            ax = Figure(figsize=(6, 6)).add_subplot()
        x = X + u
        if show_rest:
            ax.triplot(X[:, 0], X[:, 1], cells, color="0.8", lw=0.3)
        ax.triplot(x[:, 0], x[:, 1], cells, color="#c0504d", lw=0.4)
        for name, m in (self._data.get("markers") or {}).items():
            ax.plot(*m["position"][:2], "o", color="k", ms=4)
            ax.annotate(name, m["position"][:2], textcoords="offset points", xytext=(4, 4), fontsize=8)
        ax.set_aspect("equal")
        ax.set_title(f"{self.design}: {self._data['status']}", fontsize=10)
        return ax

    def to_dict(self) -> dict:
        """result.json, exactly (a deep copy)."""
        return copy.deepcopy(self._data)

    def __repr__(self) -> str:
        d = self._data
        return f"Result({d['design']!r}, {d['status']}, {d['newton_iterations']} Newton iterations)"
