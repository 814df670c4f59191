"""Sensitivities of the static equilibrium x*(u) to the tendon contractions u.

The equilibrium solves R(x, u) = grad Pi(x; u) = 0 with the contractions fully
applied (load factor 1). Tendon c stores k Q(l - L) with rest length
L = L0 - u_c, so its part of R is k s g with s = l - L and g = grad l, and

    dR/du_c = k g_c   if the tendon is taut (s > 0),   0 if it is slack (s < 0).

Q has a kink at s = 0 (a tendon exactly at its rest length, |s| <= 1e-12 L0,
e.g. every tendon of an unactuated finger): there R is not differentiable in
u_c. We take the taut branch, the one-sided derivative for increasing u_c (the
only feasible direction at the bound u_c = 0): dR/du_c = k g_c, and H gains
its right limit k g g^T (the curvature term k s B^T W B vanishes at s = 0).
These tendons are listed in Linearization.kinked; their derivatives hold for
increasing u_c only (skelfem.analysis.control restricts its steps accordingly).
Ligaments are never controls and keep the Hessian as the cable defines it.

With cable friction (skelfem.terms.cable_slip) H is the Hessian of the
cable's incremental potential with its friction limits F held, and
dR/du_c = g_z / C_z, z the tension zone holding the actuated end. That is
the exact derivative while every via point sticks (F plays no part); while
via points slip, F follows the tensions (F = mu tan(theta/2)(T + T')) and the
derivative for increasing u_c differs by a term of order mu that is left out,
and for decreasing u_c the via points stick: the equilibrium is not
differentiable there, and these are one-sided, lagged derivatives.

Differentiating R(x*(u), u) = 0 with H = dR/dx = hess Pi at x*:

    forward:  H dx*/du_c = -dR/du_c          one solve per tendon;
              a marker y = X + S x moves by dy/du = S dx*/du.
    adjoint:  H lambda = dO/dx,  dO/du = -(dR/du)^T lambda
              one solve for an objective O(x), e.g. O = |y - y'|^2
              (H is symmetric).

SNES's last Jacobian belongs to the iterate before its final step, so H is
assembled afresh at x* into the Newton solver's matrix K (fixed pattern:
MUMPS refactorises numerically, reusing its analysis), its rank-one parts
(taut cables, and tendons at the kink) go to the same Woodbury solver Newton
uses (skelfem.fem.linear), and that one factorisation serves every right-hand
side, forward and adjoint. Dirichlet rows of H are identity rows and every
right-hand side is zero there, so the pinned components of dx*/du and lambda
vanish. Everything here works on any number of MPI ranks.
"""
from __future__ import annotations

import logging

import numpy as np
from petsc4py import PETSc

from ..terms.capabilities import Lagged
from ..terms.contact import SelfContact

log = logging.getLogger("skelfem")

FOUR_POINT = ((1.0, 2 / 3), (-1.0, -2 / 3), (2.0, -1 / 12), (-2.0, 1 / 12))   # f'(0) e = sum w f(step e) + O(e^5)
KINK = 1e-12      # |s| <= KINK * L0 counts as a tendon exactly at its rest length


def tendons(model) -> list:
    """The tendon terms (the controls u), in design order."""
    return model.actuators()


def contractions(model) -> np.ndarray:
    """The tendon contractions u, mm."""
    return np.array([t.cable.contraction for t in tendons(model)], dtype=float)


def set_contractions(model, u) -> None:
    """Write u onto the model's tendons (rest lengths L = L0 - u at load factor 1)."""
    u = np.asarray(u, dtype=float)
    ts = tendons(model)
    if u.shape != (len(ts),):
        raise ValueError(f"expected {len(ts)} contractions, got shape {u.shape}")
    for t, value in zip(ts, u):
        model.set_parameter(f"cables.{t.name}.contraction", float(value))


