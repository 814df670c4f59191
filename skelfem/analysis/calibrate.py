"""Calibration: fit live parameters of a design to measured states (bounded trust-region Gauss-Newton).

    from skelfem import Session, calibrate
    with Session("geometry/finger.toml") as s:
        cal = calibrate(s, "geometry/finger_calibration.csv", fit=["materials.ecoflex.E"],
                        sigma={"markers.*": 0.1})
        print(cal.values, cal.ci95, cal.unidentifiable, cal.identify_with)

The data contract (columns, experiments, offsets) is in :mod:`skelfem.analysis.caldata`.

Misfit. With y_ij(p) the model's value of measurement column j in row i (at the
equilibrium x*_i(p) of that row's conditions), d_ij the data and sigma_j the
column's standard deviation, r_ij = (y_ij - d_ij) / sigma_j over the measured
cells of the fitted rows, and the misfit is f(p) = 1/2 |r|^2.

Sensitivities: exact up to round-off, forward mode (skelfem.analysis.calrows).

Coordinates. A positive quantity (E, a stiffness, a density, a pretension or
friction coefficient that starts > 0) is fitted in z = log(p / p0), the others
in z = (p - p0) / s (s = |p0|, 1 if p0 = 0): in log coordinates a stiffness
cannot step below zero, its box is a plain interval, and J_z = p dy/dp is
scale-free (the same for every start along a scaling).

Step. scipy's least_squares, method 'trf' (a trust-region reflective
Gauss-Newton: a step that meets a bound moves along it) with the exact
Jacobian. Every trial solves every row, each from the same row's last accepted
equilibrium (the first pass: from the previous row of its load path; a path's
first row from rest), so a row stays on its branch; a trial whose row fails
shrinks the trust region. It stops when least_squares' tolerances are met or
the next Gauss-Newton step is below 1e-3 of every standard deviation; after
max_iterations it returns its best state with converged False. Several
starts (`starts`): the design's values and others drawn within a decade of
them; the lowest misfit wins.

Uncertainty. Cov(z) = s2 (J_z^T J_z)^+ (J weighted): s2 = 1 when every
column's sigma is given, else the reduced chi-square |r|^2 / (n - m). A
positive quantity's 95 % interval is exp(log p +- q s_z), i.e. p x/÷ factor
(always > 0); a linear one's p +- q s. Unidentifiable groups are read from the
null space of J_z (singular values below rcond x the largest) in reduced row
echelon form, at the start and at the estimate (scale-free, and independent
of how the SVD turns a null space of more than one dimension); a positive
quantity whose interval spans more than a decade is not identified either.
For each group, the measurement columns the design offers but the data lack
are probed (one more pass): those whose derivative along the group's
direction is not zero would identify it.
"""
from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np

from .caldata import Calibration, Data, DataError, prepare_data  # noqa: F401 (Calibration re-exported)
from .calerror import DEFAULT as MODEL_ERROR, MAX_DOFS, ModelError, check_mode
from .calrows import Rows  # noqa: F401 (re-exported)
from ..fem.newton import SolveError

log = logging.getLogger("skelfem")

RCOND = 1e-6          # singular values below this fraction of the largest: an unidentifiable direction
GROUP = 0.2           # a parameter belongs to such a direction's group above this fraction of its largest entry
DECADE = 10.0         # a positive quantity whose 95 % interval spans more than this ratio is not identified
SEES = 1e-3           # a measurement sees a direction when its derivative along it is above this of its largest
MAX_STARTS = 100
STARTS_SPREAD = math.log(10.0)   # further starts: within a decade of the design's values (log ones), or
                                 # half their scale (the others)
SETTLED = 1e-3       # converged when the next Gauss-Newton step is below this of every standard deviation
MAX_TRIALS = 10       # trial steps allowed per iteration (least_squares' evaluation budget)
CORRECTIONS = 5       # refits to the data less the model's estimated error, at most
SETTLED_Z = 1e-2      # ... until the estimate moves by less than this (in z: a relative change for log ones;
                      # far below the correction's own share of the std, which is the whole correction)


