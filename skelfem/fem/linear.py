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

**Iterative solves** (``[solver] linear = "iterative"``): K is not factorised
but preconditioned by algebraic multigrid (PETSc GAMG, smoothed aggregation,
Chebyshev-Jacobi smoothing) with the rigid-body modes of the node
coordinates as its near-nullspace (3 in 2D, 6 in 3D); at P2 GAMG works on
the P1 Galerkin matrix under one P2 smoothing level (multigrid.Coarse). The border stays
outside K (its rows are identity rows: multigrid sees the soft body only),
and one Krylov solve (conjugate gradients) takes the whole system above at
once: its unknowns are (x, z), z on the first rank; its operator applies K,
E, C and the cables' G D G^T without forming them; its preconditioner is the
exact inverse of that system with one multigrid cycle B in place of K^{-1},
i.e. the formulas above with ZB = B [G | E] for Z (k + m cycles per
update, no Krylov solve). Newton's own steps are inexact (Eisenstat-Walker
forcing, ``skelfem.fem.newton.forcing``: ETA_MAX far from the solution, tighter near it, never
tighter than the residual test needs); every other solve (sensitivities,
adjoints) is to ``KRYLOV_RTOL``. The multigrid is built at the first update
and kept at later ones (``_lag_preconditioner``) until its iterations per
decade of residual exceed REBUILD_RATIO times a fresh one's. A Krylov solve
that fails (an indefinite K breaks CG; a stall) is retried with GMRES; a
Newton step's that still fails is taken if it reduced the residual tenfold
(``loose_steps``), else the update falls back to a MUMPS factorisation and
the formulas above for the rest of its solves, counted in ``fallbacks``
(both in result.json, never silent), where MUMPS fits (``direct_limit``).
"""
from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from petsc4py import PETSc

from ..design.resources import auto_linear
from .lowrank import Border, columns, dense, sparse_dots, sparse_product
from .multigrid import GMRES_CYCLES, KRYLOV_RTOL, LOOSE_STEP, REBUILD_RATIO, Coarse, krylov_solve, near_nullspace
from .options import default_petsc_options, iterative_petsc_options, options_held, two_level_petsc_options


class LowRankSolver:
    """Solves (K + G D G^T) x = b with one factorisation of the sparse K per update."""

    def __init__(self, K: PETSc.Mat, comm, options: dict | None = None, prefix: str = "skelfem_k_",
                 modes: np.ndarray | None = None, deflation=None, coarse: Coarse | None = None):
        """modes: the near-nullspace of K (owned rows, one mode per column) for an iterative solve
        (``[solver] linear = "iterative"``), or a function giving it where the nodes are now (a rebuilt
        multigrid follows the body); None: a direct factorisation. coarse: iterative solves by
        two-level p-multigrid on that coarse level (multigrid.Coarse) instead of GAMG on K."""
        self.K, self.comm = K, comm
        self.kind = "direct" if modes is None else "iterative"
        self.prefix = prefix
        self._nullspace = None
        self.coarse = coarse if modes is not None else None
        base = default_petsc_options() if modes is None else \
            iterative_petsc_options() if self.coarse is None else two_level_petsc_options()
        self._options = {**base, **(options or {})}
        self._modes = modes
        if modes is not None:
            self._nullspace = near_nullspace(K, modes() if callable(modes) else modes, comm)
            K.setNearNullSpace(self._nullspace)
        self.ksp = self._make_ksp(prefix, self._options, self.coarse)
        self._direct: Any = None        # iterative: the fallback factorisation, made when first needed
        self._fallen = False            # iterative: this update's solves use the fallback
        self.fallbacks = 0              # updates whose Krylov solves failed and fell back to MUMPS
        self.direct_limit = np.inf      # ... unless K has more rows than MUMPS fits (a failed Newton step)
        self.loose_steps = 0            # Newton steps taken from a stalled Krylov solve (see _krylov)
        self.krylov: list[int] = []     # iterative: Krylov iterations since each update (one entry per update)
        self._its_since, self._decades_since = 0, 0.0   # iterative: since the last update, for ...
        self._fresh_rate: float | None = None   # ... the iterations per decade of residual of a fresh multigrid
        self._rebuilt = True
        self.rtol = KRYLOV_RTOL         # iterative: the relative residual of a Newton step's solve (forcing)
        self.c = np.zeros(0)
        self.G: Any = None              # set by update (PETSc vectors, sparse or dense columns) ...
        self.Z: Any = None              # ... and by the solves that need them
        self.border: Any = None         # Border | None: the last update's
        self.C = np.zeros((0, 0))
        self._dense: dict = {}
        self._work: Any = None          # the embedded right-hand side (Border.hosts)
        self.solves = 0                 # solve phases run (one multi-RHS solve counts once)
        self._hksp: Any = None          # iterative: the whole system's KSP (_operator_mode) on (x, z): n + m rows
        self._bvecs: Any = None         # ... (rhs, solution) of that size, and two n-vectors
        self.ZB: Any = np.zeros((0, 0))  # ... B [G | E], B one multigrid cycle (an approximate K^{-1})
        self.CB = np.zeros((0, 0))      # ... the small system's matrix made from ZB
        self.deflation = deflation      # iterative: () -> W, modes the multigrid cycle is balanced against
        self.W: Any = None              # ... at the last update
        self.KW: Any = None             # ... K W and W^T K W at the last update
        self.WKW: Any = None

    def _make_ksp(self, prefix: str, options: dict, coarse: Coarse | None = None) -> PETSc.KSP:
        ksp = PETSc.KSP().create(self.comm)
        ksp.setOptionsPrefix(prefix)
        ksp.setOperators(self.K)
        if coarse is not None:
            coarse.attach(ksp.getPC(), self.K)
        with options_held(prefix, options):
            ksp.setFromOptions()
            ksp.getPC().setFromOptions()
        if self.kind == "iterative":          # only its preconditioner is applied: no Krylov work vectors
            ksp.setType("preonly")
        return ksp

    def _lag_preconditioner(self) -> None:
        """Keep the multigrid of an earlier K while it works: rebuild it only when the last update's
        solves took more than REBUILD_RATIO times the iterations per decade of residual of the update
        right after the last rebuild, or fell back. A rebuild of GAMG on K follows the body (_remake)
        when the near-nullspace is given as a function of where the nodes are; otherwise (and for the
        two-level cycle, whose P1 level keeps the first modes) it keeps the prolongators and makes the
        Galerkin products anew."""
        rate = self._its_since / self._decades_since if self._decades_since > 0 else None
        if self._rebuilt:
            self._fresh_rate = rate
        rebuild = rate is None or self._fresh_rate is None or self._fallen \
            or rate > REBUILD_RATIO * self._fresh_rate
        if rebuild and callable(self._modes) and self.coarse is None:    # GAMG on K: it uses the modes
            self._remake()
        else:
            self.ksp.getPC().setReusePreconditioner(not rebuild)
            if rebuild and self.coarse is not None:
                self.coarse.refresh(self.K)
        self._rebuilt = rebuild
        self._its_since, self._decades_since = 0, 0.0

    def _remake(self) -> None:
        """A multigrid made from scratch (set up at the next _set_up): the rigid-body modes where the
        nodes are now and new aggregates and prolongators. Modes of the undeformed body no longer span
        a bent body's slow motions: on arm3d at its solution CG took 66 iterations to 1e-2 with the
        first multigrid's modes, 10 with modes made there (19k DOFs). The old hierarchy goes first."""
        self.ksp.destroy()
        if callable(self._modes):
            if self._nullspace is not None:
                self._nullspace.destroy()
            self._nullspace = near_nullspace(self.K, self._modes(), self.comm)
            self.K.setNearNullSpace(self._nullspace)
        self.ksp = self._make_ksp(self.prefix, self._options, self.coarse)

    def _set_up(self) -> None:
        """KSPSetUp with the options in PETSc's database: multigrid reads its levels' options
        (mg_levels_*) when it makes them, at the first set-up."""
        with options_held(self.prefix, self._options):
            self.ksp.setUp()
        if callable(self._modes) and self.coarse is None and self._nullspace is not None:
            self.K.setNearNullSpace(PETSc.NullSpace().create(vectors=[], comm=self.comm))
            self._nullspace.destroy()           # GAMG has made its prolongators; the next _remake makes
            self._nullspace = None              # modes anew (6 solution-sized vectors less meanwhile)

    def update(self, parts, border: Border | None = None) -> None:
        """Factorise K (as it is now; iterative: make its multigrid) and take the rank-one parts, c_i > 0,
        as [(c_i, g_i)] (PETSc vectors) or (c, G) with G sparse (Model.low_rank_columns), and a border.
        Iterative solves keep G sparse (a cable's g touches a few cells); direct ones dense."""
        self.G = self.ZB = None                 # the last update's blocks freed before new ones are made
        self.ksp.setOperators(self.K)
        if self.kind == "iterative":
            self._lag_preconditioner()
        self._set_up()
        self._check()
        self._fallen = False
        if self.kind == "iterative":
            self.krylov.append(0)
        self.c, G = columns(parts, self.K.getLocalSize()[0])
        self.border = border
        self.H = np.zeros((0, len(self.c)))
        if self.kind == "direct":
            G = G.toarray()
            if border is not None and border.hosts is not None:
                G = border.embed(G)                         # (g_f, h_i on the hosts)
        if border is not None and border.hosts is None:
            self.H = self._dots(border.T, G)                 # h_i = T^T g_i
            G = sp.diags((~border.rows).astype(float)) @ G if sp.issparse(G) else G * ~border.rows[:, None]
        self.G = G
        self.Z = None
        if self.kind == "iterative":            # the border is outside K (Border.hosts is None)
            self._operator_mode()

    def _operator_mode(self) -> None:
        """Iterative solves on the whole system: one Krylov solve per right-hand side.

        The unknowns (x, z): x the n rows of K (the border's slaved rows stay 0), z the border's m
        (on the first rank). The operator (_Bordered.mult) is the bordered matrix of the module
        docstring with the cables' rank-one parts, applied without forming it; the preconditioner
        (_Bordered.apply) is that matrix's exact inverse with K^{-1} replaced by one multigrid
        cycle B: the same formulas as a direct solve with ZB = B [G | E] for Z (k + m cycles per
        update), symmetric positive definite when B and the system are."""
        m = 0 if self.border is None else self.border.E.shape[1]
        n, N = self.K.getSizes()[0]
        mine = m if self.comm.rank == 0 else 0
        if self._hksp is None or self._bvecs[0].getSize() != N + m:
            if self._hksp is not None:
                self._hksp.destroy()
                for v in self._bvecs:
                    v.destroy()
            ctx = _Bordered(self)
            A = PETSc.Mat().createPython([(n + mine, N + m), (n + mine, N + m)], ctx, comm=self.comm)
            A.setUp()
            self._hksp = PETSc.KSP().create(self.comm)
            self._hksp.setOperators(A)
            A.destroy()
            self._hksp.setType(self._options["ksp_type"])
            self._hksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
            self._hksp.setTolerances(atol=0.0, max_it=int(self._options["ksp_max_it"]))
            pc = self._hksp.getPC()
            pc.setType(PETSc.PC.Type.PYTHON)
            pc.setPythonContext(ctx)
            big = PETSc.Vec().createMPI((n + mine, N + m), comm=self.comm)
            self._bvecs = (big, big.duplicate(), self.K.createVecLeft(), self.K.createVecRight())
        if self.deflation is not None:
            self.W = self.deflation()
            self.KW = sparse_product(self.K, self.W)
            self.WKW = np.linalg.inv(sparse_dots(self.W, self.KW, self.comm))
        self._blocks()

    def _blocks(self) -> None:
        """ZB = B [G | E] (k + m multigrid cycles) and the small system's matrix CB made from it."""
        m = 0 if self.border is None else self.border.E.shape[1]
        E = self.border.E if m else np.zeros((self.G.shape[0], 0))
        k = len(self.c)
        ZB = np.empty((self.G.shape[0], k + m))
        for j in range(k + m):
            ZB[:, j] = self._cycle(self.G[:, [j]].toarray()[:, 0] if j < k else E[:, j - k])
        self.ZB = ZB
        self.CB = self._small_system(ZB, E, self.border)

    def forget_blocks(self) -> None:
        """Free ZB until a solve needs it again (made anew then): a Newton step's line search and the next
        assembly, whose coefficient packs are the peak of a big 3D run, go without it (arm3d's 17
        cable parts: 0.14 KB per DOF)."""
        self.ZB = None

    def fresh_iterations(self, rtol: float = 1e-8, seed: int = 0) -> int | None:
        """Krylov iterations of one solve to rtol of a seeded random right-hand side, with K and the
        rank-one parts as they are and the multigrid made afresh: the multigrid's own quality, apart
        from the forcing terms and lagging of Newton's inexact steps (iterative only; None: it failed)."""
        self._remake()
        self._set_up()
        self._rebuilt, self._fresh_rate, self._its_since, self._decades_since = True, None, 0, 0.0
        self._operator_mode()
        b = np.random.default_rng(seed + self.comm.rank).standard_normal(self.K.getLocalSize()[0])
        self.krylov.append(0)
        out, its = self._op_solve(b, rtol), self.krylov.pop()
        return None if out is None else its

    def _cycle(self, r: np.ndarray) -> np.ndarray:
        """B r: one multigrid cycle of K (the border's slaved rows, identity rows of K, passed through)."""
        rin, out = self._bvecs[2], self._bvecs[3]
        rows = None if self.border is None else self.border.rows
        rin.array_w[:] = r if rows is None else r * ~rows
        if self.W is not None:          # balanced: y = Q r + (I - Q K) B (I - K Q) r, Q = W (W^T K W)^-1 W^T
            a = self.WKW @ sparse_dots(self.W, rin.array_r[:, None], self.comm)[:, 0]
            rin.array_w[:] -= self.KW @ a
        self.ksp.getPC().apply(rin, out)
        y = out.array_r.copy()
        if self.W is not None:
            y += self.W @ (a - self.WKW @ sparse_dots(self.KW, y[:, None], self.comm)[:, 0])
        if rows is not None:
            y[rows] = r[rows]
        return y

    def _split(self, v: PETSc.Vec) -> tuple[np.ndarray, np.ndarray]:
        """(x, z) of a bordered vector, z on every rank."""
        n, a = self.K.getLocalSize()[0], v.array_r
        z = a[n:].copy()
        if self.comm.size > 1 and self.border is not None:
            z = self.comm.bcast(z, root=0)
        return a[:n], z

    def _join(self, v: PETSc.Vec, x: np.ndarray, z: np.ndarray) -> None:
        n, a = self.K.getLocalSize()[0], v.array_w
        a[:n] = x
        if len(a) > n:
            a[n:] = z

    def _op_solve(self, b: np.ndarray, rtol: float, loose: bool = False) -> np.ndarray | None:
        """x = H^{-1} b (owned rows) by one Krylov solve on the bordered system (see _krylov); None if
        it fails (the fallback from then on)."""
        rhs, sol = self._bvecs[:2]
        border = self.border
        if self.ZB is None:
            self._blocks()
        if border is None:
            self._join(rhs, b, np.zeros(0))
        else:
            self._join(rhs, b * ~border.rows, self._dots(border.T, b[:, None])[:, 0])
        self.solves += 1
        if not self._krylov(self._hksp, rhs, sol, rtol, loose):
            self._factorised()
            return None
        x, z = self._split(sol)
        return x.copy() if border is None else x * ~border.rows + border.T @ z

    def reset(self) -> None:
        """Forget a failed factorisation (the next update factorises from scratch)."""
        self._rebuilt, self._fresh_rate = False, None
        if self.kind == "iterative":             # a multigrid of K as it is now (a new K: its modes too)
            self._remake()
        else:
            self.ksp.reset()
            self.ksp.setOperators(self.K)
            with options_held(self.prefix, self._options):
                self.ksp.setFromOptions()
        if self._direct is not None:
            self._direct.destroy()
            self._direct, self._fallen = None, False
        self._dense = {}
        self.Z = None

    @property
    def options(self) -> dict:
        """The PETSc options K is solved with (a copy): the factorisation's, or the Krylov solve's."""
        return dict(self._options)

    def _check(self, ksp: PETSc.KSP | None = None) -> None:
        reason = (ksp or self.ksp).getConvergedReason()
        if reason < 0:
            raise np.linalg.LinAlgError(f"factorisation of the Newton matrix failed (KSP reason {reason})")

    def _factorised(self) -> PETSc.KSP:
        """The KSP whose factorisation the solves use: self.ksp (direct), else the fallback's."""
        if self.kind == "direct":
            return self.ksp
        if self._direct is None:
            self._direct = self._make_ksp(self.prefix + "direct_", default_petsc_options())
        if not self._fallen:
            if self.K.getSize()[0] > self.direct_limit:
                raise np.linalg.LinAlgError(f"the Krylov solve failed, and MUMPS cannot take over: "
                                            f"{self.K.getSize()[0]} DOFs, its memory model fits "
                                            f"{self.direct_limit:.0f} on this machine")
            self._direct.setOperators(self.K)
            self._direct.setUp()
            self._check(self._direct)
            self._fallen = True
            self.fallbacks += 1
        return self._direct

    def _ksp_solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """x = K^{-1} b: one back-substitution (direct, or an iterative update's fallback)."""
        self.solves += 1
        ksp = self._factorised()
        ksp.solve(b, x)
        self._check(ksp)

    def _krylov(self, ksp: PETSc.KSP, b: PETSc.Vec, x: PETSc.Vec, rtol: float, loose: bool = False) -> bool:
        """A Krylov solve (multigrid.krylov_solve), its iterations counted; whether x is taken: converged,
        or (loose: a Newton step, which needs |r| < |b| only) stalled at |r| / |b| <= LOOSE_STEP."""
        its, reached = krylov_solve(ksp, b, x, rtol, self._options["ksp_type"], GMRES_CYCLES if loose else None)
        self.krylov[-1] += its
        taken = reached <= rtol or (loose and reached <= LOOSE_STEP)
        if taken:
            self._its_since += its
            self._decades_since += -np.log10(max(reached, rtol))
            self.loose_steps += reached > rtol
        return taken

    def _multi_solve(self, cols: np.ndarray) -> np.ndarray:
        """K^{-1} cols for a block of right-hand sides (owned rows): one MUMPS solve phase."""
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
        self._factorised().getPC().getFactorMatrix().matSolve(B, X)
        self.solves += 1
        return X.getDenseArray().copy()

    def _dots(self, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """A^T B summed over ranks."""
        out = A.T @ B
        return out if self.comm.size == 1 else self.comm.allreduce(out)

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """x = (K + G D G^T)^{-1} b, reduced to the border unknowns if there is a border."""
        border = self.border
        if self.kind == "iterative" and not self._fallen:
            out = self._op_solve(b.array_r, self.rtol, loose=self.rtol > KRYLOV_RTOL)
            if out is not None:
                x.array_w[:] = out
                return
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
            self._ksp_solve(b, x)
            return
        E = border.E if border is not None else np.zeros((self.G.shape[0], 0))
        m = E.shape[1]
        bf = b.array_r if border is None else b.array_r * ~border.rows
        if self.Z is None:                      # first solve: K^{-1} [G | E | b] in one go
            Y = self._multi_solve(np.column_stack([dense(self.G), E, bf]))
            self._take_z(Y[:, :k + m], E, border)
            y = Y[:, k + m]
        elif border is None:
            self._ksp_solve(b, x)
            y = x.array_r.copy()
        else:
            bvec = b.copy()
            bvec.array_w[:] = bf
            self._ksp_solve(bvec, x)
            bvec.destroy()
            y = x.array_r.copy()
        ZG, ZE = self.Z[:, :k], self.Z[:, k:]
        rhs = np.concatenate([(self._dots(border.T, b.array_r[:, None])[:, 0] if m else np.zeros(0))  # type: ignore[union-attr]  # m > 0: a border
                              - self._dots(E, y[:, None])[:, 0],
                              -self._dots(self.G, y[:, None])[:, 0]])
        zw = np.linalg.solve(self.C, rhs)
        z, w = zw[:m], zw[m:]
        out = y - ZE @ z - ZG @ w
        if m:
            out = out + border.T @ z  # type: ignore[union-attr]  # m > 0: a border
        x.array_w[:] = out

    def _take_z(self, Z: np.ndarray, E: np.ndarray, border: Border | None) -> None:
        """Keep Z = K^{-1} [G | E] and the small system's matrix C made from it."""
        self.Z = Z
        self.C = self._small_system(Z, E, border)

    def _small_system(self, Z: np.ndarray, E: np.ndarray, border: Border | None) -> np.ndarray:
        """The matrix of the small system in (z, w) (module docstring) from Z = K^{-1} [G | E]."""
        k, m = len(self.c), E.shape[1]
        ZG, ZE = Z[:, :k], Z[:, k:]
        C = np.zeros((m + k, m + k))
        C[:m, :m] = (border.C if m else 0.0) - self._dots(E, ZE)  # type: ignore[union-attr]  # m > 0: a border
        C[:m, m:] = self.H - self._dots(E, ZG)
        C[m:, :m] = C[:m, m:].T
        C[m:, m:] = -(np.diag(1.0 / self.c) + self._dots(self.G, ZG))
        return 0.5 * (C + C.T)

    def solve_many(self, B: np.ndarray) -> np.ndarray:
        """(K + G D G^T)^{-1} B for a block of right-hand sides (owned rows, one per column).

        One MUMPS solve phase for all the columns (forward sensitivities to
        many parameters), the same answers as solve() column by column.
        """
        B = np.asarray(B, dtype=float)
        border = self.border
        if self.kind == "iterative" and not self._fallen:
            out = np.empty_like(B)
            for j in range(B.shape[1]):
                col = self._op_solve(B[:, j], KRYLOV_RTOL)
                if col is None:
                    break
                out[:, j] = col
            else:
                return out
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
            Y = self._multi_solve(np.column_stack([dense(self.G), E, Bf]))
            self._take_z(Y[:, :k + m], E, border)
            Y = Y[:, k + m:]
        else:
            Y = self._multi_solve(Bf)
        ZG, ZE = self.Z[:, :k], self.Z[:, k:]
        top = (self._dots(border.T, B) if m else np.zeros((0, B.shape[1]))) - self._dots(E, Y)  # type: ignore[union-attr]  # m > 0: a border
        ZW = np.linalg.solve(self.C, np.vstack([top, -self._dots(self.G, Y)]))
        out = Y - ZE @ ZW[:m] - ZG @ ZW[m:]
        return out + border.T @ ZW[:m] if m else out  # type: ignore[union-attr]  # m > 0: a border

    def as_pc(self, pc: PETSc.PC) -> None:
        """Make pc apply this solver (for SNES's KSP of type preonly)."""
        pc.setType(PETSc.PC.Type.PYTHON)
        pc.setPythonContext(_ApplyPC(self))

    def take_krylov(self) -> list[int]:
        """The Krylov iterations of each update since the last call (iterative; [] for direct)."""
        out, self.krylov = self.krylov, []
        return out

    def destroy(self) -> None:
        self.ksp.destroy()
        if self._hksp is not None:
            self._hksp.destroy()
            for v in self._bvecs:
                v.destroy()
            self._hksp = self._bvecs = None
        if self._direct is not None:
            self._direct.destroy()
            self._direct = None
        if self._nullspace is not None:
            self._nullspace.destroy()
            self._nullspace = None
        if self.coarse is not None:
            self.coarse.destroy()
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


class _Bordered:
    """The whole system of an iterative solve as a PETSc python Mat (mult) and its preconditioner (a
    python PC: apply); see LowRankSolver._operator_mode."""

    def __init__(self, solver: LowRankSolver):
        self.solver = solver

    def mult(self, mat, v, y):
        """[K x + E z + G s ; E^T x + C z + H s], s = D (G^T x + H^T z)."""
        s = self.solver
        x, z = s._split(v)
        xin, out = s._bvecs[2], s._bvecs[3]
        xin.array_w[:] = x
        s.K.mult(xin, out)
        yx = out.array_r.copy()
        yz = np.zeros(len(z))
        w = s._dots(s.G, x[:, None])[:, 0] + s.H.T @ z if len(s.c) else np.zeros(0)
        if len(s.c):
            w *= s.c
            yx += s.G @ w
        if len(z):
            E = s.border.E
            yx += E @ z
            yz = s._dots(E, x[:, None])[:, 0] + s.border.C @ z + s.H @ w
        s._join(y, yx, yz)

    def apply(self, pc, r, y):
        """The bordered system's inverse with one multigrid cycle B for K^{-1} (module docstring)."""
        s = self.solver
        rx, rz = s._split(r)
        k, m = len(s.c), len(rz)
        y0 = s._cycle(rx)
        if k + m == 0:
            s._join(y, y0, rz)
            return
        ZB = s.ZB
        rhs = np.concatenate([rz - (s._dots(s.border.E, y0[:, None])[:, 0] if m else 0.0),
                              -s._dots(s.G, y0[:, None])[:, 0]])
        zw = np.linalg.solve(s.CB, rhs)
        z, w = zw[:m], zw[m:]
        s._join(y, y0 - ZB[:, k:] @ z - ZB[:, :k] @ w, z)


def choose_linear(kind: str, model) -> str:
    """"direct" or "iterative" for a [solver] linear value ("auto": skelfem.design.resources.auto_linear)."""
    if kind != "auto":
        return kind
    return auto_linear(model.design, model.comm.allreduce(model.n_owned))
