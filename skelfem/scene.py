"""A Scene binds a design to a mesh: the total energy and its derivatives.

    Pi(u; a) = Pi_el(u) + sum_pins Pi_pin(u; a) + sum_cables k Q(l(u) - L(a))
               - sum_loads a f . u(X_load)

where a in [0, 1] is the load factor that ramps contractions, pretensions,
loads and pin moves. Pi_el and the spring pins are UFL forms (compiled once per
scene); cables and point loads act through interpolation matrices at material
points and add hand-written gradients and Hessians. Fixed pins are Dirichlet
conditions u = a * move on the boundary inside their region.

The solver only sees ``energy``, ``residual``, ``jacobian``, ``admissible``
and ``create_matrix``.
"""
from __future__ import annotations

import numpy as np
import ufl
from dolfinx import cpp as _cpp
from dolfinx import fem
from dolfinx import mesh as dmesh
from dolfinx.fem import petsc as fem_petsc
from petsc4py import PETSc

from .cables import Cable
from .design import DesignError
from .geometry import BODY, bone_tag_name
from .materials import cell_values_min, elastic_energy, material_fields, min_jacobian_expression
from .points import interpolation_matrix, locate_cells


class Pin:
    """Boundary facets inside a pin's region: Dirichlet DOFs or zero-length springs."""

    def __init__(self, spec, V, facets: np.ndarray, tag: int):
        self.name, self.kind, self.spec, self.tag = spec.name, spec.kind, spec, tag
        bs = V.dofmap.index_map_bs
        mesh = V.mesh
        self.nodes = fem.locate_dofs_topological(V, mesh.topology.dim - 1, facets)
        self.dofs = (self.nodes[:, None] * bs + np.arange(bs)).ravel()   # unrolled
        self.move = fem.Constant(mesh, np.zeros(bs, dtype=PETSc.ScalarType))
        self.bc = fem.dirichletbc(self.move, self.nodes, V) if self.kind == "fixed" else None

    def set_factor(self, a: float) -> None:
        self.move.value[:] = a * np.asarray(self.spec.move, dtype=float)


def _box_marker(region: np.ndarray, tol: float):
    lo, hi = np.asarray(region[0], float) - tol, np.asarray(region[1], float) + tol

    def inside(x):
        d = len(lo)
        return np.all((x[:d].T >= lo) & (x[:d].T <= hi), axis=1)
    return inside


