"""Calibration: fit live parameters of a design to measured states (bounded Gauss-Newton / LM).

    from skelfem import Session, calibrate
    with Session("geometry/finger.toml") as s:
        cal = calibrate(s, "geometry/finger_calibration.csv", fit=["materials.ecoflex.E"],
                        sigma={"markers.*": 0.1})
        print(cal.values, cal.std, cal.unidentifiable)

The data contract (columns, experiments, offsets) is in :mod:`skelfem.analysis.caldata`.

Misfit. With y_ij(p) the model's value of measurement column j in row i (at the
equilibrium x*_i(p) of that row's conditions), d_ij the data and sigma_j the
column's standard deviation, r_ij = (y_ij - d_ij) / sigma_j over the measured
cells of the fitted rows, and the misfit is f(p) = 1/2 |r|^2.

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

Step. In scaled parameters z = p / s (s = |p0|, 1 if p0 = 0) the LM step solves
min |r + J D|^2 + mu |D|^2 within the bounds (scipy's lsq_linear), accepted if
f decreases, mu by Nielsen's rule. Every trial solves every row, each from the
same row's last accepted equilibrium (the first pass: from the previous row of
its load path; a path's first row from rest), so a row stays on its branch.

Uncertainty. Cov(p) = s2 (J^T J)^+ (J weighted): s2 = 1 when every column's
sigma is given, else the reduced chi-square |r|^2 / (n - m). Groups of
parameters the data cannot separate are read from the singular vectors of the
weighted, scaled Jacobian whose singular values fall below rcond x the largest.
"""
from __future__ import annotations

import logging
import math
import time

import numpy as np
from petsc4py import PETSc

from .caldata import AXES, Calibration, Data, DataError, prepare_data  # noqa: F401 (Calibration re-exported)
from .sensitivity import Linearization
from ..fem.newton import SolveError

log = logging.getLogger("skelfem")

RCOND = 1e-6          # singular values below this fraction of the largest: an unidentifiable direction
# parameters the residual is linear in (at a fixed active set): a one-sided difference of R is exact
# (a pin's move is not: it lifts the pinned DOFs, and R at the lifted state is not linear in it)
LINEAR = ("E", "stiffness", "density", "acceleration", "force", "traction", "contraction", "pretension")
# parameters that move where a contact starts (a node's gap changes sign within 1e-4 of a ground's
# position): differenced with 1e-3 of the usual step
KINKED = ("point",)
GROUP = 0.2           # a parameter belongs to such a direction's group above this fraction of its largest entry


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
                    and not any(t.has_ufl_energy() or t.dirichlet() for t in owners)):
                self._local[p.key] = owners
            elif (session.comm.size == 1 and not self.model.rigid and p.base.rsplit(".", 1)[-1] in LINEAR
                    and all(t.has_ufl_energy() and t.gradient(self.model.u.x.array) is None
                            and not t.dirichlet() for t in owners)):
                self._ufl[p.key] = owners                 # E, densities, gravity: the UFL form alone
        self._sections = sorted({c.split(".", 1)[0] for c in data.columns})
        self._names = {c.split(".")[1] for c in data.columns}            # whose read-outs are needed
        self._linear = np.array([c.startswith("markers.") for c in data.columns])   # y = X + S x
        self._nonlinear = [sec for sec in self._sections if sec != "markers"]
        self.iteration = 0

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

    def run(self, theta, jacobian: bool = True, states=None):
        """(Y, J, states): every row solved for theta; J (rows, columns, parameters) or None.

        states: each row's start (default: the accepted ones); SolveError if a row fails.
        """
        theta = np.asarray(theta, float)
        states = self.states if states is None else states
        n = self.data.rows
        Y = np.empty((n, len(self.data.columns)))
        J = np.zeros((n, len(self.data.columns), len(theta))) if jacobian else None
        new = [None] * n
        for i in range(n):
            self._solve(i, theta, states[i])
            Y[i] = self.measure()
            if jacobian:
                J[i] = self._sensitivities(i, theta, Y[i])
            new[i] = self.model.u.x.array.copy()
            if self.progress is not None:
                self.progress(self.iteration, i + 1, n)
        return Y, J, new


# -- the fit ---------------------------------------------------------------------------------------
def _weighted(data: Data, Y, J):
    """r and J_r of the fitted rows' measured cells, weighted by 1/sigma (J in raw parameters)."""
    mask = np.isfinite(data.values) & data.train[:, None]
    R = (Y - data.values) / data.sigma
    r = R[mask]
    Jr = (J / data.sigma[None, :, None])[mask] if J is not None else None
    return r, Jr


