"""The forward model of a calibration: every row of the data solved, with its measurements and their
exact sensitivities to the fitted parameters (see :mod:`skelfem.analysis.calibrate`).

Sensitivities (exact up to round-off). At a converged row, R(x*, p) = 0, so

    dx*/dp = -H^{-1} dR/dp,      H = dR/dx at x* (factorised once per row: Linearization).

dR/dp is obtained for any live parameter by perturbing it and re-assembling the
residual at fixed x*: where R is linear in p (E, cable, spring and ground
stiffness, density, gravity, loads, tractions, a taut tendon's contraction or
pretension) a one-sided difference (one assembly per parameter, R(x*, p)
shared) is exact to round-off; otherwise (nu, a ground's point, a pin's move)
a central difference, with error h^2/6 d3R/dp3
(nu: lambda = E nu / ((1 + nu)(1 - 2 nu)) gives a relative error of about
(h / (1 - 2 nu))^2, 2e-7 at nu = 0.45 with h = 1e-4 nu). The step is 1e-4 of
the parameter, not smaller: the stiff bones' internal forces nearly cancel at
equilibrium, and with h = 1e-6 their round-off, amplified by H^-1 along the
soft modes, put 1.5 % into dx*/dE of PLA bones (E = 3000 MPa against 0.1).
A ground's point is the exception (1e-7 of it): the one-sided contact penalty
has a kink where a node's gap changes sign, and a plane moved by 1e-4 of its
position (0.01 mm) switched a node of a pushed fingertip (a J entry of 148
instead of -1.06). A parameter that moves a fixed pin (its ``move``) changes
the prescribed values g: the residual is taken at x* with the pinned DOFs at
g(p +- h), so that dR/dp holds the coupling K_fD dg/dp that H's eliminated
columns leave out, and dx*/dp = -H^-1 dR/dp + dg/dp. A measurement may also
depend on p directly (a tension k (l - L), a reaction), so the read-outs are
differenced along the joint path (x* + t dx*/dp, p + t): markers are linear in
x, the rest smooth, so the central difference has the same h^2 error.

Forward mode: one right-hand side per parameter and row, all of a row's
solved in one MUMPS solve phase (Linearization.solve_many). Adjoint mode would
need one per measurement column and row, and each read-out's gradient dy/dx
as a vector, which the terms do not expose (they expose read-outs); forward
mode gets the whole Jacobian the Gauss-Newton step needs from directional
differences of the read-outs, and a block solve costs little next to the
row's Newton solve and factorisation (studies/calibration.py --bench-only:
2 -> 20 parameters).
"""
from __future__ import annotations

import contextlib
import logging
import math
from typing import Any

import numpy as np
from petsc4py import PETSc

from .caldata import AXES, Data, DataError, is_path_parameter
from .sensitivity import Linearization
from ..fem.newton import SolveError
from ..terms.capabilities import Constraints

# parameters the residual is linear in (at a fixed active set): a one-sided difference of R is exact
# (a pin's move is not: it lifts the pinned DOFs, and R at the lifted state is not linear in it)
LINEAR = ("E", "stiffness", "density", "acceleration", "force", "traction", "contraction", "pretension")
# parameters that move where a contact starts (a node's gap changes sign within 1e-4 of a ground's
# position): differenced with 1e-3 of the usual step
KINKED = ("point",)


@contextlib.contextmanager
def _quiet():
    """skelfem's log at ERROR and above only, for the duration."""
    logger = logging.getLogger("skelfem")
    level = logger.level
    logger.setLevel(max(level, logging.ERROR))
    try:
        yield
    finally:
        logger.setLevel(level)


log = logging.getLogger("skelfem")


