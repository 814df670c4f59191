"""Compressible Neo-Hookean solid, one material per tagged region (body, bones).

Strain-energy density (paper eq. 2), with F = I + grad u, J = det F, d the
space dimension (plane strain in 2D):

    psi(F) = mu/2 (tr F^T F - d) - mu ln J + lam/2 (ln J)^2

The bulk energy is Pi_el = t * int_Omega psi dx, with t the slab thickness in
2D (t = 1 in 3D). mu and lam are piecewise-constant (DG0) fields, so a single
compiled form serves every material layout and ``materials.NAME.E`` / ``.nu``
change live.

The cells of rigid bones (``rigid = true``, :mod:`.rigid`) are left out of
the form: their nodes follow a rigid motion, so their strain is zero.

Bones are stiff: a Newton step linearises their rotation, which a stiff
bone resists as stretch. ``step_correction`` turns the linearised rotation of
each unpinned bone into the exact one (see :meth:`Elasticity.step_correction`).
"""
from __future__ import annotations

from typing import Any

import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI

from ..mesh.geometry import body_tag_name, body_tags, bone_tag_name, object_tag_name
from .base import Context, Term, touched
from .capabilities import Follows, StepCorrection
from .rigid import closest_rigid_motion


def lame(E: float, nu: float) -> tuple[float, float]:
    """Lamé parameters (mu, lam) from Young's modulus E and Poisson's ratio nu."""
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def deformation_gradient(u):
    d = u.ufl_shape[0]
    return ufl.Identity(d) + ufl.grad(u)


def psi(F, mu, lam):
    """Neo-Hookean strain-energy density psi(F)."""
    d = F.ufl_shape[0]
    J = ufl.det(F)
    return mu / 2 * (ufl.tr(F.T * F) - d) - mu * ufl.ln(J) + lam / 2 * ufl.ln(J) ** 2


def region_materials(design) -> tuple:
    """((region tag name, material), ...) of the regions that strain: the bodies, the bones (a rigid bone's
    as the others: its cells are left out by the measure) and the elastic objects. What the material
    fields and the measure were made from: a term built on it follows an edit that keeps it."""
    return tuple((body_tag_name(b), b.material) for b in design.bodies) \
        + tuple((bone_tag_name(b.name), b.material) for b in design.bones) \
        + tuple((object_tag_name(o.name), o.material) for o in design.objects if not o.rigid)


def region_layout(design) -> tuple:
    """region_materials with which bones are rigid: everything the compiled elastic form depends on,
    whichever design key (bodies.NAME.material, objects.NAME.rigid, ...) changed it."""
    return region_materials(design), tuple(b.name for b in design.bones if b.rigid)


def region_cells(ctx: Context, design) -> dict:
    """{material name: local cells} over the bodies, the bones and the elastic objects."""
    tm = ctx.tagged
    out: dict = {}
    for tag_name, material in region_materials(design):
        cells = tm.cell_tags.find(tm.tags[tag_name])
        out[material] = np.concatenate([out.get(material, np.zeros(0, np.int32)), cells])
    return out


def elastic_measure(ctx: Context, design):
    """dx over the cells that strain: all of them, less the cells of rigid bones (their strain is zero).

    Quadrature of degree 2p for P_p displacements. FFCx's own estimate for
    psi(F) (logarithms of a P_{p-1} det F) asks for 729 points per
    tetrahedron with P2; degree 4 has the same convergence order (and is
    exact for P1, whose F is constant per cell). Measured on post3d.toml at P2
    h = 1.41 (17k DOFs): the solve took 2.5 s instead of 17.1 s with the tip
    unchanged to 1e-6 mm; on finger.toml at P2 h = 1, 0.93 s instead of 1.30 s
    with the tip 1e-4 mm away (its discretisation error is about 1e-2 mm). P1 on straight cells: F is
    constant per cell, so is the integrand, and one point (degree 1) is exact; degree 2 took three points
    per triangle and four per tetrahedron for the same number (the elastic Newton matrix's assembly:
    finger.toml 0.96 against 1.06 ms, finger3d.toml at 7k DOFs 41 against 48 ms).
    """
    p = ctx.V.ufl_element().degree()
    degree = 1 if p == 1 and ctx.mesh.geometry.cmap.degree == 1 else 2 * p
    if not any(b.rigid for b in design.bones):
        return ufl.dx(metadata={"quadrature_degree": degree})
    tm = ctx.tagged
    ids = tuple(body_tags(tm, design)) + tuple(tm.tags[bone_tag_name(b.name)] for b in design.bones if not b.rigid) \
        + tuple(tm.tags[object_tag_name(o.name)] for o in design.objects if not o.rigid)
    return ufl.Measure("dx", domain=ctx.mesh, subdomain_data=tm.cell_tags,
                       metadata={"quadrature_degree": degree})(ids)


