"""Direct solves: PETSc's own LU for a small serial 2D Newton matrix, MUMPS's LDL^T otherwise.

The small solver gives the equilibria MUMPS gives (markers, tensions, reactions to 1e-8) in the same
Newton iterations; 3D and larger matrices keep MUMPS; a zero pivot (PETSc's LU does not pivot) hands
the factorisation to MUMPS, which solves the same system."""
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from skelfem import Session
from skelfem.fem.linear import LowRankSolver
from skelfem.fem.options import SMALL_DIRECT

from conftest import GEOMETRY


def _factor_type(session) -> str:
    return session.solver.lin.ksp.getPC().getFactorSolverType()


def _readouts(r) -> np.ndarray:
    d = r.to_dict()
    return np.array([p for m in d["markers"].values() for p in m["position"]]
                    + [c["tension"] for c in d["cables"].values()]
                    + [x for p in d["pins"].values() for x in p["reaction"]])


def test_a_small_2d_matrix_is_factorised_by_petsc_and_gives_mumps_equilibrium(monkeypatch):
    from skelfem.fem import newton
    with Session(GEOMETRY / "finger.toml") as s:
        monkeypatch.setattr(newton, "SMALL_DIRECT", 0)          # the same model, factorised by MUMPS
        m = Session(GEOMETRY / "finger.toml")
        assert _factor_type(s) == "petsc" and _factor_type(m) == "mumps"
        a, b = s.solve(), m.solve()
        assert a.converged and b.converged and a.newton_iterations == b.newton_iterations
        x, y = _readouts(a), _readouts(b)
        assert np.abs(x - y).max() <= 1e-8 * np.abs(x).max()
        m.close()


def test_3d_and_large_matrices_keep_mumps():
    with Session(GEOMETRY / "finger3d.toml", ["mesh.size=8"]) as s:
        assert s.dofs <= SMALL_DIRECT and _factor_type(s) == "mumps"
    with Session(GEOMETRY / "finger.toml", ["mesh.size=0.7"]) as s:
        assert s.dofs > SMALL_DIRECT and _factor_type(s) == "mumps"


def test_a_zero_pivot_hands_the_factorisation_to_mumps():
    """[[0, 1], [1, 0]]-like blocks on the diagonal: symmetric, nonsingular, a zero first pivot without
    pivoting. The update falls back to MUMPS, which solves it, and stays with it."""
    n = 6
    K = PETSc.Mat().createAIJ([n, n], nnz=2, comm=MPI.COMM_SELF)
    for i in range(0, n, 2):
        K.setValue(i, i + 1, 1.0)
        K.setValue(i + 1, i, 1.0)
        K.setValue(i + 1, i + 1, 2.0)
        K.setValue(i, i, 0.0)
    K.assemble()
    lin = LowRankSolver(K, MPI.COMM_SELF, small=True)
    assert lin.ksp.getPC().getFactorSolverType() == "petsc"
    lin.update([])
    assert lin.ksp.getPC().getFactorSolverType() == "mumps"
    b, x, r = K.createVecRight(), K.createVecRight(), K.createVecRight()
    b.array_w[:] = np.arange(1.0, n + 1)
    lin.solve(b, x)
    K.mult(x, r)
    r.axpy(-1.0, b)
    assert r.norm() <= 1e-12 * b.norm()
    lin.update([])
    assert lin.ksp.getPC().getFactorSolverType() == "mumps"
    lin.destroy()
    for v in (K, b, x, r):
        v.destroy()
