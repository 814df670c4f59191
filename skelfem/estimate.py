"""An error estimate for every observable: the same equilibrium one degree richer, on the same mesh.

Let u_h be the converged equilibrium of degree p and J any observable
(skelfem.observables: marker positions, tensions, reactions, ground and
contact forces, object poses). The estimate solves the same design on the
same mesh with Lagrange degree p + 1, started from u_h (exact: P_p lies in
P_{p+1}) with the same parameters and friction history, and reads every
observable there:

    e_d(J) = |J(u_{p+1}) - J(u_h)|        (discretisation)

This is the hierarchical (two-level) estimate: under saturation,
|J - J(u_{p+1})| <= s |J - J(u_h)| with s < 1, so

    (1 - s) |J - J(u_h)| <= e_d(J) <= (1 + s) |J - J(u_h)|,

and the enriched solve is the dual-weighted residual with the enriched
adjoint solved exactly: to first order J(u_{p+1}) - J(u_h) =
-J'(u_h) K_{p+1}^{-1} R_{p+1}(u_h) = -z_{p+1} . R_{p+1}(u_h), for every J at
once (one solve for all observables instead of one adjoint each). The
enriched solve is Newton (to RICH_RTOL of its first residual), not one linearised
step: reactions and contact forces are read from the residual on fixed and
contact DOFs, which only balance at an equilibrium (one step left a pin's
reaction 1 N off on finger3d). The saturation constant s is what limits the
effectivity (measured in docs/guide/accuracy.md: 0.60-1.51 where the mesh
resolves the body, far lower where a part has a few cells across or a cable ends in
an anchor far smaller than its cells: docs/model.md); near a
point-like quantity (a tendon ending in silicone) p + 1 on the same mesh
gains less than near smooth ones, and the estimate is lower.

In 3D the richer solve's linear solves are CG with two-level p-multigrid
above 30k DOFs (richer_linear): half the CPU time of MUMPS on the P2 matrix
at 55k DOFs. It
still costs 4-5x the P1 solve it checks in 3D (three P2 Newton iterations,
each a P2 assembly and about 20 multigrid cycles, against about eight P1
ones), and 1-2x in 2D: docs/guide/accuracy.md has the measurements, and
what was tried and did not hold (one linearised step; a frozen Jacobian).

The algebraic error is the effect on J of the Newton correction still left
at u_h (one solve with K next to u_h: the converged solve's factorisation,
one back-substitution; assembled anew only if the solver holds none):

    e_a(J) = |J(u_h + du) - J(u_h)|,   K du = -R(u_h),

and ``error`` = e_d + e_a; ``change`` is J(u_{p+1}) - J(u_h) with its sign (the
direction of the correction, for a caller that shifts data by it: calibration).
Friction histories move across when their
arrays fit the richer space (cable friction: per via point); contact
friction keeps per-node anchors, so the richer solve anchors its nodes
where u_h puts them (stuck; the first lag gives each its limit mu N) and
re-solves one quasi-static step at the same load, friction's lag included.
It cannot slip where the mesh's own load path might have: the estimate then
says so (``slip_history`` "anchored") and names the read-outs that a
different slip history moves (``not_covered``: contact and ground forces,
objects' poses), whose bars leave that out.
"""
from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from .observables import observables
from .result import plain

log = logging.getLogger("skelfem")

METHOD = "degree p+1 on the same mesh (hierarchical / dual-weighted residual)"
ALGEBRAIC_SHARE = 0.1     # the solver's error should be below this share of the discretisation error ...
ROUND_OFF = 1e-9          # ... or at round-off relative to the observable
RICH_RTOL = 1e-3          # the richer solve stops at this share of its first residual: it starts at the answer,
                          # and its own error is then a few % of the difference it measures (3D block: tip 2 %,
                          # tension 0.6 %, a pin's reaction 1e-3 N), at half the Newton iterations of 1e-9


SLIP_SENSITIVE = ("contacts.", "grounds.", "objects.")   # read-outs set by where contacts stuck and slipped on the way


