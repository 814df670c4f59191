"""What a Newton iteration costs, against its floor, over mesh sizes.

For each mesh size h the design is meshed and solved as ``simulate`` would
(through a Session), and in the same process we measure

    floor  the physical floor of one Newton iteration: assembly of the
           finite-element Hessian alone, on its own pattern, plus its
           numeric refactorisation and one solve (MUMPS reuses its symbolic
           analysis): ``floor_time``
    K      the same on the Newton matrix K (FE Hessian plus the cables'
           sparse curvature and contact blocks) plus the Woodbury solves
           of the taut cables' rank-one parts: what Newton really pays
    t_it   one Newton iteration: the time between successive SNES monitor
           calls of one load step (Jacobian, linear solve, line search,
           residual, convergence test)

and report  ratio = median over the repeats of median(t_it) / floor_time,
each repeat's iterations against the floor sampled right after them (a
machine whose speed drifts between repeats moves both alike), beside
``ratio_pooled`` = median(all t_it) / median(all floor samples). An iteration needs at least
one assembly and one refactorisation, so the ratio is >= ~1; everything
above 1 is the cables' extra solves, line search, residuals, det F checks
and Python glue, broken down per iteration in ``breakdown`` by timing the
model calls the solver makes.

Every timing is the median of ``repeats`` measurements taken in one run;
compare ratios, not absolute times, between runs on a shared machine.
"""
from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

log = logging.getLogger("skelfem.jobs.bench")   # progress, one line per size

FORMAT = 1
DOF_FLOOR = 20_000          # the floor is checked on meshes with at least this many DOFs
FLOOR_SAMPLES = 5           # floor samples (assembly + refactorisation) after each repeat's solve
RATIO_FLOOR = 1.3           # median t_it <= 1.3 x the FE floor (t_A + t_F of the FE Hessian alone)
PROBED = ("jacobian", "low_rank", "residual", "energy", "admissible", "max_step", "step_correction")
# PETSc log events inside the linear solve (LU or Cholesky), read at every SNES monitor call
EVENTS = {"factorization": ("MatLUFactorNum", "MatCholFctrNum"), "triangular_solves": ("MatSolve",)}


# -- instrumentation -------------------------------------------------------------------------------
def _event_times() -> dict:
    """Cumulative seconds of the EVENTS groups in PETSc's log."""
    from petsc4py import PETSc
    return {group: sum(PETSc.Log.Event(name).getPerfInfo()["time"] for name in names)
            for group, names in EVENTS.items()}


@dataclass
class Probe:
    """Wall-clock stamps of SNES iterations and of the work done between them.

    ``iterations`` holds one list of (monitor time, PETSc event times) per
    SNES solve; ``calls`` holds (name, start, duration) for every wrapped
    model method. Iteration k is the span between monitor calls k and k+1:
    Jacobian, linear solve, line search, residual.
    """

    iterations: list = field(default_factory=list)
    residuals: list = field(default_factory=list)
    calls: list = field(default_factory=list)
    iterates: list = field(default_factory=list)     # states x_k of the latest SNES solve

    def wrap(self, obj, name: str) -> None:
        """Replace obj.name by a timed version (instance attribute, the class is untouched)."""
        inner = getattr(obj, name)

        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                self.calls.append((name, t0, time.perf_counter() - t0))
        setattr(obj, name, timed)

    def monitor(self, snes, its, fnorm) -> None:
        now, events = time.perf_counter(), _event_times()
        if its == 0:
            self.iterations.append([])
            self.residuals.append([])
            self.iterates = []
        self.iterates.append(snes.getSolution().array_r.copy())
        self.iterations[-1].append((now, events))
        self.residuals[-1].append(float(fnorm))

    def reset(self) -> None:
        self.iterations, self.residuals, self.calls, self.iterates = [], [], [], []

    def state_errors(self) -> list[float]:
        """e_k = |x_k - x_n| over the latest SNES solve (x_n its last iterate)."""
        if not self.iterates:
            return []
        xn = self.iterates[-1]
        return [float(np.linalg.norm(x - xn)) for x in self.iterates[:-1]]

    def _spans(self):
        return [(a, b) for stamps in self.iterations for a, b in zip(stamps[:-1], stamps[1:])]

    def intervals(self) -> list[tuple[float, float]]:
        """(start, end) of every complete Newton iteration."""
        return [(a[0], b[0]) for a, b in self._spans()]

    def breakdown(self) -> dict:
        """Mean seconds per Newton iteration in each part; 'other' is the rest (SNES, Python glue).

        Probed model calls belong to the iteration in which they start;
        factorisation and triangular solves come from PETSc's event log.
        """
        spans = self._spans()
        if not spans:
            return {}
        starts = np.array([a[0] for a, _ in spans])
        ends = np.array([b[0] for _, b in spans])
        out = {name: 0.0 for name in PROBED}
        counts = {name: 0 for name in PROBED}
        for name, t0, dt in self.calls:
            k = np.searchsorted(starts, t0, side="right") - 1
            if k >= 0 and t0 < ends[k]:
                out[name] += dt
                counts[name] += 1
        for group in EVENTS:
            out[group] = sum(b[1][group] - a[1][group] for a, b in spans)
        n = len(spans)
        res = {name: value / n for name, value in out.items()}
        res["other"] = (float(np.sum(ends - starts)) - sum(out.values())) / n
        res["calls_per_iteration"] = {name: counts[name] / n for name in PROBED}
        return res


