"""Sensitivities of the static equilibrium x*(u) to the tendon contractions u.

The equilibrium solves R(x, u) = grad Pi(x; u) = 0 with the contractions fully
applied (load factor 1). Tendon c stores k Q(l - L) with rest length
L = L0 - u_c, so its part of R is k s g with s = l - L and g = grad l, and

    dR/du_c = k g_c   if the tendon is taut (s > 0),   0 if it is slack (s < 0).

Q has a kink at s = 0 (a tendon exactly at its rest length, |s| <= 1e-12 L0,
e.g. every tendon of an unactuated finger): there R is not differentiable in
u_c. We take the taut branch, the one-sided derivative for increasing u_c (the
only feasible direction at the bound u_c = 0): dR/du_c = k g_c, and H gains
its right limit k g g^T (the curvature term k s B^T W B vanishes at s = 0).
These tendons are listed in Linearization.kinked; their derivatives hold for
increasing u_c only (skelfem.control restricts its steps accordingly).
Ligaments are never controls and keep the Hessian as the cable defines it.

Differentiating R(x*(u), u) = 0 with H = dR/dx = hess Pi at x*:

    forward:  H dx*/du_c = -dR/du_c          one solve per tendon;
              a marker y = X + S x moves by dy/du = S dx*/du.
    adjoint:  H lambda = dO/dx,  dO/du = -(dR/du)^T lambda
              one solve for an objective O(x), e.g. O = |y - y'|^2
              (H is symmetric).

SNES's last Jacobian belongs to the iterate before its final step, so H is
assembled afresh at x* into the Newton solver's matrix (fixed nonzero
pattern: MUMPS refactorises numerically, reusing its analysis) and factorised
once; that factorisation serves every right-hand side, forward and adjoint.
Dirichlet rows of H are identity rows and every right-hand side is zero there,
so the pinned components of dx*/du and lambda vanish.
"""
from __future__ import annotations

import numpy as np
from petsc4py import PETSc

KINK = 1e-12      # |s| <= KINK * L0 counts as a tendon exactly at its rest length


def tendon_indices(scene) -> list[int]:
    """Positions in scene.cables of the tendons (the controls u), in design order."""
    return [i for i, c in enumerate(scene.cables) if c.kind == "tendon"]


def contractions(scene) -> np.ndarray:
    """The tendon contractions u, mm."""
    return np.array([scene.cables[i].contraction for i in tendon_indices(scene)], dtype=float)


def set_contractions(scene, u) -> None:
    """Write u onto the scene's tendons (rest lengths L = L0 - u at load factor 1)."""
    u = np.asarray(u, dtype=float)
    idx = tendon_indices(scene)
    if u.shape != (len(idx),):
        raise ValueError(f"expected {len(idx)} contractions, got shape {u.shape}")
    for i, value in zip(idx, u):
        scene.cables[i].contraction = float(value)


def stretch(cable, u: np.ndarray, L: float) -> float:
    """s = l - L (positive: taut)."""
    return cable.length(u) - L


def length_gradient(cable, u: np.ndarray) -> np.ndarray:
    """g = grad l = B^T t on the cable's DOFs (t_i = d_i / |d_i|)."""
    d = cable.segments(u)
    t = d / np.linalg.norm(d, axis=1)[:, None]
    return cable.B.T @ t.ravel()


def _direct_ksp(A: PETSc.Mat, comm) -> PETSc.KSP:
    """A direct solver with the same factorisation as the Newton solver's (MUMPS)."""
    from .solver import default_petsc_options
    options = default_petsc_options()
    ksp = PETSc.KSP().create(comm)
    ksp.setOperators(A)
    ksp.setType(options["ksp_type"])
    pc = ksp.getPC()
    pc.setType(options["pc_type"])
    pc.setFactorSolverType(options["pc_factor_mat_solver_type"])
    return ksp