def stretch(term, u: np.ndarray) -> float:
    """s = l - L of a cable term (positive: taut)."""
    return term.cable.length(u) - term.rest_length


def global_vector(model, term, values: np.ndarray) -> PETSc.Vec:
    """A vector holding `values` (on the term's global DOFs) in its owned entries, ghosts updated."""
    v = model.u.vector.duplicate()
    v.set(0.0)
    v.array_w[term.gather.local] = values[term.gather.pos]
    v.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    return v


class Linearization:
    """H and dR/du at the current converged equilibrium x* (model.u), H factorised once.

    Uses the NewtonSolver that produced x*: its matrix, its MUMPS analysis
    and its Woodbury solver. The object describes one x*: build a new one
    after the next solve. hold_lags: friction's lagged normal forces and
    tangents are held at their converged values (J = H: the derivative of
    the lagged problem, not of the equilibrium through its lags).
    """

    def __init__(self, model, solver, hold_lags: bool = False):
        if abs(model.factor - 1.0) > 1e-14:
            raise ValueError("sensitivities need the contractions fully applied "
                             f"(load factor {model.factor:g}, not 1)")
        self.model, self.solver = model, solver
        self.tendons = tendons(model)
        u = model.u.x.array
        self.kinked = [i for i, t in enumerate(self.tendons)
                       if not t.cable.friction and abs(stretch(t, u)) <= KINK * t.cable.L0]
        self._g = [self._masked_g(t) for t in self.tendons]
        # friction's N, edge tangents; hold_lags: held at their converged values (J = H, symmetric)
        self.lagged: list = [] if hold_lags else [t for t in model.having(Lagged) if t.lags() is not None]
        if self.lagged and model.comm.size > 1:
            raise ValueError("sensitivities through friction contacts run on one MPI process")
        barriers = [t for t in model.terms if isinstance(t, SelfContact) and t.project]
        for t in barriers:                      # the exact barrier Hessian, not Newton's PSD projection
            t.project = False
        try:
            solver.assemble(model.u.vector)
        finally:
            for t in barriers:
                t.project = True
        parts = model.low_rank()
        self._extra = [global_vector(model, self.tendons[i], self._g[i])   # cable.low_rank dropped k g g^T
                       for i in self.kinked if stretch(self.tendons[i], u) <= 0.0]
        parts = parts + [(self.tendons[i].cable.k, v) for i, v in zip(
            [i for i in self.kinked if stretch(self.tendons[i], u) <= 0.0], self._extra)]
        solver.lin.update(parts, model.border)   # the one numeric factorisation (rigid bones: their border)
        self.dR_du = [self._dR_du(i) for i in range(len(self.tendons))]

    @property
    def m(self) -> int:
        """Number of controls (tendons)."""
        return len(self.tendons)

    # -- H and dR/du ------------------------------------------------------------------------
    def _masked_g(self, term) -> np.ndarray:
        """g = grad l of a cable on its DOFs, zero on Dirichlet DOFs."""
        return term.cable.length_gradient(self.model.u.x.array) * self.model.free_of(term, term.cable.dofs)

    def tension_gradient(self, term) -> PETSc.Vec:
        """dT/du of a cable's tension (the pulled end's) on the free DOFs: the tendon's dR/du_c (k g, or the
        holding tension zone's with friction); a ligament's k g where taut, else zero."""
        if term in self.tendons:
            return self._dR_du(self.tendons.index(term))
        taut = stretch(term, self.model.u.x.array) > 0.0
        return global_vector(self.model, term, term.cable.k * self._masked_g(term) * float(taut))

    def _dR_du(self, i: int) -> PETSc.Vec:
        """dR/du_c = k g_c on the free DOFs of a taut (or kinked) tendon, else zero; with cable friction
        g_z / C_z of the tension zone that holds the actuated end (skelfem.terms.cable_slip)."""
        t = self.tendons[i]
        if t.cable.friction:
            u = self.model.u.x.array
            values = t.cable.contraction_gradient(u, t.rest_length) * self.model.free_of(t, t.cable.dofs)
            return global_vector(self.model, t, values)
        taut = stretch(t, self.model.u.x.array) > 0.0 or i in self.kinked
        return global_vector(self.model, t, t.cable.k * self._g[i] if taut else 0.0 * self._g[i])

    # -- solves ------------------------------------------------------------------------------
    def solve(self, rhs: PETSc.Vec) -> PETSc.Vec:
        """J^-1 rhs (rhs must be zero on Dirichlet rows): H^-1 rhs with the stored factorisation, or with
        lagged friction the exact solve of solve_many."""
        x = rhs.duplicate()
        if self.lagged:
            x.array_w[:] = self.solve_many(rhs.array_r[:, None])[:, 0]
        else:
            self.solver.lin.solve(rhs, x)
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        return x

    def h_solve_many(self, B: np.ndarray) -> np.ndarray:
        """H^-1 B with the stored factorisation of the lagged Hessian (owned entries, one per column)."""
        return self.solver.lin.solve_many(B)

    def solve_many(self, B: np.ndarray) -> np.ndarray:
        """J^-1 B for a block of right-hand sides (owned entries, one per column; zero on Dirichlet rows).

        J = H without lagged terms. With friction, whose normal forces N (and an edge's tangent) are
        lagged and held at their fixed point N = N(x), the Jacobian of the equilibrium is
        J = H + C, C v = d/de grad Pi(x; N(x + e v)) (a fourth-order central difference of the friction terms'
        gradients with their lags measured along v; no solve). J is not symmetric; GMRES on
        (I + H^-1 C) y = H^-1 b, one back-substitution per iteration, solves it exactly on the
        present branch (which nodes stick or slip, their anchors)."""
        if not self.lagged:
            return self.h_solve_many(B)
        return np.column_stack([self._exact_solve(B[:, j]) for j in range(B.shape[1])])

    def _coupling(self, v: np.ndarray) -> np.ndarray:
        """C v: the change of the lagged terms' gradients when their lags follow the state along v."""
        model = self.model
        norm = float(np.abs(v).max())
        out = np.zeros(len(v))
        if norm == 0.0:
            return out
        u = model.u.x.array.copy()
        size = max(float(np.abs(model.mesh.geometry.x).max()), 1.0)
        for t in self.lagged:
            saved = t.lags()
            e = t.lag_step * size / norm
            try:               # fourth order: the barrier's N(x) bends within a micrometre of a close contact
                for step, w in FOUR_POINT:
                    t.set_lags(t.lags_at(u + step * e * v))
                    got = t.gradient(u)
                    if got is not None:
                        np.add.at(out, got[0], w * np.asarray(got[1]) / e)
            finally:
                t.set_lags(saved)
        out[model.fixed[:len(out)]] = 0.0
        return out

    def _exact_solve(self, b: np.ndarray, tol: float = 1e-12) -> np.ndarray:
        n = len(b)

        def h_inv(r):
            return self.h_solve_many(np.asarray(r, float).reshape(n, 1))[:, 0]
        rhs = h_inv(b)
        if not np.any(rhs):
            return rhs
        return _gmres(lambda v: v + h_inv(self._coupling(v)), rhs, tol, restart=60, maxiter=5,
                      what="sensitivity through friction")

    def solve_transposed(self, rhs: PETSc.Vec) -> PETSc.Vec:
        """J^-T rhs (rhs zero on Dirichlet rows): the adjoint solve. H^-1 rhs without lagged terms (H is
        symmetric). With lagged friction J = H + C is not: C is probed column by column on the DOFs of the
        lagged terms' gradients (a ground's N_i depends on its own node alone), checked against one random
        probe (ValueError where C reaches further), and (I + H^-1 C^T) z = H^-1 rhs is solved by GMRES."""
        x = rhs.duplicate()
        if not self.lagged:
            self.solver.lin.solve(rhs, x)
        else:
            cols, C = self._coupling_columns()
            b = rhs.array_r.copy()
            n = len(b)

            def h_inv(r):
                return self.h_solve_many(np.asarray(r, float).reshape(n, 1))[:, 0]

            def transposed(v):
                out = np.zeros(n)
                out[cols] = C.T @ v
                return out
            start = h_inv(b)
            x.array_w[:] = start if not np.any(start) else _gmres(
                lambda v: v + h_inv(transposed(v)), start, 1e-12, restart=60, maxiter=5,
                what="adjoint through friction")
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        return x

    def _coupling_columns(self) -> tuple[np.ndarray, np.ndarray]:
        """(DOFs D, C[:, D]) of the lag coupling C, probed on the lagged terms' gradient DOFs; ValueError if a
        random probe finds C acting beyond D."""
        u = self.model.u.x.array
        n = len(self.model.u.vector.array_r)
        cols = np.unique(np.concatenate([np.asarray(g[0], dtype=np.int64) for g in
                                         (t.gradient(u) for t in self.lagged) if g is not None] or [np.zeros(0, int)]))
        cols = cols[cols < n]
        cols = cols[~np.asarray(self.model.fixed)[cols]]
        C = np.zeros((n, len(cols)))
        for j, k in enumerate(cols):
            e = np.zeros(n)
            e[k] = 1.0
            C[:, j] = self._coupling(e)[:n]
        r = np.random.default_rng(0).standard_normal(n)
        r[np.asarray(self.model.fixed)[:n]] = 0.0
        full, part = self._coupling(r)[:n], C @ r[cols]
        if np.abs(full - part).max() > 1e-6 * max(float(np.abs(full).max()), 1e-300):
            raise ValueError("the friction's lagged forces depend on DOFs beyond its own nodes: the adjoint "
                             "through them is not covered")
        return cols, C

    def state_sensitivities(self) -> list[PETSc.Vec]:
        """dx*/du_c = -H^-1 dR/du_c for every tendon c (forward mode)."""
        out = []
        for b in self.dR_du:
            dx = self.solve(b)
            dx.scale(-1.0)
            dx.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            out.append(dx)
        return out

    def adjoint(self, dO_dx: PETSc.Vec) -> np.ndarray:
        """dO/du = -(dR/du)^T lambda with H lambda = dO/dx (one solve); forward with lagged friction
        (J is not symmetric there, and there are few controls)."""
        if self.lagged:
            return self.forward(dO_dx)
        lam = self.solve(self.dirichlet_free(dO_dx))
        grad = np.array([-b.dot(lam) for b in self.dR_du])
        lam.destroy()
        return grad

    def forward(self, dO_dx: PETSc.Vec) -> np.ndarray:
        """dO/du = dO/dx . dx*/du_c, one solve per tendon (for checking the adjoint)."""
        rhs = self.dirichlet_free(dO_dx)
        dxs = self.state_sensitivities()
        grad = np.array([rhs.dot(dx) for dx in dxs])
        for v in dxs + [rhs]:
            v.destroy()
        return grad

    def marker_jacobian(self, index: int, mode: str = "adjoint") -> np.ndarray:
        """dy/du of marker `index`, shape (gdim, m): gdim adjoint or m forward solves."""
        markers = self.model.term("markers")
        d = self.model.dim
        S = markers.S[index * d:(index + 1) * d]
        if mode == "forward":
            dxs = self.state_sensitivities()
            J = np.column_stack([S @ markers.gather(local_values(dx)) for dx in dxs]) if dxs else np.zeros((d, 0))
            for v in dxs:
                v.destroy()
            return J
        if mode != "adjoint":
            raise ValueError(f"unknown mode {mode!r}")
        if self.lagged:                       # J is not symmetric: one forward solve per tendon
            return self.marker_jacobian(index, "forward")
        rows = [self.adjoint(global_vector(self.model, markers, S[j].toarray().ravel())) for j in range(d)]
        return np.array(rows).reshape(d, self.m)

    def dirichlet_free(self, v: PETSc.Vec) -> PETSc.Vec:
        """Copy of v with the Dirichlet rows zeroed."""
        w = v.copy()
        with w.localForm() as local:
            local.array_w[self.model.fixed] = 0.0
        return w

    def destroy(self) -> None:
        for b in self.dR_du + self._extra:
            b.destroy()


