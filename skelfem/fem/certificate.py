"""The certificate of a state: its residual, against the tolerance a batch solve of the same model meets.

The editor sends it with every frame (skelfem.editor.engine): a state is shown as converged only when
its residual is at or below that tolerance.
"""
from __future__ import annotations

import numpy as np


def certificate(solver, steps: int = 1, tol: float | None = None) -> tuple[float, float]:
    """(|R|, tol): the residual at the state of a NewtonSolver's model, and the tolerance a solve from
    rest of the same model in ``steps`` load steps holds it to at least.

    Such a solve stops at max(atol, rtol |R_0|), |R_0| the largest first residual of its load steps;
    the first is |R| at rest (pins at their first load factor's moves), so tol = max(atol, rtol x that)
    is at most its tolerance: a state with |R| <= tol is converged as a batch solve is. Two residual
    assemblies (one when tol is given: the same model, parameters and mesh as a call that returned it,
    see :func:`rest_key`); the state, load factor, parameters and history (friction's) are left as they were.
    """
    model = solver.model
    x = model.u.vector.copy()
    rest, b = x.duplicate(), x.duplicate()
    factor, committed = model.factor, model.history()    # set_factor moves friction's trial states
    try:
        if tol is None:
            rest.set(0.0)
            model.set_factor(1.0 / max(int(steps), 1))
            model.apply_bcs(rest)
            model.residual(rest, b)
            tol = max(float(solver.atol), float(solver.rtol) * float(b.norm()))
            model.set_factor(factor)
        model.residual(x, b)
        return float(b.norm()), tol
    finally:
        model.set_factor(factor)
        model.set_history(committed)
        model.sync(x)
        for v in (x, rest, b):
            v.destroy()


def rest_key(solver, steps: int = 1):
    """What the tolerance of :func:`certificate` depends on: the model, its live parameters, its nodes'
    places, the solver's tolerances and the steps; None where it depends on more (a path-dependent model's
    history), so that it is computed again."""
    model = solver.model
    if model.path_dependent:
        return None
    params = tuple((k, np.asarray(v, dtype=float).tobytes()) for k, v in sorted(model.parameters().items()))
    x = model.mesh.geometry.x
    return (id(model), id(x), hash(x.tobytes()), params, int(steps), float(solver.atol), float(solver.rtol))
