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

A **border** adds a few unknowns z that some rows follow (rigid bones: the
bone's node displacements are T z, z its rigid DOFs). Those rows of K are
identity rows and columns; the full vector x keeps its size, with x_b = T z
on the slaved rows. For a right-hand side b the reduced one is (b_f, T^T b),
b_f = b with the slaved rows zeroed, and each g_i likewise (g_f, h_i =
T^T g_i). With E = K_full T on the other rows (the coupling) and C the
reduced m x m block, the system

    [K    E] [x_f]              [b_f  ]
    [E^T  C] [z  ] + G^ D G^^T = [T^T b]

is solved from the same multi-right-hand-side solve Y = K^{-1} [G_f | E | b_f]:
with w = D (G_f^T x_f + H^T z), x_f = y - Z_E z - Z_G w and (z, w) from the
small symmetric system

    [C - E^T Z_E      H - E^T Z_G       ] [z]   [T^T b - E^T y]
    [H^T - G^T Z_E   -(D^-1 + G^T Z_G)  ] [w] = [-G^T y       ]

(without a border this is the Woodbury formula above).

In serial the model writes the border into K itself (``Border.hosts``): z
takes the rows and columns of a few slaved DOFs, which then hold E^T and C
instead of identity rows. The system above is then a plain (K + G D G^T)
solve with b -> (b_f, T^T b on the hosts) and g_i -> (g_f, h_i on the
hosts), and x = x_f + T z: one factorisation and no extra right-hand sides.
"""
from __future__ import annotations

from dataclasses import dataclass

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


@dataclass
class Border:
    """Border unknowns z of a linear solve (see the module docstring); arrays on owned rows."""
    T: np.ndarray        # (n, m): the slaved rows' values per unit z (zero elsewhere)
    rows: np.ndarray     # (n,) bool: the slaved rows (identity rows and columns of K)
    E: np.ndarray        # (n, m): K_full T on the other rows (zero on slaved and Dirichlet rows)
    C: np.ndarray        # (m, m): the reduced block T^T K T (+ second-order terms), same on every rank
    hosts: np.ndarray | None = None   # (m,): slaved rows of K that hold z (E and C already in K), serial

    def embed(self, v: np.ndarray) -> np.ndarray:
        """(v_f, T^T v on the hosts) of a full vector v (or of the columns of a block)."""
        out = v * (~self.rows if v.ndim == 1 else ~self.rows[:, None])
        out[self.hosts] = self.T.T @ v
        return out

    def expand(self, y: np.ndarray) -> np.ndarray:
        """x = y_f + T z of a solution y of the embedded system, z = y on the hosts."""
        return y * ~self.rows + self.T @ y[self.hosts]


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
        self.border = None
        self.C = np.zeros((0, 0))
        self._dense: dict = {}
        self._work = None               # the embedded right-hand side (Border.hosts)
        self.solves = 0                 # solve phases run (one multi-RHS solve counts once)

    def update(self, parts: list[tuple[float, PETSc.Vec]], border: Border | None = None) -> None:
        """Factorise K (as it is now) and take the rank-one parts [(c_i, g_i)], c_i > 0, and a border."""
        self.ksp.setOperators(self.K)
        self.ksp.setUp()
        self._check()
        self.c = np.array([c for c, _ in parts], dtype=float)
        n = self.K.getLocalSize()[0]
        self.G = np.column_stack([g.array_r for _, g in parts]) if parts else np.zeros((n, 0))
        self.border = border
        self.H = np.zeros((0, len(self.c)))
        if border is not None and border.hosts is not None:
            self.G = border.embed(self.G)                   # (g_f, h_i on the hosts)
        elif border is not None:
            self.H = self._dots(border.T, self.G)          # h_i = T^T g_i
            self.G = self.G * ~border.rows[:, None]
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
        """x = (K + G D G^T)^{-1} b, reduced to the border unknowns if there is a border."""
        border = self.border
        if border is None or border.hosts is None:
            self._solve(b, x, border)
            return
        if self._work is None:
            self._work = b.duplicate()
        self._work.array_w[:] = border.embed(b.array_r)
        self._solve(self._work, x, None)
        x.array_w[:] = border.expand(x.array_r)

    def _solve(self, b: PETSc.Vec, x: PETSc.Vec, border: Border | None) -> None:
        """solve() with the border (if any) outside K."""
        k = len(self.c)
        if k == 0 and border is None:
            self.ksp.solve(b, x)
            self.solves += 1
            self._check()
            return
        E = border.E if border is not None else np.zeros((len(self.G), 0))
        m = E.shape[1]
        bf = b.array_r if border is None else b.array_r * ~border.rows
        if self.Z is None:                      # first solve: K^{-1} [G | E | b] in one go
            Y = self._multi_solve(np.column_stack([self.G, E, bf]))
            self._take_z(Y[:, :k + m], E, border)
            y = Y[:, k + m]
        elif border is None:
            self.ksp.solve(b, x)
            self.solves += 1
            y = x.array_r.copy()
        else:
            bvec = b.copy()
            bvec.array_w[:] = bf
            self.ksp.solve(bvec, x)
            bvec.destroy()
            self.solves += 1
            y = x.array_r.copy()
        ZG, ZE = self.Z[:, :k], self.Z[:, k:]
        rhs = np.concatenate([(self._dots(border.T, b.array_r[:, None])[:, 0] if m else np.zeros(0))
                              - self._dots(E, y[:, None])[:, 0],
                              -self._dots(self.G, y[:, None])[:, 0]])
        zw = np.linalg.solve(self.C, rhs)
        z, w = zw[:m], zw[m:]
        out = y - ZE @ z - ZG @ w
        if m:
            out = out + border.T @ z
        x.array_w[:] = out

    def _take_z(self, Z: np.ndarray, E: np.ndarray, border: Border | None) -> None:
        """Keep Z = K^{-1} [G | E] and the small system's matrix C made from it."""
        k, m = len(self.c), E.shape[1]
        self.Z = Z
        ZG, ZE = Z[:, :k], Z[:, k:]
        C = np.zeros((m + k, m + k))
        C[:m, :m] = (border.C if m else 0.0) - self._dots(E, ZE)
        C[:m, m:] = self.H - self._dots(E, ZG)
        C[m:, :m] = C[:m, m:].T
        C[m:, m:] = -(np.diag(1.0 / self.c) + self._dots(self.G, ZG))
        self.C = 0.5 * (C + C.T)

    def solve_many(self, B: np.ndarray) -> np.ndarray:
        """(K + G D G^T)^{-1} B for a block of right-hand sides (owned rows, one per column).

        One MUMPS solve phase for all the columns (forward sensitivities to
        many parameters), the same answers as solve() column by column.
        """
        B = np.asarray(B, dtype=float)
        border = self.border
        if border is not None and border.hosts is not None:
            Y = self._solve_block(border.embed(B), None)
            return Y * ~border.rows[:, None] + border.T @ Y[border.hosts]
        return self._solve_block(B, border)

    def _solve_block(self, B: np.ndarray, border: Border | None) -> np.ndarray:
        k = len(self.c)
        E = border.E if border is not None else np.zeros((len(B), 0))
        m = E.shape[1]
        if k == 0 and border is None:
            return self._multi_solve(B)
        Bf = B if border is None else B * ~border.rows[:, None]
        if self.Z is None:
            Y = self._multi_solve(np.column_stack([self.G, E, Bf]))
            self._take_z(Y[:, :k + m], E, border)
            Y = Y[:, k + m:]
        else:
            Y = self._multi_solve(Bf)
        ZG, ZE = self.Z[:, :k], self.Z[:, k:]
        top = (self._dots(border.T, B) if m else np.zeros((0, B.shape[1]))) - self._dots(E, Y)
        ZW = np.linalg.solve(self.C, np.vstack([top, -self._dots(self.G, Y)]))
        out = Y - ZE @ ZW[:m] - ZG @ ZW[m:]
        return out + border.T @ ZW[:m] if m else out

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
        if self._work is not None:
            self._work.destroy()
            self._work = None


class _ApplyPC:
    """A PETSc python PC whose apply is LowRankSolver.solve (the factorisation happens in update)."""

    def __init__(self, solver: LowRankSolver):
        self.solver = solver

    def apply(self, pc, x, y):
        self.solver.solve(x, y)
