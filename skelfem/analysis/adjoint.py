"""Gradients through time: the discrete adjoint of a run ([dynamics]) with respect to schedule knots.

A run solves, for every accepted step n (t_n -> t_{n+1}, size h, BDF
coefficients alpha = (a0, a1, a2), see skelfem.terms.inertia),

    R_n = grad Pi(x_{n+1}; c(t_{n+1})) + D (x_{n+1} - x*_n) - c_I M h (a1 v_n + a2 v_{n-1}) / a0^2 = 0,
    v_{n+1} = (a0 x_{n+1} + a1 x_n + a2 x_{n-1}) / h,

with x*_n = -(a1 x_n + a2 x_{n-1}) / a0, c_I = a0^2 / h^2, D = (c_I + a a0 / h) M
(mass-proportional damping a). The tendon contractions c(t) are piecewise
linear in the schedule knots: c(t) = sum_k phi_k(t) u_k, phi_k the hat
functions of the knot times (held beyond the ends), so dR_n/du_k =
phi_k(t_{n+1}) k g (g = grad of the cable length; zero for a slack tendon,
the taut branch at the kink as in skelfem.analysis.sensitivity).

For an objective J(x_0, ..., x_N) the reverse sweep, n = N-1, ..., 0, with
x^_n, v^_n the adjoints (dJ/dx_n so far) is

    x^_{n+1} += a0/h v^_{n+1};  x^_n += a1/h v^_{n+1};  x^_{n-1} += a2/h v^_{n+1}
    H_{n+1} lam = x^_{n+1}                       (H: the step's converged Newton Hessian)
    u^_k -= phi_k(t_{n+1}) (k g)^T lam
    x^_n -= (a1/a0) D lam;  x^_{n-1} -= (a2/a0) D lam
    v^_n -= h a1/a0^2 c_I M lam;  v^_{n-1} -= h a2/a0^2 c_I M lam

H_{n+1} = hess Pi(x_{n+1}) + D is assembled and factorised again at the
stored state x_{n+1} (skelfem.analysis.sensitivity.Linearization: the same matrix,
MUMPS analysis and Woodbury solver as Newton; one factorisation and one
back-substitution per step). Every state is stored (no checkpointing):
memory N x DOFs. Dirichlet rows carry no adjoint (pinned DOFs do not depend
on the schedules). Stiffness damping (b > 0) is not differentiated (its
tangent at x_n would need third derivatives of psi): ValueError.

Friction at contacts and grounds makes a step's residual depend on the
stick anchors a_n it starts from (the history, skelfem.terms.friction) and
on its lagged normal forces and tangents, which sit at their fixed point
N = N(x_{n+1}). Both are followed exactly, in forward (tangent) mode: with
J_{n+1} = H_{n+1} + C_{n+1} the Jacobian through the lags
(skelfem.analysis.sensitivity.Linearization, hold_lags=False) and
a^_n = A(a_n, x_n) the anchors the step uses (a contact formed during the
step is anchored where it was at x_n, ``StickAnchors.stick_anchors_in_step``),

    J_{n+1} x'_{n+1} = (the right-hand side below) - dR_n/da a'^_n,
    a'_{n+1} = d/de B(x_{n+1} + e x'_{n+1}, a^_n + e a'^_n)

with B the return map (``StickAnchors.stick_anchors_after``: slipping anchors move to eps
behind their node). The derivatives through the anchors are central
differences along each tangent, a step well inside the stick zone eps
(``StickAnchors.stick_anchor_step``), on the branch of the forward run (which nodes stick
or slip; the step sequence). The gradient is then 2 (dr/du)^T r, one
tangent per knot: ``schedule_gradient`` takes this path with friction.
Cable friction (whose history has no anchors here) and runs on several
MPI processes keep the held friction of the reverse sweep: the gradient is
then approximate (``GradientResult.approximate``; 5 % from central
differences on a strip whose side slides on a wall with mu = 0.5), and the
forward runs that measure the targets stay exact.

The objective here is the tracking of markers at given times,
J = sum_i |y_m(t_i) - y'_i|^2, y_m(t) linear between the two stored states
around t_i.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from petsc4py import PETSc

from .sensitivity import Linearization, local_values
from ..terms.capabilities import History, StickAnchors


@dataclass
class TimedTarget:
    marker: str
    time: float          # s, within [0, duration]
    target: np.ndarray   # mm


@dataclass
class GradientResult:
    value: float                          # J, mm^2
    gradient: dict                        # {tendon name: dJ/du at its knots (array)}
    positions: list                       # achieved marker positions at the targets' times
    report: object = None                 # the forward DynamicsReport
    approximate: bool = False             # friction held (cable friction, MPI): not the exact gradient
    forward_time: float = 0.0
    adjoint_time: float = 0.0
    extra: dict = field(default_factory=dict)


def knot_weights(times: np.ndarray, t: float) -> np.ndarray:
    """phi_k(t) of the piecewise-linear interpolation through knot times (held beyond the ends)."""
    return np.array([np.interp(t, times, e) for e in np.eye(len(times))])


def _bracket(step_times: np.ndarray, t: float) -> tuple[int, int, float]:
    """(i, j, w): y(t) = (1 - w) y_i + w y_j from the stored states at step_times."""
    j = int(np.searchsorted(step_times, t, side="left"))
    j = min(max(j, 1), len(step_times) - 1)
    i = j - 1
    w = (t - step_times[i]) / (step_times[j] - step_times[i])
    return i, j, float(np.clip(w, 0.0, 1.0))


def _gradient_through_anchors(session, targets: list[TimedTarget], rep, forward_time: float) -> GradientResult:
    """J and its gradient from the forward sensitivities (one tangent sweep of every knot together),
    where friction's anchors carry the history the reverse sweep cannot."""
    t1 = time.perf_counter()
    design, model = session.design, session.model
    r, J, _ = schedule_sensitivities(session, targets, report=rep)
    grad, j = {}, 0
    for t in model.actuators():              # the columns: each scheduled tendon's knots, in design order
        knots = design.cable(t.name).schedule
        if knots is not None:
            grad[t.name] = 2.0 * J[:, j:j + len(knots)].T @ r
            j += len(knots)
    d = model.dim
    positions = [r[i * d:(i + 1) * d] + np.asarray(tt.target, float) for i, tt in enumerate(targets)]
    return GradientResult(float(r @ r), grad, positions, rep, False, forward_time, time.perf_counter() - t1)


