"""Inertia and Rayleigh damping: time steps as minimisations of an incremental potential.

A time step of size h from t_n to t_{n+1} = t_n + h minimises

    E(x) = Pi(x) + 1/(2 beta h^2) |x - x~|_M^2 + 1/(2 gamma h) |x - x*|_C^2,

Pi the static energy (every other term, at full load), M the consistent mass
matrix (from the UFL energy, so nothing is assembled by hand), C = a M + b K_n
the Rayleigh damping matrix with K_n the elastic tangent at the last accepted
state. dE/dx = 0 is the time-discrete equation of motion

    M a_{n+1} + C v_{n+1} + grad Pi(x_{n+1}) = 0

of the backward differentiation formula on (x, v) with, for steps h_{n+1}
and h_n, w = h_{n+1} / h_n and coefficients (alpha_0, alpha_1, alpha_2):

    v_{n+1} = (alpha_0 x_{n+1} + alpha_1 x_n + alpha_2 x_{n-1}) / h
    a_{n+1} = (alpha_0 v_{n+1} + alpha_1 v_n + alpha_2 v_{n-1}) / h

    implicit Euler (BDF1):  (1, -1, 0)
    BDF2 (variable step):   ((1 + 2w)/(1 + w), -(1 + w), w^2/(1 + w));  w = 1: (3/2, -2, 1/2)

Eliminating v_{n+1} gives a_{n+1} = (x - x~) / (beta h^2) and v_{n+1} =
(x - x*) / (gamma h) with beta = 1/alpha_0^2, gamma = 1/alpha_0 and

    x* = -(alpha_1 x_n + alpha_2 x_{n-1}) / alpha_0
    x~ = x* - h (alpha_1 v_n + alpha_2 v_{n-1}) / alpha_0^2

(Euler: x~ = x_n + h v_n, beta = 1; BDF2 at w = 1: x~ = 4/3 x_n - 1/3 x_{n-1}
+ 8/9 h v_n - 2/9 h v_{n-1}, beta = 4/9). The damping part is the gradient
of 1/(2 gamma h) |x - x*|_C^2 because dv_{n+1}/dx = 1/(gamma h). BDF2 starts
with one Euler step (its local error O(h^2) keeps the global order 2), and a
step size change (a cut step) just changes w.

Units: rho in kg/m^3, lengths in mm, time in s. rho |v|^2 dV in
kg/m^3 mm^3 mm^2/s^2 = 1e-9 kg mm^2/s^2 = 1e-12 N mm (1 kg mm^2/s^2 =
1e-6 kg m^2/s^2 = 1e-6 N m = 1e-3 N mm), so

    1/2 |x - x~|_M^2 = 1/2 * 1e-12 * t int rho |u - u~|^2 dx   (N mm s^2),

the same factor that makes 1 kg/m^3 x 1 mm/s^2 = 1e-12 N/mm^3 (gravity's
1e-9 N/mm^3 per m/s^2). t is the slab depth in 2D.

Outside a time step (``start`` not called, or after ``stop``) every
coefficient is zero and the term adds nothing, so a static solve of the same
model is unaffected. u~, x*, 1/(beta h^2), 1/(gamma h) are a fem.Function
and fem.Constants: changing h recompiles nothing.

Parameters: ``materials.NAME.density`` (shared with gravity) and, with
stiffness damping, ``materials.NAME.E`` / ``.nu`` (shared with elasticity).
"""
from __future__ import annotations

from typing import Any

import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI

from ..mesh.geometry import object_tag_name
from .base import Context, Term, constant
from .capabilities import History
from .elasticity import deformation_gradient, lame, psi, region_cells

MASS_UNIT = 1e-12     # N mm per kg/m^3 mm^3 (mm/s)^2; equivalently N/mm^3 per kg/m^3 mm/s^2


def bdf_coefficients(order: int, w: float = 1.0) -> tuple[float, float, float]:
    """(alpha_0, alpha_1, alpha_2) of the BDF derivative for the step ratio w = h_{n+1} / h_n."""
    if order == 1:
        return 1.0, -1.0, 0.0
    return (1.0 + 2.0 * w) / (1.0 + w), -(1.0 + w), w * w / (1.0 + w)


