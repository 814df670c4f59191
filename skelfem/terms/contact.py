"""Self-contact: the IPC barrier between parts of the body's boundary, in 2D and 3D; its boundary machinery
serves contact between pieces too (:mod:`.objects`).

In 3D the collision mesh is the boundary's triangles (a P2 triangle split
into four through its edge midpoints) with their edges, and the same
barrier, filter and collision-free steps apply (``boundary_facets``). The
weights w_k below are then areas (ipctk's area weighting: a third of the
areas of the triangles around a vertex or an edge) and t = 1, so Pi_c is a
quadrature of a surface integral in N mm as in 2D. ipctk leaves out the
pairs that share a vertex (neighbouring triangles); the smallest rest
distance is then between faces across a notch or a slot, or between a
vertex and a face two triangles away on a concave edge, and dhat must stay
below it (``build``). The rest of this note describes the 2D polygon.

The collision mesh is the boundary polygon of the mesh (outline and holes):
its vertices are the boundary nodes of the displacement space, x = X + u,
and its edges the boundary facets. For P1 these are the mesh's boundary
vertices and edges; for P2 every boundary facet is split at its midpoint
node, so the polygon interpolates the (slightly curved) quadratic boundary
through all its nodes -- the contact surface is that polygon, an O(h^2)
approximation of the P2 boundary.

With d_k the distance of collision k (vertex-edge pairs within dhat, found by
ipctk), w_k its weight (half the vertex's boundary length, so the sum is a
quadrature of a boundary integral) and the clamped log barrier on squared
distances, b(s) = -(s - dhat^2)^2 ln(s / dhat^2) for s < dhat^2 (ipctk's
"physical" scaling divides it by dhat^3, a length),

    Pi_c(u) = t kappa sum_k w_k b(d_k^2) / dhat^3,

kappa in MPa (default: the body's Young's modulus), t the slab thickness (1 in 3D).
Pi_c is +inf at contact, so a state reached from an intersection-free one
along a collision-free path never interpenetrates: every Newton step is
limited before the line search starts to 0.8 times the time of first contact
along the straight path x0 + s p (continuous collision detection), so no
trial state comes closer than a fifth of the gap it had to close.

Gradient and Hessian come from ipctk on the collision mesh's DOFs and are
mapped to the space's DOFs through one index array (node * bs + component);
the Hessian is projected to positive semi-definite per collision (ipctk's
CLAMP) for Newton, and `project=False` gives the exact one (FD tests,
sensitivities). The projection keeps Newton's directions descent ones while
contacts come and go, at the price of a linearly converging tail once the
faces touch; the exact Hessian converges quadratically there but may
wander before. Self-contact (``settle=True``) takes the exact Hessian once
the contacts have settled: when the collisions (the same primitive pairs)
are those of the Hessian before it in the same load (or time) step. On
finger_knuckles.toml that cut the solve from 91 to 44 Newton iterations
(its third load step, where the notches close, from 50 to 11), on the 3D
finger_knuckles3d.toml from 98 to 56 (studies/knuckle_contact3d.py), and a
3D notched strip pulled 8 mm, whose projected tail did not converge in 50
iterations per step (752 in all, every step cut), converges in 39
(tests/test_contact_3d.py). Contact between pieces keeps the projected
Hessian.

Contact pairs change between iterations, and the matrix pattern must hold
every node pair a collision couples. It holds the pairs that can couple
soon, not the whole boundary x boundary block (which in 3D made every
factorisation dense): every facet's own nodes, and the boundary nodes
within reach of each other (a collision's nodes lie within dhat plus two
edge lengths of each other). When a Hessian needs a pair outside (the
pieces moved on, or friction's lagged anchors), the term adds it with the
pairs within reach where the nodes are now and says so (``outgrown``);
the Newton solver then makes a new matrix and assembles again
(``PatternOutgrown``). The pattern only grows.

Read-outs (``contact.self``): ``min_distance``, the smallest distance
between non-adjacent boundary parts (mm, asserted positive), and
``normal_magnitude``, half the sum of the magnitudes of the barrier's nodal
forces (N; each contact pushes both its faces, so for one contact patch
this is the force pressing its faces together; their vector sum is zero).
solution.xdmf holds the nodal forces as ``contact_normal_force``
(:func:`skelfem.io.xdmf.contact_fields`). There is no friction between
parts of one body.

Under MPI every rank holds the whole boundary polygon (global node numbers,
gathered once; the positions through a DofGather at each call) and computes
the same barrier; each rank adds the rows it owns, and the collision-free
step is the smallest over ranks.
"""
from __future__ import annotations

