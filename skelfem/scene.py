"""A Scene binds a design to a mesh: the total energy and its derivatives.

    Pi(u; a) = Pi_el(u) + sum_pins Pi_pin(u; a) + sum_grounds Pi_g(u)
               + sum_cables k Q(l(u) - L(a)) - sum_loads a f . u(X_load) + Pi_c(u)

where a in [0, 1] is the load factor that ramps contractions, pretensions,
loads and pin moves. Pi_el, the spring pins and the grounds are UFL forms
(compiled once per scene). Everything else is an *energy term*: an object
on the local DOF vector u with

    energy(u) -> float
    gradient(u) -> (dofs, values)                   grad, on local DOFs (dofs unique)
    hessian(u) -> [(dofs, dense block), ...]        hess, inside pattern()
    pattern() -> [nodes, ...]                       node blocks the Hessian may fill
    max_step(u0, p) -> alpha in [0, 1]              admissible part of the step u0 + s p
    admissible(u) -> bool
    bounds_steps: bool                              whether max_step can be < 1
    set_factor(a)

Cables, point loads and self-contact (skelfem.contact, the IPC barrier Pi_c)
are such terms; adding one touches neither the matrix code nor the solver.
Fixed pins are Dirichlet conditions u = a * move on the boundary inside their
region; their rows and columns never carry term entries.

The solver only sees ``energy``, ``residual``, ``jacobian``, ``admissible``,
``max_step`` and ``create_matrix``.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import ufl
from dolfinx import cpp as _cpp
from dolfinx import fem
from dolfinx import mesh as dmesh
from dolfinx.fem import petsc as fem_petsc
from petsc4py import PETSc

from .cables import Cable
from .design import DesignError
from .geometry import BODY, bone_tag_name
from .grounds import build_grounds, ground_energy, ground_forces
from .materials import cell_values_min, elastic_energy, material_fields, min_jacobian_expression
from .points import global_dof_numbers, global_interpolation


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


class CableTerm:
    """A cable (skelfem.cables.Cable) as an energy term; its rest length follows the load factor."""

    bounds_steps = False

    def __init__(self, cable: Cable, bs: int):
        self.cable, self.name, self.factor = cable, cable.name, 0.0
        self.gather = cable.gather           # dofs below are global numbers (= local in serial)
        self.nodes = np.unique(cable.dofs // bs).astype(np.int32)

    def set_factor(self, a: float) -> None:
        self.factor = float(a)

    def energy(self, u):
        return self.cable.energy(u, self.cable.rest_length(self.factor))

    def gradient(self, u):
        return self.cable.dofs, self.cable.gradient(u, self.cable.rest_length(self.factor))

    def hessian(self, u):
        return [(self.cable.dofs, self.cable.hessian(u, self.cable.rest_length(self.factor)))]

    def pattern(self):
        return [self.nodes]

    def max_step(self, u0, p):
        return 1.0

    def admissible(self, u):
        return True


class LoadTerm:
    """Point loads: -a f . (S u), linear in u (no Hessian); S acts on the DOFs of `gather`."""

    name = "loads"
    bounds_steps = False

    def __init__(self, S, gather, f: np.ndarray):
        self.S, self.gather, self.f, self.factor = S, gather, f, 0.0

    def set_factor(self, a: float) -> None:
        self.factor = float(a)

    def energy(self, u):
        return -self.factor * float(self.f @ (self.S @ self.gather(u)))

    def gradient(self, u):
        return self.gather.dofs, -self.factor * (self.S.T @ self.f)

    def hessian(self, u):
        return []

    def pattern(self):
        return []

    def max_step(self, u0, p):
        return 1.0

    def admissible(self, u):
        return True


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
        self.grounds = build_grounds(design.grounds, self.u, t)
        if self.grounds:
            Pi = Pi + ground_energy(self.grounds)
        R = ufl.derivative(Pi, self.u, v)
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
        self.load_S, self.load_gather = self._points_operator(
            {l.name: l.at for l in design.loads}, "loads", "at")
        self.load_f = np.concatenate([np.asarray(l.force, float) for l in design.loads]) \
            if design.loads else np.zeros(0)
        self.marker_names = list(design.markers)
        self._marker_S, self.marker_gather = self._points_operator(design.markers, "markers", "")
        self.marker_X = np.array([design.markers[n] for n in self.marker_names], float).reshape(-1, self.dim)
        self.global_dofs = global_dof_numbers(self.V).astype(PETSc.IntType)   # local -> global, unrolled
        self.rigid_groups = self._bone_dofs()

        # hand-written energy terms
        self.contact = self._build_contact() if design.contact.self_contact else None
        self.terms = [CableTerm(c, self.bs) for c in self.cables]
        if len(self.load_f):
            self.terms.append(LoadTerm(self.load_S, self.load_gather, self.load_f))
        if self.contact is not None:
            self.terms.append(self.contact)

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

    def ground_forces(self) -> list[np.ndarray]:
        """Net force the body exerts on each ground plane, N (see skelfem.grounds)."""
        return ground_forces(self.grounds, self.comm)

    def _build_contact(self):
        """The IPC self-contact term; refuses designs it cannot honour (one-line DesignError)."""
        from .contact import SelfContact
        d, where = self.design, f"{self.design.source}: contact.self"
        if d.dim != 2:
            raise DesignError(f"{where}: self-contact is implemented for dim = 2 only")
        if self.comm.size > 1:
            raise DesignError(f"{where}: self-contact runs on one MPI process (got {self.comm.size})")
        if d.solver.line_search != "energy":
            raise DesignError(f"{where}: self-contact needs solver.line_search = \"energy\" "
                              f"(got {d.solver.line_search!r}): only it limits steps to collision-free ones")
        E_body = d.materials[d.body.material].E
        contact = SelfContact(self.V, d.contact.dhat, E_body, self.thickness)
        d0 = contact.min_distance(np.zeros(self.n_local))
        if d0 <= d.contact.dhat:
            raise DesignError(f"{self.design.source}: contact.dhat: {d.contact.dhat:g} mm is not below the "
                              f"smallest rest distance between boundary parts ({d0:.3g} mm); "
                              "lower dhat or coarsen the mesh")
        return contact

    def _build_cable(self, spec) -> Cable:
        try:
            return Cable.build(self.V, spec)
        except ValueError as exc:
            raise DesignError(f"{self.design.source}: cables.{spec.name}.path: {exc}") from None

    def _points_operator(self, points: dict, section: str, key: str):
        """(S, gather): u at the material points is S @ gather(u), on every rank."""
        names = list(points)
        X = np.array([points[n] for n in names], float).reshape(-1, self.dim)
        S, gather, owner = global_interpolation(self.V, X)
        for name, o in zip(names, owner):
            if o == self.comm.size:
                where = f"{section}.{name}" + (f".{key}" if key else "")
                raise DesignError(f"{self.design.source}: {where}: point lies outside the mesh")
        return S, gather

    @property
    def marker_S(self):
        """Marker interpolation on local DOFs, u(X_m) = (S u)_m (one process only)."""
        if self.comm.size > 1:
            raise RuntimeError("marker_S acts on one process's DOFs; use marker_positions under MPI")
        g = self.marker_gather
        S = self._marker_S.tocoo()
        return sp.csr_matrix((S.data, (S.row, g.local[S.col])), shape=(S.shape[0], self.n_local))

    def _bone_dofs(self) -> list[np.ndarray]:
        """Owned unrolled DOFs (n_nodes, bs) of each bone that has no pinned DOF.

        The list is the same on every rank (a rank may hold no node of a bone).
        """
        from mpi4py import MPI
        groups = []
        tdim = self.mesh.topology.dim
        n_owned = self.V.dofmap.index_map.size_local
        for b in self.design.bones:
            cells = self.tm.cell_tags.find(self.tm.tags[bone_tag_name(b.name)])
            nodes = fem.locate_dofs_topological(self.V, tdim, cells)
            nodes = nodes[nodes < n_owned]
            dofs = nodes[:, None] * self.bs + np.arange(self.bs)
            count = self.comm.allreduce(len(nodes), op=MPI.SUM)
            pinned = self.comm.allreduce(bool(self.fixed[dofs].any()), op=MPI.LOR)
            if count >= 3 and not pinned:
                groups.append(dofs)
        self._dof_X = self.V.tabulate_dof_coordinates()[:, :self.dim]
        return groups

    def _sum(self, a):
        """Sum over ranks (a no-op in serial)."""
        return a if self.comm.size == 1 else self.comm.allreduce(a)

    def rigid_correction(self, u0: np.ndarray, p: np.ndarray, a: float) -> np.ndarray:
        """Second-order correction that makes each bone follow an exact rotation.

        On a bone's nodes (current positions y, centroid c) the step a p is
        split into a rigid part a (t + omega x (y - c)) (least squares) and the
        rest; the correction (R(a omega) - I - a [omega]x)(y - c) turns the
        linearised rotation into the exact one. Zero outside bones. u0 and p
        are owned DOF arrays; sums run over all ranks.
        """
        corr = np.zeros_like(p)
        for dofs in self.rigid_groups:   # one vectorised block per bone
            y = self._dof_X[dofs[:, 0] // self.bs] + u0[dofs]
            n = self._sum(len(y))
            r = y - self._sum(y.sum(axis=0)) / n
            q = p[dofs] - self._sum(p[dofs].sum(axis=0)) / n
            if self.dim == 2:
                w = float(self._sum(np.sum(r[:, 0] * q[:, 1] - r[:, 1] * q[:, 0])) / self._sum(np.sum(r * r)))
                th = a * w
                c, s_ = np.cos(th), np.sin(th)
                rot = np.column_stack([c * r[:, 0] - s_ * r[:, 1], s_ * r[:, 0] + c * r[:, 1]])
                lin = r + th * np.column_stack([-r[:, 1], r[:, 0]])
            else:
                M = self._sum(np.einsum("ni,nj->ij", r, r))
                w = np.linalg.solve(np.trace(M) * np.eye(3) - M, self._sum(np.cross(r, q).sum(axis=0)))
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

    # -- load factor -----------------------------------------------------------------
    def set_factor(self, a: float) -> None:
        """Ramp contractions, pretensions, loads and pin moves to a fraction a."""
        self.factor = float(a)
        for p in self.pins:
            p.set_factor(a)
        for term in self.terms:
            term.set_factor(a)

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
        """det F > 0 everywhere and every term accepts the state (e.g. no self-intersection)."""
        if not self.min_jacobian(x) > 0.0:
            return False
        u = self.u.x.array
        return all(term.admissible(u) for term in self.terms)

    @property
    def bounds_steps(self) -> bool:
        """Whether some term limits the step (only the energy line search honours that)."""
        return any(term.bounds_steps for term in self.terms)

    def max_step(self, x0: np.ndarray, p: np.ndarray) -> float:
        """Largest alpha in [0, 1] such that every term admits the path x0 + s p, s <= alpha.

        x0 and p are local DOF arrays. Bones lie strictly inside the body, so
        the line search's rigid-rotation correction never moves a boundary
        node: contact sees exactly the straight path.
        """
        alpha = 1.0
        for term in self.terms:
            alpha = min(alpha, term.max_step(x0, p))
        return float(alpha)

    def energy(self, x: PETSc.Vec) -> float:
        """Total energy Pi(x) in N mm."""
        u = self._sync(x)
        from mpi4py import MPI
        e = self.comm.allreduce(fem.assemble_scalar(self.energy_form), op=MPI.SUM)
        return e + self._point_energy(u)

    def _point_energy(self, u: np.ndarray) -> float:
        return float(sum(term.energy(u) for term in self.terms))

    def point_gradient(self, u: np.ndarray) -> np.ndarray:
        """Gradient of the energy terms (cables, loads, contact), on local DOFs."""
        g = np.zeros(self.n_local)
        for term in self.terms:
            dofs, values = term.gradient(u)
            gather = getattr(term, "gather", None)
            if gather is None:
                g[dofs] += values                 # local DOFs
            else:
                gather.scatter_add(values, g)     # global DOFs: add the owned ones
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
        """Matrix whose pattern holds the UFL Hessian and every term's node blocks.

        DOLFINx only preallocates row lengths, and PETSc drops unused slots at
        the first final assembly; so the whole pattern is filled with explicit
        zeros here. It never changes afterwards (new entries raise), blocks a
        term leaves empty in one iteration stay available for the next, and
        the symbolic factorisation is reused across Newton iterations.
        """
        pattern = fem.create_sparsity_pattern(self.jacobian_form)
        parallel = self.comm.size > 1
        for term in self.terms:
            if parallel and getattr(term, "gather", None) is not None:
                continue                          # global blocks: filled below
            for nodes in term.pattern():
                nodes = np.asarray(nodes, dtype=np.int32)
                pattern.insert(nodes, nodes)
        pattern.assemble()
        A = _cpp.la.petsc.create_matrix(self.comm, pattern)
        if parallel:
            self._fill_pattern_parallel(A)
            A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
            return A
        # serial: fill the pattern directly (under MPI the pattern's column map
        # has ghosts the matrix's local numbering lacks, hence the other path)
        graph = pattern.graph
        n_owned = pattern.index_map(0).size_local
        offsets = graph.offsets[:n_owned + 1]
        zeros = np.zeros(offsets[-1] * self.bs * self.bs, dtype=PETSc.ScalarType)
        A.setValuesBlockedLocalCSR(offsets.astype(PETSc.IntType), graph.array[:offsets[-1]].astype(PETSc.IntType),
                                   zeros, addv=PETSc.InsertMode.INSERT_VALUES)
        A.assemble()
        A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        return A

    def _fill_pattern_parallel(self, A: PETSc.Mat) -> None:
        """Create every entry the Jacobian will ever touch, as zeros (MPI).

        One assembly of the UFL Hessian inserts exactly the element entries of
        later assemblies; a cable couples DOFs owned by several ranks, which
        DOLFINx's pattern cannot name, so its block (own rows x all its DOFs)
        is reserved here once. PETSc drops preallocated slots left empty at
        the first final assembly, so all of this precedes it.
        """
        _cpp.fem.petsc.assemble_matrix(A, self.jacobian_form, _pack_constants(self.jacobian_form),
                                       _pack_coefficients(self.jacobian_form), self.bcs)
        A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
        A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
        A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
        for term in self.terms:
            gather = getattr(term, "gather", None)
            if gather is not None and term.pattern():
                rows, cols = gather.owned_dofs.astype(PETSc.IntType), gather.dofs.astype(PETSc.IntType)
                A.setValues(rows, cols, np.zeros((len(rows), len(cols))), addv=PETSc.InsertMode.ADD_VALUES)
        A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
        A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
        _cpp.fem.petsc.insert_diagonal(A, self.V._cpp_object, self.bcs, 1.0)
        A.assemble()
        A.zeroEntries()

    def _term_fixed(self, term) -> np.ndarray:
        """Pinned flags of a global-DOF term's DOFs (gathered once)."""
        cache = self.__dict__.setdefault("_fixed_cache", {})
        if id(term) not in cache:
            cache[id(term)] = term.gather(self.fixed.astype(float)) > 0.5
        return cache[id(term)]

    def jacobian(self, x: PETSc.Vec, A: PETSc.Mat) -> None:
        """hess Pi with Dirichlet rows and columns replaced by the identity."""
        u = self._sync(x)
        A.zeroEntries()
        _cpp.fem.petsc.assemble_matrix(A, self.jacobian_form, _pack_constants(self.jacobian_form),
                                       _pack_coefficients(self.jacobian_form), self.bcs)
        A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
        A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
        for term in self.terms:
            gather = getattr(term, "gather", None)
            for dofs, H in term.hessian(u):
                if gather is None:                # local DOFs
                    free = ~self.fixed[dofs]
                    rows = cols = self.global_dofs[dofs]
                    H = H * free[:, None] * free[None, :]
                else:                             # global DOFs: this rank sets its own rows
                    free = ~self._term_fixed(term)
                    cols = dofs.astype(PETSc.IntType)
                    rows = cols[gather.pos]
                    H = H[gather.pos] * free[gather.pos, None] * free[None, :]
                A.setValues(rows, cols, H, addv=PETSc.InsertMode.ADD_VALUES)
        A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
        A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
        _cpp.fem.petsc.insert_diagonal(A, self.V._cpp_object, self.bcs, 1.0)
        A.assemble()

    # -- read-outs ---------------------------------------------------------------------------
    def marker_positions(self, u: np.ndarray | None = None) -> np.ndarray:
        """Current marker positions (every rank gets all of them; collective under MPI)."""
        u = self.u.x.array if u is None else u
        return self.marker_X + (self._marker_S @ self.marker_gather(u)).reshape(-1, self.dim)

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
