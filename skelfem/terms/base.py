"""The energy-term contract and the context terms build themselves from.

The total energy is a sum of terms, one per physical ingredient,

    Pi(u; a) = sum_terms Pi_term(u; a),

with a in [0, 1] the load factor that ramps contractions, pretensions, loads
and pin moves. A term contributes to Pi in one or both of two ways:

* a UFL energy (``ufl_energy``) that the model sums with the others and
  compiles once (elasticity, spring pins, grounds, gravity, tractions), its
  derivatives derived by ``ufl.derivative``;
* hand-written energy, gradient and Hessian on a few DOFs (cables, point
  loads, self-contact). The Hessian is split in a sparse part that goes into
  the Newton matrix (``hessian``, inside ``pattern``) and rank-one parts
  c g g^T that stay out of it (``low_rank``), handled by the linear solver
  with the Sherman-Morrison-Woodbury formula, so no term puts a dense block
  into the matrix.

DOF arrays of a hand-written term are local indices, or, when the term has a
``gather`` (a :class:`skelfem.mesh.points.DofGather`), global DOF numbers known on
every rank (terms acting at material points that may lie on any rank).

Besides the energy a term exposes its *parameters* (the ``--set`` keys it owns,
changed live without re-meshing or recompiling), its *read-outs* (what goes
into result.json under ``section``), step bounds and admissibility for the
line search, an optional step correction (exact rigid rotations of bones),
Dirichlet conditions, rigid bodies (node groups that follow a few rigid DOFs), and a per-step hook for
history-dependent ingredients.

When an edit keeps the mesh (its nodes may move: the editor's drafts), a term
may ``follow`` the new design in place; the model builds anew the ingredients
whose terms cannot, and keeps its compiled forms only if none of those has a
UFL energy (:meth:`skelfem.fem.model.Model.refresh`).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any, TYPE_CHECKING

import numpy as np
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh
from petsc4py import PETSc

if TYPE_CHECKING:
    from ..design.spec import Design
    from ..mesh.geometry import TaggedMesh


class Term:
    """Base class of every energy term; the defaults describe a term that does nothing."""

    section: str = ""            # result.json key and design section, e.g. "cables"
    name: str = ""               # entry name within the section
    gather: Any = None           # DofGather: DOFs are global numbers; None: local indices
    bounds_steps: bool = False   # whether max_step can return < 1
    actuated: bool = False       # an actuator: its contraction is a control of Soft IK, tracking and optimisation

    def __init_subclass__(cls, **kwargs):
        """A method named almost like a hook (``end_steps``, ``readouts``) is a misspelt hook that the
        model would never call: refuse the class when it is defined."""
        super().__init_subclass__(**kwargs)
        import difflib
        hooks = [n for n, v in vars(Term).items() if not n.startswith("_") and callable(v)]
        for name, value in vars(cls).items():
            if name.startswith("_") or name in hooks or not callable(value):
                continue
            close = difflib.get_close_matches(name, hooks, n=1, cutoff=0.85)
            if close:
                raise TypeError(f"{cls.__name__}.{name}: not a Term hook; did you mean {close[0]}? "
                                "(a misspelt hook is never called)")

    # -- energy ------------------------------------------------------------------------------------
    def ufl_energy(self, ctx: "Context"):
        """UFL integral of this term's energy, or None (called once, after all terms are built)."""
        return None

    def has_ufl_energy(self) -> bool:
        """Whether ufl_energy gives an integral (answered before the context is finalised)."""
        return type(self).ufl_energy is not Term.ufl_energy

    def energy(self, u: np.ndarray) -> float:
        """Hand-written part of the energy at the local DOF array u, N mm."""
        return 0.0

    def gradient(self, u: np.ndarray):
        """(dofs, values) of the hand-written gradient, or None."""
        return None

    def hessian(self, u: np.ndarray) -> list:
        """[(dofs, dense block)] of the sparse part of the Hessian; every block inside pattern()."""
        return []

    def low_rank(self, u: np.ndarray) -> list:
        """[(c, dofs, g)]: rank-one parts c g g^T of the Hessian kept out of the matrix (c > 0)."""
        return []

    def pattern(self) -> list:
        """[(row nodes, column nodes)] blocks the sparse Hessian may fill (node = DOF // bs)."""
        return []

    def rigid_body(self):
        """A :class:`skelfem.terms.rigid.RigidBody` whose nodes this term makes move rigidly, or None.

        The model then solves for the body's rigid DOFs instead of its nodes'
        displacements (identity rows in the matrix, a border in the linear solve).
        """
        return None

    # -- line search ------------------------------------------------------------------------------
    sweeps_steps = False   # max_step sweeps the whole trajectory (continuous collision detection): costly
    #                        for long steps, so Model.max_step asks it last, on the step the others allow

    def max_step(self, u0: np.ndarray, p: np.ndarray) -> float:
        """Largest alpha in [0, 1] such that u0 + s p is admissible for s <= alpha."""
        return 1.0

    def admissible(self, u: np.ndarray) -> bool:
        return True

    def step_correction(self, u0: np.ndarray, p: np.ndarray, alpha: float):
        """Correction added to the trial state u0 + alpha p (owned DOFs), or None."""
        return None

    def carry_over(self, u: np.ndarray) -> None:
        """Adjust, in place, a start state u (owned DOFs) interpolated from another mesh after an edit."""

    def energy_scale(self) -> float:
        """Size of the terms that cancel in the energy (sets the round-off level of Pi)."""
        return 0.0

    # -- parameters and load ramp ---------------------------------------------------------------
    def parameters(self) -> dict:
        """{--set key: value} of the parameters this term changes live."""
        return {}

    def set_parameter(self, key: str, value) -> None:
        raise KeyError(key)

    def set_factor(self, a: float) -> None:
        """Apply the load factor a in [0, 1] to whatever this term ramps."""

    # -- following a design on the same mesh ----------------------------------------------------------
    def follow(self, ctx: "Context", changed: set) -> bool:
        """Become, in place, the term ctx.design would build on this mesh, whose nodes may have moved.

        changed: the design's dotted keys (``pins.base.region``, ``bones.distal.outline``...) that
        differ from the design this term was built for, live parameters aside (the model sets
        those). True if done (node-position caches dropped, compiled UFL energy still valid);
        False if the term must be built anew. The default is False: built anew.
        """
        return False

    # -- constraints, read-outs, history ------------------------------------------------------------
    def dirichlet(self) -> list:
        """[(DirichletBC, unrolled local DOFs)] this term imposes."""
        return []

    def finite_anchors(self) -> list:
        """[(centre, radius)]: where the term acts on a small disk (2D) or ball (3D) of material, a near
        point force that --tol grades the mesh around (cables' ends and bends in silicone)."""
        return []

    def readout(self, model) -> dict:
        """{name: {...}} reported in result.json under ``section`` (at a converged state)."""
        return {}

    def end_step(self, model) -> None:
        """Called after every accepted load or time step (history: friction, inertia)."""

    def failure(self, model, converged: bool = True) -> str | None:
        """Why the state is no equilibrium (a free object that nothing holds), or None; converged=False:
        the state where Newton gave up."""
        return None

    def verdict(self, model) -> str | None:
        """Why no equilibrium can lie ahead of the present Newton iterate (a free object falling with nothing
        in its way), or None; Newton ends the solve with it at once (the same answer on every rank). Newton
        asks it after every step of the terms that override it."""
        return None

    def update_lag(self, model) -> bool:
        """Refresh lagged quantities (friction's normal forces) at a converged state; True: solve again."""
        return False

    def rest(self) -> None:
        """Back to rest: forget every history (a cable's slips through its via points); the model's
        u is being set to 0 for a solve from rest."""

    def take_notes(self) -> list:
        """Warnings for the next result (a history started at a state the solver did not reach with this
        term as it is now: friction switched on at a loaded state), each once; [] if none."""
        return []

    # -- history, to try a step and take it back (Soft IK's trial solves) ------------------------
    history_fields: tuple = ()   # attributes that hold the term's history (friction's anchors, slip states)

    def history(self):
        """A copy of the term's history (what end_step, update_lag and set_factor change), or None."""
        if not self.history_fields:
            return None
        return {k: copy.deepcopy(getattr(self, k)) for k in self.history_fields}

    def set_history(self, history) -> None:
        """Put back a history returned by history(): a step that was tried and refused leaves nothing."""
        for k, v in (history or {}).items():
            setattr(self, k, copy.deepcopy(v))

    # -- lagged quantities, for exact sensitivities (skelfem.analysis.sensitivity) ----------------
    lag_step = 1e-8    # the step of the differences of lags_at, times the model's size (below a ground's
    #                    penetration, where N(u) has a kink)

    def lags(self):
        """A copy of the lagged quantities that follow the state (friction's normal forces N, an
        edge's tangent), or None: nothing lagged. At a converged state they are their own fixed
        point, lags_at(u) == lags()."""
        return None

    def set_lags(self, lags) -> None:
        """Put back lagged quantities returned by lags() or lags_at()."""

    def lags_at(self, u: np.ndarray):
        """The lagged quantities as update_lag would measure them at state u, on the present branch
        (which nodes stick, slip, broke away; the anchors), without relaxation: what makes the lagged
        Jacobian exact, J v = H v + d/de gradient(u; lags_at(u + e v))."""
        return None

    # -- stick anchors through time, for exact derivatives of runs (skelfem.analysis.adjoint) ---------
    def stick_anchors(self):
        """The continuous part of the history that the present state's residual uses (friction's
        stick anchors a, a flat float array), or None. A term with a history but no anchors (cable
        friction) makes derivatives through time approximate."""
        return None

    def set_stick_anchors(self, a) -> None:
        """Put back anchors returned by stick_anchors() (or perturbed ones)."""

    def stick_anchor_step(self) -> tuple[float, float]:
        """(a change of an anchor entry, a change of a displacement in mm), both small against the stick
        zone eps: the steps of the central differences through the anchors (every node stays on its
        branch)."""
        return 1.0, 1.0

    def stick_anchors_in_step(self, a_start, u_start):
        """The anchors a converged step uses, from the anchors a_start it began with and the state
        u_start it began from (a contact that formed during the step is anchored where it was at
        u_start); the term holds the converged step's history."""
        return a_start

    def stick_anchors_after(self, u):
        """The anchors the return map (end_step) would give at state u from the present anchors, with
        the lagged quantities at lags_at(u), on the present branch; changes nothing."""
        return self.stick_anchors()