from typing import Any

import ipctk
import numpy as np
import scipy.sparse as sp
from dolfinx import fem as dolfinx_fem
from dolfinx import mesh as dmesh
from mpi4py import MPI
from scipy.spatial import cKDTree

from ..mesh.geometry import body_tag_name, object_tag_name
from .base import Context, Term
from .capabilities import History, StepBounds

CCD_TOLERANCE = 1e-3    # continuous collision detection brackets the time of first contact to this x dhat
# Tight Inclusion's breadth-first search of one query may run this many refinements; past them it returns
# the earliest time it could not exclude (conservative: never past first contact). Its default, 1e7, let
# one grazing face-vertex query of a 3D gripper run for over an hour and grow to 3 GB.
CCD_MAX_ITERATIONS = 100_000
PATTERN_REACH = 2.0     # the matrix pattern holds node pairs that may collide after moving this x dhat more


def boundary_facets(V) -> tuple[np.ndarray, np.ndarray]:
    """Boundary nodes of V (local node indices, sorted) and the boundary's simplices through them.

    A boundary facet's nodes come from its cell's DOFs through the element's
    facet closure (vertices first, then the P2 midpoints), all vectorised.
    2D: edges, a P2 edge split at its midpoint node into two. 3D: triangles,
    a P2 triangle split into four through its three edge midpoints (each
    midpoint matched to its pair of vertices by position: the mesh is
    straight-sided).
    """
    mesh = V.mesh
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    mesh.topology.create_connectivity(tdim, tdim - 1)
    facets = dmesh.exterior_facet_indices(mesh.topology)
    f2c = mesh.topology.connectivity(tdim - 1, tdim)
    cells = f2c.array[f2c.offsets[facets]]                        # the one cell of a boundary facet
    c2f = mesh.topology.connectivity(tdim, tdim - 1).array.reshape(-1, tdim + 1)
    local = np.argmax(c2f[cells] == facets[:, None], axis=1)      # facet's local index in that cell
    layout = V.dofmap.dof_layout
    closure = np.array([layout.entity_closure_dofs(tdim - 1, i) for i in range(tdim + 1)])
    cell_dofs = V.dofmap.list.array.reshape(-1, layout.num_dofs)
    fdofs = cell_dofs[cells[:, None], closure[local]]             # (n_facets, tdim or more)
    if fdofs.shape[1] == tdim:
        pieces = fdofs
    elif tdim == 2:                                               # P2: a -> midpoint -> b
        pieces = np.vstack([fdofs[:, [0, 2]], fdofs[:, [2, 1]]])
    else:                                                         # P2 triangle: four
        x = V.tabulate_dof_coordinates()
        v, m = fdofs[:, :3], fdofs[:, 3:]
        pairs = np.array([[1, 2], [0, 2], [0, 1]])                # the edge opposite each vertex
        mids = 0.5 * (x[v[:, pairs[:, 0]]] + x[v[:, pairs[:, 1]]])              # (n, 3 edges, 3)
        which = np.argmin(np.linalg.norm(mids[:, :, None] - x[m][:, None], axis=3), axis=2)
        o = np.take_along_axis(m, which, axis=1)                  # o[:, i]: the midpoint opposite vertex i
        pieces = np.vstack([np.column_stack([v[:, 0], o[:, 2], o[:, 1]]), np.column_stack([v[:, 1], o[:, 0], o[:, 2]]),
                            np.column_stack([v[:, 2], o[:, 1], o[:, 0]]), o])
    comm = mesh.comm
    if comm.size > 1:                    # global node numbers, the whole boundary on every rank
        imap = V.dofmap.index_map
        pieces = imap.local_to_global(pieces.ravel().astype(np.int32)).reshape(pieces.shape)
        every = np.vstack(comm.allgather(pieces))
        _, first = np.unique(np.sort(every, axis=1), axis=0, return_index=True)   # shared facets once
        pieces = every[np.sort(first)]
    nodes = np.unique(pieces)
    return nodes.astype(np.int64 if comm.size > 1 else np.int32), np.searchsorted(nodes, pieces).astype(np.int32)