RICH_ITERATIVE_DOFS = 30_000   # 3D richer solves above this many DOFs are iterative (richer_linear)


class EstimateError(Exception):
    """The observables cannot be estimated for this run (e.g. a run in time)."""


def observables_of(model) -> dict[str, float]:
    """{observable: value} of the model's current state, from the terms' read-outs (as result.json)."""
    data = model.readouts()
    if isinstance(data.get("contacts"), dict):
        data["contacts"] = list(data["contacts"].values())
    return observables(plain(data))


def richer(design):
    """The design with a Lagrange degree one higher (the same mesh is reused: nothing is re-meshed)."""
    return dataclasses.replace(design, mesh=dataclasses.replace(design.mesh, degree=int(design.mesh.degree) + 1))


def richer_linear(design, dofs: int) -> str:
    """The richer solve's linear solves: in 3D above RICH_ITERATIVE_DOFS (unless [solver] linear asks for one)
    CG with two-level p-multigrid (the P1 level of the same mesh under one smoothing of the richer matrix,
    skelfem.fem.multigrid.Coarse): MUMPS fills in a P2 factorisation of a tetrahedral mesh far more than a P1
    one (block3d at h = 1.5 mm, 55k P2 DOFs: 8.5 s of CPU against 4.2 s). Below it, and in 2D, the design's
    choice ("auto": MUMPS), which is as fast at 10k P2 DOFs and faster for nearly incompressible bodies,
    whose P2 multigrid needs 50-60 Krylov iterations per Newton step (finger3d, nu = 0.49, 9k P2 DOFs: 0.9 s
    against 1.7 s)."""
    if design.dim == 3 and design.solver.linear == "auto" and dofs > RICH_ITERATIVE_DOFS:
        return "iterative"
    return design.solver.linear


def _fits(old, new) -> bool:
    """Whether a term's history `old` has the structure and array shapes of `new` (the richer term's)."""
    if isinstance(old, np.ndarray) or isinstance(new, np.ndarray):
        return isinstance(old, np.ndarray) and isinstance(new, np.ndarray) and old.shape == new.shape
    if isinstance(old, dict) and isinstance(new, dict):
        return old.keys() == new.keys() and all(_fits(old[k], new[k]) for k in old)
    if isinstance(old, (list, tuple)) and isinstance(new, (list, tuple)):
        return len(old) == len(new) and all(_fits(a, b) for a, b in zip(old, new))
    return True


def _carry_history(model, rich) -> bool:
    """Copy each term's history into the richer model where it fits; False if some term must start anew."""
    fitted = True
    for term, new_term, h in zip(model.terms, rich.terms, model.history()):
        if h is None:
            continue
        if type(term) is type(new_term) and _fits(h, new_term.history()):
            new_term.set_history(h)
        else:
            fitted = False
    return fitted


def _same_parameters(model, rich) -> None:
    """Give the richer model the live parameter values the model holds: they may have been set in place
    (Model.set_parameter: a calibration's rows) and differ from the design's."""
    now = rich.parameters()
    for key, value in model.parameters().items():
        if key in now and not np.array_equal(np.asarray(now[key], float), np.asarray(value, float)):
            rich.set_parameter(key, value)
    rich.changes.clear()


def algebraic(session, J: dict[str, float]) -> dict[str, float]:
    """e_a of every observable: the change one more Newton correction at u_h would make (state restored)."""
    model, solver = session.model, session.solver
    x = model.u.vector
    saved = x.copy()
    b, dx = x.duplicate(), x.duplicate()
    try:
        if not solver.factorised:     # a converged solve leaves K next to u_h factorised: a back-substitution
            solver.jacobian(x)
        model.residual(x, b)
        solver.lin.solve(b, dx)
        x.axpy(-1.0, dx)
        model.apply_bcs(x)
        model.sync(x)
        moved = observables_of(model)
    finally:
        saved.copy(x)
        model.sync(x)
        for v in (saved, b, dx):
            v.destroy()
    return {k: abs(moved.get(k, v) - v) for k, v in J.items()}


