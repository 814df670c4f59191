"""Newton's linear solves: a sparse factorisation plus rank-one updates.

The Hessian of the total energy is H = K + sum_i c_i g_i g_i^T: K sparse (the
finite-element Hessian, the cables' curvature parts, contact), the g_i the
length gradients of taut cables, each coupling every DOF along its cable.
Putting g_i g_i^T into the matrix would add a dense block per cable; instead
K alone is factorised (MUMPS LDL^T, symbolic analysis reused across Newton
iterations) and the Sherman-Morrison-Woodbury formula gives

    H^{-1} b = K^{-1} b - Z (D^{-1} + G^T Z)^{-1} G^T K^{-1} b,   Z = K^{-1} G,

D = diag(c_i), and the same iterates as a factorisation of H (to
round-off). The first solve after a factorisation does K^{-1} [G | b] as one
multi-right-hand-side solve (MUMPS handles m + 1 columns for little more
than the price of one: 12.9 ms for 4 columns against 10.1 ms for one at
24k DOFs); later solves with the same factorisation (sensitivities) take
one back-substitution each. Under MPI G and Z are distributed by rows and
G^T x is an allreduce of m numbers, so nothing dense crosses ranks.
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
        self.K, self.comm = K, comm
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
        self.c = np.zeros(0)
        self.G = self.Z = None
        self.C = np.zeros((0, 0))
        self._dense: dict = {}
        self.solves = 0                 # solve phases run (one multi-RHS solve counts once)

    def update(self, parts: list[tuple[float, PETSc.Vec]]) -> None:
        """Factorise K (as it is now) and take the rank-one parts [(c_i, g_i)], c_i > 0."""
        self.ksp.setOperators(self.K)
        self.ksp.setUp()
        self._check()
        self.c = np.array([c for c, _ in parts], dtype=float)
        n = self.K.getLocalSize()[0]
        self.G = np.column_stack([g.array_r for _, g in parts]) if parts else np.zeros((n, 0))
        self.Z = None

    def reset(self) -> None:
        """Forget a failed factorisation (the next update factorises from scratch)."""
        self.ksp.reset()
        self.ksp.setOperators(self.K)
        self.ksp.setFromOptions()
        self._dense = {}
        self.Z = None

    def _check(self) -> None:
        reason = self.ksp.getConvergedReason()
        if reason < 0:
            raise np.linalg.LinAlgError(f"factorisation of the Newton matrix failed (KSP reason {reason})")

    def _multi_solve(self, cols: np.ndarray) -> np.ndarray:
        """K^{-1} cols for a block of right-hand sides (owned rows), one MUMPS solve phase."""
        n, k = cols.shape
        if k not in self._dense:
            B = PETSc.Mat().createDense([(n, None), (k, k)], comm=self.comm)
            X = PETSc.Mat().createDense([(n, None), (k, k)], comm=self.comm)
            B.setUp()
            X.setUp()
            self._dense[k] = (B, X)
        B, X = self._dense[k]
        B.getDenseArray()[:] = cols
        B.assemble()
        X.assemble()
        self.ksp.getPC().getFactorMatrix().matSolve(B, X)
        self.solves += 1
        return X.getDenseArray().copy()

    def _dots(self, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """A^T B summed over ranks."""
        out = A.T @ B
        return out if self.comm.size == 1 else self.comm.allreduce(out)

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """x = (K + G D G^T)^{-1} b."""
        m = len(self.c)
        if m == 0:
            self.ksp.solve(b, x)
            self.solves += 1
            self._check()
            return
        if self.Z is None:                      # first solve: K^{-1} [G | b] in one go
            Y = self._multi_solve(np.column_stack([self.G, b.array_r]))
            self.Z, y = Y[:, :m], Y[:, m]
            C = np.diag(1.0 / self.c) + self._dots(self.G, self.Z)
            self.C = 0.5 * (C + C.T)
        else:
            self.ksp.solve(b, x)
            self.solves += 1
            y = x.array_r.copy()
        w = self._dots(self.G, y[:, None])[:, 0]
        x.array_w[:] = y - self.Z @ np.linalg.solve(self.C, w)

    def as_pc(self, pc: PETSc.PC) -> None:
        """Make pc apply this solver (for SNES's KSP of type preonly)."""
        pc.setType(PETSc.PC.Type.PYTHON)
        pc.setPythonContext(_ApplyPC(self))

    def destroy(self) -> None:
        self.ksp.destroy()
        for B, X in self._dense.values():
            B.destroy()
            X.destroy()
        self._dense = {}


class _ApplyPC:
    """A PETSc python PC whose apply is LowRankSolver.solve (the factorisation happens in update)."""

    def __init__(self, solver: LowRankSolver):
        self.solver = solver

    def apply(self, pc, x, y):
        self.solver.solve(x, y)