def boundary_coordinates(V, nodes: np.ndarray) -> np.ndarray:
    """Rest coordinates of boundary nodes: local indices in serial, global numbers (every rank) under MPI."""
    x = V.tabulate_dof_coordinates()[:, :V.mesh.geometry.dim]
    comm = V.mesh.comm
    if comm.size == 1:
        return x[nodes]
    imap = V.dofmap.index_map
    n = imap.size_local
    glob = imap.local_to_global(np.arange(n, dtype=np.int32))
    mine = np.isin(glob, nodes)
    X = np.zeros((len(nodes), x.shape[1]))
    X[np.searchsorted(nodes, glob[mine])] = x[:n][mine]
    comm.Allreduce(MPI.IN_PLACE, X, op=MPI.SUM)            # each node owned by one rank
    return X


def fortran_array(a) -> np.ndarray:
    return np.asfortranarray(a, dtype=float)


class SelfContact(Term, StepBounds, History):
    """The IPC barrier term over the body's boundary."""

    section, name = "contact", "self"
    bounds_steps = True

    def __init__(self, V, dhat: float, stiffness: float, thickness: float = 1.0, project: bool = True,
                 settle: bool = False):
        # One thread: ipctk's parallel sums (barrier, friction, distances) then add in one order, so the same
        # input gives the same answer to the last bit. With two threads the order varied from run to run and
        # so did a path near a stick/slip threshold (a 3D cube at its friction limit took 9 s to 5 min to be
        # found "not held"). skelfem runs its parallelism as MPI ranks and sweep processes instead. Set here,
        # where contact is built, not at import: importing skelfem changes nothing global.
        ipctk.set_num_threads(1)
        from ..mesh.points import DofGather
        self.bs = V.dofmap.index_map_bs
        self.nodes, self.facets = boundary_facets(V)        # under MPI: global numbers, on every rank
        self.dim = V.mesh.topology.dim
        # 2D: the facets are the collision mesh's edges; 3D: its faces, with their edges
        self.edges = self.facets if self.dim == 2 else np.asarray(ipctk.edges(self.facets), np.int32)
        self.dofs = (self.nodes[:, None] * self.bs + np.arange(self.bs)).ravel()   # unrolled, node-major
        self.X = boundary_coordinates(V, self.nodes)
        self.comm = V.mesh.comm
        self.gather = DofGather(V, self.dofs) if self.comm.size > 1 else None
        self.dhat, self.kappa, self.t = float(dhat), float(stiffness), float(thickness)
        self.project = project
        self.settle = settle      # exact Hessian once the collisions have settled (see the module note)
        self._settled: Any = None   # the collisions of the last Hessian in this load step
        self.approach = 0.8       # fraction of the way to first contact a step may go
        faces = [] if self.dim == 2 else [np.asfortranarray(self.facets)]
        self.mesh = ipctk.CollisionMesh(fortran_array(self.X), np.asfortranarray(self.edges), *faces)
        self.barrier = ipctk.BarrierPotential(self.dhat, self.kappa, True)
        # the time of first contact is bracketed conservatively (never past it) to CCD_TOLERANCE x dhat:
        # ipctk's default of 1e-6 (mm) took seconds for a face landing flat on a face
        self.ccd = ipctk.TightInclusionCCD(tolerance=CCD_TOLERANCE * self.dhat, max_iterations=CCD_MAX_ITERATIONS)
        self.reach = PATTERN_REACH  # x dhat: how far the pattern looks ahead (math.inf: every boundary pair)
        self.outgrown = False       # a Hessian needed node pairs the pattern had not (see the module note)
        self._pairs: Any = None     # the node pairs the pattern holds (on first use: _near_pairs at rest)

    # -- the matrix pattern ----------------------------------------------------------------------
    def can_couple(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Whether boundary nodes a and b (indices into self.nodes) may meet in a collision."""
        return np.ones(len(a), dtype=bool)

    def _near_pairs(self, y: np.ndarray) -> np.ndarray:
        """Sorted keys i * n + j (indices into self.nodes, both orders, i = j too) of the node pairs a
        collision may couple before the nodes move a further `reach` x dhat: each facet's own
        nodes, and those closer than dhat plus two of the longest edges plus that reach."""
        n = len(self.nodes)
        f = self.facets
        i, j = np.repeat(f, f.shape[1], axis=1).ravel(), np.tile(f, f.shape[1]).ravel()
        longest = float(np.linalg.norm(y[self.edges[:, 0]] - y[self.edges[:, 1]], axis=1).max(initial=0.0))
        close = cKDTree(y).query_pairs((1 + self.reach) * self.dhat + 2 * longest, output_type="ndarray")
        close = close[self.can_couple(close[:, 0], close[:, 1])]
        keys = np.concatenate([i.astype(np.int64) * n + j, close[:, 0].astype(np.int64) * n + close[:, 1],
                               close[:, 1].astype(np.int64) * n + close[:, 0]])
        return np.unique(keys)

    def require(self, u: np.ndarray, H: sp.coo_matrix) -> None:
        """Make the pattern hold a Hessian block over self.dofs; if it did not, grow it by H's node pairs
        and those within reach at u, and mark the term ``outgrown`` (the matrix must be made anew)."""
        n, pairs = len(self.nodes), self.pairs()
        keys = np.unique(H.row.astype(np.int64) // self.bs * n + H.col // self.bs)
        at = np.minimum(np.searchsorted(pairs, keys), max(len(pairs) - 1, 0))
        if len(keys) and (not len(pairs) or not np.array_equal(pairs[at], keys)):
            self._pairs = np.union1d(pairs, np.union1d(keys, self._near_pairs(self.positions(u))))
            self.outgrown = True

    def widen(self, reach: float) -> None:
        """Let the pattern look `reach` x dhat ahead from the next matrix on (math.inf: the whole boundary
        x boundary block, no growth; to measure what the growing pattern saves)."""
        self.reach, self._pairs, self.outgrown = float(reach), None, True

    def pairs(self) -> np.ndarray:
        """The node pairs the pattern holds (keys as _near_pairs'; at first, those near at rest)."""
        if self._pairs is None:
            self._pairs = self._near_pairs(self.X)
        return self._pairs

    # -- geometry ------------------------------------------------------------------------
    def boundary_values(self, u: np.ndarray) -> np.ndarray:
        """u on the boundary DOFs (self.dofs), from a local array (gathered from every rank under MPI)."""
        return u[self.dofs] if self.gather is None else self.gather(u)

    def positions(self, u: np.ndarray) -> np.ndarray:
        """Current boundary node positions x = X + u, (n_nodes, dim)."""
        return self.X + self.boundary_values(u).reshape(-1, self.bs)

    def collisions(self, y: np.ndarray, dhat: float | None = None) -> ipctk.NormalCollisions:
        c = ipctk.NormalCollisions()
        c.use_area_weighting = True
        c.build(self.mesh, fortran_array(y), self.dhat if dhat is None else float(dhat))
        return c

    def min_distance(self, u: np.ndarray) -> float:
        """Smallest distance between non-adjacent boundary parts that may collide (the mesh's filter: for
        contact between pieces, parts of different pieces), mm (inf if none).

        ipctk 1.6's NormalCollisions.compute_minimum_distance returns the
        *squared* distance (checked against a brute-force distance in the
        tests), hence the square root.
        """
        return self.nearest(self.positions(u))

    def nearest(self, y: np.ndarray) -> float:
        """min_distance at positions y: the collisions within r = dhat, 4 dhat, 16 dhat ... (each build
        holds every pair closer than r, so the first one that finds any has the smallest), up to the
        boundary's extent. One build over the extent held every pair of a 3D finger's 1,528 boundary
        nodes and 3,052 triangles (13 s); growing r finds its 0.8 mm in two builds (gripper3d.toml's
        pieces at rest: 5.9 s to 0.2 s)."""
        reach = float(np.linalg.norm(np.ptp(y, axis=0)))
        r = self.dhat
        while True:
            c = self.collisions(y, min(r, reach))
            if len(c):
                return float(np.sqrt(c.compute_minimum_distance(self.mesh, fortran_array(y))))
            if r >= reach:
                return float("inf")
            r *= 4.0

    def intersects(self, u: np.ndarray) -> bool:
        return bool(ipctk.has_intersections(self.mesh, fortran_array(self.positions(u))))

    # -- energy term interface -----------------------------------------------------------------
    def set_factor(self, a: float) -> None:
        """Contact does not depend on the load factor; a new load step starts with projected Hessians."""
        self._settled = None

    def end_step(self, model) -> None:
        """So does the next time step of a run in time (which sets no load factor)."""
        self._settled = None

    def energy(self, u: np.ndarray) -> float:
        y = self.positions(u)
        return self.t * float(self.barrier(self.collisions(y), self.mesh, fortran_array(y)))

    def gradient(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        y = self.positions(u)
        g = self.barrier.gradient(self.collisions(y), self.mesh, fortran_array(y))
        return self.dofs, self.t * np.asarray(g).ravel()

    def hessian(self, u: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """One sparse block over the boundary DOFs, its entries where collisions couple them (none if no
        contact)."""
        y = self.positions(u)
        c = self.collisions(y)
        if len(c) == 0:
            self._settled = None
            return []
        exact = not self.project
        if self.settle and self.project:
            pairs = collision_keys(c, self.mesh)
            exact, self._settled = pairs == self._settled, pairs
        method = ipctk.PSDProjectionMethod.NONE if exact else ipctk.PSDProjectionMethod.CLAMP
        H = sp.coo_matrix(self.barrier.hessian(c, self.mesh, fortran_array(y), method))
        H.sum_duplicates()
        self.require(u, H)
        return [(self.dofs, self.t * H)]

    def pattern(self) -> list:
        """Node blocks the Hessian may fill: one (node, the nodes it may couple with) per boundary node
        (see the module note)."""
        rows, cols = np.divmod(self.pairs(), len(self.nodes))
        starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]]) if len(rows) else np.zeros(0, int)
        return [(self.nodes[rows[k]:rows[k] + 1], self.nodes[c]) for k, c in zip(starts, np.split(cols, starts[1:]))]

    def nodal_forces(self, model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (n, dim), barrier forces (n, dim) N, friction forces (n, dim): none between parts of
        one body) on every boundary node (rows as self.nodes), for the per-node contact fields."""
        y = self.positions(model.u.x.array)
        c = self.collisions(y)
        normal = np.zeros_like(y)
        if len(c):
            normal = -self.t * np.asarray(self.barrier.gradient(c, self.mesh, fortran_array(y))).reshape(y.shape)
        return y, normal, np.zeros_like(y)

    def readout(self, model) -> dict:
        """min_distance (mm, asserted positive: the barrier keeps every accepted state apart) and
        normal_magnitude (N, see the module note)."""
        gap = self.min_distance(model.u.x.array)
        if not gap > 0.0:
            raise AssertionError(f"the body passes through itself (distance {gap:g} mm)")
        _, normal, _ = self.nodal_forces(model)
        return {self.name: {"min_distance": gap, "normal_magnitude": 0.5 * float(np.linalg.norm(normal, axis=1).sum())}}

    sweeps_steps = True

    def max_step(self, u0: np.ndarray, p: np.ndarray) -> float:
        """alpha in [0, 1] such that x0 + s p, s in [0, alpha], keeps clear of contact.

        1 if the whole step is collision-free, else `approach` times ipctk's
        collision-free step size (the time of first contact, conservatively).
        """
        y0 = self.positions(u0)
        y1 = y0 + self.boundary_values(p).reshape(-1, self.bs)
        toi = float(ipctk.compute_collision_free_stepsize(self.mesh, fortran_array(y0), fortran_array(y1),
                                                          narrow_phase_ccd=self.ccd))
        if self.gather is not None:                          # one step for every rank
            toi = self.comm.allreduce(toi, op=MPI.MIN)
        return toi if toi >= 1.0 else self.approach * toi

    def admissible(self, u: np.ndarray) -> bool:
        return not self.intersects(u)


def build(ctx: Context) -> list[Term]:
    """The self-contact term if the design asks for it; refuses designs it cannot honour."""
    from ..design.spec import ENERGY_LINE_SEARCHES, DesignError
    d = ctx.design
    if not d.contact.self_contact:
        return []
    where = f"{d.source}: contact.self"
    if d.solver.line_search not in ("auto", *ENERGY_LINE_SEARCHES):   # a guard: design.py refuses it when read
        raise DesignError(f"{where}: self-contact needs solver.line_search = \"energy\" or \"curved\" "
                          f"(got {d.solver.line_search!r}): only it limits steps to collision-free ones")
    contact = SelfContact(ctx.V, d.contact.dhat, barrier_stiffness(d), float(d.thickness), settle=True)
    if len(d.bodies) + len(d.objects) > 1:     # contacts between pieces are terms/objects.py's
        contact.mesh.can_collide = ~ipctk.make_vertex_patches_filter(piece_labels(ctx, contact.nodes))
    d0 = contact.min_distance(np.zeros(len(ctx.u.x.array)))
    if d0 <= d.contact.dhat:
        raise DesignError(f"{d.source}: contact.dhat: {d.contact.dhat:g} mm is not below the "
                          f"smallest rest distance between boundary parts ({d0:.3g} mm); "
                          "lower dhat or coarsen the mesh")
    return [contact]


def collision_keys(c: ipctk.NormalCollisions, mesh: ipctk.CollisionMesh) -> frozenset:
    """The collisions as the vertex ids of their primitive pairs (one set: the same contacts, any order)."""
    groups = (c.vv_collisions, c.ev_collisions, c.ee_collisions, c.fv_collisions)
    return frozenset(tuple(coll.vertex_ids(mesh.edges, mesh.faces)) for group in groups for coll in group)


def barrier_stiffness(design) -> float:
    """kappa, MPa: the stiffest soft body's Young's modulus."""
    return max(float(design.materials[b.material].E) for b in design.bodies)


def piece_names(design) -> list[str]:
    """The pieces that touch each other: every body, then every object, by name."""
    return [b.name for b in design.bodies] + [o.name for o in design.objects]


def piece_labels(ctx: Context, nodes: np.ndarray) -> np.ndarray:
    """For local nodes: the index in piece_names of the piece each lies on (k-th body, then objects)."""
    tm, V, design = ctx.tagged, ctx.V, ctx.design
    label = np.zeros(len(nodes), np.int32)
    regions = [body_tag_name(b) for b in design.bodies] + [object_tag_name(o.name) for o in design.objects]
    for k, region in enumerate(regions):
        cells = tm.cell_tags.find(tm.tags[region])
        mine = dolfinx_fem.locate_dofs_topological(V, ctx.mesh.topology.dim, cells)
        if ctx.comm.size > 1:                 # nodes are global numbers; each rank marks those it has
            mine = V.dofmap.index_map.local_to_global(mine.astype(np.int32))
        label[np.isin(nodes, mine)] = k
    if ctx.comm.size > 1:
        ctx.comm.Allreduce(MPI.IN_PLACE, label, op=MPI.MAX)
    return label


# -- measuring interpenetration (for states reached without contact) -------------------------
def crossing_edges(y: np.ndarray, edges: np.ndarray) -> int:
    """Number of pairs of non-adjacent boundary edges that cross, vectorised over pairs."""
    a, b = y[edges[:, 0]], y[edges[:, 1]]
    i, j = np.triu_indices(len(edges), k=1)
    share = (edges[i][:, :, None] == edges[j][:, None, :]).any(axis=(1, 2))
    i, j = i[~share], j[~share]

    def orient(p, q, r):
        return np.sign((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))
    cross = ((orient(a[i], b[i], a[j]) * orient(a[i], b[i], b[j]) < 0)
             & (orient(a[j], b[j], a[i]) * orient(a[j], b[j], b[i]) < 0))
    return int(np.count_nonzero(cross))


def winding_numbers(points: np.ndarray, y: np.ndarray, edges: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """Winding number of the oriented boundary edges around each point (sum of signed angles)."""
    out = np.empty(len(points), dtype=int)
    for s in range(0, len(points), chunk):          # chunks of points bound the memory
        q = points[s:s + chunk, None]
        a, b = y[edges[:, 0]][None] - q, y[edges[:, 1]][None] - q
        ang = np.arctan2(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0], np.einsum("pek,pek->pe", a, b))
        out[s:s + chunk] = np.rint(ang.sum(axis=1) / (2 * np.pi))
    return out


def oriented_edges(X: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Edges reoriented so that every boundary loop runs with the body on its left.

    An edge is flipped when the point a little to its left lies outside the
    rest body (winding number 0 with the edges as given, loops closed).
    """
    mid = 0.5 * (X[edges[:, 0]] + X[edges[:, 1]])
    t = X[edges[:, 1]] - X[edges[:, 0]]
    left = mid + 1e-3 * np.column_stack([-t[:, 1], t[:, 0]])
    inside = _inside_rest(left, X, edges)
    return np.where(inside[:, None], edges, edges[:, ::-1])


def _inside_rest(points, X, edges) -> np.ndarray:
    """Even-odd rule on the unoriented rest boundary: inside the body or not."""
    a, b = X[edges[:, 0]], X[edges[:, 1]]
    py = points[:, 1][:, None]
    straddle = (a[None, :, 1] > py) != (b[None, :, 1] > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = a[None, :, 0] + (py - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / (b[None, :, 1] - a[None, :, 1])
    hits = straddle & (xc > points[:, 0][:, None])
    return (hits.sum(axis=1) % 2) == 1


def overlap_area(y: np.ndarray, edges_ccw: np.ndarray, box: np.ndarray, n: int = 200) -> float:
    """Area covered twice by the deformed body inside box [[x0, y0], [x1, y1]], mm^2.

    The winding number of the deformed boundary (loops oriented with the body
    on the left) counts how many layers of the body cover a point; where it is
    2 or more the body has passed through itself. Sampled on an n x n grid.
    """
    (x0, y0), (x1, y1) = box
    gx, gy = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n))
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    w = winding_numbers(pts, y, edges_ccw)
    cell = (x1 - x0) * (y1 - y0) / (n - 1) ** 2
    return float(np.count_nonzero(w >= 2) * cell)
