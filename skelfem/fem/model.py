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

Rigid bodies (``Constraints.rigid_body``: rigid bones) are solved for their rigid
DOFs q: their nodes' rows of K become identity rows and columns too, after
K T (T = du_b/dq) has given the coupling E and the reduced block
C = T^T K T + sum_i R_i . d2u_i/dq2 of the linear solver's border
(:class:`skelfem.fem.linear.Border`, ``border``). In serial the border lives in
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

from typing import Any

import numpy as np
import scipy.sparse as sp
import ufl
from dolfinx import cpp as _cpp
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

from ..mesh.points import global_dof_numbers, release_cell_tree
from ..runtime import jitcache, memory
from ..terms import BUILDERS, Context
from ..terms.capabilities import (Actuator, Constraints, ContactEvents, FiniteAnchors, Follows, History, Lagged,
                                  StepBounds, StepCorrection, Verdict)
from ..terms.elasticity import cell_value_chunks, cell_values_min, min_jacobian_expression
from .assembly import MatrixAssembly, block_keys
from ..design.parse import live_value
from .follow import MODEL_KEYS, CannotFollow, PackedCoefficients
from .multigrid import Coarse, owned_rigid_body_modes, rigid_body_modes



class Model(MatrixAssembly):
    """Pi, grad Pi and hess Pi of one design on one mesh."""

    def __init__(self, design, tagged_mesh, builders=None):
        jitcache.install()             # FFCx's compiled modules looked up once per process (idempotent)
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
        memory.allow_mmap(8 * self.n_local)   # matrices back to the system when freed, whatever MPI_Init set
        self.factor = 0.0
        x = mesh.geometry.x[:, :self.dim]
        self.size = float(self.comm.allreduce(np.linalg.norm(x.max(axis=0) - x.min(axis=0)) if len(x) else 0.0,
                                              op=MPI.MAX))   # bounding-box diagonal, mm
        t = fem.Constant(mesh, PETSc.ScalarType(self.thickness))
        self.ctx = Context(design, tagged_mesh, V, self.u, t)
        self._built = [(build, build(self.ctx)) for build in (builders or BUILDERS)]   # who built which terms
        self.terms = [term for _, terms in self._built for term in terms]
        self.ctx.finalise()
        release_cell_tree(mesh)       # a big mesh's cell tree: made again if a later build needs it
        self.global_dofs = global_dof_numbers(V).astype(PETSc.IntType)   # local -> global, unrolled
        self._constraints()
        self.border: Any = None       # the linear solver's Border at the last jacobian (rigid bodies)
        self._last_gradient = None    # (state, grad Pi) of the last residual (rigid bodies)
        self._pattern_keys = None     # node pairs (row * nodes + column) of the last matrix made (serial)
        self._extra_keys = np.zeros(0, np.int64)  # node pairs of terms replaced by refresh, kept in new matrices
        self._hosts = None            # serial rigid bodies: [(host DOFs, coupled DOFs)] per body (_border_pattern)
        self.embed_border = True      # serial: the rigid border goes into K (a direct solve; see linear.py)

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
        self._packs = PackedCoefficients()
        self._bone_nodes: dict = {}  # stiff elastic bone -> its owned nodes (stiff_bone_modes)
        self.changes: dict = {}      # {key: (value at the last solve, value now)} of live parameters
        self.step_watchers: list = []   # callables(model) told of every accepted load step (fem.jumps)

    def _constraints(self, terms=None) -> None:
        """Dirichlet conditions and rigid bodies of the terms (default: the model's own)."""
        terms = [t for t in (self.terms if terms is None else terms) if isinstance(t, Constraints)]
        fixed = np.zeros(self.n_local, dtype=bool)
        for term in terms:
            for _, dofs in term.dirichlet():
                fixed[dofs] = True
        rigid = [b for b in (term.rigid_body() for term in terms) if b is not None]
        slaved = np.zeros(self.n_owned, dtype=bool)      # owned DOFs that follow a rigid body
        for body in rigid:
            # a guard: pins hold the body's boundary and bones lie strictly inside it (design.py)
            if self.comm.allreduce(bool(fixed[body.dofs].any()), op=MPI.LOR):
                from ..design.spec import DesignError
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
        place does (Follows.follow); the others are built anew, which is allowed
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
        for key in sorted(changed & live.keys()):   # sorted: a set's order follows the hash seed
            value = live_value(design.raw, key, live[key])
            if value is not None:
                values[key] = value
        structural = changed - values.keys()
        ctx = Context(design, self.tm, self.V, self.u, self.ctx.thickness)
        old_design, self.ctx.design = self.ctx.design, design      # kept terms read the new design
        built, rebuilt, replaced = [], [], []
        try:
            for build, terms in self._built:
                if terms and all(isinstance(term, Follows) and term.follow(self.ctx, structural)
                                 for term in terms):
                    built.append((build, terms))
                    continue
                new = build(ctx)
                if any(t.has_ufl_energy() for t in terms + new):
                    raise CannotFollow
                built.append((build, new))
                rebuilt += new
                replaced += terms
            terms = [term for _, ts in built for term in ts]
            self._constraints(terms)
        except CannotFollow:
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
        if self._within_pattern([b for term in rebuilt for b in term.pattern()]) \
                and self._within_pattern(border_blocks, followers=True):
            return "same matrix"
        # the new matrix keeps the replaced terms' blocks too: while a drag moves via points from
        # cell to cell, the pattern grows a few times and then holds
        n = self.n_local // self.bs
        self._extra_keys = np.union1d(self._extra_keys,
                                      block_keys([b for term in replaced for b in term.pattern()], n))
        return "new matrix"

    def _extra_rows(self) -> list:
        """The kept node pairs (_extra_keys) as one pattern block per row node."""
        n = self.n_local // self.bs
        rows, cols = np.divmod(self._extra_keys, n)
        starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]]) if len(rows) else np.zeros(0, int)
        return [(rows[i:i + 1], c) for i, c in zip(starts, np.split(cols, starts[1:]))]

    def _within_pattern(self, blocks, followers: bool = False) -> bool:
        """Whether every pattern block (row nodes, column nodes) is inside the last matrix made (serial).
        A rigid body's nodes are kept out of the pattern, and out of the check, but for the border's blocks
        (``followers``): its host nodes carry the body's DOFs, coupled to the nodes near it (a dragged rigid
        object brought new nodes near it, and the kept matrix raised "new nonzero" in the draft's solve)."""
        if self._pattern_keys is None:
            return False
        follower = None if followers else self._follower_nodes()    # rigid bodies' nodes: not in the pattern
        if follower is not None:
            blocks = [(np.asarray(r)[~follower[np.asarray(r)]], np.asarray(c)[~follower[np.asarray(c)]])
                      for r, c in blocks]
            blocks = [(r, c) for r, c in blocks if len(r) and len(c)]
        keys = block_keys(blocks, self.n_local // self.bs)
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

    def actuators(self) -> list:
        """The terms whose contraction is a control (tendons), in design order."""
        return [t for t in self.having(Actuator) if t.actuated]

    def finite_anchors(self) -> list:
        """[(centre, radius)] of every term's finite anchors (FiniteAnchors.finite_anchors)."""
        return [a for t in self.having(FiniteAnchors) for a in t.finite_anchors()]

    def terms_in(self, section: str) -> list:
        return [t for t in self.terms if t.section == section]

    def having(self, ability: type) -> list:
        """The terms that declare an ability (a class of skelfem.terms.capabilities), in design order."""
        return [t for t in self.terms if isinstance(t, ability)]

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
        """Let every term adjust a start state x interpolated from another mesh (see Follows.carry_over)."""
        u = x.array_w
        for term in self.having(Follows):
            term.carry_over(u)
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def set_factor(self, a: float) -> None:
        """Ramp contractions, pretensions, loads and pin moves to a fraction a."""
        self.factor = float(a)
        self._last_gradient = None
        for term in self.terms:
            term.set_factor(a)

    def end_step(self) -> None:
        for term in self.having(History):
            term.end_step(self)
        for watch in self.step_watchers:
            watch(self)

    def to_rest(self) -> None:
        """u = 0 and no history (friction's slips and anchors): the start of a solve from rest."""
        self.u.x.array[:] = 0.0
        for term in self.having(History):
            term.rest()

    def rigid_body_modes(self) -> np.ndarray:
        """The rigid motions of the owned nodes (owned DOF rows, 3 columns in 2D, 6 in 3D): the
        near-nullspace of K that algebraic multigrid keeps on its coarse levels."""
        X = self.V.tabulate_dof_coordinates()[: self.n_owned // self.bs, : self.dim] \
            + self.u.x.array[: self.n_owned].reshape(-1, self.bs)[:, : self.dim]   # where the nodes are now
        return owned_rigid_body_modes(X, self.dim, self.comm)

    def coarse_space(self) -> Coarse | None:
        """The P1 level of two-level multigrid for a P2 Newton matrix (multigrid.Coarse); None at P1 and
        with rigid bodies (their border outside K made the inexact Newton crawl at 1 % per step late in
        a solve of arm3d at P2 with the two-level cycle; GAMG on the P2 matrix converges there)."""
        return Coarse.of(self.V) if int(self.design.mesh.degree) >= 2 and not self.rigid else None

    def stiff_bone_modes(self, names) -> sp.csr_matrix | None:
        """(owned DOF rows, 3 or 6 per bone), sparse: each named elastic bone's rigid motions on its own nodes
        (zero elsewhere; about the bone's centroid, where its nodes are now): the slow modes of a soft body holding much
        stiffer bones, which the multigrid cycle is balanced against (LowRankSolver). None: no names."""
        from dolfinx import fem as dfem
        from ..mesh.geometry import bone_tag_name
        if not names:
            return None
        tm, V = self.tm, self.V
        X = V.tabulate_dof_coordinates()[: self.n_owned // self.bs, : self.dim] \
            + self.u.x.array[: self.n_owned].reshape(-1, self.bs)[:, : self.dim]   # where the nodes are now
        blocks = []
        for j, name in enumerate(names):
            if name not in self._bone_nodes:     # the bone's owned nodes: the same at every Newton step
                cells = tm.cell_tags.find(tm.tags[bone_tag_name(name)])
                nodes = dfem.locate_dofs_topological(V, self.dim, cells)
                self._bone_nodes[name] = nodes[nodes < self.n_owned // self.bs]
            nodes = self._bone_nodes[name]
            count = self.comm.allreduce(len(nodes))
            centre = self.comm.allreduce(X[nodes].sum(axis=0)) / max(count, 1)
            local = rigid_body_modes(X[nodes] - centre, self.dim, centred=True)
            rows = (nodes[:, None] * self.bs + np.arange(self.bs)).ravel()
            k = local.shape[1]
            blocks.append(sp.coo_matrix((local.ravel(), (np.repeat(rows, k), np.tile(np.arange(k), len(rows))
                                                         + j * k)), shape=(self.n_owned, len(names) * k)))
        return sp.csr_matrix(sum(blocks[1:], blocks[0]))

    def history(self) -> list:
        """Every term's history (friction's anchors and slip states), to take a tried step back."""
        return [term.history() if isinstance(term, History) else None for term in self.terms]

    @property
    def path_dependent(self) -> bool:
        """Whether the equilibrium depends on the load path (active friction: contacts, grounds, cables)."""
        return any(getattr(term, "active", True) and term.history() is not None for term in self.having(History))

    def set_history(self, histories: list) -> None:
        for term, h in zip(self.terms, histories):
            if h is not None:
                term.set_history(h)

    def failure(self, converged: bool = True) -> str | None:
        """The first term's reason why the state (converged or where Newton gave up) is no equilibrium."""
        return next((why for why in (term.failure(self, converged) for term in self.having(Verdict)) if why), None)

    def update_lag(self) -> bool:
        """Let every term refresh its lagged quantities at the converged state; True: solve again."""
        return any([term.update_lag(self) for term in self.having(Lagged)])

    def contact_event(self) -> bool:
        """Whether some term took up a contact that formed at the present iterate (friction anchoring
        it, ObjectFriction.contact_event): the energy changed, so Newton ends the solve there and starts
        again from it (same answer on every rank). Terms are told if the solve is static (``in_time``)."""
        watch = self.having(ContactEvents)
        if not watch:
            return False
        u = self.u.x.array
        event = any([t.contact_event(u, not self.in_time) for t in watch])     # every term sees the iterate
        return self.comm.allreduce(event, op=MPI.LOR) if self.comm.size > 1 else event

    @property
    def in_time(self) -> bool:     # a run in time is going on (an inertia term is active)
        return any(getattr(t, "active", False) for t in self.terms_in("dynamics"))

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
        local = max((float(v.max()) for v in cell_value_chunks(self._grad_w, self.num_cells)), default=0.0)
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
        def inverted() -> np.ndarray | None:
            bad = np.concatenate([v.min(axis=1) <= 0.0 for v in cell_value_chunks(self.detF, self.num_cells)]
                                 or [np.zeros(0, bool)])
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
        return self.comm.allreduce(all(term.admissible(u) for term in self.having(StepBounds)), op=MPI.LAND)

    @property
    def bounds_steps(self) -> bool:
        """Whether some term limits the step (only the energy line search honours that)."""
        return any(term.bounds_steps for term in self.having(StepBounds))

    def max_step(self, x0: np.ndarray, p: np.ndarray) -> float:
        """Largest alpha in [0, 1] such that every term admits x0 + s p, s <= alpha (agreed over ranks).

        The terms that sweep the trajectory (contact's collision detection) are asked last, on the step
        the others allow: a free object's first Newton step, which only its tether resists, can be
        kilometres long, and sweeping that took seconds where the trust region keeps a millimetre."""
        bounded = self.having(StepBounds)
        alpha = min([1.0] + [term.max_step(x0, p) for term in bounded if not term.sweeps_steps])
        alpha = float(self.comm.allreduce(alpha, op=MPI.MIN))
        for term in bounded:
            if term.sweeps_steps and alpha > 0.0:
                alpha *= float(self.comm.allreduce(term.max_step(x0, alpha * p), op=MPI.MIN))
        return alpha

    def step_correction(self, x0: np.ndarray, p: np.ndarray, alpha: float) -> np.ndarray | float:
        """Sum of the terms' corrections to the trial state x0 + alpha p (0 if none)."""
        out = 0.0
        for term in self.having(StepCorrection):
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
        """grad Pi at the current state, owned entries, Dirichlet rows included (read-outs: the
        coefficient pack is not kept for a next evaluation, since results are written after)."""
        b = self.u.vector.duplicate()
        self.gradient(self.u.vector, b)
        self._packs.clear()
        out = b.array_r.copy()
        b.destroy()
        return out

    # -- the Newton matrix ----------------------------------------------------------------------
    def low_rank(self, x: PETSc.Vec | None = None) -> list[tuple[float, PETSc.Vec]]:
        """The rank-one parts c g g^T of hess Pi as (c, g) with g a PETSc vector, zero on Dirichlet DOFs.

        The same list (same length, same order) on every rank. A Newton step takes low_rank_columns.
        """
        c, G = self.low_rank_columns(x)
        while len(self._vectors) < len(c):
            self._vectors.append(self.u.vector.duplicate())
        out = []
        for j, vec in enumerate(self._vectors[:len(c)]):
            vec.set(0.0)
            col = G[:, j]
            vec.array_w[col.indices] = col.data
            out.append((float(c[j]), vec))
        return out

    def low_rank_columns(self, x: PETSc.Vec | None = None) -> tuple[np.ndarray, sp.csc_matrix]:
        """The rank-one parts of hess Pi as (c, G): the c_i and a sparse G (owned rows, one column g_i per
        part, zero on Dirichlet DOFs). A cable's g touches only its via points' cells: no vector of the
        mesh's size is made per part (arm3d has 17 parts)."""
        u = self.u.x.array if x is None else self.sync(x)
        c: list = []
        rows: list = []
        cols: list = []
        vals: list = []
        for term in self.terms:
            for ci, dofs, g in term.low_rank(u):
                g = np.asarray(g, float) * self.free_of(term, dofs)
                if term.gather is None:
                    dofs = np.asarray(dofs)
                    pos = np.flatnonzero(dofs < self.n_owned)
                    r, v = dofs[pos], g[pos]
                else:
                    r, v = term.gather.local, g[term.gather.pos]
                rows.append(r)
                vals.append(v)
                cols.append(np.full(len(r), len(c)))
                c.append(float(ci))
        if not c:
            return np.zeros(0), sp.csc_matrix((self.n_owned, 0))
        G = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(self.n_owned, len(c)))
        G.sum_duplicates()
        return np.array(c), G

    # -- read-outs -------------------------------------------------------------------------------
    def readouts(self) -> dict:
        """{section: {name: {...}}} of every term at the current state (collective)."""
        out: dict = {}
        for term in self.terms:
            values = term.readout(self)
            if not values:
                continue
            section = out.setdefault(term.section, {})
            for name, value in values.items():      # two terms may report on one entry (friction)
                both = isinstance(value, dict) and isinstance(section.get(name), dict)
                section[name] = {**section[name], **value} if both else value
        return out


