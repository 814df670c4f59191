"""Free objects (2D): their rigid motion, weight, contact with the body and the "not held" verdict.

An object (``[[objects]]``, :mod:`skelfem.design.objects`) is meshed as its
own region, apart from the body (``object:<name>``). A rigid one's cells
carry no strain (Elasticity gives them no material) and its nodes follow
three rigid DOFs through the machinery of rigid bones
(:class:`.rigid.RigidBody`); an elastic one (``rigid = false``,
:class:`ElasticObject`) strains with its material's E and nu like the body,
and reports the rigid motion closest to its nodes' (Kabsch).
Its boundary is part of the mesh boundary, so grounds (:mod:`.grounds`,
:mod:`.friction`) push it and hold it by friction like the body.

Energy of an object o with nodes i (displacement u_i):

    Pi_o(u; a) = -a sum_i f_i . u_i + k_o / (2 n) sum_i |u_i|^2,

f_i = 1e-9 rho g t int phi_i dx its consistent nodal weights (rho in
kg/m^3, g in m/s^2, a the load factor), and a tether k_o (N/mm, summed over
its n nodes) to its rest place, ``tether`` = 1e-9 times the body's E t: far
below any contact stiffness, it only keeps the Newton matrix regular while
the object touches nothing. The verdict (``failure``): in an equilibrium
the tether's pull must be a negligible part (``held_tol``) of the forces
on the object (weight and contacts); if it is not (and the object has
moved beyond round-off), nothing holds the object and the solve reports
``no equilibrium: object NAME is not held``.

Contact between the body and the objects (and between objects) is the IPC
barrier of :mod:`.contact` on the same boundary polygon, with a collision
filter that lets only parts of different pieces (body, each object)
collide. Read-outs: ``objects.NAME`` (``position`` of the centroid,
``rotation`` in rad, ``displacement`` of the centroid, ``weight``) and
``contacts``: per pair of pieces in contact, the ``normal_force`` acting on
the first one (N, summed: opposite pads cancel) and ``normal_magnitude``,
the sum of the magnitudes of the barrier's nodal forces on the second
piece (N: what a pinch's friction limit mu sum N is made of), and
``min_distance``, the smallest distance between different pieces (mm,
asserted positive).
"""
from __future__ import annotations

from typing import Any

import ipctk
import numpy as np
from dolfinx import fem
from mpi4py import MPI

from ..mesh.geometry import object_tag_name
from .base import Context, Term
from .capabilities import Constraints, StepBounds, Verdict
from .contact import SelfContact, barrier_stiffness, fortran_array, piece_labels, piece_names
from .gravity import KG_PER_M3_TIMES_M_PER_S2
from .rigid import RigidBody, rotation_readout


def nodal_areas(V, cells: np.ndarray) -> np.ndarray:
    """int phi_i dx over the cells for every local node: areas in 2D, volumes in 3D.

    P1: a third (2D) or a quarter (3D) of each cell's measure at its vertices.
    P2 triangles: a third at each edge midpoint, the vertex functions
    integrating to zero; P2 tetrahedra: -1/20 at each vertex and 1/5 at each
    edge midpoint (the consistent loads of a uniform weight)."""
    npc = V.dofmap.dof_layout.num_dofs
    tdim = V.mesh.topology.dim
    nodes = V.dofmap.list.array.reshape(-1, npc)[cells]
    x = V.tabulate_dof_coordinates()[:, :tdim]
    edges = np.stack([x[nodes[:, k]] - x[nodes[:, 0]] for k in range(1, tdim + 1)], axis=2)
    measure = np.abs(np.linalg.det(edges)) / (2.0 if tdim == 2 else 6.0)
    out = np.zeros(len(x))
    if npc == tdim + 1:                                   # P1
        weights = np.full(tdim + 1, 1.0 / (tdim + 1))
    elif tdim == 2:                                       # P2 triangle: vertices 0, midpoints 1/3
        weights = np.r_[np.zeros(3), np.full(3, 1.0 / 3.0)]
    else:                                                 # P2 tetrahedron
        weights = np.r_[np.full(4, -1.0 / 20.0), np.full(6, 1.0 / 5.0)]
    np.add.at(out, nodes.ravel(), (measure[:, None] * weights[None]).ravel())
    return out


