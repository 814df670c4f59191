"""Newton's linear solves: a sparse factorisation plus rank-one updates.

The Hessian of the total energy is H = K + sum_i c_i g_i g_i^T: K sparse (the
finite-element Hessian, the cables' curvature parts, contact), the g_i the
length gradients of taut cables, each coupling every DOF along its cable.
Putting g_i g_i^T into the matrix would add a dense block per cable; instead
K alone is factorised (MUMPS LDL^T, symbolic analysis reused across Newton
iterations) and the Sherman-Morrison-Woodbury formula gives

    H^{-1} b = K^{-1} b - Z (D^{-1} + G^T Z)^{-1} G^T K^{-1} b,   Z = K^{-1} G,

D = diag(c_i): m + 1 back-substitutions with the one factorisation for m
taut cables, an m x m dense solve, and the same iterates as a factorisation
of H (to round-off). Under MPI the g_i are distributed vectors and G^T x is
m dot products, so nothing dense crosses ranks.
"""
from __future__ import annotations

import numpy as np
from petsc4py import PETSc


def default_petsc_options() -> dict:
    """A fresh dict of PETSc options for the factorisation of K.

    Every K here is symmetric (UFL Hessian, cable curvature and contact
    blocks, Dirichlet rows and columns replaced symmetrically), so MUMPS's
    LDL^T (PETSc "cholesky", indefinite-safe) replaces LU: about 20 % less
    per factorisation with the same iterates.
    """
    return {"ksp_type": "preonly", "pc_type": "cholesky", "pc_factor_mat_solver_type": "mumps"}


class LowRankSolver:
    """Solves (K + G D G^T) x = b with one factorisation of the sparse K per update."""

    def __init__(self, K: PETSc.Mat, comm, options: dict | None = None, prefix: str = "skelfem_k_"):
        self.K = K
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setOptionsPrefix(prefix)
        opts = PETSc.Options()
        options = {**default_petsc_options(), **(options or {})}
        for key, value in options.items():
            opts[f"{prefix}{key}"] = value
        self.ksp.setOperators(K)
        self.ksp.setFromOptions()
        self.ksp.getPC().setFromOptions()
        for key in options:
            del opts[f"{prefix}{key}"]
        self.G: list[PETSc.Vec] = []
        self.Z: list[PETSc.Vec] = []
        self.C = np.zeros((0, 0))
        self.solves = 0                 # back-substitutions done (for benchmarks)

    def update(self, parts: list[tuple[float, PETSc.Vec]]) -> None:
        """Factorise K (as it is now) and prepare the rank-one parts [(c_i, g_i)]."""
        self.ksp.setOperators(self.K)
        self.ksp.setUp()
        while len(self.Z) < len(parts):
            self.Z.append(self.K.createVecRight())
        self.G = [g for _, g in parts]
        m = len(parts)
        C = np.diag([1.0 / c for c, _ in parts]) if m else np.zeros((0, 0))
        for i, g in enumerate(self.G):
            self._solve_K(g, self.Z[i])
        for i in range(m):
            for j in range(m):
                C[i, j] += self.G[i].dot(self.Z[j])
        self.C = 0.5 * (C + C.T)

    def _solve_K(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        self.ksp.solve(b, x)
        self.solves += 1
        reason = self.ksp.getConvergedReason()
        if reason < 0:
            raise np.linalg.LinAlgError(f"factorisation of the Newton matrix failed (KSP reason {reason})")

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """x = (K + G D G^T)^{-1} b."""
        self._solve_K(b, x)
        m = len(self.G)
        if m == 0:
            return
        w = np.array([g.dot(x) for g in self.G])
        y = np.linalg.solve(self.C, w)
        for yi, z in zip(y, self.Z[:m]):
            x.axpy(-yi, z)

    def as_pc(self, pc: PETSc.PC) -> None:
        """Make pc apply this solver (for SNES's KSP of type preonly)."""
        pc.setType(PETSc.PC.Type.PYTHON)
        pc.setPythonContext(_ApplyPC(self))

    def destroy(self) -> None:
        self.ksp.destroy()
        for z in self.Z:
            z.destroy()


class _ApplyPC:
    """A PETSc python PC whose apply is LowRankSolver.solve (the factorisation happens in update)."""

    def __init__(self, solver: LowRankSolver):
        self.solver = solver

    def apply(self, pc, x, y):
        self.solver.solve(x, y)