def local_values(v: PETSc.Vec) -> np.ndarray:
    """Owned and ghost entries of a ghosted vector, as a numpy array."""
    with v.localForm() as local:
        return local.array_r.copy()


# -- the tracking objective O = |y - y'|^2 -------------------------------------------------------
def marker_objective(model, index: int, target) -> tuple[float, PETSc.Vec]:
    """O = |y - y'|^2 for marker `index` at the current state, and dO/dx = 2 S^T (y - y')."""
    markers = model.term("markers")
    d = model.dim
    S = markers.S[index * d:(index + 1) * d]
    r = markers.positions(model.u.x.array)[index] - np.asarray(target, dtype=float)
    return float(r @ r), global_vector(model, markers, 2.0 * (S.T @ r))


# -- the friction coefficient of a cable -----------------------------------------------------------------
def friction_sensitivity(lin: Linearization, name: str, h: float = 1e-6, tol: float = 1e-10) -> np.ndarray:
    """dx*/dmu for the friction coefficient of cable `name` at the converged state of one step (its
    anchors held; serial): the local values of the state's derivative.

    With friction the equilibrium is G(x, mu) = R(x, F*(x, mu)) = 0, F* the limits that hold at x with
    their own tensions. Along the branch the state is on (each via point slipping or sticking as now:
    cable_slip.frozen_limits) F* is smooth, and dx/dmu = -(H + R_F dF*/dx)^-1 dG/dmu, H the lagged
    Hessian factorised in lin. dG/dmu and R_F (dF*/dx) v are central differences of the cables'
    gradients at fixed x (only F* moves; no solve), and the system is solved by GMRES on
    v + H^-1 R_F (dF*/dx) v = -H^-1 dG/dmu, one back-substitution per iteration. The anchors are
    the step's own (from before it): its slips are part of what mu moves.
    """
    model = lin.model
    if model.comm.size > 1:
        raise ValueError("friction sensitivities run on one MPI process")
    target = model.term("cables", name)
    if target.cable.mu_via is not None or not target.cable.friction:
        raise ValueError(f"cables.{name}.friction: sensitivities need one coefficient > 0 for the whole cable")
    u = model.u.x.array.copy()
    terms = [t for t in model.terms_in("cables") if t.cable.friction]
    frozen = {id(t): (t.cable.tensions(u, t.rest_length), t.cable.F.copy()) for t in terms}
    for t in terms:              # the step's own anchors: its slips are part of what mu moves
        t.cable.s_hat, t.cable.s_prev = t.cable.s_prev, t.cable.s_hat
        t.cable.changed()
    try:
        return _friction_solve(lin, model, target, terms, frozen, u, h, tol)
    finally:
        for t in terms:
            t.cable.s_hat, t.cable.s_prev = t.cable.s_prev, t.cable.s_hat
            t.cable.changed()