def estimate(session) -> dict:
    """{"errors": {observable: {"error", "discretisation", "algebraic", "change"}}, "estimate": {how, cost}}.

    Needs a converged static equilibrium in ``session`` (Session.solve). The
    session's state and history are left as they were.
    """
    from .fem.model import Model
    from .fem.newton import NewtonSolver
    from .fem.release import release_vectors

    model = session.model
    if not session.solved:
        raise EstimateError("no converged equilibrium to estimate")
    t0 = time.perf_counter()
    J = observables_of(model)
    e_a = algebraic(session, J)
    t1 = time.perf_counter()
    design = richer(session.design)
    rich = Model(design, model.tm)
    t2 = time.perf_counter()
    dofs = int(rich.V.dofmap.index_map.size_global * rich.bs)
    solver = NewtonSolver(rich, dataclasses.replace(design.solver, rtol=max(design.solver.rtol, RICH_RTOL),
                                                    linear=richer_linear(design, dofs)))
    info = {"method": METHOD, "degree": int(design.mesh.degree), "dofs": dofs}
    try:
        _same_parameters(model, rich)
        rich.u.interpolate(model.u)
        rich.set_factor(1.0)
        carried = _carry_history(model, rich)
        if not carried:
            rich.end_step()           # per-node anchors: stuck where u_h puts the nodes; the lag gives mu N
        report = solver.newton()      # Newton at the full load, friction's lag included
        info.update(newton_iterations=int(report.newton_iterations), status=report.status,
                    assemblies=len(solver.lin.krylov) if solver.linear == "iterative" else None,
                    krylov_iterations=int(sum(solver.lin.krylov)) if solver.linear == "iterative" else None)
        if report.converged:
            rich.end_step()           # the step accepted: read-outs of its converged state (as a solve's)
        J_rich = observables_of(rich) if report.converged else None
    finally:
        solver.destroy()
        release_vectors(rich)         # as a re-meshing Session drops its old model (calibration estimates per row)
    t3 = time.perf_counter()
    info["seconds"] = {"algebraic": round(t1 - t0, 4), "compile": round(t2 - t1, 4), "solve": round(t3 - t2, 4)}
    if J_rich is None:
        log.warning("%s: the error estimate's solve of degree %d failed (%s): no estimate",
                    session.design.name, info["degree"], info["status"])
        return {"errors": None, "estimate": info}
    errors: dict[str, dict[str, float | None]] = {}
    loose = []                        # observables whose solver error is not below a tenth of the mesh's
    for name, value in J.items():
        change = J_rich[name] - value if name in J_rich else None
        e_d = None if change is None else abs(change)
        errors[name] = {"error": None if e_d is None else e_d + e_a[name], "discretisation": e_d,
                        "algebraic": e_a[name], "change": change}
        if e_d is not None and e_a[name] > ALGEBRAIC_SHARE * e_d + ROUND_OFF * (abs(value) + 1.0):
            loose.append(name)
    info["algebraic_below_discretisation"] = not loose
    info["slip_history"] = "carried" if carried else "anchored"
    if not carried:                   # contact friction: the richer solve does not slip where the mesh's might
        info["not_covered"] = [k for k in errors if k.startswith(SLIP_SENSITIVE)]
        if info["not_covered"]:
            log.warning("%s: contact friction is anchored where the answer put it: the error bars of %s leave out "
                        "a different slip history (check them by --tol, which solves the load path per mesh)",
                        session.design.name, ", ".join(info["not_covered"][:3]) +
                        (" ..." if len(info["not_covered"]) > 3 else ""))
    if loose:
        log.warning("%s: the solver's stopping error is above a tenth of the mesh's for %s: tighten [solver] "
                    "rtol/atol", session.design.name, ", ".join(loose[:3]) + (" ..." if len(loose) > 3 else ""))
    return {"errors": errors, "estimate": info}