def _target_sources(model, targets: list[TimedTarget], rep) -> tuple[float, list, list]:
    """J's target part, the marker positions at the targets' times, and dJ/dx_n for every stored state
    (local arrays; the marker interpolation acts on gathered global DOFs)."""
    markers = model.term("markers")
    names, d, states = list(markers.names), model.dim, rep.states
    step_times = np.array([0.0] + [s[0] for s in rep.steps])
    xbar = [np.zeros(model.n_local) for _ in range(len(rep.steps) + 1)]
    value, positions = 0.0, []
    for tt in targets:
        i, j, w = _bracket(step_times, tt.time)
        k = names.index(tt.marker)
        S = markers.S[k * d:(k + 1) * d]
        y = (1 - w) * markers.positions(states[i])[k] + w * markers.positions(states[j])[k]
        r = y - np.asarray(tt.target, float)
        value += float(r @ r)
        positions.append(y)
        g = _on_local(model, markers, 2.0 * (S.T @ r))
        xbar[i] += (1 - w) * g
        xbar[j] += w * g
    return value, positions, xbar


def schedule_gradient(session, targets: list[TimedTarget]) -> GradientResult:
    """J and dJ/d(schedule knots) of every tendon with a schedule, by one forward run and one reverse sweep."""
    from ..fem.dynamics import Dynamics

    design, model, solver = session.design, session.model, session.solver
    spec = design.dynamics
    if spec is None:
        raise ValueError(f"{design.name}: no [dynamics] section")
    if spec.damping_stiffness > 0.0:
        raise ValueError("the adjoint does not differentiate stiffness damping (damping.stiffness = 0 needed)")
    t0 = time.perf_counter()
    dyn = Dynamics(model, solver, design)
    rep = dyn.run(store=True)
    if not rep.converged:
        raise RuntimeError(f"{design.name}: the forward run failed ({rep.status}) at t = {rep.t_end:g} s")
    t1 = time.perf_counter()
    if model.path_dependent and follows_anchors(model):       # friction: tangents through the anchors
        return _gradient_through_anchors(session, targets, rep, t1 - t0)
    inertia = model.term("dynamics")
    states = rep.states
    N = len(rep.steps)
    value, positions, xbar = _target_sources(model, targets, rep)
    vbar = [np.zeros(model.n_local) for _ in range(N + 1)]
    tendons = model.actuators()
    scheduled = {t.name: design.cable(t.name).schedule for t in tendons if design.cable(t.name).schedule is not None}
    grad = {name: np.zeros(len(s)) for name, s in scheduled.items()}
    M = inertia.mass_matrix()
    lam_vec = model.u.vector.duplicate()
    Mlam = model.u.vector.duplicate()
    fixed = model.fixed
    a_mass = spec.damping_mass
    try:
        for n in range(N - 1, -1, -1):
            t_next, h, (a0, a1, a2) = rep.steps[n]
            # the step's state, contractions and Hessian
            model.u.x.array[:] = states[n + 1]
            model.u.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            dyn.set_time(t_next)
            set_step(inertia, rep, n)
            lin = Linearization(model, solver, hold_lags=True)
            try:
                # v_{n+1} = (a0 x_{n+1} + a1 x_n + a2 x_{n-1}) / h
                xbar[n + 1] += a0 / h * vbar[n + 1]
                xbar[n] += a1 / h * vbar[n + 1]
                if n >= 1:
                    xbar[n - 1] += a2 / h * vbar[n + 1]
                rhs = xbar[n + 1].copy()
                rhs[fixed] = 0.0
                with lam_vec.localForm() as local:
                    local.array_w[:] = rhs
                lam = lin.solve(_owned_sum(lam_vec))
                for c, term in enumerate(lin.tendons):
                    if term.name in grad:
                        grad[term.name] -= knot_weights(scheduled[term.name][:, 0], t_next) * lin.dR_du[c].dot(lam)
                M.mult(lam, Mlam)
                m_lam = _local_sum(Mlam)
                c_i = a0 * a0 / (h * h)
                D = c_i + a_mass * a0 / h
                xbar[n] -= (a1 / a0) * D * m_lam
                vbar[n] -= h * a1 / a0 ** 2 * c_i * m_lam
                if n >= 1:
                    xbar[n - 1] -= (a2 / a0) * D * m_lam
                    vbar[n - 1] -= h * a2 / a0 ** 2 * c_i * m_lam
                lam.destroy()
            finally:
                lin.destroy()
    finally:
        inertia.stop()
        dyn.set_time(rep.t_end)
        model.u.x.array[:] = states[-1]
        model.sync(model.u.vector)
        lam_vec.destroy()
        Mlam.destroy()
    return GradientResult(value, grad, positions, rep, model.path_dependent, t1 - t0, time.perf_counter() - t1)


