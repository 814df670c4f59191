"""Shape derivatives of the discrete energy and residual: d/dX at fixed u, X the mesh's node coordinates.

For the terms whose energy is a UFL integral (elasticity, spring pins,
gravity, tractions) the derivative is UFL's CoordinateDerivative, which
FFCx 0.5 compiles:

    dPi/dX [w] = derivative(Pi, SpatialCoordinate(mesh), w),
    z^T dR/dX [w] = derivative(derivative(Pi, u, z), SpatialCoordinate(mesh), w),

w in the P1 vector space of the mesh's coordinates; exact for the discrete
energy (the quadrature moves with the cells). The hand-written cables add
theirs (skelfem.analysis.cable_shape), which depend on their sketches Q
too. A material's Young's modulus E enters psi through mu and lam, both
proportional to E, so z^T dR/dE = z^T R_M / E with R_M the elastic residual
over that material's cells.

A ground's friction (skelfem.terms.friction) acts on the body's boundary
nodes alone, through their tangential offsets d_i from their stick anchors,
their lagged normal forces N_i = k t w_i max(-gap_i, 0) (w_i the node's
boundary weight) and its slip length eps (a fraction of the body's
bounding-box diagonal). A design solved from rest anchors each node where it
rests, s_i = T^T X_i, so d_i = T^T u_i does not move with X; the rest does:
z^T R_f = sum_i b_i N_i with b_i = z_i . f_i / N_i (the force is
proportional to N_i), differentiated through the same nodal-quadrature UFL
form as the ground's penalty, plus the 1 / eps of the sticking nodes' force
through the bounding box (``_friction_adjoint``). The lag's coupling to u is
in the adjoint solve (Linearization.solve_transposed).

Covered: one MPI process, 2D and 3D (the same forms; 3D handles: bone poses
and E), elastic bones, fixed and spring pins, gravity, tractions,
frictionless cables, markers, grounds with or without friction (2D tested).
Refused with a ValueError naming the ingredient: rigid bones and objects,
contact between bodies, cable friction, point loads, turned pins, dynamics.
"""
from __future__ import annotations

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc

from ..terms.base import Term
from ..terms.capabilities import History
from ..terms.cables import CableTerm
from ..terms.elasticity import Elasticity, deformation_gradient, psi
from ..terms.friction import GroundFriction
from ..terms.grounds import nodal_ds
from .cable_shape import CableShape, mesh_edges, radius_gradient

COVERED = (CableTerm, GroundFriction)   # hand-written terms whose shape derivative is known (friction's: zero
#                                         while the boundary stays, see above)


def uncovered(model) -> str | None:
    """Why design gradients do not cover this model, or None."""
    design = model.design
    if model.comm.size > 1:
        return "design gradients run on one MPI process"
    if model.rigid:
        return f"bones.{model.rigid[0].name}.rigid: design gradients do not cover rigid bones yet"
    if design.dynamics is not None:
        return "dynamics: design gradients cover static equilibria"
    for pin in design.pins:
        if getattr(pin, "angle", 0.0):
            return f"pins.{pin.name}.rotate: design gradients do not cover turned pins yet"
    for term in model.terms:
        hand = type(term).gradient is not Term.gradient
        if hand and not isinstance(term, COVERED):
            return f"{term.section}.{term.name}: design gradients do not cover this ingredient yet"
        if isinstance(term, CableTerm) and term.cable.friction:
            return f"cables.{term.name}.friction: design gradients do not cover cable friction"
        if isinstance(term, History) and term.history() is not None and not isinstance(term, GroundFriction):
            return f"{term.section}.{term.name}: design gradients do not cover this friction"
    return None