def convergence_orders(history, noise: float = 0.0) -> list[float]:
    """Estimated orders q_k = log(e_{k+1}/e_k) / log(e_k/e_{k-1}) of the last three steps.

    q -> 2 for Newton's quadratic convergence, 1 for linear convergence.
    Values at or below ``noise`` (round-off level) are left out.
    """
    r = np.asarray([v for v in history if v > noise], float)
    if len(r) < 3:
        return []
    ratios = np.log(r[1:] / r[:-1])
    q = ratios[1:] / ratios[:-1]
    return [float(v) for v in q[-3:]]


# -- measurements ---------------------------------------------------------------------------------
def _median(values) -> float:
    return float(np.median(values)) if len(values) else float("nan")


def _new_ksp(comm, options: dict):
    from petsc4py import PETSc
    ksp = PETSc.KSP().create(comm)
    ksp.setType(options.get("ksp_type", "preonly"))
    pc = ksp.getPC()
    pc.setType(options.get("pc_type", "lu"))
    pc.setFactorSolverType(options.get("pc_factor_mat_solver_type", "mumps"))
    return ksp


class LinearTimer:
    """t_A = assemble() and t_F = numeric refactorisation + one solve of A, sampled in pairs.

    Each sample assembles before it refactorises, so the matrix state changes
    and PETSc redoes only the numeric factorisation (the nonzero pattern,
    hence MUMPS's symbolic analysis, is unchanged).
    """

    def __init__(self, assemble, A, ksp):
        self.assemble, self.A, self.ksp = assemble, A, ksp
        self.b = A.createVecRight()
        self.b.set(1.0)
        self.y = self.b.duplicate()
        self.t_a, self.t_f, self.first = [], [], float("nan")

    def _factor_solve(self) -> None:
        self.ksp.setOperators(self.A)
        self.ksp.setUp()
        self.ksp.solve(self.b, self.y)

    def first_factorization(self) -> float:
        """Symbolic analysis + numeric factorisation + solve, on a fresh KSP."""
        self.assemble()
        t0 = time.perf_counter()
        self._factor_solve()
        self.first = time.perf_counter() - t0
        return self.first

    def sample(self, n: int) -> None:
        for _ in range(n):
            t0 = time.perf_counter()
            self.assemble()
            t1 = time.perf_counter()
            self._factor_solve()
            self.t_f.append(time.perf_counter() - t1)
            self.t_a.append(t1 - t0)

    def result(self) -> dict:
        return {"assembly_time": _median(self.t_a), "refactorization_time": _median(self.t_f),
                "nnz": int(self.A.getInfo()["nz_used"])}

    def destroy(self) -> None:
        self.b.destroy()
        self.y.destroy()


