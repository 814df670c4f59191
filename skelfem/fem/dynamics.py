"""Forward dynamics: time steps of a model as minimisations of an incremental potential.

Each step from t to t + h sets the tendons' scheduled contractions at t + h
(``cables.NAME.contraction``, the same live parameter ``--set`` uses), lets
the inertia term (:mod:`skelfem.terms.inertia`) build its predictor x~ and
coefficients for h, starts Newton at x~ (or at x_n if x~ is not admissible)
and, if Newton converges, accepts the state (``model.end_step``: the inertia
term shifts its history). A step that fails is never accepted: the state
goes back to x_n (and friction to its anchors and slips at t) and the step is
retried with h / 2, down to dt / 2^max_cuts;
after a cut h doubles back towards dt on steps that converge easily. Loads,
gravity, pin moves and tendons without a schedule act at full value from
t = 0 (a sudden load); the run starts at rest in the reference shape.

    from skelfem import Session
    with Session("flick.toml") as s:
        run = s.run_in_time()                     # a DynamicResult
        run.trajectory[-1]                # {"time": ..., "tip_x": ..., "flexor_tension": ...}
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger("skelfem")

MAX_CUTS = 8            # a step is halved at most this many times below dt
EASY_ITERATIONS = 8     # a step that converges in at most this many iterations lets h grow back
KEEP_ROWS = 2000        # trajectory rows kept in memory (every row goes to trajectory.csv as it is made)
KEEP_HISTORY = 1000     # energy-history points and attempts kept for result.json


class Decimated:
    """A list that keeps at most ``cap`` evenly spaced entries of everything appended, and the last.

    Entries 0, s, 2s, ... are kept; when more than cap are, every other one goes and s doubles.
    A run of a million steps holds about cap rows instead of a million (~12 KB each before).
    """

    def __init__(self, cap: int):
        self.cap, self.stride, self.count = int(cap), 1, 0
        self.kept: list = []
        self.last = None

    def append(self, value) -> None:
        if self.count % self.stride == 0:
            self.kept.append(value)
            if len(self.kept) > self.cap:
                self.kept = self.kept[::2]
                self.stride *= 2
        self.last = value
        self.count += 1

    def values(self) -> list:
        if self.count and (self.count - 1) % self.stride:
            return self.kept + [self.last]
        return list(self.kept)

    def __iter__(self):
        return iter(self.values())

    def __len__(self) -> int:
        return len(self.kept) + (1 if self.count and (self.count - 1) % self.stride else 0)

    def __getitem__(self, i):
        if isinstance(i, int) and i == -1 and self.count:
            return self.last
        return self.values()[i]

    def __add__(self, other):
        return self.values() + list(other)

    def __radd__(self, other):
        return list(other) + self.values()


@dataclass
class DynamicsReport:
    """What a run did; the fields ``result_dict`` reads, plus the time history."""
    converged: bool = False
    status: str = "not_started"
    newton_iterations: int = 0
    load_steps: int = 0                  # accepted time steps
    cuts: int = 0                        # failed attempts (each halved the step)
    linear_solver: str = "direct"        # as SolveReport's
    linear_iterations: Decimated = field(default_factory=lambda: Decimated(KEEP_HISTORY))   # per time step
    linear_fallbacks: int = 0
    linear_loose_steps: int = 0
    residual_history: Decimated = field(default_factory=lambda: Decimated(KEEP_HISTORY))
    attempts: Decimated = field(default_factory=lambda: Decimated(KEEP_HISTORY))
    energy: float = float("nan")         # potential energy Pi at the last accepted state
    min_jacobian: float = float("nan")
    time: float = 0.0                    # wall-clock seconds
    t_end: float = 0.0                   # simulated time reached
    times: Decimated = field(default_factory=lambda: Decimated(KEEP_HISTORY))
    kinetic: Decimated = field(default_factory=lambda: Decimated(KEEP_HISTORY))
    potential: Decimated = field(default_factory=lambda: Decimated(KEEP_HISTORY))
    # one row (dict) per accepted state, t = 0 included: all of them up to KEEP_ROWS, then evenly decimated
    # (and the last); on_step sees each row as it is made (trajectory.csv holds them all)
    trajectory: Decimated = field(default_factory=lambda: Decimated(KEEP_ROWS))
    states: list = field(default_factory=list)        # with store=True: x_n (local arrays), t = 0 included
    steps: list = field(default_factory=list)         # with store=True: (t_{n+1}, h, alphas) per accepted step
    histories: list = field(default_factory=list)     # with store=True and friction: model.history() converged


def _snap(t: float, dt: float) -> float:
    """t rounded to 12 significant digits of dt (0.29000000000000015 -> 0.29): sums of steps stay readable."""
    return float(round(t, 12 - int(np.floor(np.log10(dt)))))


def schedule_keys(design) -> dict:
    """{live parameter key: CableSpec} of every tendon with a schedule."""
    return {f"cables.{c.name}.contraction": c for c in design.tendons if c.schedule is not None}


def trajectory_columns(design) -> list[str]:
    """Columns of trajectory.csv: time, <marker>_x, _y (, _z), <cable>_tension, energies."""
    axes = "xyz"[:design.dim]
    return (["time"] + [f"{m}_{a}" for m in design.markers for a in axes]
            + [f"{c.name}_tension" for c in design.cables] + ["kinetic_energy", "potential_energy"])


class Dynamics:
    """Steps one model in time with its Newton solver (``spec``: a DynamicsSpec)."""

    def __init__(self, model, solver, design):
        if design.dynamics is None:
            raise ValueError(f"{design.name}: no [dynamics] section")
        self.model, self.solver, self.design = model, solver, design
        self.spec = design.dynamics
        self.inertia = model.term("dynamics")
        self.schedules = schedule_keys(design)
        self.markers = model.terms_in("markers")
        self.cables = model.terms_in("cables")

    # -- one state's numbers ---------------------------------------------------------------------
    def potential(self) -> float:
        """Pi at the model's state: the model's energy without the inertia term's share (collective)."""
        model = self.model
        return model.energy(model.u.vector) - self.inertia.own_energy()

    def row(self, t: float, kinetic: float, potential: float) -> dict:
        """One line of trajectory.csv at the model's current state (collective)."""
        u = self.model.u.x.array
        out = {"time": t}
        axes = "xyz"[:self.model.dim]
        if self.markers:
            for name, p in zip(self.markers[0].names, self.markers[0].positions(u)):
                out.update({f"{name}_{a}": float(v) for a, v in zip(axes, p)})
        for term in self.cables:
            out[f"{term.name}_tension"] = float(term.cable.tension(u, term.rest_length))
        out["kinetic_energy"], out["potential_energy"] = kinetic, potential
        return out

    def set_time(self, t: float) -> None:
        """The scheduled contractions at time t."""
        for key, cable in self.schedules.items():
            self.model.set_parameter(key, cable.contraction_at(t))
        self.model.changes.clear()

    # -- the run -----------------------------------------------------------------------------------
    def run(self, on_step=None, progress=None, store: bool = False) -> DynamicsReport:
        """Step from rest to the duration; on_step(t, report) after every accepted state (t = 0 too),
        progress(fraction) now and then; store=True keeps every state and step (the adjoint).
        Returns the report (the model holds the last accepted state)."""
        t_wall = time.perf_counter()
        model, solver, inertia, spec = self.model, self.solver, self.inertia, self.spec
        rep = DynamicsReport()
        model.set_factor(1.0)
        self.set_time(0.0)
        model.to_rest()
        model.apply_bcs(model.u.vector)
        inertia.start(model.u.x.array, damping=(spec.damping_mass, spec.damping_stiffness))
        path_dependent = model.path_dependent
        if store:
            rep.states.append(model.u.x.array.copy())
        try:
            self._record(rep, 0.0, on_step)
            T, dt = spec.duration, spec.dt
            t, h, cuts_in_row = 0.0, dt, 0
            committed = model.history()         # friction's anchors and slips at t: a failed step's go
            while T - t > 1e-9 * dt:
                h_try = min(h, T - t)
                if T - t - h_try < 1e-6 * dt:
                    h_try = T - t                     # no sliver of a last step
                t_next = _snap(t + h_try, dt) if t + h_try < T - 1e-9 * dt else T
                self.set_time(t_next)
                tilde = inertia.prepare(h_try)
                x_n = inertia.x[0]
                model.u.x.array[:] = tilde
                model.apply_bcs(model.u.vector)
                if not model.admissible(model.u.vector):
                    model.u.x.array[:] = x_n
                    model.apply_bcs(model.u.vector)
                step = solver.newton()
                rep.newton_iterations += step.newton_iterations
                rep.attempts.append({"time": t_next, "dt": h_try, "iterations": step.newton_iterations,
                                     "status": step.status})
                if step.converged:
                    if store:
                        rep.states.append(model.u.x.array.copy())
                        rep.steps.append((t_next, h_try, inertia.alpha))
                        if path_dependent:                  # the step's anchors and lags (exact adjoint)
                            rep.histories.append(model.history())
                    model.end_step()
                    committed = model.history()
                    t = t_next
                    rep.load_steps += 1
                    rep.residual_history.append(step.residual_history[0])
                    rep.linear_iterations.append(solver.lin.take_krylov())
                    self._record(rep, t, on_step)
                    cuts_in_row = 0
                    if h < dt and step.newton_iterations <= EASY_ITERATIONS:
                        h = min(2.0 * h, dt)
                    if progress is not None:
                        progress(t / T)
                    continue
                rep.cuts += 1
                cuts_in_row += 1
                log.info("time step to t = %.6g s (dt %.3g s) failed (%s)", t_next, h_try, step.status)
                model.u.x.array[:] = x_n
                model.set_history(committed)
                model.sync(model.u.vector)
                if cuts_in_row > MAX_CUTS or h_try / 2.0 < dt / 2.0 ** MAX_CUTS:   # never below dt / 2^MAX_CUTS
                    rep.status = step.status
                    break
                h = h_try / 2.0
            else:
                rep.converged, rep.status = True, "converged"
            rep.t_end = t
            rep.linear_solver = solver.lin.kind
            rep.linear_fallbacks, rep.linear_loose_steps = solver.lin.fallbacks, solver.lin.loose_steps
            solver.lin.fallbacks = solver.lin.loose_steps = 0
        finally:
            self.set_time(rep.t_end)
            inertia.stop()
        model.sync(model.u.vector)
        rep.energy = rep.potential[-1]
        rep.min_jacobian = model.min_jacobian(model.u.vector)
        rep.time = time.perf_counter() - t_wall
        log.info("%s: %d time steps to t = %.4g s, %d Newton iterations, %d cut(s), %.1f s",
                 self.design.name, rep.load_steps, rep.t_end, rep.newton_iterations, rep.cuts, rep.time)
        return rep

    def _record(self, rep: DynamicsReport, t: float, on_step) -> None:
        kinetic, potential = self.inertia.kinetic_energy(), self.potential()
        rep.times.append(t)
        rep.kinetic.append(kinetic)
        rep.potential.append(potential)
        rep.trajectory.append(self.row(t, kinetic, potential))
        if on_step is not None:
            on_step(t, rep)


def dynamics_summary(design, report: DynamicsReport) -> dict:
    """The "dynamics" block of result.json."""
    spec = design.dynamics
    total = np.add(report.kinetic.values(), report.potential.values())
    return {
        "dt": spec.dt, "duration": spec.duration, "integrator": spec.integrator,
        "damping": {"mass": spec.damping_mass, "stiffness": spec.damping_stiffness},
        "time_reached": report.t_end, "steps": report.load_steps, "cuts": report.cuts,
        "newton_iterations": report.newton_iterations,
        # at most KEEP_HISTORY + 1 points, evenly spaced, the last included; trajectory.csv has every step
        "energy_history": {"time": report.times.values(), "kinetic": report.kinetic.values(),
                           "potential": report.potential.values(), "total": total.tolist(),
                           "every": report.times.stride, "points": report.times.count},
        "schedules": {c.name: c.schedule for c in design.tendons if c.schedule is not None},
    }