class ShapeDerivative:
    """dPi/dX and z^T dR/dX of one model at its present mesh and state (forms compiled once)."""

    def __init__(self, model):
        why = uncovered(model)
        if why:
            raise ValueError(why)
        self.model = model
        mesh, u = model.mesh, model.u
        parts = [e for e in (term.ufl_energy(model.ctx) for term in model.terms) if e is not None]
        Pi = sum(parts[1:], parts[0])
        X = ufl.SpatialCoordinate(mesh)
        V1 = fem.VectorFunctionSpace(mesh, ("Lagrange", 1))
        w = ufl.TestFunction(V1)
        self.z = fem.Function(model.V)
        self._energy = fem.form(ufl.derivative(Pi, X, w))
        self._adjoint = fem.form(ufl.derivative(ufl.derivative(Pi, u, self.z), X, w))
        # V1's DOFs are the geometry nodes, numbered apart: node_of[dof]
        self.node_of = np.empty(len(mesh.geometry.x), dtype=np.int64)
        self.node_of[V1.dofmap.list.array] = mesh.geometry.dofmap.array
        elastic = model.term("materials")
        assert isinstance(elastic, Elasticity)
        self.elastic = elastic
        self.chi = fem.Function(elastic.mu.function_space)       # 1 on one material's cells
        energy = model.ctx.thickness * psi(deformation_gradient(u), self.chi * elastic.mu,
                                           self.chi * elastic.lam) * elastic.dx
        self._material = fem.form(ufl.derivative(energy, u, self.z))
        self.frictions = [self._friction_form(t, w) for t in model.terms
                          if isinstance(t, GroundFriction) and t.active]
        self.trace_cables()

    def _friction_form(self, term, w):
        """(term, b, form): form = d/dX of sum_i b_i N_i at fixed u, N_i = k t w_i max(-gap_i, 0) on the ground's
        nodal quadrature (the boundary weights w_i and the gaps at the nodes move with them); b_i in b's first
        components at the friction's nodes."""
        mesh, u = self.model.mesh, self.model.u
        b = fem.Function(self.model.V)
        X = ufl.SpatialCoordinate(mesh)
        n, p = ufl.as_vector([float(v) for v in term.normal]), ufl.as_vector([float(v) for v in term.point])
        N = term.k * term.t * ufl.max_value(-ufl.dot(X + u - p, n), 0.0)
        return term, b, fem.form(ufl.derivative(b[0] * N * nodal_ds(u), X, w))

    def _friction_adjoint(self, z: np.ndarray) -> np.ndarray:
        """z^T dR_f/dX (n, d) of the grounds' friction at fixed u, its anchors where the nodes rest (a design
        solved from rest: s_i = T^T X_i, so d_i = T^T u_i does not move with X). Its force on node i is
        proportional to the lagged N_i (mu N_i d_i / eps sticking, mu N_i d_i / r slipping), so
        z^T R_f = sum_i b_i N_i with b_i = z_i . f_i / N_i, and N_i moves with X through its boundary weight and
        gap (the UFL form above); a sticking node's force is also proportional to 1 / eps, eps = slip_length
        times the body's bounding-box diagonal (its derivative by a central difference in eps, exact to
        1e-12 as f is linear in 1 / eps; the diagonal's as the cables' default radius)."""
        u = self.model.u.x.array
        x = self.model.mesh.geometry.x[:, :self.model.mesh.geometry.dim]
        out = np.zeros((len(self.node_of), x.shape[1]))
        for term, b, form in self.frictions:
            N = term.lags()
            if N is None:
                continue
            zf = self._z_dot_force(term, u, z)
            b.x.array[:] = 0.0
            b.x.array[term.dofs[:, 0]] = np.where(N > 0.0, zf / np.where(N > 0.0, N, 1.0), 0.0)
            out += self._nodes(form)
            eps = term.eps
            try:
                term.eps = eps * (1.0 + 1e-6)
                up = float(self._z_dot_force(term, u, z).sum())
                term.eps = eps * (1.0 - 1e-6)
                down = float(self._z_dot_force(term, u, z).sum())
            finally:
                term.eps = eps
            out += (up - down) / (2e-6 * eps) * (term.slip_length / 0.01) * radius_gradient(x)
        return out

    @staticmethod
    def _z_dot_force(term, u, z) -> np.ndarray:
        """z_i . f_i per friction node (f: its gradient, the tangential force on the node's DOFs)."""
        f = np.zeros(len(u))
        got = term.gradient(u)
        if got is not None:
            np.add.at(f, got[0], got[1])
        return (z[term.dofs] * f[term.dofs]).sum(axis=1)

    def trace_cables(self) -> None:
        """Trace the model's cables on the mesh as it is now (after its nodes moved)."""
        model = self.model
        edges = mesh_edges(model.mesh)
        self.cables = {t.name: CableShape(model, t, edges) for t in model.terms if isinstance(t, CableTerm)}

    def _nodes(self, form) -> np.ndarray:
        vec = fem_petsc.assemble_vector(form)
        values = vec.array.copy()
        vec.destroy()
        d = self.model.mesh.geometry.dim
        out = np.zeros((len(self.node_of), d))
        out[self.node_of] = values.reshape(-1, d)
        return out

    def energy(self) -> tuple[np.ndarray, dict]:
        """(dPi/dX (n, 2), {cable: dPi/dQ}) at the present state."""
        u = self.model.u.x.array
        gX = self._nodes(self._energy)
        gQ = {}
        for name, c in self.cables.items():
            dX, gQ[name] = c.energy_gradient(u)
            gX += dX
        return gX, gQ

    def adjoint(self, z: np.ndarray) -> tuple[np.ndarray, dict]:
        """(z^T dR/dX (n, 2), {cable: z^T dR/dQ}) for a local DOF array z (zero on Dirichlet DOFs)."""
        u = self.model.u.x.array
        self.z.x.array[:] = z
        gX = self._nodes(self._adjoint)
        if self.frictions:
            gX += self._friction_adjoint(z)
        gQ = {}
        for name, c in self.cables.items():
            dX, gQ[name] = c.adjoint_gradient(u, z)
            gX += dX
        return gX, gQ

    def modulus(self, z: np.ndarray, material: str) -> float:
        """z^T dR/dE of a material (R is linear in E: z^T R_material / E)."""
        elastic = self.elastic
        if material not in elastic.cells:
            raise KeyError(material)
        self.z.x.array[:] = z
        self.chi.x.array[:] = 0.0
        self.chi.x.array[elastic.cells[material]] = 1.0
        value = fem.assemble_scalar(self._material)
        return float(value) / float(elastic.materials[material][0])