class Scene:
    """Everything needed to evaluate Pi, grad Pi and hess Pi for one design."""

    def __init__(self, design, tagged_mesh):
        self.design = design
        self.tm = tagged_mesh
        mesh = self.mesh = tagged_mesh.mesh
        self.comm = mesh.comm
        self.dim = mesh.geometry.dim
        self.thickness = float(design.thickness) if design.dim == 2 else 1.0
        V = self.V = fem.VectorFunctionSpace(mesh, ("Lagrange", int(design.mesh.degree)))
        self.u = fem.Function(V, name="displacement")
        self.bs = V.dofmap.index_map_bs
        imap = V.dofmap.index_map
        self.n_local = (imap.size_local + imap.num_ghosts) * self.bs
        self.num_cells = mesh.topology.index_map(mesh.topology.dim).size_local
        self.factor = 0.0
        x = mesh.geometry.x[:, :self.dim]
        self.size = float(self.comm.allreduce(np.linalg.norm(x.max(axis=0) - x.min(axis=0)) if len(x) else 0.0,
                                              op=__import__("mpi4py").MPI.MAX))  # bounding-box diagonal, mm

        self.region_material = self._region_materials()
        mu, lam = material_fields(mesh, tagged_mesh.cell_tags, self.region_material)
        self.pins, facet_tags = self._build_pins()
        self.bcs = [p.bc for p in self.pins if p.bc is not None]
        self.fixed = np.zeros(self.n_local, dtype=bool)
        for p in self.pins:
            if p.kind == "fixed":
                self.fixed[p.dofs] = True

        # UFL part of the energy: elasticity and spring pins
        ds = ufl.Measure("ds", domain=mesh, subdomain_data=facet_tags)
        t = fem.Constant(mesh, PETSc.ScalarType(self.thickness))
        Pi = elastic_energy(self.u, mu, lam, t)
        v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
        springs = [0.5 * fem.Constant(mesh, PETSc.ScalarType(p.spec.stiffness)) * t
                   * ufl.inner(self.u - p.move, self.u - p.move) * ds(p.tag)
                   for p in self.pins if p.kind == "spring"]
        self.spring_form = None
        if springs:
            Pi_springs = sum(springs[1:], springs[0])
            self.spring_form = fem.form(ufl.derivative(Pi_springs, self.u, v))
            Pi = Pi + Pi_springs
        R = ufl.derivative(Pi, self.u, v)
        ground_energy, self.ground_force_forms = self._grounds(t)
        if ground_energy is not None:
            Pi = Pi + ground_energy
        self.energy_form = fem.form(Pi)
        self.residual_form = fem.form(R)
        self.jacobian_form = fem.form(ufl.derivative(R, self.u, du))
        self.detF = min_jacobian_expression(self.u)
        # round-off of Pi: psi sums terms of size mu, lam that cancel, so
        # differences below eps * t int (mu + lam) dx cannot be resolved
        scale = fem.assemble_scalar(fem.form(t * (mu + lam) * ufl.dx))
        from mpi4py import MPI
        self.energy_noise = 64 * np.finfo(float).eps * self.comm.allreduce(scale, op=MPI.SUM)

        # point terms: cables, loads, markers
        self.cables = [self._build_cable(c) for c in design.cables]
        self.load_S, self.load_f = self._points_operator(
            {l.name: l.at for l in design.loads}, "loads", "at")
        if design.loads:
            self.load_f = np.concatenate([np.asarray(l.force, float) for l in design.loads])
        self.marker_names = list(design.markers)
        self.marker_S, _ = self._points_operator(design.markers, "markers", "")
        self.marker_X = np.array([design.markers[n] for n in self.marker_names], float).reshape(-1, self.dim)
        self.global_dofs = self._global_dofs()
        self.rigid_groups = self._bone_dofs()

    # -- construction helpers ----------------------------------------------------
    def _region_materials(self) -> dict:
        d = self.design
        out = {self.tm.tags[BODY]: d.materials[d.body.material]}
        for b in d.bones:
            out[self.tm.tags[bone_tag_name(b.name)]] = d.materials[b.material]
        return out

    def _build_pins(self):
        mesh = self.mesh
        fdim = mesh.topology.dim - 1
        mesh.topology.create_connectivity(fdim, mesh.topology.dim)
        x = mesh.geometry.x
        tol = 1e-8 * float(np.abs(x).max() + 1.0)
        pins, all_facets, all_values = [], [], []
        for i, spec in enumerate(self.design.pins):
            facets = dmesh.locate_entities_boundary(mesh, fdim, _box_marker(spec.region, tol))
            n = self.comm.allreduce(len(facets))
            if n == 0:
                raise DesignError(f"{self.design.source}: pins.{spec.name}.region: "
                                  "no boundary facet of the mesh lies inside the region")
            pins.append(Pin(spec, self.V, facets, i + 1))
            all_facets.append(facets)
            all_values.append(np.full(len(facets), i + 1, dtype=np.int32))
        facets = np.concatenate(all_facets) if all_facets else np.zeros(0, np.int32)
        values = np.concatenate(all_values) if all_values else np.zeros(0, np.int32)
        order = np.argsort(facets)
        facets, idx = np.unique(facets[order], return_index=True)
        tags = dmesh.meshtags(mesh, fdim, facets.astype(np.int32), values[order][idx])
        return pins, tags

    def _grounds(self, t):
        """Penalty half-spaces: Pi_g = k t/2 int_boundary min(gap, 0)^2 ds, gap = (x - p) . n.

        The force on the plane is k t int min(gap, 0) ds * n (it points into
        the plane when the body presses on it).
        """
        if not self.design.grounds:
            return None, []
        X = ufl.SpatialCoordinate(self.mesh)
        energy, forces = None, []
        for g in self.design.grounds:
            n = fem.Constant(self.mesh, np.asarray(g.normal, dtype=PETSc.ScalarType))
            p = fem.Constant(self.mesh, np.asarray(g.point, dtype=PETSc.ScalarType))
            k = fem.Constant(self.mesh, PETSc.ScalarType(g.stiffness))
            pen = ufl.min_value(ufl.dot(X + self.u - p, n), 0.0)
            term = 0.5 * k * t * pen ** 2 * ufl.ds
            energy = term if energy is None else energy + term
            forces.append((np.asarray(g.normal, float), fem.form(k * t * pen * ufl.ds)))
        return energy, forces

    def ground_forces(self) -> list[np.ndarray]:
        """Net force the body exerts on each ground plane, N."""
        from mpi4py import MPI
        return [n * self.comm.allreduce(fem.assemble_scalar(form), op=MPI.SUM)
                for n, form in self.ground_force_forms]

    def _build_cable(self, spec) -> Cable:
        try:
            return Cable.build(self.V, spec)
        except ValueError as exc:
            raise DesignError(f"{self.design.source}: cables.{spec.name}.path: {exc}") from None

    def _points_operator(self, points: dict, section: str, key: str):
        names = list(points)
        X = np.array([points[n] for n in names], float).reshape(-1, self.dim)
        cells = locate_cells(self.mesh, X)
        for name, c in zip(names, cells):
            if c < 0:
                where = f"{section}.{name}" + (f".{key}" if key else "")
                raise DesignError(f"{self.design.source}: {where}: point lies outside the mesh")
        return interpolation_matrix(self.V, X, cells), np.zeros(len(names) * self.dim)

    def _bone_dofs(self) -> list[np.ndarray]:
        """Unrolled DOFs (n_nodes, bs) of each bone that has no pinned DOF."""
        groups = []
        tdim = self.mesh.topology.dim
        for b in self.design.bones:
            cells = self.tm.cell_tags.find(self.tm.tags[bone_tag_name(b.name)])
            nodes = fem.locate_dofs_topological(self.V, tdim, cells)
            dofs = nodes[:, None] * self.bs + np.arange(self.bs)
            if len(nodes) >= 3 and not self.fixed[dofs].any():
                groups.append(dofs)
        self._dof_X = self.V.tabulate_dof_coordinates()[:, :self.dim]
        return groups

    def rigid_correction(self, u0: np.ndarray, p: np.ndarray, a: float) -> np.ndarray:
        """Second-order correction that makes each bone follow an exact rotation.

        On a bone's nodes (current positions y, centroid c) the step a p is
        split into a rigid part a (t + omega x (y - c)) (least squares) and the
        rest; the correction (R(a omega) - I - a [omega]x)(y - c) turns the
        linearised rotation into the exact one. Zero outside bones.
        """
        corr = np.zeros_like(p)
        for dofs in self.rigid_groups:   # one vectorised block per bone
            y = self._dof_X[dofs[:, 0] // self.bs] + u0[dofs]
            r = y - y.mean(axis=0)
            q = p[dofs] - p[dofs].mean(axis=0)
            if self.dim == 2:
                w = float(np.sum(r[:, 0] * q[:, 1] - r[:, 1] * q[:, 0]) / np.sum(r * r))
                th = a * w
                c, s_ = np.cos(th), np.sin(th)
                rot = np.column_stack([c * r[:, 0] - s_ * r[:, 1], s_ * r[:, 0] + c * r[:, 1]])
                lin = r + th * np.column_stack([-r[:, 1], r[:, 0]])
            else:
                M = np.einsum("ni,nj->ij", r, r)
                w = np.linalg.solve(np.trace(M) * np.eye(3) - M, np.sum(np.cross(r, q), axis=0))
                th = a * w
                angle = np.linalg.norm(th)
                if angle < 1e-14:
                    continue
                k = th / angle
                rot = (r * np.cos(angle) + np.cross(k, r) * np.sin(angle)
                       + np.outer(r @ k, k) * (1 - np.cos(angle)))
                lin = r + np.cross(th, r)
            corr[dofs] = rot - lin
        return corr

    def _global_dofs(self) -> np.ndarray:
        imap = self.V.dofmap.index_map
        nodes = imap.local_to_global(np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32))
        return (nodes[:, None] * self.bs + np.arange(self.bs)).ravel().astype(PETSc.IntType)

    # -- load factor -----------------------------------------------------------------
    def set_factor(self, a: float) -> None:
        """Ramp contractions, pretensions, loads and pin moves to a fraction a."""
        self.factor = float(a)
        for p in self.pins:
            p.set_factor(a)

    def rest_lengths(self) -> list[float]:
        return [c.rest_length(self.factor) for c in self.cables]

    def apply_bcs(self, x: PETSc.Vec) -> None:
        """Write the prescribed pin displacements into x."""
        fem_petsc.set_bc(x, self.bcs)
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    # -- state ---------------------------------------------------------------------------
    def _sync(self, x: PETSc.Vec) -> np.ndarray:
        if x is not self.u.vector:
            x.copy(self.u.vector)
        self.u.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        return self.u.x.array

    def min_jacobian(self, x: PETSc.Vec | None = None) -> float:
        """Smallest det F over the mesh (sampled at DG nodes), reduced over ranks."""
        if x is not None:
            self._sync(x)
        from mpi4py import MPI
        return self.comm.allreduce(cell_values_min(self.detF, self.num_cells), op=MPI.MIN)

    def admissible(self, x: PETSc.Vec) -> bool:
        return self.min_jacobian(x) > 0.0

    def energy(self, x: PETSc.Vec) -> float:
        """Total energy Pi(x) in N mm."""
        u = self._sync(x)
        from mpi4py import MPI
        e = self.comm.allreduce(fem.assemble_scalar(self.energy_form), op=MPI.SUM)
        return e + self._point_energy(u)

    def _point_energy(self, u: np.ndarray) -> float:
        e = sum(c.energy(u, L) for c, L in zip(self.cables, self.rest_lengths()))
        if len(self.load_f):
            e -= self.factor * float(self.load_f @ (self.load_S @ u))
        return e

    def point_gradient(self, u: np.ndarray) -> np.ndarray:
        """Gradient of the cable and load terms, on local DOFs."""
        g = np.zeros(self.n_local)
        for c, L in zip(self.cables, self.rest_lengths()):
            g[c.dofs] += c.gradient(u, L)
        if len(self.load_f):
            g -= self.factor * (self.load_S.T @ self.load_f)
        return g

    def gradient(self, x: PETSc.Vec, b: PETSc.Vec) -> None:
        """Full gradient of Pi, Dirichlet rows included (for reactions)."""
        u = self._sync(x)
        with b.localForm() as b_local:
            b_local.set(0.0)
        fem_petsc.assemble_vector(b, self.residual_form)
        with b.localForm() as b_local:
            b_local.array_w[:] += self.point_gradient(u)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)

    def residual(self, x: PETSc.Vec, b: PETSc.Vec) -> None:
        """grad Pi with Dirichlet rows replaced by x - g (zero when x satisfies the pins)."""
        self.gradient(x, b)
        fem_petsc.set_bc(b, self.bcs, x, -1.0)

    # -- Jacobian --------------------------------------------------------------------------
    def create_matrix(self) -> PETSc.Mat:
        """Matrix whose pattern holds the UFL Hessian and every cable's dense block."""
        pattern = fem.create_sparsity_pattern(self.jacobian_form)
        for c in self.cables:
            nodes = np.unique(c.dofs // self.bs).astype(np.int32)
            pattern.insert(nodes, nodes)
        pattern.assemble()
        A = _cpp.la.petsc.create_matrix(self.comm, pattern)
        A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        return A

    def jacobian(self, x: PETSc.Vec, A: PETSc.Mat) -> None:
        """hess Pi with Dirichlet rows and columns replaced by the identity."""
        u = self._sync(x)
        A.zeroEntries()
        _cpp.fem.petsc.assemble_matrix(A, self.jacobian_form, _pack_constants(self.jacobian_form),
                                       _pack_coefficients(self.jacobian_form), self.bcs)
        A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
        A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
        for c, L in zip(self.cables, self.rest_lengths()):
            H = c.hessian(u, L)
            free = ~self.fixed[c.dofs]
            H = H * free[:, None] * free[None, :]
            rows = self.global_dofs[c.dofs]
            A.setValues(rows, rows, H, addv=PETSc.InsertMode.ADD_VALUES)
        A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
        A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
        _cpp.fem.petsc.insert_diagonal(A, self.V._cpp_object, self.bcs, 1.0)
        A.assemble()

    # -- read-outs ---------------------------------------------------------------------------
    def marker_positions(self, u: np.ndarray | None = None) -> np.ndarray:
        u = self.u.x.array if u is None else u
        return self.marker_X + (self.marker_S @ u).reshape(-1, self.dim)

    def reactions(self) -> dict:
        """Force each pin exerts on the body, N (sum over the pin's DOFs)."""
        b = self.u.vector.duplicate()
        self.gradient(self.u.vector, b)
        full = b.array_r.copy()
        if self.spring_form is not None:
            b.set(0.0)
            fem_petsc.assemble_vector(b, self.spring_form)
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            spring = -b.array_r
        out = {}
        for p in self.pins:
            owned = p.dofs[p.dofs < len(full)]
            r = (full if p.kind == "fixed" else spring)[owned].reshape(-1, self.bs).sum(axis=0)
            out[p.name] = self.comm.allreduce(np.asarray(r, float))
        b.destroy()
        return out


def _pack_constants(form):
    return _cpp.fem.pack_constants(form)


def _pack_coefficients(form):
    return _cpp.fem.pack_coefficients(form)