# -- the fit ---------------------------------------------------------------------------------------
def _weighted(data: Data, Y, J, sigma=None):
    """r and J_r of the fitted rows' measured cells, weighted by 1/sigma (J in raw parameters); sigma:
    (rows, columns) of each cell (default: its column's)."""
    mask = np.isfinite(data.values) & data.train[:, None]
    sigma = np.broadcast_to(data.sigma if sigma is None else sigma, data.values.shape)
    R = (Y - data.values) / sigma
    r = R[mask]
    Jr = (J / sigma[:, :, None])[mask] if J is not None else None
    return r, Jr


def calibrate(session, data, fit=None, sigma=None, bounds=None, holdout: float = 0.0, *,
              max_iterations: int = 20, starts: int = 1, xtol: float = 1e-8, ftol: float = 1e-8,
              gtol: float = 1e-8, rcond: float = RCOND, progress=None, seed: int = 0,
              model_error: str = MODEL_ERROR, max_dofs: int = MAX_DOFS) -> Calibration:
    """Fit the live parameters `fit` of the session's design to `data` (see the module doc).

    data: a CSV path, CSV text, {column: values} or a prepared Data (then fit,
    sigma, bounds and holdout are taken from it). starts: the number of starts
    (the first at the design's values, the others drawn within a decade of
    them, seeded); the lowest misfit wins. progress(iteration, row, rows)
    is called after every row solve. The session's model is given back its
    design's parameter values (its state is the last row's equilibrium, from
    which the next solve warm-starts); apply the estimate with
    ``session.set(cal.overrides(session.design))``. A fit that does not
    converge returns its best state with ``converged`` False. model_error: what the fit does
    with the model's own discretisation error, estimated in every cell at the start and at the
    estimate (skelfem.analysis.calerror: "inflate", "refine" (re-meshes the session, up to
    max_dofs; the session keeps the finer mesh) or "ignore"); reported in ``model_error``.
    """
    t0 = time.perf_counter()
    if session.comm.size > 1:
        raise ValueError(f"calibration runs on one MPI process (got {session.comm.size})")
    if not 1 <= int(starts) <= MAX_STARTS:
        raise DataError(f"starts {starts}: must be >= 1 and <= {MAX_STARTS}")
    check_mode(model_error)
    if not isinstance(data, Data):
        data = prepare_data(session.design, data, fit, sigma, bounds, holdout, seed)
    err = ModelError(data, model_error, max_dofs)
    theta0 = np.array([p.initial for p in data.parameters], float)
    while True:                         # refine: re-mesh until the model's error is below the target
        with Rows(session, data, progress) as rows:
            err.start = err.estimate(rows, theta0)[0]
            finer = err.wants_finer(session, err.start)
            if not finer:
                cal = _fit(rows, data, t0, max_iterations, int(starts), seed, xtol, ftol, gtol, rcond, err)
                finer = err.wants_finer(session, err.end, "estimate")
        if not finer:
            return cal
        err.halve(session)


class _Stop(Exception):
    """The iteration limit: the fit ends at its last accepted state."""


class _Done(Exception):
    """Converged: the next Gauss-Newton step is far below the estimate's standard deviations."""


