"""The model: Pi(u; a) = sum of the registered terms, and its derivatives.

Every physical ingredient is a term (:mod:`skelfem.terms`); the model builds
them from the design, sums their UFL energies into one form compiled once
(with its residual and Jacobian forms), and adds the hand-written ones on
their few DOFs. It names no ingredient. The solver sees ``energy``,
``residual``, ``jacobian`` (the sparse Newton matrix K), ``low_rank`` (the
rank-one parts c g g^T kept out of K), ``admissible``, ``max_step`` and
``step_correction``; output reads ``readouts``; control reads and writes
``parameters``.

Dirichlet DOFs (fixed pins) have identity rows and columns in K and carry no
term entries, and their entries of every low-rank vector are zero.

Rigid bodies (``Term.rigid_body``: rigid bones) are solved for their rigid
DOFs q: their nodes' rows of K become identity rows and columns too, after
K T (T = du_b/dq) has given the coupling E and the reduced block
C = T^T K T + sum_i R_i . d2u_i/dq2 of the linear solver's border
(:class:`skelfem.linear.Border`, ``border``). In serial the border lives in
K itself: each body's q takes the rows and columns of the first DOFs of its
first nodes (its *hosts*), which hold E and C, so one factorisation covers
it; under MPI the linear solver adds it from K^{-1} E. The residual on those
rows is the projection of grad Pi onto the rigid modes, and ``apply_bcs``
puts every rigid body exactly on its closest rigid motion.

``refresh`` makes the model follow an edit that keeps the mesh (moved nodes,
cables, markers, pins...) without compiling anything again: terms follow in
place or are built anew, and the Newton matrix is kept while its pattern holds.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import ufl
from dolfinx import cpp as _cpp
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

from . import jitcache
from .linear import Border
from .points import global_dof_numbers
from .terms import BUILDERS, Context
from .terms.elasticity import cell_values_min, min_jacobian_expression

jitcache.install()


class Model:
    """Pi, grad Pi and hess Pi of one design on one mesh."""

    def __init__(self, design, tagged_mesh, builders=None):
        self.design, self.tm = design, tagged_mesh
        mesh = self.mesh = tagged_mesh.mesh
        self.comm = mesh.comm
        self.dim = mesh.geometry.dim
        self.thickness = float(design.thickness) if design.dim == 2 else 1.0
        V = self.V = fem.VectorFunctionSpace(mesh, ("Lagrange", int(design.mesh.degree)))
        self.u = fem.Function(V, name="displacement")
        self.bs = V.dofmap.index_map_bs
        imap = V.dofmap.index_map
        self.n_local = (imap.size_local + imap.num_ghosts) * self.bs
        self.n_owned = imap.size_local * self.bs
        self.num_cells = mesh.topology.index_map(mesh.topology.dim).size_local
        self.factor = 0.0
        x = mesh.geometry.x[:, :self.dim]
        self.size = float(self.comm.allreduce(np.linalg.norm(x.max(axis=0) - x.min(axis=0)) if len(x) else 0.0,
                                              op=MPI.MAX))   # bounding-box diagonal, mm
        t = fem.Constant(mesh, PETSc.ScalarType(self.thickness))
        self.ctx = Context(design, tagged_mesh, V, self.u, t)
        self._built = [(build, build(self.ctx)) for build in (builders or BUILDERS)]   # who built which terms
        self.terms = [term for _, terms in self._built for term in terms]
        self.ctx.finalise()
        self.global_dofs = global_dof_numbers(V).astype(PETSc.IntType)   # local -> global, unrolled
        self._constraints()
        self.border = None            # the linear solver's Border at the last jacobian (rigid bodies)
        self._last_gradient = None    # (state, grad Pi) of the last residual (rigid bodies)
        self._pattern_keys = None     # node pairs (row * nodes + column) of the last matrix made (serial)
        self._extra_keys = np.zeros(0, np.int64)  # node pairs of terms replaced by refresh, kept in new matrices
        self._hosts = None            # serial rigid bodies: [(host DOFs, coupled DOFs)] per body (_border_pattern)

        parts = [e for e in (term.ufl_energy(self.ctx) for term in self.terms) if e is not None]
        Pi = sum(parts[1:], parts[0])
        v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
        R = ufl.derivative(Pi, self.u, v)
        self.energy_form = fem.form(Pi)
        self.residual_form = fem.form(R)
        self.jacobian_form = fem.form(ufl.derivative(R, self.u, du))
        self.detF = min_jacobian_expression(self.u)
        self._w = fem.Function(V)                         # scratch field for max_gradient
        k = max(V.ufl_element().degree() - 1, 0)
        W = fem.FunctionSpace(self.mesh, ("DG", k))
        self._grad_w = fem.Expression(ufl.sqrt(ufl.inner(ufl.grad(self._w), ufl.grad(self._w))),
                                      W.element.interpolation_points())
        self._vectors: list[PETSc.Vec] = []
        self._fixed_cache: dict = {}
        self._block_cache: dict = {}   # (term, block) -> its map into the matrix (see _term_blocks_at)
        self._csr_cache = None
        self._packs = _Packs()
        self.changes: dict = {}      # {key: (value at the last solve, value now)} of live parameters

    def _constraints(self, terms=None) -> None:
        """Dirichlet conditions and rigid bodies of the terms (default: the model's own)."""
        terms = self.terms if terms is None else terms
        fixed = np.zeros(self.n_local, dtype=bool)
        for term in terms:
            for _, dofs in term.dirichlet():
                fixed[dofs] = True
        rigid = [b for b in (term.rigid_body() for term in terms) if b is not None]
        slaved = np.zeros(self.n_owned, dtype=bool)      # owned DOFs that follow a rigid body
        for body in rigid:
            # a guard: pins hold the body's boundary and bones lie strictly inside it (design.py)
            if self.comm.allreduce(bool(fixed[body.dofs].any()), op=MPI.LOR):
                from .design import DesignError
                raise DesignError(f"{self.design.source}: bones.{body.name}.rigid: a rigid bone cannot be held "
                                  "by a fixed pin (make it elastic)")
            slaved[body.dofs] = True
        self.bcs = [bc for term in terms for bc, _ in term.dirichlet()]
        self.fixed = self.ctx.fixed = fixed
        self.rigid, self.slaved = rigid, slaved
        self._slaved_rows = self.global_dofs[np.flatnonzero(slaved)].astype(PETSc.IntType)

    # -- following a design on the same mesh -------------------------------------------------------
    def refresh(self, design, changed) -> str | None:
        """Follow design on this mesh, whose nodes may have moved, keeping the compiled forms.

        changed: the dotted design keys that differ from the model's design
        (skelfem.design.flatten). Each ingredient whose terms can follow in
        place does (Term.follow); the others are built anew, which is allowed
        only if none of their terms, old or new, has a UFL energy. Live
        parameters among the changes are set as ``set_parameter`` would.
        Returns None when the model cannot follow (nothing was changed: build a
        new model), "same matrix" when the Newton matrix's pattern still holds
        every term's blocks, and "new matrix" when the caller must make a new one
        (``create_matrix``). Serial only.
        """
        live = self.parameters()
        changed = set(changed)
        if self.comm.size != 1 or any(k.split(".", 1)[0] in MODEL_KEYS for k in changed):
            return None
        values = {}
        for key in changed & live.keys():
            try:
                values[key] = _raw_value(design.raw, key)
            except (KeyError, StopIteration, TypeError):      # dropped for its default: build anew
                pass
        structural = changed - values.keys()
        ctx = Context(design, self.tm, self.V, self.u, self.ctx.thickness)
        old_design, self.ctx.design = self.ctx.design, design      # kept terms read the new design
        built, rebuilt, replaced = [], [], []
        try:
            for build, terms in self._built:
                if terms and all(term.follow(self.ctx, structural) for term in terms):
                    built.append((build, terms))
                    continue
                new = build(ctx)
                if any(t.has_ufl_energy() for t in terms + new):
                    raise _CannotFollow
                built.append((build, new))
                rebuilt += new
                replaced += terms
            terms = [term for _, ts in built for term in ts]
            self._constraints(terms)
        except _CannotFollow:
            self.ctx.design = old_design
            return None
        except BaseException:
            self.ctx.design = old_design
            raise
        ctx.fixed = self.fixed
        self.design, self._built, self.terms = design, built, terms
        for key, value in values.items():
            if key in self.parameters():
                self.set_parameter(key, value)
        x = self.mesh.geometry.x[:, :self.dim]
        self.size = float(np.linalg.norm(x.max(axis=0) - x.min(axis=0)))
        self._fixed_cache.clear()
        self._block_cache.clear()
        self._csr_cache = None
        self._last_gradient = self.border = None
        border_blocks, self._hosts = self._border_pattern([b for term in terms for b in term.pattern()])
        if self._within_pattern([b for term in rebuilt for b in term.pattern()] + border_blocks):
            return "same matrix"
        # the new matrix keeps the replaced terms' blocks too: while a drag moves via points from
        # cell to cell, the pattern grows a few times and then holds
        n = self.n_local // self.bs
        self._extra_keys = np.union1d(self._extra_keys,
                                      _block_keys([b for term in replaced for b in term.pattern()], n))
        return "new matrix"

    def _extra_rows(self) -> list:
        """The kept node pairs (_extra_keys) as one pattern block per row node."""
        n = self.n_local // self.bs
        rows, cols = np.divmod(self._extra_keys, n)
        starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]]) if len(rows) else np.zeros(0, int)
        return [(rows[i:i + 1], c) for i, c in zip(starts, np.split(cols, starts[1:]))]

    def _within_pattern(self, blocks) -> bool:
        """Whether every pattern block (row nodes, column nodes) is inside the last matrix made (serial)."""
        if self._pattern_keys is None:
            return False
        keys = _block_keys(blocks, self.n_local // self.bs)
        if not len(keys):
            return True
        if not len(self._pattern_keys):
            return False
        at = np.minimum(np.searchsorted(self._pattern_keys, keys), len(self._pattern_keys) - 1)
        return bool(np.array_equal(self._pattern_keys[at], keys))

    # -- terms and parameters -------------------------------------------------------------------
    def term(self, section: str, name: str | None = None):
        """The term of a section (and name); KeyError if there is none."""
        for term in self.terms:
            if term.section == section and (name is None or term.name == name):
                return term
        raise KeyError(f"{section}.{name}" if name else section)

    def terms_in(self, section: str) -> list:
        return [t for t in self.terms if t.section == section]

    def parameters(self) -> dict:
        """{--set key: value} of every parameter that changes live (no re-mesh, no recompile)."""
        return {k: v for term in self.terms for k, v in term.parameters().items()}

    def set_parameter(self, key: str, value) -> None:
        """Change a live parameter; the change is remembered (``changes``) until the next solve."""
        owners = [term for term in self.terms if key in term.parameters()]
        if not owners:
            raise KeyError(key)
        old = self.changes.get(key, (np.array(owners[0].parameters()[key], dtype=float), None))[0]
        self._last_gradient = None
        for term in owners:          # a key may belong to several terms (density: gravity and inertia)
            term.set_parameter(key, value)
        self.changes[key] = (old, np.array(owners[0].parameters()[key], dtype=float))

    def parameter_path(self, s: float) -> None:
        """Set every changed parameter to old + s (new - old): s = 0 the last solved state, 1 the new one."""
        self._last_gradient = None
        for key, (old, new) in self.changes.items():
            value = old + s * (new - old)
            for term in self.terms:
                if key in term.parameters():
                    term.set_parameter(key, float(value) if value.ndim == 0 else value)

    def carry_over(self, x: PETSc.Vec) -> None:
        """Let every term adjust a start state x interpolated from another mesh (see Term.carry_over)."""
        u = x.array_w
        for term in self.terms:
            term.carry_over(u)
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def set_factor(self, a: float) -> None:
        """Ramp contractions, pretensions, loads and pin moves to a fraction a."""
        self.factor = float(a)
        self._last_gradient = None
        for term in self.terms:
            term.set_factor(a)

    def end_step(self) -> None:
        for term in self.terms:
            term.end_step(self)

    def failure(self, converged: bool = True) -> str | None:
        """The first term's reason why the state (converged or where Newton gave up) is no equilibrium."""
        return next((why for why in (term.failure(self, converged) for term in self.terms) if why), None)

    def update_lag(self) -> bool:
        """Let every term refresh its lagged quantities at the converged state; True: solve again."""
        return any([term.update_lag(self) for term in self.terms])

    # -- state ----------------------------------------------------------------------------------
    def sync(self, x: PETSc.Vec) -> np.ndarray:
        """Make self.u hold x (ghosts updated); returns its local array."""
        if x is not self.u.vector:
            x.copy(self.u.vector)
        self.u.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        return self.u.x.array

    def apply_bcs(self, x: PETSc.Vec) -> None:
        """Write the prescribed pin displacements into x and put each rigid body on its closest rigid motion."""
        fem_petsc.set_bc(x, self.bcs)
        if self.rigid:
            u = x.array_r.copy()
            for body in self.rigid:
                body.snap(u)
            x.array_w[:] = u
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def min_jacobian(self, x: PETSc.Vec | None = None) -> float:
        """Smallest det F over the mesh (sampled at DG nodes), reduced over ranks."""
        if x is not None:
            self.sync(x)
        return self.comm.allreduce(cell_values_min(self.detF, self.num_cells), op=MPI.MIN)

    def max_gradient(self, v: PETSc.Vec) -> float:
        """max |grad v| over the mesh (exact for P1 and P2 fields; reduced over ranks)."""
        v.copy(self._w.vector)
        self._w.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        cells = np.arange(self.num_cells, dtype=np.int32)
        local = float(self._grad_w.eval(cells).max()) if self.num_cells else 0.0
        return self.comm.allreduce(local, op=MPI.MAX)

    def untangle(self, x: PETSc.Vec, sweeps: int = 20) -> int:
        """Smooth a start state x on its inverted cells until det F > 0 everywhere (at most `sweeps`).

        A displacement interpolated from a coarser mesh can invert a small
        cell: near a clamped corner's strain singularity the coarse P2 field's
        det F dips below zero between the points where the coarse solve checked
        it (finger_bones from h = 1 to 0.5: one cell of 0.05 mm at det F =
        -0.07), and the warm re-solve fell back to a ramp from rest (26 Newton
        iterations; 24 from the untangled start). Each sweep moves the nodes of
        every cell with det F <= 0 to the mean of their cells' mean
        displacements (a Laplacian step), then re-applies the pins and rigid
        bones; the state elsewhere stays as it was. Returns the sweeps made
        (0: x was admissible).
        """
        cells = np.arange(self.num_cells, dtype=np.int32)

        def inverted() -> np.ndarray:
            bad = self.detF.eval(cells).min(axis=1) <= 0.0 if self.num_cells else np.zeros(0, bool)
            return bad if self.comm.allreduce(bool(bad.any()), op=MPI.LOR) else None

        self.sync(x)
        bad = inverted()
        if bad is None:
            return 0
        nodes = self.V.dofmap.list.array.reshape(-1, self.V.dofmap.dof_layout.num_dofs)[:self.num_cells]
        count = np.maximum(np.bincount(nodes.ravel(), minlength=self.n_local // self.bs), 1)
        for sweep in range(1, sweeps + 1):
            u = self.u.x.array.reshape(-1, self.bs)
            mean = u[nodes].mean(axis=1)                                  # (cells, bs)
            around = np.zeros_like(u)
            np.add.at(around, nodes.ravel(), np.repeat(mean, nodes.shape[1], axis=0))
            moved = np.unique(nodes[bad])
            u[moved] = around[moved] / count[moved, None]
            x.array_w[:] = u.ravel()[:len(x.array_w)]
            self.apply_bcs(x)
            self.sync(x)
            bad = inverted()
            if bad is None:
                return sweep
        return sweeps

    def admissible(self, x: PETSc.Vec) -> bool:
        """det F > 0 everywhere and every term accepts the state (e.g. no self-intersection)."""
        if not self.min_jacobian(x) > 0.0:
            return False
        u = self.u.x.array
        return self.comm.allreduce(all(term.admissible(u) for term in self.terms), op=MPI.LAND)

    @property
    def bounds_steps(self) -> bool:
        """Whether some term limits the step (only the energy line search honours that)."""
        return any(term.bounds_steps for term in self.terms)

    def max_step(self, x0: np.ndarray, p: np.ndarray) -> float:
        """Largest alpha in [0, 1] such that every term admits x0 + s p, s <= alpha (agreed over ranks)."""
        alpha = min([1.0] + [term.max_step(x0, p) for term in self.terms])
        return float(self.comm.allreduce(alpha, op=MPI.MIN))

    def step_correction(self, x0: np.ndarray, p: np.ndarray, alpha: float) -> np.ndarray | float:
        """Sum of the terms' corrections to the trial state x0 + alpha p (0 if none)."""
        out = 0.0
        for term in self.terms:
            c = term.step_correction(x0, p, alpha)
            if c is not None:
                out = out + c
        return out

    @property
    def energy_noise(self) -> float:
        """Round-off level of Pi: terms of size mu, lam cancel in psi."""
        return 64 * np.finfo(float).eps * sum(term.energy_scale() for term in self.terms)

    # -- energy and gradient ------------------------------------------------------------------
    def energy(self, x: PETSc.Vec) -> float:
        """Total energy Pi(x) in N mm."""
        u = self.sync(x)
        form = self.energy_form
        e = self.comm.allreduce(_cpp.fem.assemble_scalar(form, _cpp.fem.pack_constants(form),
                                                         self._packs(form)), op=MPI.SUM)
        return e + float(sum(term.energy(u) for term in self.terms))

    def term_gradient(self, u: np.ndarray) -> np.ndarray:
        """Gradient of the hand-written terms, on local DOFs (global-DOF terms add their owned entries)."""
        g = np.zeros(self.n_local)
        for term in self.terms:
            out = term.gradient(u)
            if out is None:
                continue
            dofs, values = out
            if term.gather is None:
                np.add.at(g, dofs, values)
            else:
                term.gather.scatter_add(values, g)
        return g

    def gradient(self, x: PETSc.Vec, b: PETSc.Vec) -> None:
        """Full gradient of Pi, Dirichlet rows included (for reactions)."""
        u = self.sync(x)
        form = self.residual_form
        with b.localForm() as b_local:
            b_local.set(0.0)
            _cpp.fem.assemble_vector(b_local.array_w, form, _cpp.fem.pack_constants(form), self._packs(form))
            b_local.array_w[:] += self.term_gradient(u)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)

    def residual(self, x: PETSc.Vec, b: PETSc.Vec) -> None:
        """grad Pi with Dirichlet rows replaced by x - g (zero when x satisfies the pins), and on a
        rigid body's rows its projection onto the body's rigid modes (zero iff T^T grad Pi = 0)."""
        self.gradient(x, b)
        fem_petsc.set_bc(b, self.bcs, x, -1.0)
        if self.rigid:
            u, r = self.u.x.array, b.array_r.copy()
            self._last_gradient = (x.array_r.copy(), r.copy())       # for the border's d2u/dq2 term
            for body in self.rigid:
                body.project(body.modes(u), r)
            b.array_w[:] = r

    def full_gradient(self) -> np.ndarray:
        """grad Pi at the current state, owned entries, Dirichlet rows included."""
        b = self.u.vector.duplicate()
        self.gradient(self.u.vector, b)
        out = b.array_r.copy()
        b.destroy()
        return out

    # -- the Newton matrix ----------------------------------------------------------------------
    def _term_blocks(self, term):
        """The term's pattern blocks as (global rows this rank sets, global columns)."""
        bs = self.bs
        for rn, cn in term.pattern():
            rows = (np.asarray(rn, np.int64)[:, None] * bs + np.arange(bs)).ravel()
            cols = (np.asarray(cn, np.int64)[:, None] * bs + np.arange(bs)).ravel()
            if term.gather is None:
                rows, cols = self.global_dofs[rows], self.global_dofs[cols]
            lo = self.V.dofmap.index_map.local_range[0] * bs
            rows = rows[(rows >= lo) & (rows < lo + self.n_owned)]
            yield rows.astype(PETSc.IntType), cols.astype(PETSc.IntType)

    def _form_cells(self) -> np.ndarray:
        """The cells the Hessian's form integrates over (rigid bodies' cells are not among them)."""
        form, kind = self.jacobian_form, fem.IntegralType.cell
        return np.unique(np.concatenate([form.domains(kind, i) for i in form.integral_ids(kind)]))

    def _cell_pattern(self):
        """The UFL Hessian's pattern from the cells its form integrates over only (DOLFINx's own
        pattern takes every cell): the cells of rigid bodies add no entries."""
        imap = self.V.dofmap.index_map
        pattern = _cpp.la.SparsityPattern(self.comm, [imap, imap], [self.bs, self.bs])
        dofmap = self.V.dofmap.list
        for c in self._form_cells():
            nodes = dofmap.links(c)
            pattern.insert(nodes, nodes)
        return pattern

    def _border_pattern(self, blocks) -> tuple[list, list | None]:
        """Serial rigid bodies: the pattern blocks that put the border into K, and the host map.

        Body j's q_j takes the rows and columns of the first m_j DOFs of its
        first ceil(m_j / bs) nodes (its hosts; m_j = 3 in 2D, 6 in 3D). Its
        coupling E_j = (K T)_j is non-zero on the rows of K that reach the
        body: the nodes of every assembled cell or term block (``blocks``:
        (row nodes, column nodes)) that touches one of its nodes. Returns
        ([(rows, cols)] node blocks: hosts x coupled, coupled x hosts, hosts x
        hosts), [(host DOFs, coupled DOFs)] per body); ([], None) under MPI or
        without rigid bodies.
        """
        if self.comm.size != 1 or not self.rigid:
            return [], None
        bs, n = self.bs, self.n_local // self.bs
        npc = self.V.dofmap.dof_layout.num_dofs
        cell_nodes = self.V.dofmap.list.array.reshape(-1, npc)[self._form_cells()]
        rows, cols = np.divmod(_block_keys(blocks, n), n)          # every node pair of the blocks
        out, hosts = [], []
        for body in self.rigid:
            nodes = np.unique(body.dofs[:, 0] // bs)
            inside = np.zeros(n, dtype=bool)
            inside[nodes] = True
            near = np.unique(np.concatenate([cell_nodes[inside[cell_nodes].any(axis=1)].ravel(),
                                             rows[inside[cols]], cols[inside[rows]]]).astype(np.int64))
            near = near[~inside[near]]
            host_nodes = body.dofs[:-(-body.m // bs), 0] // bs
            out += [(host_nodes, near), (near, host_nodes)]
            hosts.append((body.dofs[:-(-body.m // bs)].ravel()[:body.m],
                          (near[:, None] * bs + np.arange(bs)).ravel()))
        every = np.concatenate([h for h, _ in hosts]) // bs
        out.append((every, every))
        return out, hosts

    def create_matrix(self) -> PETSc.Mat:
        """The sparse Newton matrix K: the UFL Hessian's pattern plus every term's (sparse) blocks.

        Every entry the Jacobian will ever touch is created here, as a zero,
        before the first final assembly (PETSc drops unused preallocated
        slots then); afterwards the pattern never changes (new entries
        raise), so MUMPS reuses its analysis across Newton iterations.
        """
        pattern = self._cell_pattern() if self.rigid else fem.create_sparsity_pattern(self.jacobian_form)
        if self.comm.size == 1:        # serial: the term blocks (and the rigid border) go into DOLFINx's pattern
            blocks = [block for term in self.terms for block in term.pattern()] + self._extra_rows()
            border_blocks, self._hosts = self._border_pattern(blocks)
            for rn, cn in blocks + border_blocks:
                pattern.insert(np.asarray(rn, np.int32), np.asarray(cn, np.int32))
        pattern.assemble()
        A = _cpp.la.petsc.create_matrix(self.comm, pattern)
        if self.comm.size == 1:
            graph = pattern.graph
            n_owned = pattern.index_map(0).size_local
            offsets = graph.offsets[:n_owned + 1]
            rows = np.repeat(np.arange(n_owned, dtype=np.int64), np.diff(offsets))
            self._pattern_keys = np.sort(rows * (self.n_local // self.bs) + graph.array[:offsets[-1]])
            zeros = np.zeros(offsets[-1] * self.bs * self.bs, dtype=PETSc.ScalarType)
            A.setValuesBlockedLocalCSR(offsets.astype(PETSc.IntType),
                                       graph.array[:offsets[-1]].astype(PETSc.IntType),
                                       zeros, addv=PETSc.InsertMode.INSERT_VALUES)
        else:                          # MPI: element entries by one assembly, term blocks by their owners
            _assemble_form(A, self.jacobian_form, self.bcs)
            A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
            A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
            A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
            for term in self.terms:
                for rows, cols in self._term_blocks(term):
                    if len(rows):
                        A.setValues(rows, cols, np.zeros((len(rows), len(cols))),
                                    addv=PETSc.InsertMode.ADD_VALUES)
            A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
            A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
            _cpp.fem.petsc.insert_diagonal(A, self.V._cpp_object, self.bcs, 1.0)
        A.assemble()
        A.zeroEntries()
        A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        A.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)     # identity rows of rigid bodies
        return A

    def _free(self, term, dofs) -> np.ndarray:
        """Which of a term's DOFs are not Dirichlet DOFs."""
        if term.gather is None:
            return ~self.fixed[dofs]
        key = id(term)
        if key not in self._fixed_cache:
            self._fixed_cache[key] = term.gather(self.fixed.astype(float)) > 0.5
        return ~self._fixed_cache[key]

    def _owned_rows(self, term, dofs) -> tuple[np.ndarray, np.ndarray]:
        """(positions in dofs of the rows this rank sets, their global numbers)."""
        if term.gather is None:
            pos = np.flatnonzero(np.asarray(dofs) < self.n_owned)
            return pos, self.global_dofs[np.asarray(dofs)[pos]]
        return term.gather.pos, np.asarray(dofs, np.int64)[term.gather.pos]

    def _block_map(self, term, dofs, row, col) -> tuple:
        """Which entries of a term's COO block this rank adds (owned, free rows and columns), and where."""
        free = self._free(term, dofs)
        pos, grow = self._owned_rows(term, dofs)
        keep = np.zeros(len(dofs), dtype=bool)
        keep[pos] = True
        sel = np.flatnonzero(keep[row] & free[row] & free[col])
        gcol = self.global_dofs[np.asarray(dofs)] if term.gather is None else np.asarray(dofs, np.int64)
        rowmap = np.full(len(dofs), -1, np.int64)
        rowmap[pos] = grow
        return sel, rowmap[row[sel]], gcol[col[sel]]

    def _term_blocks_at(self, u: np.ndarray) -> tuple[list, list]:
        """Every term's sparse Hessian blocks at u: ([(dofs, row, col, sel, rows, cols)], [values]).

        A block whose dofs, row and column arrays are the same objects as last
        time (a cable's curvature) reuses its map into the matrix.
        """
        blocks, values = [], []
        for term in self.terms:
            for i, (dofs, H) in enumerate(term.hessian(u)):
                H = H if sp.isspmatrix_coo(H) else sp.coo_matrix(H)
                if H.nnz == 0:
                    continue
                c = self._block_cache.get((id(term), i))
                if c is None or c[0] is not dofs or c[1] is not H.row or c[2] is not H.col:
                    c = (dofs, H.row, H.col, *self._block_map(term, dofs, H.row, H.col))
                    self._block_cache[(id(term), i)] = c
                blocks.append(c)
                values.append(H.data[c[3]])
        return blocks, values

    def _add_term_blocks(self, A: PETSc.Mat, u: np.ndarray) -> None:
        """A += the terms' sparse Hessian blocks, duplicates summed; the CSR layout is kept while it holds."""
        blocks, values = self._term_blocks_at(u)
        if not blocks:
            return
        cache = self._csr_cache
        if cache is None or len(cache[0]) != len(blocks) or any(a is not c[1] for a, c in zip(cache[0], blocks)):
            rows = np.concatenate([c[4] for c in blocks])
            cols = np.concatenate([c[5] for c in blocks])
            order = np.lexsort((cols, rows))
            r, k = rows[order], cols[order]
            new = np.r_[True, (r[1:] != r[:-1]) | (k[1:] != k[:-1])]
            slot = np.empty(len(order), np.int64)
            slot[order] = np.cumsum(new) - 1
            urows, counts = np.unique(r[new], return_counts=True)
            indptr = np.r_[0, np.cumsum(counts)].astype(PETSc.IntType)
            cache = ([c[1] for c in blocks], slot, int(new.sum()), urows.astype(PETSc.IntType),
                     indptr, k[new].astype(PETSc.IntType))
            self._csr_cache = cache
        _, slot, n, urows, indptr, indices = cache
        data = np.bincount(slot, weights=np.concatenate(values), minlength=n)
        A.setValuesIJV(indptr, indices, data, addv=PETSc.InsertMode.ADD_VALUES, rowmap=urows)

    def jacobian(self, x: PETSc.Vec, A: PETSc.Mat) -> None:
        """K = hess Pi without the rank-one parts, Dirichlet rows and columns replaced by the identity."""
        u = self.sync(x)
        A.zeroEntries()
        _assemble_form(A, self.jacobian_form, self.bcs, self._packs(self.jacobian_form))   # adds; so do the terms
        self._add_term_blocks(A, u)
        A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
        A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
        _cpp.fem.petsc.insert_diagonal(A, self.V._cpp_object, self.bcs, 1.0)
        A.assemble()
        if self.rigid:
            self._reduce_rigid(x, A)

    def _reduce_rigid(self, x: PETSc.Vec, A: PETSc.Mat) -> None:
        """The border of the rigid bodies from the assembled K (E = K T off their rows, C = T^T K T +
        sum R . d2u/dq2), then their rows and columns of K replaced by the identity."""
        u = self.u.x.array.copy()
        last = self._last_gradient
        if last is not None and np.array_equal(last[0], x.array_r):
            grad = last[1]                  # SNES evaluated the residual at x just before
        else:
            b = x.duplicate()
            self.gradient(x, b)
            fem_petsc.set_bc(b, self.bcs, x, -1.0)
            grad = b.array_r.copy()
            b.destroy()
        blocks = [(body, body.modes(u)) for body in self.rigid]
        m = sum(body.m for body in self.rigid)
        T = np.zeros((self.n_owned, m))
        j = 0
        for body, Tb in blocks:
            T[body.dofs.ravel(), j:j + body.m] = Tb.reshape(-1, body.m)
            j += body.m
        n_global = self.V.dofmap.index_map.size_global * self.bs
        B = PETSc.Mat().createDense([(self.n_owned, n_global), (None, m)], array=T, comm=self.comm)
        KT = A.matMult(B).getDenseArray().copy()            # K T, one sparse-dense product
        B.destroy()
        C = T.T @ KT
        C = C if self.comm.size == 1 else self.comm.allreduce(C)
        j = 0
        for body, _ in blocks:
            C[j:j + body.m, j:j + body.m] += body.second_derivative(u, grad)
            j += body.m
        KT[self.slaved] = 0.0
        C = 0.5 * (C + C.T)
        A.zeroRowsColumns(self._slaved_rows, diag=1.0)
        hosts = None if self._hosts is None else self._embed_border(A, KT, C)
        self.border = Border(T, self.slaved, KT, C, hosts)
        self.sync(x)

    def _embed_border(self, A: PETSc.Mat, KT: np.ndarray, C: np.ndarray) -> np.ndarray:
        """Write E = K T and C into the hosts' rows and columns of A (serial); the host DOFs in q's order."""
        g, j, insert = self.global_dofs, 0, PETSc.InsertMode.INSERT_VALUES
        for host, near in self._hosts:
            E = KT[near, j:j + len(host)]
            A.setValues(g[near], g[host], E, addv=insert)
            A.setValues(g[host], g[near], E.T.copy(), addv=insert)
            j += len(host)
        hosts = np.concatenate([h for h, _ in self._hosts])
        A.setValues(g[hosts], g[hosts], C, addv=insert)
        A.assemble()
        return hosts

    def low_rank(self, x: PETSc.Vec | None = None) -> list[tuple[float, PETSc.Vec]]:
        """The rank-one parts c g g^T of hess Pi as (c, g) with g a PETSc vector, zero on Dirichlet DOFs.

        The same list (same length, same order) on every rank.
        """
        u = self.u.x.array if x is None else self.sync(x)
        parts = [(term, c, dofs, g) for term in self.terms for c, dofs, g in term.low_rank(u)]
        while len(self._vectors) < len(parts):
            self._vectors.append(self.u.vector.duplicate())
        out = []
        for (term, c, dofs, g), vec in zip(parts, self._vectors):
            g = np.asarray(g, float) * self._free(term, dofs)
            vec.set(0.0)
            if term.gather is None:
                pos = np.flatnonzero(np.asarray(dofs) < self.n_owned)
                vec.array_w[np.asarray(dofs)[pos]] = g[pos]
            else:
                vec.array_w[term.gather.local] = g[term.gather.pos]
            out.append((float(c), vec))
        return out

    # -- read-outs -------------------------------------------------------------------------------
    def readouts(self) -> dict:
        """{section: {name: {...}}} of every term at the current state (collective)."""
        out: dict = {}
        for term in self.terms:
            values = term.readout(self)
            section = out.setdefault(term.section, {}) if values else None
            for name, value in (values or {}).items():      # two terms may report on one entry (friction)
                both = isinstance(value, dict) and isinstance(section.get(name), dict)
                section[name] = {**section[name], **value} if both else value
        return out


def _assemble_form(A: PETSc.Mat, form, bcs, coefficients=None) -> None:
    coefficients = _cpp.fem.pack_coefficients(form) if coefficients is None else coefficients
    _cpp.fem.petsc.assemble_matrix(A, form, _cpp.fem.pack_constants(form), coefficients, bcs)


def _block_keys(blocks, n: int) -> np.ndarray:
    """Sorted unique node pairs row * n + column of pattern blocks [(row nodes, column nodes)]; blocks
    of one shape are stacked, so the work is a few array operations per shape, not per block."""
    by_shape: dict = {}
    for rn, cn in blocks:
        by_shape.setdefault((len(rn), len(cn)), ([], []))
        by_shape[len(rn), len(cn)][0].append(rn)
        by_shape[len(rn), len(cn)][1].append(cn)
    keys = [(np.asarray(R, np.int64)[:, :, None] * n + np.asarray(C, np.int64)[:, None, :]).ravel()
            for R, C in by_shape.values()]
    return np.unique(np.concatenate(keys)) if keys else np.zeros(0, np.int64)


MODEL_KEYS = ("format", "dim", "thickness", "mesh")   # design keys no term follows: a new model


class _CannotFollow(Exception):
    """An ingredient with a UFL energy would have to be built anew (Model.refresh)."""


def _raw_value(raw: dict, key: str):
    """The value of a dotted design key (named entries by name) in a design's raw dict."""
    node = raw
    for part in key.split("."):
        if isinstance(node, list):
            node = next(e for e in node if isinstance(e, dict) and e.get("name") == part)
        else:
            node = node[part]
    return node


class _Packs:
    """Packed coefficients of the compiled forms, shared while the coefficients are unchanged.

    Pi, grad Pi and hess Pi have the same coefficients (u and the material
    fields), and a Newton iteration evaluates them at the same state (the
    accepted trial's energy, then the residual and the Jacobian there), so
    one packing serves all three. A pack is reused only while every
    coefficient array equals, entry by entry, the one it was packed from;
    forms whose coefficients or integrals differ get their own pack.
    """

    def __init__(self):
        self.packs: dict = {}      # form signature -> (copies of the coefficient arrays, packed coefficients)

    @staticmethod
    def _signature(form) -> tuple:
        integrals = tuple((t, tuple(form.integral_ids(t))) for t in form.integral_types)
        return tuple(id(c) for c in form.coefficients), integrals

    def __call__(self, form) -> dict:
        key = self._signature(form)
        arrays = [c.x.array for c in form.coefficients]
        held = self.packs.get(key)
        if held is None or not all(np.array_equal(a, b) for a, b in zip(arrays, held[0])):
            held = self.packs[key] = ([a.copy() for a in arrays], _cpp.fem.pack_coefficients(form))
        return held[1]