class NewtonTimer(LinearTimer):
    """t_A and t_F on the solver's own matrix K: assembly + low-rank parts; factorisation + Woodbury solve."""

    def __init__(self, model, solver):
        x = model.u.vector

        def assemble():
            model.jacobian(x, solver.A)
            self.parts = model.low_rank_columns(x)
        super().__init__(assemble, solver.A, None)
        self.solver, self.model = solver, model

    def _factor_solve(self) -> None:
        self.solver.lin.update(self.parts, self.model.border)
        self.solver.lin.solve(self.b, self.y)

    def result(self) -> dict:
        out = super().result()
        out["low_rank_parts"] = len(self.parts)
        return out


def fe_pattern_timer(model, options: dict) -> LinearTimer:
    """t_A and t_F of the UFL Hessian alone on its own pattern: the floor of a Newton iteration.

    Nodes the UFL Hessian gives no stiffness (inside a rigid bone or a rigid object: their cells carry
    no strain, their motion is the rigid body's few DOFs, outside this matrix) have empty rows that
    leave it singular; they get a 1 on the diagonal, like pinned nodes, so the floor is the factorisation
    of the elastic part."""
    from petsc4py import PETSc
    from dolfinx.fem import petsc as fem_petsc

    A = fem_petsc.create_matrix(model.jacobian_form)
    A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)     # the held rows' diagonal, once
    held = A.createVecLeft()

    def assemble():
        A.zeroEntries()
        fem_petsc.assemble_matrix(A, model.jacobian_form, bcs=model.bcs)
        A.assemble()
        if held_any:
            A.setDiagonal(held, addv=PETSc.InsertMode.ADD_VALUES)
    held_any = False
    assemble()
    held.array_w[:] = _stiffless_rows(A, model.u.function_space.dofmap.index_map_bs)
    held_any = bool(model.comm.allreduce(int(held.array_r.sum())))
    timer = LinearTimer(assemble, A, _new_ksp(model.comm, options))
    timer.first_factorization()
    return timer


def _stiffless_rows(A, bs: int) -> np.ndarray:
    """1.0 on the owned rows of the nodes whose every component has a zero diagonal in the assembled A
    (an empty row), else 0."""
    diagonal = A.getDiagonal()
    zero = np.repeat((diagonal.array_r == 0.0).reshape(-1, bs).all(axis=1), bs)
    diagonal.destroy()
    return zero.astype(float)


def residual_floor(model, samples: int = 3) -> float:
    """Round-off floor of |R| at the current state: |R(x (1 + eps s)) - R(x)| for random signs s.

    No iterate can be resolved better than x itself is represented, so a
    residual at this level is converged to machine precision.
    """
    x = model.u.vector.copy()
    b0, b1 = x.duplicate(), x.duplicate()
    model.residual(x, b0)
    rng = np.random.default_rng(0)
    eps = np.finfo(float).eps
    values = []
    for _ in range(samples):
        y = x.copy()
        y.array_w[:] *= 1.0 + eps * rng.choice([-1.0, 1.0], size=len(y.array_r))
        model.residual(y, b1)
        b1.axpy(-1.0, b0)
        values.append(b1.norm())
        y.destroy()
    model.residual(x, b0)       # leave model.u at x
    for v in (x, b0, b1):
        v.destroy()
    return _median(values)


def newton_order(model, solver, scales=(0.03, 0.01, 0.003, 0.001)) -> dict:
    """Order of one undamped Newton step from perturbed equilibria.

    From x0 = (1 + eps) u* (u* the equilibrium, pins kept), one full step
    x1 = x0 - H(x0)^{-1} R(x0). Newton's method is quadratic when
    |R(x1)| ~ C |R(x0)|^2: the slope of log |R(x1)| against log |R(x0)| is 2.
    This is independent of the line search and of where SNES happened to
    stop. (The residual, not |x - u*|, is the measure: with bones 10^4 times
    stiffer than the silicone, C in the state norm is so large that the
    asymptotic range of |x - u*| lies near round-off.)
    """
    from ..fem.multigrid import KRYLOV_RTOL
    u_star = model.u.vector.copy()
    x, r, p = u_star.duplicate(), u_star.duplicate(), u_star.duplicate()
    r0, r1 = [], []
    try:
        for eps in scales:
            u_star.copy(x)
            x.scale(1.0 + eps)
            model.apply_bcs(x)
            model.residual(x, r)
            r0.append(float(r.norm()))
            solver.jacobian(x)
            solver.lin.rtol = KRYLOV_RTOL           # iterative: an exact step, not an inexact Newton one
            solver.lin.solve(r, p)
            x.axpy(-1.0, p)
            model.residual(x, r)
            r1.append(float(r.norm()))
    finally:
        model.sync(u_star)
        for v in (x, r, p, u_star):
            v.destroy()
    ok = [(a, b) for a, b in zip(r0, r1) if a > 0 and b > 0]
    slope = float(np.polyfit(np.log([a for a, _ in ok]), np.log([b for _, b in ok]), 1)[0]) \
        if len(ok) >= 2 else float("nan")
    return {"scales": list(scales), "r0": r0, "r1": r1, "slope": slope}