class _Objective:
    """The weighted residuals r(z) and their Jacobian in the fit's coordinates z, for least_squares.

    fun(z) solves every row (with its sensitivities) from the rows' last accepted
    equilibria; a row that fails gives NaN (least_squares then shrinks its trust
    region). least_squares asks for the Jacobian only where it accepts a step:
    jac(z) returns that solve's Jacobian and makes its equilibria the rows' starts.
    Both are divided by the start's |r| (1 if zero), so that least_squares'
    tolerances are relative to the start's misfit whatever the sigmas.
    """

    def __init__(self, rows, data: Data, max_iterations: int, sigma=None):
        self.rows, self.data, self.P, self.sigma = rows, data, data.parameters, sigma
        self.max_iterations = max_iterations
        self.trials: dict = {}
        self.accepted: Any = None       # (z, Y, r, Jz) of the last accepted point
        self.iterations, self.failed = -1, 0
        self.history: list = []
        self.norm = 1.0

    def theta(self, z) -> np.ndarray:
        return np.array([p.from_z(v) for p, v in zip(self.P, z)], float)

    def evaluate(self, z):
        """(Y, states, r, Jz) at z; SolveError if a row fails."""
        theta = self.theta(z)
        Y, J, states = self.rows.run(theta)
        r, Jr = _weighted(self.data, Y, J, self.sigma)
        Jz = Jr * np.array([p.dvalue_dz(v) for p, v in zip(self.P, theta)])
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(Jz))):
            raise SolveError("the weighted residuals or their derivatives are not finite")
        return Y, states, r, Jz

    def fun(self, z):
        key = np.asarray(z, float).tobytes()
        if key not in self.trials:
            try:
                self.trials[key] = self.evaluate(z)
            except SolveError as exc:
                log.info("calibrate: a trial step failed (%s); a smaller step", exc)
                self.failed += 1
                return np.full(self._n, np.nan)
        return self.trials[key][2] * self.norm

    def jac(self, z, f=None):
        key = np.asarray(z, float).tobytes()
        if key not in self.trials:
            self.fun(z)
        Y, states, r, Jz = self.trials[key]
        self.trials = {key: self.trials[key]}
        self.rows.states = states
        self.accepted = (np.array(z, float), Y, r, Jz)
        self.history.append(0.5 * float(r @ r))
        self.iterations += 1
        self.rows.iteration = self.iterations + 1
        if self.iterations:
            log.info("calibrate: iteration %d, cost %.6g", self.iterations, self.history[-1])
        if self.iterations and self._settled(r, Jz):
            raise _Done
        if self.iterations >= self.max_iterations:
            raise _Stop
        return Jz * self.norm

    def _settled(self, r, Jz) -> bool:
        """Whether the Gauss-Newton step from here moves every parameter by less than SETTLED of its
        standard deviation (its rounding by the solves' tolerance is then all that is left to gain)."""
        n, m = Jz.shape
        U, sv, Vt = np.linalg.svd(Jz, full_matrices=False)
        keep = sv > RCOND * sv[0] if len(sv) and sv[0] > 0 else np.zeros(len(sv), bool)
        if n <= m or not keep.any():
            return False
        step = Vt[keep].T @ ((U[:, keep].T @ r) / sv[keep])
        s2 = 1.0 if np.all(self.data.sigma_given) else float(r @ r) / (n - m)
        std = np.sqrt(s2 * np.sum((Vt[keep] / sv[keep, None]) ** 2, axis=0))
        return bool(np.all(np.abs(step) <= SETTLED * std))

    def start(self, z0):
        """Evaluate the start (SolveError if a row fails there)."""
        self.rows.states = [None] * self.data.rows
        Y, states, r, Jz = self.evaluate(z0)
        self._n = len(r)
        size = float(np.linalg.norm(r))
        self.norm = 1.0 / size if size > 0 else 1.0
        self.trials = {np.asarray(z0, float).tobytes(): (Y, states, r, Jz)}
        return Jz


def _one_fit(rows, data: Data, z0, max_iterations: int, xtol: float, ftol: float, gtol: float,
             sigma=None) -> dict:
    """One trust-region fit (least_squares 'trf': a step on a bound moves along it) from z0; sigma: the
    cells' (rows, columns), default their columns'."""
    from scipy.optimize import least_squares
    obj = _Objective(rows, data, max_iterations, sigma)
    J0 = obj.start(z0)
    lo, hi = np.array([p.z_bounds() for p in data.parameters]).T.reshape(2, -1)
    converged, status = False, "max_iterations"
    try:
        res = least_squares(obj.fun, z0, jac=obj.jac, bounds=(lo, hi), method="trf", x_scale=1.0,
                            xtol=xtol, ftol=ftol, gtol=gtol, max_nfev=MAX_TRIALS * (max_iterations + 1),
                            tr_solver="exact")
        converged = res.status > 0
        status = {1: "gradient", 2: "no further decrease", 3: "small step", 4: "small step",
                  0: "too many trial steps", -1: "improper input"}.get(res.status, str(res.status))
    except _Done:
        converged, status = True, f"step below {SETTLED:g} of the standard deviations"
    except _Stop:
        pass
    z, Y, r, Jz = obj.accepted
    return {"z": z, "Y": Y, "r": r, "Jz": Jz, "J0": J0, "cost": 0.5 * float(r @ r), "converged": converged,
            "status": status, "iterations": max(obj.iterations, 0), "history": obj.history,
            "failed": obj.failed}