def calibrate(session, data, fit=None, sigma=None, bounds=None, holdout: float = 0.0, *,
              max_iterations: int = 20, xtol: float = 1e-8, gtol: float = 1e-14, rcond: float = RCOND,
              progress=None, seed: int = 0) -> Calibration:
    """Fit the live parameters `fit` of the session's design to `data` (see the module doc).

    data: a CSV path, CSV text, {column: values} or a prepared Data (then fit,
    sigma, bounds and holdout are taken from it). progress(iteration, row, rows)
    is called after every row solve. The session's model is given back its
    design's parameter values (its state is the last row's equilibrium, from
    which the next solve warm-starts); apply the estimate with
    ``session.set(cal.overrides(session.design))``.
    """
    t0 = time.perf_counter()
    if session.comm.size > 1:
        raise ValueError(f"calibration runs on one MPI process (got {session.comm.size})")
    if not isinstance(data, Data):
        data = prepare_data(session.design, data, fit, sigma, bounds, holdout, seed)
    with Rows(session, data, progress) as rows:
        return _fit(rows, data, t0, max_iterations, xtol, gtol, rcond)


def _fit(rows, data: Data, t0: float, max_iterations: int, xtol: float, gtol: float, rcond: float) -> Calibration:
    """The Levenberg-Marquardt iterations and the uncertainty at the estimate (see calibrate)."""
    from scipy.optimize import lsq_linear
    from scipy.stats import t as student

    P = data.parameters
    m = len(P)
    scale = np.array([p.scale for p in P])
    lo = np.array([p.lower for p in P]) / scale
    hi = np.array([p.upper for p in P]) / scale
    theta = np.array([p.initial for p in P])
    try:
        Y, J, states = rows.run(theta)
    except SolveError as exc:
        raise SolveError(f"at the start: {exc}") from None
    rows.states = states
    r, Jr = _weighted(data, Y, J)
    cost = 0.5 * float(r @ r)
    history, status, converged = [cost], "max_iterations", False
    A = Jr * scale
    mu, it, rejected = 1e-3, 0, 0                           # Marquardt: damping relative to diag(A^T A)
    while it < max_iterations:
        rows.iteration = it + 1
        g = A.T @ r
        if np.max(np.abs(g)) <= gtol * max(1.0, 2.0 * cost) or cost == 0.0:
            status, converged = "gradient", True
            break
        z = theta / scale
        d = np.sqrt(np.maximum(np.sum(A * A, axis=0), 1e-30 * max(float(np.max(np.sum(A * A, axis=0))), 1e-300)))
        K = np.vstack([A, math.sqrt(mu) * np.diag(d)])
        sol = lsq_linear(K, np.concatenate([-r, np.zeros(m)]), bounds=(lo - z, hi - z),
                         method="bvls" if m <= 30 else "trf", lsmr_tol="auto")
        D = sol.x
        if np.max(np.abs(D)) <= xtol * (1.0 + np.max(np.abs(z))):
            status, converged = "small step", True
            break
        pred = float(r @ r - np.sum((r + A @ D) ** 2))
        if not np.all(np.isfinite(D)) or pred <= 1e-10 * max(float(r @ r), 1e-300):
            status, converged = "no further decrease predicted", True
            break
        it += 1
        trial = np.clip((z + D) * scale, [p.lower for p in P], [p.upper for p in P])
        try:
            Yt, Jt, st = rows.run(trial)
        except SolveError as exc:
            log.info("calibrate: trial step failed (%s); more damping", exc)
            mu *= 10.0
            continue
        rt, Jrt = _weighted(data, Yt, Jt)
        ct = 0.5 * float(rt @ rt)
        rho = (2.0 * (cost - ct)) / pred
        if rho > 0.0:
            theta, Y, J, r, cost, A = trial, Yt, Jt, rt, ct, Jrt * scale
            rows.states = st
            history.append(cost)
            log.info("calibrate: iteration %d, cost %.6g, mu %.3g", it, cost, mu)
            rejected = 0
        else:
            rejected += 1
            if rejected >= 6:      # at the minimum within the solves' round-off, or stuck
                status = "no decrease in 6 damped steps"
                converged = cost <= 1e-14 * history[0] or pred <= 1e-6 * max(2.0 * cost, 1e-300)
                break
        mu = mu / 10.0 if rho > 0.75 else (mu if rho > 0.25 else mu * (2.0 if rho > 0.0 else 4.0))
        mu = min(max(mu, 1e-12), 1e12)
    # uncertainty
    n = len(r)
    U, sv, Vt = np.linalg.svd(A, full_matrices=False) if m else (None, np.zeros(0), np.zeros((0, 0)))
    keep = sv > rcond * (sv[0] if len(sv) else 0.0)
    groups = []
    for k in np.flatnonzero(~keep):
        v = np.abs(Vt[k])
        groups.append(sorted(np.flatnonzero(v >= GROUP * v.max()).tolist()))
    groups = _merge(groups)
    inv = (Vt[keep].T / sv[keep] ** 2) @ Vt[keep] if m else np.zeros((0, 0))
    all_given = bool(np.all(data.sigma_given))
    s2 = 1.0 if all_given else (2.0 * cost / (n - m) if n > m else math.nan)
    cov = s2 * inv * np.outer(scale, scale)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    bad = sorted({i for g in groups for i in g})
    std[bad] = math.inf
    q = 1.959963984540054 if all_given or n <= m else float(student.ppf(0.975, n - m))
    ci = np.column_stack([theta - q * std, theta + q * std])
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    corr[bad, :] = math.nan
    corr[:, bad] = math.nan
    np.fill_diagonal(corr, 1.0)
    rms = _rms(data, Y, data.train)
    hold = None
    if (~data.train).any():
        Rw = ((Y - data.values) / data.sigma)[~data.train]
        hold = {"rows": int((~data.train).sum()), "rms": _rms(data, Y, ~data.train),
                "weighted_rms": float(np.sqrt(np.nanmean(Rw ** 2)))}
    return Calibration(
        keys=[p.key for p in P], initial=np.array([p.initial for p in P]), values=theta, std=std, ci95=ci,
        covariance=cov, correlation=corr, singular_values=sv,
        unidentifiable=[[P[i].key for i in g] for g in groups], iterations=it, converged=converged,
        status=status, cost=cost, history=history, columns=list(data.columns), rms=rms, holdout=hold,
        model_values=Y, data=data, offsets=[p.key for p in P if p.offset], s2=s2, solves=rows.solves,
        newton_iterations=rows.newton_iterations, time=time.perf_counter() - t0)