class RigidObject(Term, StepBounds, Constraints, Verdict):
    """One free rigid object: its weight, its tether, its kinematics and its read-out."""

    section = "objects"
    tether = 1e-9        # k_o / (E_body t)
    held_tol = 1e-3      # the tether may carry at most this share of the forces on the object
    step_limit = 0.25    # a Newton step moves no node of the object by more than this share of its size
    bounds_steps = True
    contact: Any = None   # the PieceContact of the pieces (build), and this object's piece in it
    piece = -1

    def __init__(self, ctx: Context, spec):
        self.ctx, self.name, self.spec = ctx, spec.name, spec
        tm, V, bs = ctx.tagged, ctx.V, ctx.bs
        design = ctx.design
        cells = tm.cell_tags.find(tm.tags[object_tag_name(spec.name)])
        self.nodes = fem.locate_dofs_topological(V, ctx.mesh.topology.dim, cells)
        owned = self.nodes[self.nodes < V.dofmap.index_map.size_local]
        self.dofs = owned[:, None] * bs + np.arange(bs)
        self.X = V.tabulate_dof_coordinates()[owned, :ctx.dim]
        self.body = RigidBody(spec.name, self.dofs, self.X, ctx.comm)
        t = float(ctx.thickness.value)
        w = nodal_areas(V, cells)[owned]
        self.w_area = w
        self.area = float(ctx.comm.allreduce(w.sum()))
        self.centroid0 = ctx.comm.allreduce(w @ self.X) / self.area
        self.w = KG_PER_M3_TIMES_M_PER_S2 * t * w                 # nodal volumes x (N/mm^3 per kg/m^3 m/s^2)
        self.rho = float(design.materials[spec.material].density or 0.0)
        self.g = np.zeros(ctx.dim) if design.gravity is None else np.asarray(design.gravity, float).copy()
        self._weights()
        self.factor = 0.0
        self.k = self.tether * barrier_stiffness(design) * t
        self.n = self.body.count
        self.size = spec.size

    def _weights(self) -> None:
        self.f = self.rho * self.w[:, None] * self.g                   # (k, dim) N at a = 1

    def rigid_body(self):
        return self.body

    def parameters(self) -> dict:
        out: dict = {f"materials.{self.spec.material}.density": self.rho}
        if self.ctx.design.gravity is not None:
            out["gravity.acceleration"] = self.g.copy()
        return out

    def set_parameter(self, key: str, value) -> None:
        if key == "gravity.acceleration":
            self.g = np.asarray(value, float).reshape(self.g.shape).copy()
        elif key == f"materials.{self.spec.material}.density":
            self.rho = float(value)
        else:
            raise KeyError(key)
        self._weights()

    def pattern(self) -> list:
        return [(self.nodes[i:i + 1], self.nodes[i:i + 1]) for i in range(len(self.nodes))]

    def set_factor(self, a: float) -> None:
        self.factor = float(a)

    def energy(self, u: np.ndarray) -> float:
        ub = u[self.dofs]
        return self._total(float(-self.factor * np.sum(self.f * ub) + 0.5 * self.k / self.n * np.sum(ub * ub)))

    def _total(self, local: float) -> float:
        """Pi is global: the sum over ranks of each one's owned nodes."""
        return self.ctx.comm.allreduce(local) if self.ctx.comm.size > 1 else local

    def gradient(self, u: np.ndarray):
        return self.dofs.ravel(), (-self.factor * self.f + self.k / self.n * u[self.dofs]).ravel()

    def hessian(self, u: np.ndarray) -> list:
        import scipy.sparse as sp
        d = self.dofs.ravel()
        return [(d, sp.identity(len(d), format="coo") * (self.k / self.n))]

    def max_step(self, u0: np.ndarray, p: np.ndarray) -> float:
        """alpha <= 1 such that alpha p moves no node of the object by more than step_limit x its size.

        A direction only the tether resists (the object touches nothing yet, or
        every contact node slips, where the exact friction Hessian has no
        stiffness along the slip) is as long as the tiny tether makes it: a
        trust region on the object keeps such steps from throwing it away."""
        reach = float(np.linalg.norm(p[self.dofs], axis=1).max(initial=0.0))
        reach = self.ctx.comm.allreduce(reach, op=MPI.MAX) if self.ctx.comm.size > 1 else reach
        limit = self.step_limit * self.size
        return 1.0 if reach <= limit else limit / reach

    def weight(self) -> np.ndarray:
        return self.ctx.comm.allreduce(self.f.sum(axis=0))

    def failure(self, model, converged: bool = True) -> str | None:
        """'no equilibrium: object NAME is not held' when the tether carries the object (converged), or
        when Newton gave up with the object gone further than its own size."""
        if any(getattr(t, "active", False) for t in model.terms_in("dynamics")):
            return None                         # in a run in time an object may fly: inertia holds it
        u = model.u.x.array
        pull = self.ctx.comm.allreduce((self.k / self.n * u[self.dofs]).sum(axis=0))
        loads = self.ctx.comm.allreduce(self._loads(model, u))
        moved = self.ctx.comm.allreduce(float(np.abs(u[self.dofs]).max(initial=0.0)), op=MPI.MAX)
        if not converged:
            return f"no equilibrium: object {self.name} is not held" if moved > self.size else None
        if np.linalg.norm(pull) > self.held_tol * loads and moved > 1e-9 * self.size:   # not round-off
            return f"no equilibrium: object {self.name} is not held"
        return None

    def verdict(self, model) -> str | None:
        """'no equilibrium: object NAME is not held' at a Newton iterate where the object falls free: its
        load pulls it, it has moved further than its own size from its rest place, and nothing is in its
        way (PieceContact.in_the_way: no other piece within dhat of the band it sweeps along its load, no
        ground ahead or within dhat). Only the tether could stop it, a million times below any support:
        Newton would go on falling a trust region per step until it gave up."""
        if self.contact is None or any(getattr(t, "active", False) for t in model.terms_in("dynamics")):
            return None
        load = self.factor * self.weight()
        size = float(np.linalg.norm(load))
        u = model.u.x.array
        moved = self.ctx.comm.allreduce(float(np.abs(u[self.dofs]).max(initial=0.0)), op=MPI.MAX)
        if not (size > 0.0 and moved > self.size):
            return None
        d = load / size
        if self.contact.in_the_way(u, self.piece, d) or self._ground_in_the_way(model, u, d):
            return None
        return f"no equilibrium: object {self.name} is not held"

    def _ground_in_the_way(self, model, u: np.ndarray, d: np.ndarray) -> bool:
        """Whether a ground lies ahead of the object along d (d . n < 0) or within dhat of its nodes."""
        from .grounds import Ground
        y = self.X + u[self.dofs]
        for g in model.terms_in("grounds"):
            if not isinstance(g, Ground):
                continue
            n = g.normal / np.linalg.norm(g.normal)
            low = self.ctx.comm.allreduce(float(((y - g.point) @ n).min(initial=np.inf)), op=MPI.MIN)
            if d @ n < 0.0 or low <= self.contact.dhat:
                return True
        return False

    def _loads(self, model, u: np.ndarray) -> float:
        """Sum of the magnitudes of the nodal forces on the object but the tether's: weight and contacts
        (at a rigid object's nodes the full gradient holds just these)."""
        g = model.full_gradient()[self.dofs] - self.k / self.n * u[self.dofs]
        return float(np.linalg.norm(g, axis=1).sum())

    def readout(self, model) -> dict:
        t, R = self.body.fit(model.u.x.array)
        c = self.centroid(model.u.x.array, t, R)
        return {self.name: {"position": c, "rotation": rotation_readout(R),
                            "displacement": c - self.centroid0, "weight": self.weight()}}

    def centroid(self, u: np.ndarray, t: np.ndarray, R: np.ndarray) -> np.ndarray:
        """The centroid at u: the rest centroid moved by the rigid motion (t, R)."""
        return self.centroid0 + t + (R - np.eye(self.ctx.dim)) @ (self.centroid0 - self.body.c0)