def _fit(rows, data: Data, t0: float, max_iterations: int, starts: int, seed: int, xtol: float, ftol: float,
         gtol: float, rcond: float, err: ModelError) -> Calibration:
    """The trust-region fits from every start and the uncertainty at the best estimate (see calibrate)."""
    from scipy.stats import t as student

    P = data.parameters
    m = len(P)
    zlo, zhi = (np.array([p.z_bounds()[k] for p in P]) for k in (0, 1))
    rng = np.random.default_rng(seed)
    fits: list = []                  # one per start: its fit, or None where it failed
    z0s = [np.zeros(m)]
    spread = np.array([STARTS_SPREAD if p.log else 0.5 for p in P])
    for _ in range(starts - 1):
        z = rng.uniform(-1.0, 1.0, m) * spread
        z0s.append(np.clip(z, zlo + 1e-9 * np.abs(zlo), zhi - 1e-9 * np.abs(zhi)))
    sig = err.sigma()
    for k, z0 in enumerate(z0s):
        try:
            fits.append(_one_fit(rows, data, z0, max_iterations, xtol, ftol, gtol, sig))
        except SolveError as exc:
            if k == 0:
                raise SolveError(f"at the start: {exc}") from None
            log.info("calibrate: start %d failed (%s)", k + 1, exc)
            fits.append(None)
    best = _corrected(rows, min((f for f in fits if f is not None), key=lambda f: f["cost"]), err,
                      max_iterations, xtol, ftol, gtol, sig)
    z, Y, r, A, cost = best["z"], best["Y"], best["r"], best["Jz"], best["cost"]
    theta = np.array([p.from_z(v) for p, v in zip(P, z)], float)
    dz = np.array([p.dvalue_dz(v) for p, v in zip(P, theta)], float)     # d theta / d z

    # identifiability from the structure: directions the Jacobian (in z: scale-free) does not see
    g0, basis0, _ = _null_groups(fits[0]["J0"], rcond)
    g1, basis1, _ = _null_groups(A, rcond)
    groups = _merge(g0 + g1)
    # uncertainty (in z; a positive quantity's interval is exp(log theta +- q s))
    n = len(r)
    U, svals, Vt = np.linalg.svd(A, full_matrices=False) if m else (None, np.zeros(0), np.zeros((0, 0)))
    keep = svals > rcond * (svals[0] if len(svals) else 0.0)
    inv = (Vt[keep].T / svals[keep] ** 2) @ Vt[keep] if m else np.zeros((0, 0))
    all_given = bool(np.all(data.sigma_given))
    s2 = 1.0 if all_given else (2.0 * cost / (n - m) if n > m else math.nan)
    cov_z = err.covariance(A, inv, s2, np.isfinite(data.values) & data.train[:, None], sig)
    std_z = np.sqrt(np.maximum(np.diag(cov_z), 0.0))
    bad = sorted({i for g in groups for i in g})
    std_z[bad] = math.inf
    q = 1.959963984540054 if all_given or n <= m else float(student.ppf(0.975, n - m))
    logp = np.array([p.log for p in P], bool)
    cov = cov_z * np.outer(dz, dz)
    std = std_z * np.abs(dz)
    with np.errstate(over="ignore", invalid="ignore"):
        factor = np.where(logp, np.exp(q * std_z), math.nan)
        ci = np.where(logp[:, None], np.column_stack([theta / factor, theta * factor]),
                      np.column_stack([theta - q * std, theta + q * std]))
        corr = cov_z / np.outer(std_z, std_z)
    corr[bad, :] = math.nan
    corr[:, bad] = math.nan
    np.fill_diagonal(corr, 1.0)
    identified, reasons = [], []
    for i, p in enumerate(P):
        if i in bad:
            why = "the data cannot separate it from " + ", ".join(P[j].key for g in groups if i in g for j in g
                                                                    if j != i) if any(
                len(g) > 1 and i in g for g in groups) else "the data do not see it"
        elif not math.isfinite(std_z[i]):
            why = "no interval"
        elif p.log and factor[i] ** 2 > DECADE:
            why = f"its 95 % interval spans more than a decade (x/÷ {factor[i]:.3g})"
        else:
            why = ""
        identified.append(not why)
        reasons.append(why)
    keys = [[P[i].key for i in g] for g in groups]
    hints = _identify_with(rows, data, theta, dz, groups, list(basis0) + list(basis1)) if groups else []
    rms = _rms(data, Y, data.train)
    hold = None
    if (~data.train).any():                 # predictions: corrected by the model's estimated error, if not ignored
        Yp = Y + np.nan_to_num(err.change) if err.mode != "ignore" and err.change is not None else Y
        Rw = ((Yp - data.values) / data.sigma)[~data.train]
        hold = {"rows": int((~data.train).sum()), "rms": _rms(data, Yp, ~data.train),
                "weighted_rms": float(np.sqrt(np.nanmean(Rw ** 2)))}
    runs = [{"initial": {p.key: float(p.from_z(v)) for p, v in zip(P, z0)},
             **({"failed": True} if f is None else
                {"cost": f["cost"], "iterations": f["iterations"], "converged": bool(f["converged"]),
                 "status": f["status"], "best": f is best})} for z0, f in zip(z0s, fits)]
    return Calibration(
        keys=[p.key for p in P], initial=np.array([p.initial for p in P]), values=theta, std=std, ci95=ci,
        covariance=cov, correlation=corr, singular_values=svals,
        unidentifiable=keys, iterations=best["iterations"], converged=bool(best["converged"]),
        status=best["status"], cost=cost, history=best["history"], columns=list(data.columns), rms=rms,
        holdout=hold, model_values=Y, data=data, offsets=[p.key for p in P if p.offset], s2=s2,
        solves=rows.solves, newton_iterations=rows.newton_iterations, time=time.perf_counter() - t0,
        factor=factor, identified=identified, reasons=reasons,
        groups_start=[[P[i].key for i in g] for g in g0], groups_end=[[P[i].key for i in g] for g in g1],
        identify_with=hints, starts=runs, model_error=err.report(dz),
        model_errors=err.end)