def touched(changed: set, *prefixes: str) -> bool:
    """Whether any dotted key in changed is one of prefixes, lies under one or holds one."""
    return any(k == p or k.startswith(p + ".") or p.startswith(k + ".") for k in changed for p in prefixes)


def constant(mesh, value) -> fem.Constant:
    """A fem.Constant holding a float or a vector."""
    v = np.asarray(value, dtype=PETSc.ScalarType)
    return fem.Constant(mesh, v if v.ndim else PETSc.ScalarType(v))


def _box_marker(region: np.ndarray, tol: float):
    lo, hi = np.asarray(region[0], float) - tol, np.asarray(region[1], float) + tol

    def inside(x):
        d = len(lo)
        return np.all((x[:d].T >= lo) & (x[:d].T <= hi), axis=1)
    return inside


@dataclass(eq=False)
class Context:
    """What terms build from: the design, the mesh and the displacement field.

    Boundary boxes (pins, tractions) are registered with :meth:`boundary`
    while the terms are built; the model then tags every facet with the set of
    boxes it lies in (one meshtags object, so every ds integral of the energy
    shares one subdomain data) and terms integrate over a box with
    :meth:`ds` inside ``ufl_energy``.
    """

    design: Design
    tagged: TaggedMesh
    V: fem.FunctionSpace
    u: fem.Function                  # the displacement
    thickness: fem.Constant          # t: slab depth in 2D, 1 in 3D
    fixed: np.ndarray | None = None  # Dirichlet flags of the local DOFs (set by the model)
    anchor_radius: float | None = None   # cables' default anchor radius (cable_route, made on first use)
    _boxes: list = field(default_factory=list)
    _facets: list = field(default_factory=list)
    _measure: Any = None
    _codes: np.ndarray | None = None

    @property
    def mesh(self):
        return self.tagged.mesh

    @property
    def comm(self):
        return self.tagged.mesh.comm

    @property
    def dim(self) -> int:
        return self.tagged.mesh.geometry.dim

    @property
    def bs(self) -> int:
        return self.V.dofmap.index_map_bs

    def boundary(self, region) -> tuple[int, np.ndarray]:
        """Register a box; returns (its id, the local boundary facets inside it)."""
        facets = self.boundary_facets(region)
        self._boxes.append(np.asarray(region, float))
        self._facets.append(facets)
        return len(self._boxes) - 1, facets

    def boundary_facets(self, region) -> np.ndarray:
        """The local boundary facets inside a box (not registered)."""
        mesh = self.mesh
        fdim = mesh.topology.dim - 1
        mesh.topology.create_connectivity(fdim, mesh.topology.dim)
        tol = 1e-8 * float(np.abs(mesh.geometry.x).max() + 1.0)
        return dmesh.locate_entities_boundary(mesh, fdim, _box_marker(np.asarray(region, float), tol))

    def finalise(self) -> None:
        """Tag each facet with the bit set of the boxes containing it (code 1 + sum 2^box)."""
        mesh = self.mesh
        fdim = mesh.topology.dim - 1
        if not self._facets:
            self._measure = ufl.Measure("ds", domain=mesh)
            return
        allf = np.unique(np.concatenate(self._facets)).astype(np.int32)
        code = np.zeros(len(allf), dtype=np.int64)
        for i, f in enumerate(self._facets):
            code[np.searchsorted(allf, f)] += 1 << i
        self._codes = np.unique(code)
        tags = dmesh.meshtags(mesh, fdim, allf, code.astype(np.int32))
        self._measure = ufl.Measure("ds", domain=mesh, subdomain_data=tags)

    def ds(self, box: int, metadata: dict | None = None):
        """The boundary measure restricted to the facets of box `box`."""
        codes = self._codes if self._codes is not None else np.zeros(0, dtype=np.int64)
        ids = tuple(int(c) for c in codes if c >> box & 1)
        # the ids agree over ranks only if every rank saw the same codes; gather them
        ids = tuple(sorted(set(int(c) for part in self.comm.allgather(ids) for c in part)))
        if not ids:
            return None
        m = self._measure if metadata is None else self._measure(metadata=metadata)
        return m(ids)