def min_jacobian_expression(u):
    """det F sampled at the nodes of a DG space rich enough for P1/P2 fields."""
    mesh = u.function_space.mesh
    degree = u.function_space.ufl_element().degree()
    k = mesh.topology.dim * (degree - 1)
    W = fem.FunctionSpace(mesh, ("DG", k))
    return fem.Expression(ufl.det(deformation_gradient(u)), W.element.interpolation_points())


EVAL_CELLS = 1 << 16     # cells per evaluation of an Expression: its packed coefficients (u per cell, 0.1 KB
#                          a cell of a 3D P1 mesh) stay a few MB instead of the whole mesh's at once


def cell_value_chunks(expr, num_cells: int):
    """expr evaluated at the local cells, EVAL_CELLS at a time: (cells, points) arrays in cell order."""
    for start in range(0, num_cells, EVAL_CELLS):
        yield expr.eval(np.arange(start, min(start + EVAL_CELLS, num_cells), dtype=np.int32))


def cell_values_min(expr, num_cells: int) -> float:
    return min((float(v.min()) for v in cell_value_chunks(expr, num_cells)), default=np.inf)


class Elasticity(Term, StepCorrection, Follows):
    """Pi_el = t int psi(F(u)) dx with mu, lam per region."""

    section, name = "materials", "elasticity"

    def __init__(self, ctx: Context):
        self.ctx = ctx
        design = ctx.design
        self.materials = {name: [m.E, m.nu] for name, m in design.materials.items()}
        self.cells = region_cells(ctx, design)
        self.layout = region_layout(design)
        Q = fem.FunctionSpace(ctx.mesh, ("DG", 0))
        self.mu, self.lam = fem.Function(Q, name="mu"), fem.Function(Q, name="lam")
        self._update_fields()
        self.dx = elastic_measure(ctx, design)
        self._scale_form = fem.form(ctx.thickness * (self.mu + self.lam) * self.dx)
        self._groups: Any = None
        self._fit: Any = None
        self._corr: Any = None        # (u0, p, alpha, correction) of the last call

    def _update_fields(self) -> None:
        for name, cells in self.cells.items():
            mu, lam = lame(*self.materials[name])
            self.mu.x.array[cells] = mu
            self.lam.x.array[cells] = lam

    def ufl_energy(self, ctx: Context):
        return ctx.thickness * psi(deformation_gradient(ctx.u), self.mu, self.lam) * self.dx

    def energy_scale(self) -> float:
        """t int (mu + lam) dx, assembled again only when the materials or the nodes have moved."""
        key = (tuple(map(tuple, self.materials.values())), float(self.ctx.mesh.geometry.x.sum()))
        held = getattr(self, "_scale", (None,))[0]
        if self.ctx.comm.allreduce(held != key, op=MPI.LOR):      # every rank assembles, or none
            self._scale = (key, self.ctx.comm.allreduce(fem.assemble_scalar(self._scale_form), op=MPI.SUM))
        return self._scale[1]

    def follow(self, ctx: Context, changed: set) -> bool:
        """The same regions, materials and rigid bones (compared as built, whatever keys changed them), and
        no other change of [materials]: keep the fields; drop the bones' node positions."""
        if touched(changed, "materials") or region_layout(ctx.design) != self.layout:
            return False
        self._groups = self._fit = self._corr = None
        return True

    # -- parameters: materials.NAME.E and .nu of the materials in use ---------------------------
    def parameters(self) -> dict:
        return {f"materials.{n}.{k}": v for n in self.cells
                for k, v in zip(("E", "nu"), self.materials[n])}

    def set_parameter(self, key: str, value) -> None:
        _, name, which = key.split(".")
        if name not in self.cells or which not in ("E", "nu"):
            raise KeyError(key)
        self.materials[name][("E", "nu").index(which)] = float(value)
        self._update_fields()

    # -- exact rotations of stiff bones ------------------------------------------------------------
    def _bone_groups(self) -> list:
        """Owned unrolled DOFs (n_nodes, bs) of each bone and each rigid object with no pinned DOF (same
        list on every rank): the node groups that turn by exact rotations."""
        ctx, design = self.ctx, self.ctx.design
        tm, V, bs = ctx.tagged, ctx.V, ctx.bs
        tdim = ctx.mesh.topology.dim
        n_owned = V.dofmap.index_map.size_local
        groups = []
        regions = [bone_tag_name(b.name) for b in design.bones] \
            + [object_tag_name(o.name) for o in design.objects if o.rigid]
        for region in regions:
            cells = tm.cell_tags.find(tm.tags[region])
            nodes = fem.locate_dofs_topological(V, tdim, cells)
            nodes = nodes[nodes < n_owned]
            dofs = nodes[:, None] * bs + np.arange(bs)
            count = ctx.comm.allreduce(len(nodes), op=MPI.SUM)
            assert ctx.fixed is not None                # set by the model before the terms are asked
            pinned = ctx.comm.allreduce(bool(ctx.fixed[dofs].any()), op=MPI.LOR)
            if count >= 3 and not pinned:
                groups.append(dofs)
        X = V.tabulate_dof_coordinates()[:, :ctx.dim]
        return [(dofs, X[dofs[:, 0] // bs]) for dofs in groups]

    def _sum(self, a):
        comm = self.ctx.comm
        return a if comm.size == 1 else comm.allreduce(a)

    def _rigid_fits(self, u0: np.ndarray, p: np.ndarray) -> list:
        """Per bone: (dofs, r = y - c, omega), the least-squares rotation rate of p about the centroid.

        Kept for the last (u0, p) pair: a line search tries several alpha on one direction.
        """
        if self._fit is not None and self._fit[0] is u0 and self._fit[1] is p:
            return self._fit[2]
        if self._groups is None:
            self._groups = self._bone_groups()
        dim, fits = self.ctx.dim, []
        w: float | np.ndarray           # the rotation: an angle in 2D, a vector in 3D
        for dofs, X in self._groups:   # one vectorised block per bone
            y = X + u0[dofs]
            n = self._sum(len(y))
            r = y - self._sum(y.sum(axis=0)) / n
            q = p[dofs] - self._sum(p[dofs].sum(axis=0)) / n
            if dim == 2:
                w = float(self._sum(np.sum(r[:, 0] * q[:, 1] - r[:, 1] * q[:, 0])) / self._sum(np.sum(r * r)))
            else:
                M = self._sum(np.einsum("ni,nj->ij", r, r))
                w = np.linalg.solve(np.trace(M) * np.eye(3) - M, self._sum(np.cross(r, q).sum(axis=0)))
            fits.append((dofs, r, w))
        self._fit = (u0, p, fits)
        return fits

    def carry_over(self, u: np.ndarray) -> None:
        """Make each free bone's start displacement its best-fitting rigid motion (Kabsch).

        A field interpolated from another mesh strains a bone whose outline
        moved (nodes that were silicone are now bone, 10^4 times stiffer);
        the rigid motion y = c_y + R (X - c_X) that fits the interpolated
        positions best in least squares costs the bone no energy.
        """
        if self._groups is None:
            self._groups = self._bone_groups()
        for dofs, X in self._groups:
            cx, cy, R = closest_rigid_motion(X, X + u[dofs], self._sum)
            u[dofs] = cy + (X - cx) @ R.T - X

    def step_correction(self, u0: np.ndarray, p: np.ndarray, alpha: float):
        """Second-order correction that makes each bone follow an exact rotation.

        On a bone's nodes (current positions y, centroid c) the step alpha p is
        split into a rigid part alpha (t + omega x (y - c)) (least squares) and
        the rest; the correction (R(alpha omega) - I - alpha [omega]x)(y - c)
        turns the linearised rotation into the exact one. Zero outside bones.
        """
        if self._groups is None:
            self._groups = self._bone_groups()
        if not self._groups:
            return None
        last = self._corr
        if last is not None and last[0] is u0 and last[1] is p and last[2] == alpha:
            return last[3]                          # the line search asks again for the step it accepts
        corr = np.zeros_like(p)
        for dofs, r, w in self._rigid_fits(u0, p):
            th = alpha * w
            if self.ctx.dim == 2:
                c, s_ = np.cos(th), np.sin(th)
                rot = np.column_stack([c * r[:, 0] - s_ * r[:, 1], s_ * r[:, 0] + c * r[:, 1]])
                lin = r + th * np.column_stack([-r[:, 1], r[:, 0]])
            else:
                angle = np.linalg.norm(th)
                if angle < 1e-14:
                    continue
                k = th / angle
                rot = (r * np.cos(angle) + np.cross(k, r) * np.sin(angle)
                       + np.outer(r @ k, k) * (1 - np.cos(angle)))
                lin = r + np.cross(th, r)
            corr[dofs] = rot - lin
        corr.flags.writeable = False
        self._corr = (u0, p, alpha, corr)
        return corr


def build(ctx: Context) -> list[Term]:
    return [Elasticity(ctx)]
