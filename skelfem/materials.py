"""Compressible Neo-Hookean solid, one material per tagged subdomain.

Strain-energy density (paper eq. 2), with F = I + grad u, J = det F, d the
space dimension (plane strain in 2D):

    psi(F) = mu/2 (tr F^T F - d) - mu ln J + lam/2 (ln J)^2

The bulk energy is Pi_el = t * int_Omega psi dx, with t the slab thickness in
2D (t = 1 in 3D). mu and lam are piecewise-constant (DG0) fields, so a single
compiled form serves every material layout.
"""
from __future__ import annotations

import numpy as np
import ufl
from dolfinx import fem


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


def material_fields(mesh, cell_tags, region_material: dict) -> tuple:
    """DG0 fields (mu, lam) from a map {tag value: Material}."""
    Q = fem.FunctionSpace(mesh, ("DG", 0))
    mu, lam = fem.Function(Q, name="mu"), fem.Function(Q, name="lam")
    for tag, material in region_material.items():
        cells = cell_tags.find(tag)
        m, l = lame(material.E, material.nu)
        mu.x.array[cells] = m
        lam.x.array[cells] = l
    return mu, lam


def elastic_energy(u, mu, lam, thickness: float):
    """UFL form of Pi_el = t * int psi(F(u)) dx."""
    return thickness * psi(deformation_gradient(u), mu, lam) * ufl.dx


def min_jacobian_expression(u):
    """det F sampled at the nodes of a DG space rich enough for P1/P2 fields."""
    mesh = u.function_space.mesh
    degree = u.function_space.ufl_element().degree()
    k = mesh.topology.dim * (degree - 1)
    W = fem.FunctionSpace(mesh, ("DG", k))
    points = W.element.interpolation_points()
    return fem.Expression(ufl.det(deformation_gradient(u)), points)


def cell_values_min(expr, num_cells: int) -> float:
    cells = np.arange(num_cells, dtype=np.int32)
    return float(expr.eval(cells).min()) if num_cells else np.inf