def velocity(rep, n: int):
    """v_n of stored state n from step n - 1's BDF formula (v_0 = 0: a run starts at rest)."""
    if n == 0:
        return 0.0
    _, h, (a0, a1, a2) = rep.steps[n - 1]
    return (a0 * rep.states[n] + a1 * rep.states[n - 1] + (a2 * rep.states[n - 2] if a2 != 0.0 else 0.0)) / h


def set_step(inertia, rep, n: int) -> None:
    """The inertia term as it was in step n (x~, x*, coefficients): the Hessian of a rigid body holds the
    full gradient on its nodes, inertia's force included."""
    _, h, alpha = rep.steps[n]
    back = alpha[2] != 0.0                   # BDF2: x_{n-1}, v_{n-1} too (never in the first step)
    inertia.set_step(h, alpha, rep.states[n], rep.states[n - 1] if back else 0.0, velocity(rep, n),
                     velocity(rep, n - 1) if back else 0.0)


def follows_anchors(model) -> bool:
    """Whether derivatives through time can follow the run's friction exactly: every active history is
    stick anchors (contacts, grounds; not cable friction), on one MPI process."""
    held = [t for t in model.terms if isinstance(t, History) and getattr(t, "active", True) and t.history() is not None]
    return model.comm.size == 1 and all(isinstance(t, StickAnchors) and t.stick_anchors() is not None for t in held)