class ElasticObject(RigidObject):
    """A free elastic object: its tether as a rigid one's, its strain by Elasticity and its weight by
    Gravity (its region has its material, as the body's), and no rigid kinematics; its rotation is the
    closest rigid motion's. ``weight`` is still reported (and counted in the verdict)."""

    def rigid_body(self):
        return None

    def energy(self, u: np.ndarray) -> float:
        ub = u[self.dofs]
        return self._total(float(0.5 * self.k / self.n * np.sum(ub * ub)))

    def gradient(self, u: np.ndarray):
        return self.dofs.ravel(), (self.k / self.n * u[self.dofs]).ravel()

    def _loads(self, model, u: np.ndarray) -> float:
        """Its weight and the hand-written terms' nodal forces on it but the tether's (contacts, their
        friction): the full gradient would also hold the elastic forces, which balance them."""
        f = model.term_gradient(u)[self.dofs] - self.k / self.n * u[self.dofs] - self.factor * self.f
        return float(np.linalg.norm(f, axis=1).sum())

    def centroid(self, u: np.ndarray, t: np.ndarray, R: np.ndarray) -> np.ndarray:
        """The centre of mass at u: its nodes' positions weighted by their rest areas (exact for P1)."""
        y = self.X + u[self.dofs]
        return self.ctx.comm.allreduce(self.w_area @ y) / self.area


