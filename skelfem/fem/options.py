"""PETSc options: every option set the solvers use, and the one way they reach PETSc's database.

Each ``*_petsc_options()`` returns a fresh dict (merged with a user's by the caller, never mutated);
``options_held`` puts {prefix + key: value} into the database for a ``setFromOptions`` and takes it out
again, so a later solver with the same prefix inherits nothing. The linear solves (skelfem.fem.linear)
and the SNES Newton solver (skelfem.fem.newton) set their options through it.
"""
from __future__ import annotations

from petsc4py import PETSc

from .multigrid import KRYLOV_RTOL


def default_petsc_options() -> dict:
    """A fresh dict of PETSc options for the factorisation of K.

    Every K here is symmetric (UFL Hessian, cable curvature and contact
    blocks, Dirichlet rows and columns replaced symmetrically), so MUMPS's
    LDL^T (PETSc "cholesky", indefinite-safe) replaces LU: about 20 % less
    per factorisation with the same iterates.
    """
    return {"ksp_type": "preonly", "pc_type": "cholesky", "pc_factor_mat_solver_type": "mumps"}


def iterative_petsc_options() -> dict:
    """A fresh dict of PETSc options for CG preconditioned by GAMG (see the module docstring)."""
    return {"ksp_type": "cg", "ksp_norm_type": "unpreconditioned", "ksp_rtol": KRYLOV_RTOL,
            "ksp_atol": 0.0, "ksp_max_it": 500,
            "pc_type": "gamg", "pc_gamg_type": "agg", "pc_gamg_agg_nsmooths": 1,
            "pc_gamg_reuse_interpolation": True, "pc_gamg_threshold": 0.01,
            "mg_levels_ksp_type": "chebyshev", "mg_levels_pc_type": "jacobi",
            "mg_levels_ksp_max_it": 3, "mg_levels_esteig_ksp_type": "cg"}


def two_level_petsc_options() -> dict:
    """A fresh dict of PETSc options for CG preconditioned by two-level p-multigrid (``Coarse``): Chebyshev-
    Jacobi smoothing on K's own (P2) level, and on the coarse (P1) level GAMG as iterative_petsc_options."""
    gamg = iterative_petsc_options()
    krylov = {k: gamg.pop(k) for k in ("ksp_type", "ksp_norm_type", "ksp_rtol", "ksp_atol", "ksp_max_it")}
    levels = {k: v for k, v in gamg.items() if k.startswith("mg_levels_")}
    return {**krylov, "pc_type": "mg", "pc_mg_galerkin": "none", **levels,
            "mg_coarse_ksp_type": "preonly", **{f"mg_coarse_{k}": v for k, v in gamg.items()}}


def snes_petsc_options(strategy: str) -> dict:
    """A fresh dict of PETSc options for the SNES Newton solver with line search `strategy` (the
    energy strategies are SNES's "basic" line search behind skelfem's pre-check; "residual" is PETSc's
    backtracking on |grad Pi|; "trust_region" sets the SNES type instead and needs none)."""
    if strategy == "trust_region":
        return {}
    return {"snes_linesearch_type": "bt" if strategy == "residual" else "basic"}


class options_held:
    """PETSc's options database holds {prefix + key: value} inside the with block only (a later solver
    with the same prefix must not inherit them)."""

    def __init__(self, prefix: str, options: dict):
        self.prefix, self.options, self.db = prefix, options, PETSc.Options()

    def __enter__(self):
        for key, value in self.options.items():
            self.db[f"{self.prefix}{key}"] = value

    def __exit__(self, *exc):
        for key in self.options:
            self.db.delValue(f"{self.prefix}{key}")