class AnchorTangents:
    """a' per column of the terms with anchors through a run (schedule_sensitivities)."""

    def __init__(self, model, columns: int):
        self.model = model
        self.terms = [t for t in model.terms if isinstance(t, StickAnchors) and t.stick_anchors() is not None]
        self.after = [np.zeros((len(t.stick_anchors()), columns)) for t in self.terms]   # a'_n (after end_step)
        self.used = [a.copy() for a in self.after]                                 # a'^_n (in the step)

    @staticmethod
    def _central(term, da: np.ndarray, dx: np.ndarray, f):
        """(f(term, a + e da, e dx) - f(term, a - e da, -e dx)) / 2e, a the term's anchors, e such that
        every change stays well inside the stick zone (0 where there is no direction); anchors put back."""
        s_a, s_x = term.stick_anchor_step()
        na, nx = float(np.abs(da).max(initial=0.0)), float(np.abs(dx).max(initial=0.0))
        e = min(s_a / na if na > 0 else np.inf, s_x / nx if nx > 0 else np.inf)
        if not np.isfinite(e):
            return 0.0
        base, got = term.stick_anchors(), []
        try:
            for sign in (1.0, -1.0):
                got.append(f(term, base + sign * e * da, sign * e * dx))
        finally:
            term.set_stick_anchors(base)
        return (got[0] - got[1]) / (2 * e)

    def in_step(self, x_start: np.ndarray, dx_start: np.ndarray) -> None:
        """a'^_n = dA(a_n, x_n)[a'_n, x'_n] (x'_n: local arrays, one column each)."""
        def used(t, a, ex):
            return t.stick_anchors_in_step(a, x_start + ex)
        for k, t in enumerate(self.terms):
            for p in range(self.used[k].shape[1]):
                self.used[k][:, p] = self._central(t, self.after[k][:, p], dx_start[:, p], used)

    def residual(self, p: int, n: int) -> np.ndarray:
        """dR/da a'^_n of column p (local entries, zero on Dirichlet rows; one process)."""
        u = self.model.u.x.array

        def gradient(t, a, _):
            t.set_stick_anchors(a)
            g, got = np.zeros(n), t.gradient(u)
            if got is not None:
                np.add.at(g, got[0], np.asarray(got[1]))
            return g
        out = np.zeros(n)
        for k, t in enumerate(self.terms):
            out += self._central(t, self.used[k][:, p], np.zeros(0), gradient)
        out[self.model.fixed[:n]] = 0.0
        return out

    def after_step(self, x: np.ndarray, dx: np.ndarray) -> None:
        """a'_{n+1} = dB(x_{n+1}, a^_n)[x'_{n+1}, a'^_n] (x, dx: local arrays; dx one column each)."""
        def after(t, a, ex):
            t.set_stick_anchors(a)
            return t.stick_anchors_after(x + ex)
        for k, t in enumerate(self.terms):
            for p in range(self.used[k].shape[1]):
                self.after[k][:, p] = self._central(t, self.used[k][:, p], dx[:, p], after)


def _on_local(model, term, values: np.ndarray) -> np.ndarray:
    """A local array (ghosts included) holding values given on a gathered term's global DOFs (owned
    entries only: a sum over ranks of owned entries is the global vector)."""
    out = np.zeros(model.n_local)
    out[term.gather.local] = values[term.gather.pos]
    return out


def _owned_sum(v: PETSc.Vec) -> PETSc.Vec:
    """v as a right-hand side: owned entries as they are (ghost entries hold nothing)."""
    v.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    return v


def _local_sum(v: PETSc.Vec) -> np.ndarray:
    """Owned entries of v as a local array, ghost entries zero (adjoint contributions are summed
    over owned entries only)."""
    out = np.zeros(len(local_values(v)))
    out[:len(v.array_r)] = v.array_r
    return out


