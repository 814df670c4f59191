"""Multigrid for the iterative linear solves (skelfem.fem.linear): the two-level coarse space, the
rigid-body near-nullspace and Krylov solves with their GMRES fallback. Its PETSc option sets are in
skelfem.fem.options, the direct-or-iterative choice in skelfem.fem.linear and how tightly an inexact
Newton step is solved (the forcing term) in skelfem.fem.newton."""
from __future__ import annotations

import numpy as np
from petsc4py import PETSc



KRYLOV_RTOL = 1e-12       # |r| / |b| of a tight iterative solve (sensitivities to 1e-8 behind a 1e4 condition)

GMRES_RESTART = 20        # the fallback GMRES's restart (its vectors: restart + 1, each the size of a solution)
GMRES_CYCLES = 5          # ... and a Newton step's restarts before it is judged stalled (arm3d P2 at nu 0.45:
#                           restarts after the first left |r| / |b| at 1.2e-2 for 480 iterations)
LOOSE_STEP = 0.1          # ... and then taken if |r| / |b| got this low (a tight solve keeps ksp_max_it)
REBUILD_RATIO = 2.0       # a lagged multigrid is rebuilt when it needs this many times the iterations


def set_krylov_type(ksp: PETSc.KSP, ksp_type: str) -> None:
    """CG (left-preconditioned) or the fallback GMRES: right-preconditioned (the preconditioner is one
    fixed linear cycle, so no flexible variant is needed), restarted after GMRES_RESTART iterations
    (FGMRES(30) kept 61 vectors: 0.49 KB per DOF above the level, the peak of arm3d at 1.43M DOFs);
    both stop on the true residual."""
    ksp.setType(ksp_type)
    ksp.setPCSide(PETSc.PC.Side.RIGHT if ksp_type == "gmres" else PETSc.PC.Side.LEFT)
    if ksp_type == "gmres":
        ksp.setGMRESRestart(GMRES_RESTART)
    ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)


def krylov_solve(ksp: PETSc.KSP, b: PETSc.Vec, x: PETSc.Vec, rtol: float, first: str,
                 cycles: int | None = None) -> tuple[int, float]:
    """x from a Krylov solve to |r| / |b| <= rtol from 0: `first` (CG), and if it fails (an indefinite K
    breaks CG) GMRES, for at most `cycles` restarts if given. (iterations, the |r| / |b| of x: at most
    rtol if it converged, inf if CG failed and GMRES diverged); ksp is left with `first`."""
    its, reached, max_it = 0, np.inf, ksp.getTolerances()[3]
    ksp.setTolerances(rtol=rtol)
    for ksp_type in dict.fromkeys((first, "gmres")):
        if ksp.getType() != ksp_type:
            set_krylov_type(ksp, ksp_type)
        if ksp_type != first and cycles is not None:
            ksp.setTolerances(max_it=min(max_it, cycles * GMRES_RESTART))
        ksp.solve(b, x)
        its += ksp.getIterationNumber()
        reason = ksp.getConvergedReason()
        if reason > 0:
            reached = rtol
            break
        if ksp_type == "gmres" and reason == PETSc.KSP.ConvergedReason.DIVERGED_MAX_IT:
            bnorm = b.norm()        # GMRES minimises the true residual: x is its best
            reached = ksp.getResidualNorm() / bnorm if bnorm > 0.0 else np.inf
    if ksp.getType() != first:
        set_krylov_type(ksp, first)
    ksp.setTolerances(max_it=max_it)
    return its, reached


class Coarse:
    """The coarse level of two-level p-multigrid for a P2 Newton matrix K: P1 on the same mesh.

    P interpolates P1 functions into K's space (sparse: a vertex copies itself, an edge's midpoint
    averages its two vertices), the coarse matrix is the Galerkin product A_c = P^T K P, and GAMG
    (with the P1 nodes' rigid-body modes as its near-nullspace) works on A_c: a quarter to an
    eighth of K's unknowns, so its hierarchy is made for a fraction of the price of one on K,
    while one Chebyshev-Jacobi smoothing of K takes the P2 part."""

    def __init__(self, P: PETSc.Mat, modes: np.ndarray, comm):
        self.P, self.modes, self.comm = P, modes, comm
        self.Ac = None
        self._nullspace = None

    @classmethod
    def of(cls, V) -> "Coarse":
        """The P1 level of a vector P2 space V (its rigid-body modes about the nodes' centroid)."""
        import dolfinx.cpp.fem.petsc as cpp_petsc
        from dolfinx import fem
        mesh = V.mesh
        dim = mesh.geometry.dim
        V1 = fem.VectorFunctionSpace(mesh, ("Lagrange", 1))
        P = cpp_petsc.interpolation_matrix(V1._cpp_object, V._cpp_object)
        P.assemble()
        X = V1.tabulate_dof_coordinates()[: V1.dofmap.index_map.size_local, :dim]
        return cls(P, owned_rigid_body_modes(X, dim, mesh.comm), mesh.comm)

    def attach(self, pc: PETSc.PC, K: PETSc.Mat) -> None:
        """Make pc the two-level multigrid of K (A_c made anew from K's pattern)."""
        self.destroy_coarse()
        Ac = self.Ac = K.PtAP(self.P)
        self._nullspace = near_nullspace(Ac, self.modes, self.comm)
        Ac.setNearNullSpace(self._nullspace)
        pc.setType(PETSc.PC.Type.MG)
        pc.setMGLevels(2)
        pc.setMGInterpolation(1, self.P)
        pc.getMGCoarseSolve().setOperators(self.Ac)

    def refresh(self, K: PETSc.Mat) -> None:
        """A_c = P^T K P with K's values now (same pattern)."""
        K.PtAP(self.P, self.Ac)

    def destroy_coarse(self) -> None:
        for obj in (self.Ac, self._nullspace):
            if obj is not None:
                obj.destroy()
        self.Ac = self._nullspace = None

    def destroy(self) -> None:
        self.destroy_coarse()
        self.P.destroy()


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


def owned_rigid_body_modes(X: np.ndarray, dim: int, comm) -> np.ndarray:
    """rigid_body_modes of each rank's own points X about the centroid of all ranks' points."""
    centre = comm.allreduce(X.sum(axis=0)) / max(comm.allreduce(len(X)), 1)
    return rigid_body_modes(X - centre, dim, centred=True)


def near_nullspace(K: PETSc.Mat, modes: np.ndarray, comm) -> PETSc.NullSpace:
    """An orthonormal PETSc near-nullspace from the owned rows of the modes (modified Gram-Schmidt)."""
    vecs: list = []
    for j in range(modes.shape[1]):
        v = K.createVecLeft()
        v.array_w[:] = modes[:, j]
        for w in vecs:
            v.axpy(-v.dot(w), w)
        v.normalize()
        vecs.append(v)
    return PETSc.NullSpace().create(vectors=vecs, comm=comm)