def _friction_solve(lin, model, target, terms, frozen, u, h, tol) -> np.ndarray:
    from ..terms import cable_slip

    def gradient_with(t, F) -> np.ndarray:
        saved = t.cable.F
        t.cable.F = F
        t.cable.changed()
        try:
            return t.cable.gradient(u, t.rest_length) * model.free_of(t, t.cable.dofs)
        finally:
            t.cable.F = saved
            t.cable.changed()

    def limits_at(t, x, scale: float = 1.0) -> np.ndarray:
        cab = t.cable
        d = cab.d0 + (cab.B @ cab.values(x)).reshape(cab.d0.shape)
        norm = np.linalg.norm(d, axis=1)
        s = cab.s_hat.copy()
        s[0], s[-1] = cab.L0 - t.rest_length, 0.0
        b = norm - (cab.seg0 + s[1:] - s[:-1])
        mu_tan = scale * cab.coefficients() * cable_slip.bend_tangents(d / norm[:, None])
        T, F = frozen[id(t)]
        return cable_slip.frozen_limits(b, cab.compliances(), mu_tan, T, F)

    def assemble(parts) -> np.ndarray:
        out = np.zeros(len(u))
        for t, values in parts:
            v = global_vector(model, t, values)
            out += v.array_r[:len(u)]
            v.destroy()
        return out

    mu = target.cable.mu
    dG = assemble([(target, (gradient_with(target, limits_at(target, u, (mu + h) / mu))
                             - gradient_with(target, limits_at(target, u, (mu - h) / mu))) / (2 * h))])
    size = max(float(np.abs(model.mesh.geometry.x).max()), 1.0)

    def coupling(v: np.ndarray) -> np.ndarray:
        """R_F (dF*/dx) v, by a central difference of the limits along v."""
        norm = float(np.abs(v).max())
        if norm == 0.0:
            return np.zeros_like(v)
        eps = 1e-6 * size / norm
        return assemble([(t, (gradient_with(t, limits_at(t, u + eps * v)) - gradient_with(t, limits_at(t, u - eps * v)))
                          / (2 * eps)) for t in terms])

    def h_inv(b: np.ndarray) -> np.ndarray:
        b = b.copy()
        b[model.fixed[:len(b)]] = 0.0
        return lin.h_solve_many(b[:, None])[:, 0]

    return _gmres(lambda v: v + h_inv(coupling(v)), -h_inv(dG), tol, restart=80, maxiter=3,
                  what="friction sensitivity")