def _corrected(rows, fit: dict, err: ModelError, max_iterations: int, xtol: float, ftol: float, gtol: float,
               sig) -> dict:
    """The fit to the data less the model's estimated error (calerror), refitted from `fit` with the error
    estimated again at each new estimate until z moves by less than SETTLED_Z (at most CORRECTIONS times);
    `fit` itself when the error is ignored or the fit did not converge. Sets err.end and err.change (the
    last estimate) and err.shift (how far z moved; None if the first refit failed)."""
    P = rows.data.parameters
    out, err.shift = fit, None
    err.uncorrected = np.array([p.from_z(v) for p, v in zip(P, fit["z"])], float)
    for _ in range(CORRECTIONS):
        theta = np.array([p.from_z(v) for p, v in zip(P, out["z"])], float)
        err.end, err.change = err.estimate(rows, theta, rows.states)
        if err.mode == "ignore" or not len(P) or not fit["converged"]:     # a fit that stopped: not corrected
            break
        states = rows.states
        try:
            new = _one_fit(rows, err.corrected(), out["z"], max_iterations, xtol, ftol, gtol, sig)
        except SolveError as exc:
            log.info("calibrate: the refit to the data less the model's error failed (%s)", exc)
            rows.states = states
            break
        moved = float(np.max(np.abs(new["z"] - out["z"])))
        new["iterations"] += out["iterations"]                  # every iteration, the first fit's and the refits'
        out, err.shift = new, new["z"] - fit["z"]
        err.corrections += 1
        if moved < SETTLED_Z:
            break
    return out


