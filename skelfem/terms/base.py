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
changed live without re-meshing or recompiling) and its *read-outs* (what goes
into result.json under ``section``). That is the whole contract of ``Term``.

Optional abilities are small classes of their own (skelfem.terms.capabilities)
that a term inherits beside ``Term`` and the model finds with ``isinstance``:
step bounds and admissibility for the line search, a step correction (exact
rigid rotations of bones), Dirichlet conditions and rigid bodies, following an
edit on the same mesh (``Follows``: the model builds anew the ingredients
whose terms cannot, and keeps its compiled forms only if none of those has a
UFL energy, :meth:`skelfem.fem.model.Model.refresh`), a per-step hook with a
history, lagged quantities, contact events, stick anchors, finite anchors,
actuation and verdicts.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, TYPE_CHECKING

import numpy as np
import scipy.sparse as sp
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh
from petsc4py import PETSc

from .capabilities import CAPABILITIES

if TYPE_CHECKING:
    from ..design.spec import Design
    from ..mesh.geometry import TaggedMesh


class CooBlock:
    """A sparse Hessian block in COO form on a term's dofs (duplicates summed): scipy's coo_matrix's
    row, col and data without its checks and index conversions (a cable's curvature, every Newton step:
    building coo_matrix objects for finger.toml's five cables took 0.4 ms of a 2.4 ms assembly)."""

    __slots__ = ("data", "row", "col", "shape")

    def __init__(self, data: np.ndarray, row: np.ndarray, col: np.ndarray, shape: tuple[int, int]):
        self.data, self.row, self.col, self.shape = data, row, col, shape

    @property
    def nnz(self) -> int:
        return len(self.data)

    def tocoo(self) -> sp.coo_matrix:
        return sp.coo_matrix((self.data, (self.row, self.col)), shape=self.shape)

    def tocsr(self):
        return self.tocoo().tocsr()

    def toarray(self) -> np.ndarray:
        return self.tocoo().toarray()


class Term:
    """Base class of every energy term, the small contract: its energy (a UFL integral and/or a
    hand-written energy, gradient, sparse Hessian inside a declared pattern and rank-one parts), its
    live parameters and load ramp, and its read-outs. The defaults describe a term that does nothing.
    Optional abilities (step bounds, constraints, history, lags, anchors, actuation, verdicts...) are
    the classes of skelfem.terms.capabilities, which a term inherits beside this one."""

    section: str = ""            # result.json key and design section, e.g. "cables"
    name: str = ""               # entry name within the section
    gather: Any = None           # DofGather: DOFs are global numbers; None: local indices

    def __init_subclass__(cls, **kwargs):
        """A method of an ability the class does not declare (``end_step`` without History), or named
        almost like a hook (``end_steps``, ``readouts``), would never be called: refuse the class when
        it is defined."""
        super().__init_subclass__(**kwargs)
        import difflib
        owner = {n: c for c in (Term, *CAPABILITIES) for n, v in vars(c).items()
                 if not n.startswith("_") and callable(v)}
        for name, value in vars(cls).items():
            if name.startswith("_") or not callable(value):
                continue
            if name in owner:
                if not issubclass(cls, owner[name]):
                    raise TypeError(f"{cls.__name__}.{name}: a hook of {owner[name].__name__}, which "
                                    f"{cls.__name__} does not declare (add it to the class's bases: "
                                    "undeclared hooks are never called)")
                continue
            close = difflib.get_close_matches(name, list(owner), n=1, cutoff=0.85)
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
        """[(dofs, block)] of the sparse part of the Hessian (a dense array, a scipy sparse matrix or a
        :class:`CooBlock`); every block inside pattern()."""
        return []

    def low_rank(self, u: np.ndarray) -> list:
        """[(c, dofs, g)]: rank-one parts c g g^T of the Hessian kept out of the matrix (c > 0)."""
        return []

    def pattern(self) -> list:
        """[(row nodes, column nodes)] blocks the sparse Hessian may fill (node = DOF // bs)."""
        return []

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

    # -- read-outs --------------------------------------------------------------------------------
    def readout(self, model) -> dict:
        """{name: {...}} reported in result.json under ``section`` (at a converged state)."""
        return {}


def touched(changed: set, *prefixes: str) -> bool:
    """Whether any dotted key in changed is one of prefixes, lies under one or holds one."""
    return any(k == p or k.startswith(p + ".") or p.startswith(k + ".") for k in changed for p in prefixes)


PREVIEW = "#preview"     # in a refresh's changed keys: the state will be a preview (Session.edit(preview=True))


def bone_poses_only(ctx, changed: set) -> bool:
    """Whether changed is a preview's (PREVIEW among its keys) of nothing but 3D bones' poses
    (``bones.B.move``, ``bones.B.rotate...``): the editor's 3D drafts on nodes moved by
    skelfem.mesh.morph3d, which cables and markers follow by keeping their points in the cells they were
    found in (an approximation a preview allows; the release re-meshes). Anyone else's edit (a design
    gradient's moved mesh) builds them anew, exact."""
    keys = set(changed) - {PREVIEW}
    return ctx.design.dim == 3 and PREVIEW in changed and bool(keys) and all(
        len(k.split(".")) > 2 and k.split(".")[0] == "bones" and k.split(".")[2] in ("move", "rotate")
        for k in keys)


def moved_nodes_only(ctx, changed: set) -> bool:
    """Whether changed is a preview's of nothing but moved mesh nodes: 3D bones' poses (bone_poses_only),
    or 2D polygons dragged vertex by vertex (the outlines and holes of the body, bodies, bones and objects:
    the editor's 2D drafts on nodes moved by skelfem.mesh.morph). Cables and markers then keep their points
    in the cells they were found in (a preview's approximation; the release re-meshes)."""
    if bone_poses_only(ctx, changed):
        return True
    keys = set(changed) - {PREVIEW}
    return ctx.design.dim == 2 and PREVIEW in changed and bool(keys) and all(_polygon_key(k) for k in keys)


def _polygon_key(key: str) -> bool:
    parts = key.split(".")
    return key in ("body.outline", "body.holes") or (
        len(parts) == 3 and parts[0] in ("bodies", "bones", "objects") and parts[2] in ("outline", "holes"))


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