def _gmres(matvec, rhs: np.ndarray, tol: float, restart: int, maxiter: int, what: str) -> np.ndarray:
    """y with matvec(y) = rhs to tol |rhs| by GMRES from y = rhs (a preconditioned system I + small);
    short of it but within GMRES_ACCEPT |rhs| (a strong coupling, e.g. a disk rolled between two
    fingers), y with a warning; RuntimeError naming `what` beyond."""
    from scipy.sparse.linalg import LinearOperator, gmres
    n = len(rhs)
    A = LinearOperator((n, n), matvec=lambda v: matvec(np.asarray(v).ravel()), dtype=float)
    atol = tol * max(float(np.linalg.norm(rhs)), 1e-300)
    if float(np.linalg.norm(A.matvec(rhs) - rhs)) <= atol:     # the start solves it (no coupling along it):
        return rhs                                            # SciPy 1.10's GMRES returns NaN from there
    try:
        y, info = gmres(A, rhs, x0=rhs, rtol=0.0, atol=atol, restart=restart, maxiter=maxiter)
    except TypeError:                                 # SciPy < 1.12 calls rtol tol
        y, info = gmres(A, rhs, x0=rhs, tol=0.0, atol=atol, restart=restart, maxiter=maxiter)
    residual = float(np.linalg.norm(A.matvec(y) - rhs))
    if info != 0 and residual > 1e3 * atol:        # SciPy 1.10 may report its iteration limit when done
        scale = max(float(np.linalg.norm(rhs)), 1e-300)
        if residual > GMRES_ACCEPT * scale:
            raise RuntimeError(f"{what}: GMRES did not converge (|r| {residual:.3g})")
        log.info("%s: GMRES reached %.2g relative, not %.2g", what, residual / scale, tol)
    return y


GMRES_ACCEPT = 1e-6       # a derivative this accurate still steers Soft IK and optimisation