def _null_groups(A, rcond: float):
    """(groups, basis, singular values) of the directions A does not see.

    The null space (singular values below rcond x the largest) in reduced row
    echelon form: a basis that does not depend on how the SVD rotated it within
    the null space; a group is the parameters of a basis vector (entries above
    GROUP of its largest), overlapping groups merged.
    """
    m = A.shape[1]
    if m == 0:
        return [], np.zeros((0, 0)), np.zeros(0)
    _, sv, Vt = np.linalg.svd(A, full_matrices=True)
    s = np.zeros(m)
    s[:len(sv)] = sv
    null = Vt[s <= rcond * s[0]] if s[0] > 0 else np.eye(m)
    if not len(null):
        return [], np.zeros((0, m)), sv
    R = _rref(null)
    groups = [np.flatnonzero(np.abs(row) > GROUP * np.abs(row).max()).tolist() for row in R]
    return _merge(groups), R, sv


def _rref(M, tol: float = 1e-9) -> np.ndarray:
    """The reduced row echelon form of M's rows (Gauss-Jordan, partial pivoting), rows normalised."""
    R = np.array(M, float)
    rows, cols = R.shape
    r = 0
    for c in range(cols):
        if r == rows:
            break
        k = r + int(np.argmax(np.abs(R[r:, c])))
        if abs(R[k, c]) <= tol:
            continue
        R[[r, k]] = R[[k, r]]
        R[r] /= R[r, c]
        for i in range(rows):
            if i != r:
                R[i] -= R[i, c] * R[r]
        r += 1
    R = R[:r]
    return R / np.linalg.norm(R, axis=1, keepdims=True)


def _identify_with(rows, data: Data, theta, dz, groups, basis) -> list:
    """Per group: the measurements this design offers but the data lack that see the group's directions
    (basis: null directions in z; their Jacobian along them, one more pass over the rows), and a known
    load or mass for a group of stiffnesses (scaling every stiffness leaves no force in place)."""
    from .caldata import measurement_columns
    design = rows.session.design
    extra = [c for c in measurement_columns(design) if c not in data.columns]
    seen: dict = {}
    if extra:
        probe = Data(extra, np.zeros((data.rows, len(extra))), np.ones(len(extra)), np.zeros(len(extra), bool),
                     data.conditions, data.experiments, data.parameters, data.train, data.source)
        try:
            more = Rows(rows.session, probe)
            _, J, _ = more.run(theta, states=rows.states)
            Jz = J[data.train] * dz                         # (rows, columns, parameters)
        except SolveError as exc:
            log.info("calibrate: no suggestions (%s)", exc)
            Jz = None
        finally:
            rows.restore()
        if Jz is not None:
            for j, c in enumerate(extra):
                M = Jz[:, j, :]
                size = np.linalg.norm(M)
                for gi, g in enumerate(groups):
                    along = [b for b in basis if set(np.flatnonzero(np.abs(b) > GROUP * np.abs(b).max())) <= set(g)]
                    if size > 0 and max((np.linalg.norm(M @ b) for b in along), default=0.0) > SEES * size:
                        seen.setdefault(gi, []).append(c)
    out = []
    for gi, g in enumerate(groups):
        names = []
        for c in seen.get(gi, []):
            sec, name, rest = c.split(".", 2)
            label = {"cables": f"{c} (a tension column)", "grounds": f"grounds.{name}.force (a force sensor)",
                     "pins": f"pins.{name}.reaction (the force at the pin)",
                     "markers": f"markers.{name} (another marker's position)"}[sec]
            if label not in names:
                names.append(label)
        if all(data.parameters[i].base.rsplit(".", 1)[-1] in ("E", "stiffness") for i in g):
            names.append("a known load or mass (a [[loads]] force or gravity with densities in some rows)")
        if not names:
            names.append("rows in which it acts (it changes no measurement of these rows)")
        out.append(names)
    return out


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