class PieceContact(SelfContact):
    """The IPC barrier between different pieces (the body, each object) of the mesh boundary."""

    section, name = "contacts", "pieces"

    def __init__(self, ctx: Context, objects: list, dhat: float, stiffness: float, project: bool = True):
        super().__init__(ctx.V, dhat, stiffness, float(ctx.thickness.value), project)
        self.pieces = piece_names(ctx.design)           # the bodies, then the objects
        self.bodies = len(ctx.design.bodies)
        self.objects = objects
        self._weights: Any = None     # boundary weights of the nodes (grounds' quadrature), on demand
        self.label = piece_labels(ctx, self.nodes)
        self.mesh.can_collide = ipctk.make_vertex_patches_filter(self.label)

    def can_couple(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The barrier acts between different pieces only (the body's own boundary never meets itself)."""
        return self.label[a] != self.label[b]

    def nodal_forces(self, model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (n, dim), barrier forces (n, dim) N, friction forces (n, dim) N) on every boundary node
        (rows as self.nodes; self.label tells the piece), for pictures of the contact forces."""
        u = model.u.x.array
        y = self.positions(u)
        c = self.collisions(y)
        normal = np.zeros_like(y)
        if len(c):
            normal = -self.t * np.asarray(self.barrier.gradient(c, self.mesh, fortran_array(y))).reshape(y.shape)
        friction = np.zeros_like(y)
        for term in model.terms_in("contacts"):
            if term is not self and hasattr(term, "vertex_forces"):
                friction += term.vertex_forces(u)
        return y, normal, friction

    def _on_grounds(self, model, u: np.ndarray) -> dict:
        """Per ground and object on it: the force the object exerts on the ground (normal, and friction
        if the ground has it), from the ground's nodal penalty forces on the object's nodes."""
        from .friction import GroundFriction, boundary_weights
        from .grounds import Ground
        if not any(isinstance(g, Ground) for g in model.terms_in("grounds")):
            return {}
        if self._weights is None:
            self._weights = boundary_weights(model.V)
        X = model.V.tabulate_dof_coordinates()[:, :self.bs]
        out = {}
        for ground in model.terms_in("grounds"):
            if not isinstance(ground, Ground):
                continue
            k = float(ground.parameters()[f"grounds.{ground.name}.stiffness"])
            friction = next((t for t in model.terms_in("grounds") if isinstance(t, GroundFriction)
                             and t.name == ground.name and t.nodal is not None), None)
            comm, owned = self.comm, model.V.dofmap.index_map.size_local
            for obj in self.objects:
                nodes = obj.nodes[(obj.nodes < owned)]                # each node counted by its owner
                nodes = nodes[self._weights[nodes] > 0]
                y = X[nodes] + u[(nodes[:, None] * self.bs + np.arange(self.bs))]
                N = comm.allreduce(float((k * self.t * self._weights[nodes]
                                          * np.maximum(-((y - ground.point) @ ground.normal), 0.0)).sum()))
                if not N > 0:
                    continue
                entry = {"between": [ground.name, obj.name], "normal_force": -N * ground.normal}
                if friction is not None:
                    fn, ff, slipping, Nf = friction.nodal
                    mine = np.isin(fn, nodes)
                    held, total = comm.allreduce(np.array([Nf[mine & ~slipping].sum(), Nf[mine].sum()]))
                    entry.update(friction_force=comm.allreduce(ff[mine].sum(axis=0)),
                                 sticking=float(held / total) if total > 0 else 1.0)
                out[f"{ground.name}|{obj.name}"] = entry
        return out

    def readout(self, model) -> dict:
        """Per pair of pieces in contact: the barrier's force on the first piece (the one named first);
        per ground and object on it, the object's force on the ground."""
        u = model.u.x.array
        y = self.positions(u)
        c = self.collisions(y)
        out = self._on_grounds(model, u)
        gap = self.min_distance(u)
        if not gap > 0.0:                               # the barrier keeps every accepted state apart
            raise AssertionError(f"pieces interpenetrate (distance {gap:g} mm)")
        for (i, j), force in self.pair_forces(y, c).items():
            a, b = self.pieces[i], self.pieces[j]
            on_a, on_b = self.label == i, self.label == j
            f = force[on_a].sum(axis=0)
            if np.linalg.norm(f) > 0:
                out[f"{a}|{b}"] = {"between": [a, b], "normal_force": f,
                                   "normal_magnitude": float(np.linalg.norm(force[on_b], axis=1).sum()),
                                   "min_distance": gap}
        return out

    def in_the_way(self, u: np.ndarray, piece: int, d: np.ndarray) -> bool:
        """Whether some facet of another piece may stop piece `piece` moving along d (unit): a facet whose
        bounding box, in coordinates across d, meets the piece's own widened by dhat, and that reaches
        beyond the piece's rear (along d) less dhat. Conservative: a piece touching another, or one
        beside it, is in the way."""
        y = self.positions(u)
        mine = self.label == piece
        others = self.facets[self.label[self.facets[:, 0]] != piece]
        if not mine.any() or not len(others):
            return bool(len(others))
        across = np.linalg.svd(d[None, :])[2][1:].T                      # (dim, dim - 1) orthonormal across d
        c, a = y @ across, y @ d
        lo, hi = c[mine].min(axis=0) - self.dhat, c[mine].max(axis=0) + self.dhat
        cf = c[others]                                                   # (m, dim, dim - 1)
        meets = (cf.max(axis=1) >= lo).all(axis=1) & (cf.min(axis=1) <= hi).all(axis=1)
        return bool((meets & (a[others].max(axis=1) >= a[mine].min() - self.dhat)).any())

    def pair_forces(self, y: np.ndarray, c) -> dict:
        """{(i, j), i < j: the barrier's nodal forces (n, dim) N of the collisions between pieces i and j},
        each collision's share taken from its own gradient (a node may touch two pieces at once)."""
        out: dict = {}
        edges, faces = self.mesh.edges, self.mesh.faces
        for coll in [*c.vv_collisions, *c.ev_collisions, *c.ee_collisions, *c.fv_collisions]:
            ids = np.array([v for v in coll.vertex_ids(edges, faces) if v >= 0])
            pieces = self.label[ids]
            pair = (int(pieces.min()), int(pieces.max()))
            if pair[0] == pair[1]:
                continue
            g = self.t * np.asarray(self.barrier.gradient(coll, coll.dof(y, edges, faces))).reshape(-1, y.shape[1])
            force = out.setdefault(pair, np.zeros_like(y))
            np.add.at(force, ids, -g[:len(ids)])
        return out


def build(ctx: Context) -> list[Term]:
    """The objects, and contact with friction between every two pieces (bodies, objects) if there are two."""
    from ..design.spec import DesignError
    d = ctx.design
    if len(d.bodies) + len(d.objects) < 2:
        return []
    objects = [(RigidObject if spec.rigid else ElasticObject)(ctx, spec) for spec in d.objects]
    contact = PieceContact(ctx, objects, d.contact.dhat, barrier_stiffness(d))
    for k, obj in enumerate(objects):
        obj.contact, obj.piece = contact, len(d.bodies) + k           # pieces: the bodies, then the objects
    d0 = contact.min_distance(np.zeros(len(ctx.u.x.array)))
    if d0 <= d.contact.dhat:
        raise DesignError(f"{d.source}: contact.dhat: {d.contact.dhat:g} mm is not below the smallest rest "
                          f"distance between the bodies and objects ({d0:.3g} mm); lower dhat or move them apart")
    from .object_friction import ObjectFriction
    return objects + [contact, ObjectFriction(ctx, contact, objects)]