def schedule_sensitivities(session, targets: list[TimedTarget], report=None) -> tuple[np.ndarray, np.ndarray,
                                                                                       list]:
    """Forward (tangent) sensitivities of the targets' marker positions to the schedule knots.

    Returns (residuals r, Jacobian dr/du, parameter names): r stacks y(t_i) - y'_i
    (len(targets) * dim), dr/du has one column per (tendon, knot) of every
    scheduled tendon, in design order. The tangents of all knots go through
    the steps together, n = 0, ..., N-1:

        H_{n+1} x'_{n+1} = -M [D (a1 x'_n + a2 x'_{n-1}) / a0 + c_I h (a1 v'_n + a2 v'_{n-1}) / a0^2]
                           - sum_k phi_k(t_{n+1}) k g
        v'_{n+1} = (a0 x'_{n+1} + a1 x'_n + a2 x'_{n-1}) / h

    one factorisation and one multi-column back-substitution per step (for
    Gauss-Newton). `report`: a DynamicsReport with stored states of the
    current schedules (a new forward run if None).
    """
    from ..fem.dynamics import Dynamics

    design, model, solver = session.design, session.model, session.solver
    spec = design.dynamics
    if spec.damping_stiffness > 0.0:
        raise ValueError("the sensitivities do not differentiate stiffness damping (damping.stiffness = 0 needed)")
    dyn = Dynamics(model, solver, design)
    rep = report if report is not None else dyn.run(store=True)
    if not rep.converged:
        raise RuntimeError(f"{design.name}: the forward run failed ({rep.status}) at t = {rep.t_end:g} s")
    inertia = model.term("dynamics")
    tendons = model.actuators()
    scheduled = [(t.name, design.cable(t.name).schedule) for t in tendons if design.cable(t.name).schedule is not None]
    columns = [(n, k) for n, sched in scheduled for k in range(len(sched))]
    P = len(columns)
    n_owned = len(model.u.vector.array_r)
    N = len(rep.steps)
    residuals = _TargetResiduals(model, targets, rep, P)
    xs = [np.zeros((n_owned, P)), np.zeros((n_owned, P))]        # x'_n, x'_{n-1}
    vs = [np.zeros((n_owned, P)), np.zeros((n_owned, P))]
    M = inertia.mass_matrix()
    vec, out = model.u.vector.duplicate(), model.u.vector.duplicate()
    fixed = model.fixed[:n_owned]
    a_mass = spec.damping_mass
    through = model.path_dependent and follows_anchors(model)       # friction: its anchors followed exactly
    saved = model.history() if through else None
    anchors: Any = AnchorTangents(model, P) if through else None
    try:
        residuals.record(0, xs[0])
        for n in range(N):
            t_next, h, (a0, a1, a2) = rep.steps[n]
            model.u.x.array[:] = rep.states[n + 1]
            model.u.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            dyn.set_time(t_next)
            set_step(inertia, rep, n)
            if through:
                model.set_history(rep.histories[n])                # the step's converged anchors and lags
            lin = Linearization(model, solver, hold_lags=not through)
            try:
                if through:
                    anchors.in_step(rep.states[n], xs[0])
                c_i = a0 * a0 / (h * h)
                D = c_i + a_mass * a0 / h
                hist = D * (a1 * xs[0] + a2 * xs[1]) / a0 + c_i * h * (a1 * vs[0] + a2 * vs[1]) / a0 ** 2
                xdot = np.zeros((n_owned, P))
                for p, (name, k) in enumerate(columns):
                    vec.array_w[:] = hist[:, p]
                    M.mult(vec, out)
                    b = -out.array_r.copy()
                    c = [j for j, term in enumerate(lin.tendons) if term.name == name][0]
                    b -= knot_weights(dict(scheduled)[name][:, 0], t_next)[k] * lin.dR_du[c].array_r
                    if through:
                        b -= anchors.residual(p, n_owned)
                    b[fixed] = 0.0
                    vec.array_w[:] = b
                    sol = lin.solve(vec)
                    xdot[:, p] = sol.array_r
                    sol.destroy()
                vdot = (a0 * xdot + a1 * xs[0] + a2 * xs[1]) / h
                if through:
                    anchors.after_step(rep.states[n + 1], xdot)
                xs, vs = [xdot, xs[0]], [vdot, vs[0]]
            finally:
                lin.destroy()
            residuals.record(n + 1, xs[0])
    finally:
        inertia.stop()
        dyn.set_time(rep.t_end)
        model.u.x.array[:] = rep.states[-1]
        model.sync(model.u.vector)
        if through:
            model.set_history(saved)
        vec.destroy()
        out.destroy()
    return residuals.r, residuals.J, [f"cables.{n}.schedule[{k}]" for n, k in columns]


class _TargetResiduals:
    """r = y(t_i) - y'_i and dr/du, filled state by state: each target takes its share of the two stored
    states (and their tangents) its time falls between."""

    def __init__(self, model, targets: list[TimedTarget], rep, columns: int):
        self.model, self.targets, self.rep, self.columns = model, targets, rep, columns
        self.markers = model.term("markers")
        self.names, self.d = list(self.markers.names), model.dim
        step_times = np.array([0.0] + [s[0] for s in rep.steps])
        self.need: dict[int, list] = {}                     # step index -> (target, weight) using that state
        for i, tt in enumerate(targets):
            a, b, w = _bracket(step_times, tt.time)
            self.need.setdefault(a, []).append((i, 1 - w))
            self.need.setdefault(b, []).append((i, w))
        self.r = np.zeros(len(targets) * self.d)
        self.J = np.zeros((len(targets) * self.d, columns))

    def record(self, n: int, xdot: np.ndarray) -> None:
        """Add state n and its tangents xdot (owned rows, one column per parameter) to the targets."""
        markers, d = self.markers, self.d
        for i, w in self.need.get(n, []):
            k = self.names.index(self.targets[i].marker)
            S = markers.S[k * d:(k + 1) * d]
            y = markers.positions(self.rep.states[n])[k]
            self.r[i * d:(i + 1) * d] += w * (y - np.asarray(self.targets[i].target, float))
            if self.columns:
                cols = np.column_stack([markers.gather(_full(self.model, xdot[:, p])) for p in range(self.columns)])
                self.J[i * d:(i + 1) * d] += w * (S @ cols)


def _full(model, owned: np.ndarray) -> np.ndarray:
    """A local array (ghosts updated) from owned values."""
    v = model.u.vector.duplicate()
    try:
        v.array_w[:] = owned
        v.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        return local_values(v)
    finally:
        v.destroy()