# -- the forward model over all rows ------------------------------------------------------------
class Rows:
    """Solves every row of the data for given parameters, with measurements and their sensitivities."""

    def __init__(self, session, data: Data, progress=None, step: float = 1e-4):
        self.session, self.model, self.solver = session, session.model, session.solver
        self.data, self.progress, self.h = data, progress, float(step)
        live = self.model.parameters()
        self.base = {k: (np.array(v, float) if np.ndim(v) else float(v)) for k, v in live.items()}
        for p in data.parameters:
            if any(b not in live for b, _ in p.targets):
                raise DataError(f"fit: {p.key!r} is not a live parameter of the model")
        for key in data.conditions:
            if key not in live and key.rpartition(".")[0] not in live:
                raise DataError(f"{data.source}: column {key!r} is not a live parameter of the model")
        self.starts = data.starts()
        self.states: list = [None] * data.rows          # each row's last accepted equilibrium
        self.solves = self.newton_iterations = 0
        # parameters owned by hand-written terms only (cables, springs...): dR/dp from those terms'
        # gradients, no assembly of the whole residual (serial, no rigid bones, no Dirichlet owners)
        self._local, self._ufl = {}, {}
        for p in data.parameters:
            owners = [t for t in self.model.terms if any(b in t.parameters() for b, _ in p.targets)]
            if (session.comm.size == 1 and not self.model.rigid and p.base.rsplit(".", 1)[-1] in LINEAR
                    and not any(t.has_ufl_energy() or _holds_dofs(t) for t in owners)):
                self._local[p.key] = owners
            elif (session.comm.size == 1 and not self.model.rigid and p.base.rsplit(".", 1)[-1] in LINEAR
                    and all(t.has_ufl_energy() and t.gradient(self.model.u.x.array) is None
                            and not _holds_dofs(t) for t in owners)):
                self._ufl[p.key] = owners                 # E, densities, gravity: the UFL form alone
        self._sections = sorted({c.split(".", 1)[0] for c in data.columns})
        self._names = {c.split(".")[1] for c in data.columns}            # whose read-outs are needed
        self._linear = np.array([c.startswith("markers.") for c in data.columns])   # y = X + S x
        self._nonlinear = [sec for sec in self._sections if sec != "markers"]
        self.iteration = 0
        # a cable's friction: its Jacobian column is a central difference over the load paths re-solved
        self._path = [j for j, p in enumerate(data.parameters) if is_path_parameter(p.base)]
        self.path_step = 1e-3          # of the coefficient: the rows' Newton tolerance is far below its effect

    # parameters of a row
    def _values(self, theta, i: int) -> dict:
        """{live key: value} for row i under fitted values theta."""
        vals = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in self.base.items()}

        def put(key, value, add=False):
            base, comp = (key, None) if key in vals else (key.rpartition(".")[0], AXES.index(key[-1]))
            if comp is None:
                vals[base] = vals[base] + value if add else value
            else:
                vals[base][comp] = vals[base][comp] + value if add else value
        for key, col in self.data.conditions.items():
            put(key, float(col[i]))
        for p, v in zip(self.data.parameters, theta):
            for b, comp in p.targets:
                put(b if comp is None else f"{b}.{AXES[comp]}", float(v), add=p.offset)
        return vals

    def _apply(self, vals: dict) -> None:
        now = self.model.parameters()
        for k, v in vals.items():
            if not np.array_equal(np.asarray(now[k], float), np.asarray(v, float)):
                self.model.set_parameter(k, v)

    # measurements
    def measure(self, sections=None) -> np.ndarray:
        """The measurement columns at the model's current state (NaN outside sections, if given)."""
        model = self.model
        sections = self._sections if sections is None else sections
        out: dict = {}
        for term in model.terms:
            if term.section in sections and (term.section == "markers" or term.name in self._names):
                values = term.readout(model)
                if values:
                    out.setdefault(term.section, {}).update(values)
        y = np.empty(len(self.data.columns))
        for j, col in enumerate(self.data.columns):
            sec, name, rest = col.split(".", 2)
            if sec not in sections:
                y[j] = math.nan
                continue
            item = out[sec][name]
            if sec == "markers":
                y[j] = item["position"][AXES.index(rest)]
            elif sec == "cables":
                y[j] = item["tension"]
            else:
                what, ax = rest.split(".")
                y[j] = np.asarray(item[what], float)[AXES.index(ax)]
        return y

    # one row
    def _solve(self, i: int, theta, start) -> None:
        model, solver = self.model, self.solver
        self._apply(self._values(theta, i))
        if model.path_dependent:     # friction: the history is the path's, so each path is followed from rest
            start = None
        if start is not None:
            model.u.x.array[:] = start
            model.changes.clear()                    # no predictor from another row's factorisation
            report = solver.resolve(1)
        elif self.starts[i] or not self.session.solved:
            model.to_rest()
            report = solver.solve(self.session.design.solver.steps)
        else:
            report = solver.resolve(1)
        self.solves += 1
        self.newton_iterations += report.newton_iterations
        self.session.solved = bool(report.converged)
        if not report.converged:
            raise SolveError(f"row {i + 1}: the equilibrium did not converge ({report.status})")

    def _sensitivities(self, i: int, theta, y0) -> np.ndarray:
        """dy/dtheta at row i's equilibrium, (columns, parameters).

        Every parameter's dR/dp first, then dx*/dp for all of them in one solve
        phase (Linearization.solve_many), then the read-outs along each path.
        """
        model = self.model
        lin = Linearization(model, self.solver)
        x0 = model.u.vector.copy()
        bp, bm, r0, u0 = x0.duplicate(), x0.duplicate(), None, None
        vals = self._values(theta, i)
        params = self.data.parameters
        m, n = len(params), len(x0.array_r)
        J = np.zeros((len(self.data.columns), m))
        dR, dG, steps = np.zeros((n, m)), np.zeros((n, m)), np.zeros(m)
        try:
            for j, p in enumerate(params):
                if j in self._path:                       # differenced over the paths (run)
                    continue
                value = vals[p.base] if p.component is None else vals[p.base][p.component]
                h = self.h * max(abs(value), p.scale)
                if p.base.rsplit(".", 1)[-1] in KINKED:   # contact switches within a step: a tiny one
                    h *= 1e-3
                steps[j] = h
                if p.key in self._local:                  # only hand-written terms: their gradients
                    model.sync(x0)
                    self._term_difference(self._local[p.key], vals, p, h, bp)
                elif p.key in self._ufl:                  # only the compiled energy: its residual alone
                    if u0 is None:
                        u0 = x0.duplicate()
                        self._ufl_residual(x0, u0)
                    self._set(p, vals, h)
                    self._ufl_residual(x0, bp)
                    bp.axpy(-1.0, u0)
                    bp.scale(1.0 / h)
                elif p.base.rsplit(".", 1)[-1] in LINEAR:   # R linear in p: one-sided is exact
                    if r0 is None:
                        r0 = x0.duplicate()
                        model.residual(x0, r0)
                    self._set(p, vals, h)
                    model.residual(x0, bp)
                    bp.axpy(-1.0, r0)
                    bp.scale(1.0 / h)
                else:           # central; the pins' prescribed values moved with p (lifted: x_D = g(p))
                    moved = []
                    for s, b in ((h, bp), (-h, bm)):
                        self._set(p, vals, s)
                        xs = x0.copy()
                        model.apply_bcs(xs)
                        model.residual(xs, b)
                        moved.append(xs.array_r.copy())
                        xs.destroy()
                    bp.axpy(-1.0, bm)
                    bp.scale(1.0 / (2.0 * h))               # dR/dp, Dirichlet rows zero
                    dG[:, j] = (moved[0] - moved[1]) / (2.0 * h)   # dx_D/dp = dg/dp on the pinned DOFs
                self._set(p, vals, 0.0)
                dR[:, j] = bp.array_r
            DX = dG - lin.solve_many(dR) if m else dR      # dx*/dp, every parameter (owned entries)
            x0a = x0.array_r.copy()
            for j, p in enumerate(params):
                if j in self._path:
                    continue
                h, ys = steps[j], []
                for s in (h, -h):                        # markers are linear in x: one side suffices
                    self._set(p, vals, s)
                    model.u.vector.array_w[:] = x0a + s * DX[:, j]     # x* + s dx*/dp
                    model.u.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
                    ys.append(self.measure(None if s > 0 else self._nonlinear))
                J[:, j] = np.where(self._linear, (ys[0] - y0) / h, (ys[0] - ys[1]) / (2.0 * h))
                self._set(p, vals, 0.0)
        finally:
            self._apply(vals)
            x0.copy(model.u.vector)
            model.sync(model.u.vector)
            model.changes.clear()
            for v in (x0, bp, bm, r0, u0):
                if v is not None:
                    v.destroy()
            lin.destroy()
        return J

    def _ufl_residual(self, x, b) -> None:
        """The compiled energy's part of grad Pi at x, Dirichlet rows zero (no hand-written terms)."""
        from dolfinx.fem import petsc as fem_petsc
        model = self.model
        model.sync(x)
        with b.localForm() as local:
            local.set(0.0)
        fem_petsc.assemble_vector(b, model.residual_form)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        b.array_w[model.fixed[:len(b.array_r)]] = 0.0

    def _term_difference(self, owners, vals, p, h: float, out) -> None:
        """(R(x*, p + h) - R(x*, p)) / h from the owning terms' hand-written gradients alone."""
        model = self.model
        u = model.u.x.array
        g = np.zeros(model.n_local)
        for sign, step in ((1.0, h), (-1.0, 0.0)):
            self._set(p, vals, step)
            for term in owners:
                res = term.gradient(u)
                if res is None:
                    continue
                dofs, values = res
                if term.gather is None:
                    np.add.at(g, dofs, sign * np.asarray(values, float))
                else:
                    term.gather.scatter_add(sign * np.asarray(values, float), g)
        g[model.fixed] = 0.0
        with out.localForm() as local:
            local.set(0.0)
            local.array_w[:] = g / h
        out.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)

    def _set(self, p, vals: dict, s: float) -> None:
        """Set p's live keys to their row values + s (the others stay as they are)."""
        for b, comp in p.targets:
            if comp is None:
                self.model.set_parameter(b, vals[b] + s)
            else:
                v = vals[b].copy()
                v[comp] += s
                self.model.set_parameter(b, v)

    def restore(self) -> None:
        """Give the model back the design's values of every live parameter (after the last row)."""
        self._apply(self.base)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.restore()

    def errors(self, theta, states=None) -> tuple[np.ndarray, np.ndarray]:
        """(E, S), each (rows, columns): every measured column's estimated model error |exact - computed|
        (skelfem.estimate) and the richer degree's signed change at each row's equilibrium for theta, the
        rows solved in order from states (default: their load paths from rest); NaN where a row's estimate
        failed. SolveError if a row fails."""
        from ..estimate import EstimateError, estimate
        theta = np.asarray(theta, float)
        states = [None] * self.data.rows if states is None else states
        E = np.full((self.data.rows, len(self.data.columns)), math.nan)
        S = E.copy()
        for i in range(self.data.rows):
            self._solve(i, theta, states[i])
            try:
                with _quiet():                    # its advice on the solver's tolerance is for a run
                    found = estimate(self.session)["errors"] or {}
            except (EstimateError, RuntimeError, np.linalg.LinAlgError, PETSc.Error) as exc:
                log.warning("calibrate: row %d: no model error estimate (%s)", i + 1, exc)
                found = {}
            for j, c in enumerate(self.data.columns):
                e = found.get(c) or {}
                if e.get("error") is not None:
                    E[i, j], S[i, j] = e["error"], e["change"]
            if self.progress is not None:
                self.progress(self.iteration, i + 1, self.data.rows)
        return E, S

    def run(self, theta, jacobian: bool = True, states=None):
        """(Y, J, states): every row solved for theta; J (rows, columns, parameters) or None.

        states: each row's start (default: the accepted ones); SolveError if a row fails.
        """
        theta = np.asarray(theta, float)
        states = self.states if states is None else states
        n = self.data.rows
        Y = np.empty((n, len(self.data.columns)))
        J: Any = np.zeros((n, len(self.data.columns), len(theta))) if jacobian else None
        new = [None] * n
        for i in range(n):
            self._solve(i, theta, states[i])
            Y[i] = self.measure()
            if jacobian and len(self._path) < len(theta):
                try:
                    J[i] = self._sensitivities(i, theta, Y[i])
                except (RuntimeError, np.linalg.LinAlgError, PETSc.Error) as exc:   # GMRES through friction...
                    self.session.solved = False
                    raise SolveError(f"row {i + 1}: the equilibrium converged but its sensitivity solve "
                                     f"failed ({exc})") from None
            new[i] = self.model.u.x.array.copy()
            if self.progress is not None:
                self.progress(self.iteration, i + 1, n)
        if jacobian:
            for j in self._path:
                J[:, :, j] = self._path_column(theta, j)
        return Y, J, new

    def _path_column(self, theta, j: int) -> np.ndarray:
        """dY/dtheta_j (rows, columns) by central differences of the measurements over every load path
        solved from rest at theta_j +- h: a friction coefficient moves the history the rows carry."""
        h = self.path_step * max(abs(float(theta[j])), self.data.parameters[j].scale)
        Ys = []
        for s in (h, -h):
            t = np.array(theta, float)
            t[j] += s
            Y = np.empty((self.data.rows, len(self.data.columns)))
            for i in range(self.data.rows):
                self._solve(i, t, None)
                Y[i] = self.measure()
            Ys.append(Y)
        return (Ys[0] - Ys[1]) / (2.0 * h)


def _holds_dofs(term) -> bool:
    """Whether a term imposes Dirichlet conditions (its parameter moves DOFs, not a force)."""
    return isinstance(term, Constraints) and bool(term.dirichlet())