def _reset(model) -> None:
    """Back to the rest state at load factor 0 (for a repeated solve)."""
    model.to_rest()
    model.set_factor(0.0)


def _instrument(model, solver) -> Probe:
    from petsc4py import PETSc
    PETSc.Log.begin()
    probe = Probe()
    for name in PROBED:
        if hasattr(model, name):
            probe.wrap(model, name)
    solver.snes.setMonitor(probe.monitor)
    return probe


def _uninstrument(model, solver) -> None:
    solver.snes.cancelMonitor()
    for name in PROBED:
        model.__dict__.pop(name, None)


def measure(model, solver, steps: int, repeats: int, options: dict) -> dict:
    """Solve `repeats` times from rest; after each solve sample t_A, t_F at the equilibrium.

    Interleaving keeps the iteration times and their floor under the same
    machine load. Newton iteration times come from the SNES monitor stamps.
    """
    probe = _instrument(model, solver)
    timer, fe_timer = None, None
    solve_times, its, iteration_times, breakdowns, errors, paired = [], [], [], [], [], []
    try:
        for k in range(repeats):
            _reset(model)
            probe.reset()
            report = solver.solve(steps)
            solve_times.append(report.time)
            its.append(report.newton_iterations)
            mine = [b - a for a, b in probe.intervals()]
            iteration_times += mine
            breakdowns.append(probe.breakdown())
            errors = probe.state_errors()
            _uninstrument(model, solver)
            if timer is None:
                timer, fe_timer = NewtonTimer(model, solver), fe_pattern_timer(model, options)
            timer.sample(FLOOR_SAMPLES)
            fe_timer.sample(FLOOR_SAMPLES)
            floor = _median(fe_timer.t_a[-FLOOR_SAMPLES:]) + _median(fe_timer.t_f[-FLOOR_SAMPLES:])
            paired.append(_median(mine) / floor)
            if not report.converged or k == repeats - 1:
                break
            probe = _instrument(model, solver)
    finally:
        _uninstrument(model, solver)
    keys = [k for k in breakdowns[0] if k != "calls_per_iteration"] if breakdowns[0] else []
    breakdown = {k: _median([b[k] for b in breakdowns if b]) for k in keys}
    if keys:
        breakdown["calls_per_iteration"] = breakdowns[-1]["calls_per_iteration"]
    row = {
        "converged": bool(report.converged), "status": report.status,
        "newton_iterations": int(its[-1]), "load_steps": int(report.load_steps),
        "solve_time": _median(solve_times),
        "iteration_time_median": _median(iteration_times),
        "iteration_time_mean": _median(solve_times) / max(its[-1], 1),
        "ratio_per_repeat": paired,
        "breakdown": breakdown,
        "residual_history": [list(map(float, h)) for h in report.residual_history],
        "linear_solver": solver.linear,
        "krylov_per_newton": [int(k) for step in report.linear_iterations for k in step],
        "state_errors": errors[-4:],
        "newton_matrix": timer.result(),
        **fe_timer.result(),
    }
    row["first_factorization_time"] = fe_timer.first
    fe_timer.ksp.destroy()
    fe_timer.A.destroy()
    for t in (timer, fe_timer):
        t.destroy()
    return row