class Inertia(Term, History):
    """1/(2 beta h^2) |x - x~|_M^2 + 1/(2 gamma h) |x - x*|_(aM + bK_n)^2, with its time-step history."""

    section, name = "dynamics", "inertia"

    def __init__(self, ctx: Context):
        self.ctx = ctx
        self._M = None                  # the mass matrix, assembled on first use
        design, mesh = ctx.design, ctx.mesh
        spec = design.dynamics
        assert spec is not None                         # built for a design with [dynamics] only
        self.order = 2 if spec.integrator == "bdf2" else 1
        self.cells = region_cells(ctx, design)          # cells that strain (body, bones): rho, mu, lambda
        self.rigid_cells = object_cells(ctx, design)     # free rigid objects' cells: rho only
        self.materials = {n: [design.materials[n].density, design.materials[n].E, design.materials[n].nu]
                          for n in [*self.cells, *self.rigid_cells]}
        Q = fem.FunctionSpace(mesh, ("DG", 0))
        self.rho = fem.Function(Q, name="density")
        self.stiffness_damping = spec.damping_stiffness > 0.0
        if self.stiffness_damping:
            self.mu, self.lam = fem.Function(Q, name="mu"), fem.Function(Q, name="lam")
        self._update_fields()
        self.u_tilde = fem.Function(ctx.V, name="predictor")      # x~
        self.u_star = fem.Function(ctx.V, name="damping_reference")   # x*
        self.u_last = fem.Function(ctx.V, name="last_state")      # x_n: the tangent of stiffness damping
        self.v = fem.Function(ctx.V, name="velocity")              # v_n (kinetic energy)
        self.c_inertia = constant(mesh, 0.0)      # MASS_UNIT / (beta h^2)
        self.c_mass_damping = constant(mesh, 0.0)     # a MASS_UNIT / (gamma h)
        self.c_stiffness_damping = constant(mesh, 0.0)    # b / (gamma h)
        self.damping = (float(spec.damping_mass), float(spec.damping_stiffness))
        t = ctx.thickness
        self._kinetic_form = fem.form(0.5 * MASS_UNIT * t * self.rho * ufl.dot(self.v, self.v) * ufl.dx)
        self._own_form: Any = None
        self.active = False
        self.h = 0.0                # step size of the step being solved (0: none)
        self.x: list[np.ndarray] = []       # x_n, x_{n-1} (local arrays, ghosts included)
        self.vel: list[np.ndarray] = []     # v_n, v_{n-1}
        self.h_last = 0.0                   # h_n: the size of the last accepted step
        self._alpha = (1.0, -1.0, 0.0)

    @property
    def alpha(self) -> tuple[float, float, float]:
        """(alpha_0, alpha_1, alpha_2) of the step being solved (or last solved)."""
        return self._alpha

    def _update_fields(self) -> None:
        if self._M is not None and self._M.handle:
            self._M.destroy()
        self._M = None                  # the mass matrix follows the density
        for name, cells in self.cells.items():
            rho, E, nu = self.materials[name]
            self.rho.x.array[cells] = rho
            if self.stiffness_damping:
                mu, lam = lame(E, nu)
                self.mu.x.array[cells] = mu
                self.lam.x.array[cells] = lam
        for name, cells in self.rigid_cells.items():      # an object has mass, and no strain to damp
            self.rho.x.array[cells] = self.materials[name][0]

    # -- energy ------------------------------------------------------------------------------------
    def ufl_energy(self, ctx: Context):
        u, t = ctx.u, ctx.thickness
        w = u - self.u_star
        e = 0.5 * t * self.rho * (self.c_inertia * ufl.dot(u - self.u_tilde, u - self.u_tilde)
                                  + self.c_mass_damping * ufl.dot(w, w)) * ufl.dx
        if self.stiffness_damping:
            # 1/2 b/(gamma h) (x - x*)^T K_n (x - x*), K_n the elastic Hessian at x_n:
            # t int 1/2 G : (d^2 psi / dF^2)(F_n) : G dx, G = grad(x - x*)
            F = ufl.variable(deformation_gradient(self.u_last))
            A = ufl.diff(ufl.diff(psi(F, self.mu, self.lam), F), F)
            G = ufl.grad(w)
            i, j, k, m = ufl.indices(4)
            e = e + 0.5 * t * self.c_stiffness_damping * G[i, j] * A[i, j, k, m] * G[k, m] * ufl.dx
        self._own_form = fem.form(e)
        return e

    def own_energy(self) -> float:
        """This term's share of the model's energy at the model's current state (collective)."""
        return self.ctx.comm.allreduce(fem.assemble_scalar(self._own_form), op=MPI.SUM)

    def kinetic_energy(self) -> float:
        """1/2 v_n^T M v_n, N mm (collective)."""
        return self.ctx.comm.allreduce(fem.assemble_scalar(self._kinetic_form), op=MPI.SUM)

    # -- parameters ---------------------------------------------------------------------------------
    def parameters(self) -> dict:
        out = {f"materials.{n}.density": m[0] for n, m in self.materials.items()}
        if self.stiffness_damping:
            out.update({f"materials.{n}.{k}": self.materials[n][i] for n in self.cells
                        for i, k in ((1, "E"), (2, "nu"))})
        return out

    def set_parameter(self, key: str, value) -> None:
        if key not in self.parameters():
            raise KeyError(key)
        _, name, which = key.split(".")
        self.materials[name][("density", "E", "nu").index(which)] = float(value)
        self._update_fields()

    # -- time stepping --------------------------------------------------------------------------------
    def start(self, x0: np.ndarray, v0: np.ndarray | None = None, damping=None) -> None:
        """Begin a run at state x0 (local array) with velocity v0 (default: at rest)."""
        self.x = [np.array(x0, dtype=float)]
        self.vel = [np.zeros_like(self.x[0]) if v0 is None else np.array(v0, dtype=float)]
        self.h_last, self.h = 0.0, 0.0
        if damping is not None:
            self.damping = (float(damping[0]), float(damping[1]))
            if self.damping[1] > 0.0 and not self.stiffness_damping:
                raise ValueError("stiffness damping needs a model built with it")
        self.u_last.x.array[:] = self.x[0]
        self.v.x.array[:] = self.vel[0]
        self.active = True

    def stop(self) -> None:
        """End the run: the term adds nothing any more."""
        self.active, self.h = False, 0.0
        for c in (self.c_inertia, self.c_mass_damping, self.c_stiffness_damping):
            c.value = 0.0

    def prepare(self, h: float) -> np.ndarray:
        """Set x~, x* and the coefficients for a step of size h from the last accepted state; returns x~."""
        if not self.active:
            raise RuntimeError("prepare() before start()")
        order = min(self.order, len(self.x))
        alpha = bdf_coefficients(order, h / self.h_last if order == 2 else 1.0)
        x_m, v_m = (self.x[1], self.vel[1]) if order == 2 else (0.0, 0.0)
        return self.set_step(h, alpha, self.x[0], x_m, self.vel[0], v_m)

    def set_step(self, h: float, alpha, x_n, x_m, v_n, v_m) -> np.ndarray:
        """x~, x* and the coefficients of a step of size h with BDF coefficients alpha, from the state and
        velocity before it and one step further back (x_m, v_m; unused where alpha_2 = 0); returns x~.
        The adjoint sets each stored step back this way: a rigid body's Hessian holds the full gradient
        on its nodes, the inertia force M (x - x~) / (beta h^2) included."""
        a0, a1, a2 = alpha
        self._alpha, self.h = (a0, a1, a2), float(h)
        star = -(a1 * x_n + a2 * x_m) / a0
        tilde = star - h * (a1 * v_n + a2 * v_m) / a0 ** 2
        self.u_star.x.array[:] = star
        self.u_tilde.x.array[:] = tilde
        self.set_coefficients(h, a0)
        return tilde

    def set_coefficients(self, h: float, alpha0: float) -> None:
        """1/(beta h^2) and 1/(gamma h) of a step (beta = 1/alpha0^2, gamma = 1/alpha0): the Hessian of
        the step's incremental potential (x~, x* do not enter it)."""
        self.c_inertia.value = MASS_UNIT * alpha0 ** 2 / (h * h)
        self.c_mass_damping.value = self.damping[0] * MASS_UNIT * alpha0 / h
        self.c_stiffness_damping.value = self.damping[1] * alpha0 / h

    def mass_matrix(self):
        """The consistent mass matrix M (PETSc, no boundary conditions), in N s^2/mm: 1/2 v^T M v is the
        kinetic energy in N mm. Compiled and assembled on first use (the adjoint)."""
        if self._M is None:
            from dolfinx.fem import petsc as fem_petsc
            V = self.ctx.V
            w, v = ufl.TrialFunction(V), ufl.TestFunction(V)
            form = fem.form(MASS_UNIT * self.ctx.thickness * self.rho * ufl.inner(w, v) * ufl.dx)
            self._M = fem_petsc.assemble_matrix(form)
            self._M.assemble()
        return self._M

    def velocity(self, x: np.ndarray) -> np.ndarray:
        """v_{n+1} of the step being solved, at state x."""
        a0, a1, a2 = self._alpha
        x_m = self.x[1] if a2 != 0.0 else 0.0
        return (a0 * x + a1 * self.x[0] + a2 * x_m) / self.h

    def end_step(self, model) -> None:
        """Accept the model's state as x_{n+1}: shift the history (only during a time step)."""
        if not self.active or self.h <= 0.0:
            return
        x = model.u.x.array.copy()
        v = self.velocity(x)
        self.x = [x, self.x[0]]
        self.vel = [v, self.vel[0]]
        self.h_last, self.h = self.h, 0.0
        self.u_last.x.array[:] = x
        self.v.x.array[:] = v


def object_cells(ctx: Context, design) -> dict:
    """{material name: local cells} over the free rigid objects ([[objects]]; elastic ones strain, and
    region_cells has them)."""
    tm = ctx.tagged
    out: dict = {}
    for spec in (o for o in design.objects if o.rigid):
        cells = tm.cell_tags.find(tm.tags[object_tag_name(spec.name)])
        out[spec.material] = np.concatenate([out.get(spec.material, np.zeros(0, np.int32)), cells])
    return out


def build(ctx: Context) -> list[Term]:
    return [Inertia(ctx)] if ctx.design.dynamics is not None else []
