"""Multigrid for the iterative linear solves (skelfem.fem.linear): PETSc options, the rigid-body
near-nullspace, and how tightly an inexact Newton step is solved (the forcing term)."""
from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from ..design.resources import auto_linear


KRYLOV_RTOL = 1e-12       # |r| / |b| of a tight iterative solve (sensitivities to 1e-8 behind a 1e4 condition)

ETA_MAX = 0.01            # the loosest forcing term of an inexact Newton step
REBUILD_RATIO = 2.0       # a lagged multigrid is rebuilt when it needs this many times the iterations


def forcing(residuals: list[float], last: float) -> float:
    """Eisenstat and Walker's second forcing term for Newton step k: eta = 0.9 (|F_k| / |F_k-1|)^2,
    safeguarded (not below 0.9 last^2 while that is above 0.1) and kept in [KRYLOV_RTOL, ETA_MAX]:
    loose while Newton is far from the solution, as tight as a direct solve near it."""
    if len(residuals) < 2 or residuals[-2] <= 0.0:
        return ETA_MAX
    eta = 0.9 * (residuals[-1] / residuals[-2]) ** 2
    if 0.9 * last ** 2 > 0.1:
        eta = max(eta, 0.9 * last ** 2)
    return float(min(max(eta, KRYLOV_RTOL), ETA_MAX))


def iterative_petsc_options() -> dict:
    """A fresh dict of PETSc options for CG preconditioned by GAMG (see the module docstring)."""
    return {"ksp_type": "cg", "ksp_norm_type": "unpreconditioned", "ksp_rtol": KRYLOV_RTOL,
            "ksp_atol": 0.0, "ksp_max_it": 500,
            "pc_type": "gamg", "pc_gamg_type": "agg", "pc_gamg_agg_nsmooths": 1,
            "pc_gamg_reuse_interpolation": True, "pc_gamg_threshold": 0.01,
            "mg_levels_ksp_type": "chebyshev", "mg_levels_pc_type": "jacobi",
            "mg_levels_ksp_max_it": 3, "mg_levels_esteig_ksp_type": "cg"}


def rigid_body_modes(X: np.ndarray, dim: int, centred: bool = False) -> np.ndarray:
    """(n * dim, 3 or 6) the rigid motions of points X (n, dim), interleaved like the DOFs: the
    translations, then the rotations about the points' centroid (2D: one, 3D: three; centred: X is
    already relative to the centre, as under MPI, where each rank holds a part of the points)."""
    n = len(X)
    Y = X[:, :dim] - (X[:, :dim].mean(axis=0) if n and not centred else 0.0)
    modes = []
    for k in range(dim):
        m = np.zeros((n, dim))
        m[:, k] = 1.0
        modes.append(m)
    axes = [(0, 1)] if dim == 2 else [(0, 1), (1, 2), (2, 0)]
    for a, b in axes:
        m = np.zeros((n, dim))
        m[:, a], m[:, b] = -Y[:, b], Y[:, a]
        modes.append(m)
    return np.column_stack([m.ravel() for m in modes])


def near_nullspace(K: PETSc.Mat, modes: np.ndarray, comm) -> PETSc.NullSpace:
    """An orthonormal PETSc near-nullspace from the owned rows of the modes (modified Gram-Schmidt)."""
    vecs = []
    for j in range(modes.shape[1]):
        v = K.createVecLeft()
        v.array_w[:] = modes[:, j]
        for w in vecs:
            v.axpy(-v.dot(w), w)
        v.normalize()
        vecs.append(v)
    return PETSc.NullSpace().create(vectors=vecs, comm=comm)


def choose_linear(kind: str, model) -> str:
    """"direct" or "iterative" for a [solver] linear value ("auto": skelfem.design.resources.auto_linear)."""
    if kind != "auto":
        return kind
    return auto_linear(model.design, model.comm.allreduce(model.n_owned))