def bench_size(path, size: float, degree: int | None = None, overrides=(), repeats: int = 3,
               petsc_options: dict | None = None, steps: int | None = None) -> dict:
    """Every measurement for one mesh size; returns one row of the table."""
    from ..session import Session

    sets = [*overrides, f"mesh.size={size}"] + ([f"mesh.degree={degree}"] if degree else [])
    t0 = time.perf_counter()
    session = Session(path, sets)
    t_scene = time.perf_counter() - t0
    design, model = session.design, session.model
    if petsc_options:
        from ..fem.newton import NewtonSolver
        session.solver.destroy()
        session.solver = NewtonSolver(model, design.solver, petsc_options=petsc_options)
    solver = session.solver
    options = solver.lin.options          # the floor factorises as Newton does
    n_steps = int(steps or design.solver.steps)
    row = {"size": float(size), "degree": int(design.mesh.degree), "dofs": session.dofs,
           "cells": int(model.mesh.topology.index_map(model.mesh.topology.dim).size_global),
           "steps": n_steps, "mesh_and_model_time": t_scene}
    row.update(measure(model, solver, n_steps, repeats, options))
    row["floor_time"] = row["assembly_time"] + row["refactorization_time"]
    nm = row["newton_matrix"]
    nm["floor_time"] = nm["assembly_time"] + nm["refactorization_time"]
    row["ratio_pooled"] = row["iteration_time_median"] / row["floor_time"]
    row["ratio"] = _median(row["ratio_per_repeat"])
    row["ratio_mean"] = row["iteration_time_mean"] / row["floor_time"]
    last = row["residual_history"][-1] if row["residual_history"] else []
    row["last_residuals"] = last[-5:]
    row["residual_floor"] = residual_floor(model)
    row["convergence_orders"] = convergence_orders(row["state_errors"], noise=1e-14 * model.size)
    if row["converged"]:
        row["newton_order"] = newton_order(model, solver)
    its = row["krylov_per_newton"]
    row["krylov_mean"] = sum(its) / len(its) if its else None
    row["peak_kb_per_dof"] = _peak_kb(model.comm) / row["dofs"]
    row = _reduce(model.comm, row)
    session.close()
    return row


def _peak_kb(comm) -> float:
    """The peak resident memory of this process so far (KB), summed over the ranks: what the sizes
    measured up to now needed at most (each row's own when the sizes go from coarse to fine, as by default)."""
    import resource
    return float(comm.allreduce(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss))


def _reduce(comm, row: dict) -> dict:
    """Times are the slowest rank's."""
    from mpi4py import MPI
    if comm.size == 1:
        return row
    for key, value in list(row.items()):
        if key.endswith("_time") or key.startswith("iteration_time"):
            row[key] = comm.allreduce(value, op=MPI.MAX)
    return row


def run(design, sizes=(4.0, 2.0, 1.0, 0.45), degree: int | None = None, overrides=(), repeats: int = 3,
        petsc_options: dict | None = None, steps: int | None = None) -> dict:
    """Benchmark a design file over mesh sizes; returns the bench.json content."""
    rows = []
    for h in sizes:
        row = bench_size(design, h, degree, overrides, repeats, petsc_options, steps)
        rows.append(row)
        log.info("h = %-5g %7d DOFs: assembly %.1f ms, refactorization %.1f ms, iteration %.1f ms "
                 "(ratio %.2f), %d iterations, %s", h, row["dofs"], 1e3 * row["assembly_time"],
                 1e3 * row["refactorization_time"], 1e3 * row["iteration_time_median"], row["ratio"],
                 row["newton_iterations"], row["status"])
    from mpi4py import MPI
    return {"format": FORMAT, "design": str(design), "degree": rows[0]["degree"] if rows else degree,
            "repeats": int(repeats), "petsc_options": dict(petsc_options or {}),
            "machine": {"cpus": os.cpu_count(), "mpi_ranks": MPI.COMM_WORLD.size,
                        "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS")},
            "rows": rows, "floor": floor_check(rows)}