def _rms(data: Data, Y, rows) -> dict:
    out = {}
    for j, c in enumerate(data.columns):
        d = (Y[rows, j] - data.values[rows, j])
        d = d[np.isfinite(d)]
        out[c] = float(np.sqrt(np.mean(d ** 2))) if len(d) else None
    return out


def _merge(groups: list) -> list:
    """Union of overlapping index groups."""
    out: list = []
    for g in groups:
        g = set(g)
        for h in [h for h in out if h & g]:
            g |= h
            out.remove(h)
        out.append(g)
    return [sorted(g) for g in out]


def misfit(session, data: Data, theta, jacobian: bool = True):
    """(f, grad f) of the misfit at theta (every row solved from its path's start; for checks)."""
    with Rows(session, data) as rows:
        Y, J, _ = rows.run(theta, jacobian)
    r, Jr = _weighted(data, Y, J)
    return 0.5 * float(r @ r), (Jr.T @ r if jacobian else None)


def synthesize(session, conditions: dict, columns, experiments=None, noise: dict | None = None,
               rng=None) -> dict:
    """Synthetic measurements: {column: values} for each row of conditions ({key: values}), solved in order.

    noise: {column or fnmatch pattern: std} of Gaussian noise added (rng: a numpy Generator).
    Rows of one experiment form a load path from rest, as in a calibration.
    """
    import fnmatch
    conditions = {k: np.asarray(v, float) for k, v in conditions.items()}
    n = len(next(iter(conditions.values()))) if conditions else 1
    experiments = list(experiments) if experiments is not None else ["1"] * n
    cols = list(columns)
    data = Data(cols, np.zeros((n, len(cols))), np.ones(len(cols)), np.zeros(len(cols), bool),
                conditions, [str(e) for e in experiments], [], np.ones(n, bool))
    with Rows(session, data) as rows:
        Y, _, _ = rows.run(np.zeros(0), jacobian=False)
    if noise:
        rng = rng if rng is not None else np.random.default_rng(0)
        for j, c in enumerate(cols):
            sd = [v for pat, v in noise.items() if fnmatch.fnmatchcase(c, pat)]
            if sd:
                Y[:, j] += rng.normal(0.0, sd[-1], n)
    out = {k: v.copy() for k, v in conditions.items()}
    if experiments is not None:
        out["experiment"] = [str(e) for e in experiments]
    out.update({c: Y[:, j].copy() for j, c in enumerate(cols)})
    return out