class Linearization:
    """H and dR/du at the current converged equilibrium x* (scene.u), H factorised once.

    Pass the NewtonSolver that produced x* to reuse its matrix and its MUMPS
    analysis; without one a matrix and an LU solver of the same kind are made.
    The object describes one x*: build a new one after the next solve.
    """

    def __init__(self, scene, solver=None):
        if abs(scene.factor - 1.0) > 1e-14:
            raise ValueError("sensitivities need the contractions fully applied "
                             f"(load factor {scene.factor:g}, not 1)")
        self.scene = scene
        self.tendons = tendon_indices(scene)
        self._own = solver is None
        self.H = scene.create_matrix() if self._own else solver.A
        self.ksp = _direct_ksp(self.H, scene.comm) if self._own else solver.ksp
        self.kinked = self._assemble_H()
        self.ksp.setOperators(self.H)
        self.ksp.setUp()                       # the one numeric factorisation
        self.dR_du = [self._dR_du(i) for i in self.tendons]

    @property
    def m(self) -> int:
        """Number of controls (tendons)."""
        return len(self.tendons)

    # -- H and dR/du ------------------------------------------------------------------------
    def _stretch(self, i: int) -> float:
        """s = l - L of cable i at x*."""
        c = self.scene.cables[i]
        return stretch(c, self.scene.u.x.array, c.rest_length(self.scene.factor))

    def _at_kink(self, i: int) -> bool:
        return abs(self._stretch(i)) <= KINK * self.scene.cables[i].L0

    def _masked_g(self, i: int) -> np.ndarray:
        """g = grad l of cable i on its DOFs, zero on Dirichlet DOFs."""
        scene = self.scene
        c = scene.cables[i]
        return length_gradient(c, scene.u.x.array) * ~scene.fixed[c.dofs]

    def _assemble_H(self) -> list[int]:
        """hess Pi at x*, plus k g g^T for tendons at the kink; returns those tendons."""
        scene = self.scene
        scene.jacobian(scene.u.vector, self.H)
        kinked = [i for i in self.tendons if self._at_kink(i)]
        for i in (i for i in kinked if self._stretch(i) <= 0.0):   # cable.hessian had dropped k g g^T
            c = scene.cables[i]
            g = self._masked_g(i)
            rows = scene.global_dofs[c.dofs]
            self.H.setValues(rows, rows, c.k * np.outer(g, g), addv=PETSc.InsertMode.ADD_VALUES)
        self.H.assemble()
        return kinked

    def _dR_du(self, i: int) -> PETSc.Vec:
        """dR/du_c = k g_c on the free DOFs of a taut tendon, else zero."""
        scene = self.scene
        b = scene.u.vector.duplicate()
        b.set(0.0)
        if self._stretch(i) > 0.0 or i in self.kinked:
            c = scene.cables[i]
            with b.localForm() as local:
                local.array_w[c.dofs] += c.k * self._masked_g(i)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return b

    # -- solves ------------------------------------------------------------------------------
    def solve(self, rhs: PETSc.Vec) -> PETSc.Vec:
        """H^-1 rhs with the stored factorisation (rhs must be zero on Dirichlet rows)."""
        x = rhs.duplicate()
        self.ksp.solve(rhs, x)
        if self.ksp.getConvergedReason() < 0:
            raise RuntimeError(f"linear solve failed ({self.ksp.getConvergedReason()})")
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        return x

    def state_sensitivities(self) -> list[PETSc.Vec]:
        """dx*/du_c = -H^-1 dR/du_c for every tendon c (forward mode)."""
        out = []
        for b in self.dR_du:
            dx = self.solve(b)
            dx.scale(-1.0)
            dx.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            out.append(dx)
        return out

    def adjoint(self, dO_dx: PETSc.Vec) -> np.ndarray:
        """dO/du = -(dR/du)^T lambda with H lambda = dO/dx (one solve)."""
        lam = self.solve(self._dirichlet_free(dO_dx))
        grad = np.array([-b.dot(lam) for b in self.dR_du])
        lam.destroy()
        return grad

    def forward(self, dO_dx: PETSc.Vec) -> np.ndarray:
        """dO/du = dO/dx . dx*/du_c, one solve per tendon (for checking the adjoint)."""
        rhs = self._dirichlet_free(dO_dx)
        dxs = self.state_sensitivities()
        grad = np.array([rhs.dot(dx) for dx in dxs])
        for v in dxs + [rhs]:
            v.destroy()
        return grad

    def marker_jacobian(self, index: int, mode: str = "adjoint") -> np.ndarray:
        """dy/du of marker `index`, shape (gdim, m): gdim adjoint or m forward solves."""
        scene = self.scene
        d = scene.dim
        S = scene.marker_S[index * d:(index + 1) * d]
        if mode == "forward":
            dxs = self.state_sensitivities()
            J = np.column_stack([S @ _local(dx) for dx in dxs]) if dxs else np.zeros((d, 0))
            for v in dxs:
                v.destroy()
            return J
        if mode != "adjoint":
            raise ValueError(f"unknown mode {mode!r}")
        rows = [self.adjoint(_vector(scene, S[j].toarray().ravel())) for j in range(d)]
        return np.array(rows).reshape(d, self.m)

    def _dirichlet_free(self, v: PETSc.Vec) -> PETSc.Vec:
        """Copy of v with the Dirichlet rows zeroed."""
        w = v.copy()
        with w.localForm() as local:
            local.array_w[self.scene.fixed] = 0.0
        return w

    def destroy(self) -> None:
        for b in self.dR_du:
            b.destroy()
        if self._own:
            self.ksp.destroy()
            self.H.destroy()


def _local(v: PETSc.Vec) -> np.ndarray:
    """Owned and ghost entries of a ghosted vector, as a numpy array."""
    with v.localForm() as local:
        return local.array_r.copy()


def _vector(scene, local_values: np.ndarray) -> PETSc.Vec:
    """A ghosted vector assembled from contributions on local (owned + ghost) DOFs."""
    v = scene.u.vector.duplicate()
    v.set(0.0)
    with v.localForm() as local:
        local.array_w[:] = local_values
    v.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    return v


# -- the tracking objective O = |y - y'|^2 -------------------------------------------------------
def marker_objective(scene, index: int, target) -> tuple[float, PETSc.Vec]:
    """O = |y - y'|^2 for marker `index` at the current state, and dO/dx = 2 S^T (y - y')."""
    d = scene.dim
    S = scene.marker_S[index * d:(index + 1) * d]
    r = scene.marker_positions()[index] - np.asarray(target, dtype=float)
    return float(r @ r), _vector(scene, 2.0 * (S.T @ r))