def floor_check(rows) -> dict:
    """The floor on the largest converged mesh with >= DOF_FLOOR DOFs (P1 in 2D)."""
    big = [r for r in rows if r["dofs"] >= DOF_FLOOR and r["converged"]]
    if not big:
        return {"checked": False, "reason": f"no converged mesh with >= {DOF_FLOOR} DOFs"}
    r = max(big, key=lambda r: r["dofs"])
    orders = r["convergence_orders"]
    return {"checked": True, "size": r["size"], "dofs": r["dofs"], "ratio": r["ratio"],
            "limit": RATIO_FLOOR, "ratio_ok": bool(r["ratio"] <= RATIO_FLOOR),
            "last_residuals": r["last_residuals"], "residual_floor": r["residual_floor"],
            "state_errors": r["state_errors"], "convergence_orders": orders,
            "newton_order": r["newton_order"]["slope"],
            "quadratic": bool(r["newton_order"]["slope"] >= 1.8)}


# -- presentation ----------------------------------------------------------------------------------
COLUMNS = (("h", "size", "{:g}"), ("DOFs", "dofs", "{:d}"), ("assembly ms", "assembly_time", "ms"),
           ("refact+solve ms", "refactorization_time", "ms"), ("iteration ms", "iteration_time_median", "ms"),
           ("mean it ms", "iteration_time_mean", "ms"), ("its/solve", "newton_iterations", "{:d}"),
           ("ratio", "ratio", "{:.2f}"), ("K A+F+S ms", None, "newton"), ("nnz FE", "nnz", "{:d}"),
           ("nnz K", None, "nnz_k"), ("Krylov/it", "krylov_mean", "krylov"),
           ("peak KB/DOF", "peak_kb_per_dof", "{:.2f}"))


def _cell(row, key, fmt) -> str:
    if fmt == "ms":
        return f"{1e3 * row[key]:.1f}"
    if fmt == "newton":
        k = row["newton_matrix"]
        return f"{1e3 * k['assembly_time']:.1f}+{1e3 * k['refactorization_time']:.1f}"
    if fmt == "nnz_k":
        return f"{row['newton_matrix']['nnz']:d}"
    if fmt == "krylov":
        return "-" if row[key] is None else f"{row[key]:.1f}"
    return fmt.format(row[key])


def format_table(result: dict) -> str:
    """The bench table, then the last residuals of the largest mesh and the floor verdict."""
    head = [c[0] for c in COLUMNS]
    body = [[_cell(r, key, fmt) for _, key, fmt in COLUMNS] for r in result["rows"]]
    widths = [max(len(x) for x in col) for col in zip(head, *body)]
    lines = ["  ".join(x.rjust(w) for x, w in zip(line, widths)) for line in [head, *body]]
    for r in result["rows"]:
        if not r["converged"]:
            lines.append(f"h = {r['size']:g}: solve FAILED ({r['status']})")
    if result["rows"]:
        r = result["rows"][-1]
        lines.append(f"h = {r['size']:g}: last |R| " + " ".join(f"{v:.1e}" for v in r["last_residuals"])
                     + f" (round-off floor {r['residual_floor']:.0e}); |x_k - x_n| "
                     + " ".join(f"{v:.1e}" for v in r["state_errors"])
                     + ", orders " + " ".join(f"{q:.2f}" for q in r["convergence_orders"]))
        if "newton_order" in r:
            o = r["newton_order"]
            lines.append(f"h = {r['size']:g}: one full Newton step from (1+eps) u*: |R| "
                         + " ".join(f"{a:.1e} -> {b:.1e}," for a, b in zip(o["r0"], o["r1"]))
                         + f" slope {o['slope']:.2f} (2 = quadratic)")
        b = r["breakdown"]
        if b:
            parts = ", ".join(f"{k} {1e3 * v:.1f}" for k, v in b.items() if k != "calls_per_iteration")
            lines.append(f"h = {r['size']:g}: per iteration (ms): {parts}")
    f = result["floor"]
    if f["checked"]:
        verdict = "OK" if f["ratio_ok"] else "MISSED"
        lines.append(f"floor at {f['dofs']} DOFs: iteration / (FE assembly + refactorization) = "
                     f"{f['ratio']:.2f} (limit {f['limit']}) {verdict}; "
                     f"Newton order {f['newton_order']:.2f}: {'quadratic' if f['quadratic'] else 'NOT quadratic'}")
    else:
        lines.append(f"floor not checked: {f['reason']}")
    return "\n".join(lines)


def write(path: Path, result: dict) -> None:
    from ..io.files import write_json
    write_json(path, result)
