"""Coulomb friction between pieces (bodies, objects), anchored on the other piece's surface.

Written below for 2D (edges, a scalar slip); in 3D the anchor is a point of
a boundary triangle in barycentric coordinates b, T the triangle's
orthonormal tangent basis (3 x 2) and the slip d = T^T (y_i - sum_k b_k y_k)
a 2-vector, with r = |d| in the slider below (a slipping node then keeps the
stiffness F / r across its slip); a contact that forms during a solve is
anchored at once (``contact_event``).

The body's boundary nodes touch the objects' boundary edges through the IPC
barrier (:class:`.objects.PieceContact`). A body node i in contact sticks
to a point of an object edge (a, b): the *anchor*, at the edge parameter
s_i, which moves with the object. With T_i the edge's unit tangent (lagged,
like the normal force) the tangential slip of the node is

    d_i = T_i . (y_i - (1 - s_i) y_a - s_i y_b),

linear in the positions of the three nodes, and the node has the same
dissipation potential as on a ground (:mod:`.friction`): a Coulomb slider
of strength F_i = mu N_i regularised over the slip length eps,

    e_i = F_i d_i^2 / (2 eps)      if |d_i| <= eps,     F_i (|d_i| - eps / 2) otherwise,

with N_i the barrier's force on node i (lagged and iterated to a fixed
point with the solver, ``update_lag``; half the magnitude of the barrier's
nodal force, each side of a contact carrying half), mu the pair's coefficient
(``[contact.pairs]``, else ``[contact] friction``). After each accepted step
the return map slides the anchor of a slipping node along the object's
boundary to eps behind it (onto the next edge past an edge's end), a
sticking node keeps it, a node that has left the barrier's reach loses it
and a node that enters it is anchored where it is. As on grounds, a step's
first solve holds every anchored node by a spring (the last lag's
stiffness mu N_i / eps, so that it starts where the last step ended; a new
contact's E t w_i / eps, which keeps it inside the sticking zone, where
Newton converges fast) until the lag gives its N, and mu_s drops to mu_k once a node has slipped
by more than D_c.

Newton uses the exact Hessian (zero along the slip of a slipping node in
2D). ``project = True`` replaces it with the secant stiffness F_i / |d_i|
(positive, like self-contact's projected barrier Hessian); measured on the
pinch near its limit it is ten times slower (359 Newton iterations against
31) and it slows a sliding object to a crawl, so it is off.

Every boundary vertex of a piece (the body, each object) anchors on the
edges of the other pieces, so friction acts both where the body's nodes
press on an object's side and where an object's corner presses into the
body; N_i is half the magnitude of the barrier's nodal force on vertex i,
so the two sides of one contact share its strength mu N (counted once in
all). An attribution by collision type (the vertex of a vertex-edge pair)
jumps when two facing nodes swap roles, and the lag then cycles between
two states (measured on the gripper: a 2-cycle of period 2 rounds that
never ended); the nodal force is continuous in the positions. Pairs of objects rub too (their coefficient
from their materials).

Landing (static solves, 2D and 3D). An object that touches no other piece
when a step begins lands in it: a contact it makes during the solve is
taken up at once (``contact_event``), anchored where it formed (only a
vertex that faces the other piece's facet), held stuck until the lag gives
its N, and then anchored again where it settled in the barrier
(``_settle``). The object meets its support with no slip and is held
unless its tangential load exceeds mu N (the guide's Objects and friction,
Landing). Other contacts keep the rules above.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

from .base import Term
from .capabilities import ContactEvents, History, Lagged, StickAnchors
from .contact import barrier_stiffness, fortran_array
from .facets import closest_facet, closest_on_facets, plane_coordinates, tangents


class ObjectFriction(Term, History, Lagged, ContactEvents, StickAnchors):
    """Friction of every boundary vertex of each piece against the other pieces' boundary facets."""

    section, name = "contacts", "friction"
    slip_length = 1e-6      # eps, as a fraction of the body's size
    project = False         # True: Newton's Hessian of a slipping node is its secant F / |d| (exact: 0 along d)
    breakaway = 1e-4        # D_c, as a fraction of the body's size
    candidates = 16         # 3D: facets of each other piece tried per vertex (nearest by centroid)
    tie_break = 1e-3        # facets ranked by distance + this x its part along the facet (see _closest)
    facing_reach = 1e-2     # a vertex faces a facet if its projection lies on it or this x dhat beside it at most
    lag_step = 1e-7         # the barrier's N(u) is smooth: a larger step than a ground's, less round-off
    history_fields = ("facet", "b", "T", "N", "fresh", "sliding", "trial", "run", "_report", "_relax",
                      "_lag_change", "_N_step", "_y0", "_start_facet", "_landing")

    def __init__(self, ctx, contact, objects):
        design = ctx.design
        self.u_fn = ctx.u
        self.c = contact
        self.gather = contact.gather
        self.t = contact.t
        self.bs = dim = contact.bs
        # 3D: a contact that forms during a solve is anchored at once (contact_event); 2D: when the solve
        # ends (update_lag). In 2D anchoring at once made a box dropped on a box lose the upper one.
        self.anchor_during_solve = dim == 3
        X = contact.X
        size = float(np.linalg.norm(np.ptp(X, axis=0)))
        self.eps, self.dc = self.slip_length * size, self.breakaway * size
        self.body_vertices = np.arange(len(X))               # every boundary vertex (body and objects) ...
        self.vertex_piece = contact.label                    # ... of its piece, anchored on other pieces' facets
        facets = contact.facets
        self.facets = facets                                 # (m, dim) vertex indices: every boundary facet
        self.facet_piece = contact.label[facets[:, 0]]
        mats = [b.material for b in design.bodies] + [o.spec.material for o in objects]
        coeff = [[design.friction.between(a, b) for b in mats] for a in mats]
        self.mu_k_pair = np.array([[c.kinetic for c in row] for row in coeff])
        self.mu_s_pair = np.array([[c.static for c in row] for row in coeff])
        np.fill_diagonal(self.mu_k_pair, 0.0)                # a piece does not rub on itself here
        np.fill_diagonal(self.mu_s_pair, 0.0)
        listed = [[frozenset((a, b)) in design.friction.pairs for b in mats] for a in mats]
        self.default_pair = ~np.array(listed, bool) & ~np.eye(len(mats), dtype=bool)   # [contact]'s pairs
        self.default = design.friction.default
        # the vertices' boundary weights (their share of the facets' measures): the fresh springs' areas
        edges = X[facets[:, 1:]] - X[facets[:, :1]]
        measure = (np.linalg.norm(edges[:, 0], axis=1) if dim == 2
                   else 0.5 * np.linalg.norm(np.cross(edges[:, 0], edges[:, 1]), axis=1))
        w = np.zeros(len(X))
        np.add.at(w, facets.ravel(), np.repeat(measure / dim, dim))
        self.w = w
        self._facet_size = float(np.linalg.norm(edges, axis=-1).max(initial=1.0))   # the longest facet edge
        self.k_fresh = barrier_stiffness(design) * self.t / self.eps      # stuck within eps: N/mm per mm
        n = len(self.body_vertices)
        self.facet = np.full(n, -1)                          # anchor facet (row of facets), -1: none
        self.b = np.zeros((n, dim))                          # the anchor's barycentric coordinates on it
        self.T = np.zeros((n, dim, dim - 1))                 # lagged tangent basis of the anchor facet
        self.N = np.zeros(n)                                 # lagged normal force
        self.fresh = np.zeros(n, bool)
        self.sliding = np.zeros(n, bool)
        self.trial = np.zeros(n, bool)
        self.run = np.zeros(n)
        self._report = None
        self._relax, self._lag_change = 1.0, None        # the lag's relaxation (update_lag)
        self._N_step = self.N.copy()                         # N at the last accepted step
        self._y0 = contact.X.copy()                          # vertex positions at the step's start
        self._start_facet = self.facet.copy()                 # the anchors the step started with
        self._landing = np.zeros(len(contact.pieces), bool)  # objects that start the step touching nothing
        self._converged = None   # (u, friction forces, vertex states) of the last accepted step (keyed by u)

    @property
    def active(self) -> bool:
        return bool(self.mu_s_pair.max() > 0.0)

    # -- geometry -------------------------------------------------------------------------------
    def _closest(self, P: np.ndarray, piece: np.ndarray):
        """closest_facet among the facets of the other pieces, at the positions self._y."""
        return closest_facet(P, piece, self._y, self.facets, self.facet_piece, self.candidates, self.tie_break)

    def _anchor_new(self, y: np.ndarray, which: np.ndarray | None = None, start: np.ndarray | None = None,
                    landing: np.ndarray | None = None, only_landing: bool = False) -> None:
        """Anchor the unanchored vertices (of which, default all) within dhat of another piece's facet:
        where they are, or (start: the positions at the step's start) where they were relative to that
        facet when the step began -- a contact made during a step has not slipped yet.

        landing (a flag per piece, see _begin_step): a contact of a landing piece is anchored where it
        is, and only if its vertex faces the facet (its projection onto the facet's line or plane lies
        on it, or within facing_reach x dhat of it: corners placed in line are told apart by round-off);
        a vertex beside a corner of the other piece is left to that corner, which anchors on this
        piece's facets (anchored on a side facet, its stuck spring held a landing box along the
        contact's normal, and the pair's barrier force grew to 6,000 times the weight it carried).
        only_landing: anchor no other contact."""
        if not len(self.facets):
            return
        self._y = y
        free = np.flatnonzero((self.facet < 0) & (True if which is None else which))
        if not len(free):
            return
        j, b, dist = self._closest(y[self.body_vertices[free]], self.vertex_piece[free])
        near = dist <= self.c.dhat
        lands = np.zeros(len(free), bool) if landing is None \
            else near & (landing[self.vertex_piece[free]] | landing[self.facet_piece[j]])
        if only_landing:
            near &= lands
        rest = near & ~lands
        if start is not None and rest.any():
            b = b.copy()
            b[rest] = closest_on_facets(start[self.body_vertices[free[rest]]], start, self.facets[j[rest]])
        if lands.any():
            b = b.copy()
            P, F = y[self.body_vertices[free[lands]]], self.facets[j[lands]]
            b[lands] = plane_coordinates(P, y, F)
            on_plane = np.einsum("nj,njk->nk", b[lands], y[F])
            on_facet = np.einsum("nj,njk->nk", closest_on_facets(P, y, F), y[F])
            near[lands] = np.linalg.norm(on_plane - on_facet, axis=1) <= self.facing_reach * self.c.dhat
        idx = free[near]
        self.facet[idx], self.b[idx] = j[near], b[near]
        self.T[idx] = tangents(y, self.facets[j[near]])

    def _anchor_points(self, y: np.ndarray, on: np.ndarray) -> np.ndarray:
        return np.einsum("nj,njk->nk", self.b[on], y[self.facets[self.facet[on]]])

    def _slip(self, y: np.ndarray):
        """(anchored nodes, d (n, dim - 1)) at positions y: d = T^T (y_i - sum_k b_k y_k)."""
        on = np.flatnonzero(self.facet >= 0)
        d = np.einsum("nka,nk->na", self.T[on], y[self.body_vertices[on]] - self._anchor_points(y, on))
        return on, d

    # -- the potential ----------------------------------------------------------------------------
    def _mu(self) -> np.ndarray:
        master = np.where(self.facet >= 0, self.facet_piece[np.maximum(self.facet, 0)], self.vertex_piece)
        return np.where(self.trial, self.mu_k_pair[self.vertex_piece, master],
                        self.mu_s_pair[self.vertex_piece, master])

    def _parts(self, u: np.ndarray):
        """(anchored nodes with F > 0, d (n, dim - 1), r = |d|, K, F, sticking)."""
        y = self.c.positions(u)
        on, d = self._slip(y)
        F = np.where(self.fresh[on], np.inf, self._mu()[on] * self.N[on])
        keep = F > 0
        on, d, F = on[keep], d[keep], F[keep]
        last = self._mu()[on] * self.N[on] / self.eps            # fresh: the last lag's stiffness, if any
        K = np.where(self.fresh[on], np.where(last > 0, last, self.k_fresh * self.w[on]), F / self.eps)
        r = np.linalg.norm(d, axis=1)
        stick = K * r <= F
        F = np.where(stick & np.isinf(F), K * r, F)
        return on, d, r, K, F, stick

    def _dofs(self, on: np.ndarray) -> np.ndarray:
        """(n, (dim + 1) x dim) DOFs: the vertex, then its anchor facet's nodes."""
        verts = np.column_stack([self.body_vertices[on], self.facets[self.facet[on]]])
        nodes = self.c.nodes[verts]
        return (nodes[:, :, None] * self.bs + np.arange(self.bs)).reshape(len(on), -1)

    def _coefficients(self, on: np.ndarray) -> np.ndarray:
        """dd/dy for the vertex and its facet's nodes: (n, dim - 1, (dim + 1) dim) = [T^T, -b_1 T^T, ...]."""
        Tt = np.swapaxes(self.T[on], 1, 2)                                  # (n, dim - 1, dim)
        c = np.column_stack([np.ones(len(on)), -self.b[on]])                 # (n, dim + 1)
        return (c[:, None, :, None] * Tt[:, :, None, :]).reshape(len(on), Tt.shape[1], -1)

    def energy(self, u: np.ndarray) -> float:
        if not self.active:
            return 0.0
        on, d, r, K, F, stick = self._parts(u)
        return float(np.sum(np.where(stick, 0.5 * K * r ** 2, F * r - 0.5 * F ** 2 / np.where(stick, 1.0, K))))

    def _force(self, u: np.ndarray):
        """(anchored nodes, de/dd (n, dim - 1)): K d sticking, F d / r slipping."""
        on, d, r, K, F, stick = self._parts(u)
        return on, np.where(stick, K, F / np.where(stick, 1.0, r))[:, None] * d

    def gradient(self, u: np.ndarray):
        """On the contact's boundary DOFs (all of them: under MPI its gather's)."""
        if not self.active:
            return None
        on, f = self._force(u)
        if not len(on):
            return None
        g = np.zeros(len(self.c.dofs))
        np.add.at(g, self._positions(on).ravel(), np.einsum("na,nax->nx", f, self._coefficients(on)).ravel())
        return self.c.dofs, g

    def _positions(self, on: np.ndarray) -> np.ndarray:
        """Positions in the contact's boundary DOFs of _dofs(on)."""
        return np.searchsorted(self.c.dofs, self._dofs(on))

    def hessian(self, u: np.ndarray) -> list:
        """G^T C G per anchored vertex: C = K I sticking, F / r (I - e e^T) slipping (e = d / r; 0 in 2D),
        F / r I with `project`."""
        if not self.active:
            return []
        on, d, r, K, F, stick = self._parts(u)
        m = d.shape[1]
        e = d / np.where(r > 0, r, 1.0)[:, None]
        along = np.where(stick | self.project, 0.0, 1.0)
        C = np.where(stick, K, F / np.where(stick, 1.0, r))[:, None, None] \
            * (np.eye(m)[None] - along[:, None, None] * e[:, :, None] * e[:, None, :])
        keep = np.abs(C).reshape(len(on), m * m).max(axis=1, initial=0.0) > 0
        on, C = on[keep], C[keep]
        if not len(on):
            return []
        G = self._coefficients(on)
        pos = self._positions(on)
        values = np.einsum("nax,nab,nby->nxy", G, C, G)
        rows = np.repeat(pos[:, :, None], pos.shape[1], axis=2)
        cols = np.repeat(pos[:, None, :], pos.shape[1], axis=1)
        n = len(self.c.dofs)
        H = sp.coo_matrix((values.ravel(), (rows.ravel(), cols.ravel())), shape=(n, n))
        self.c.require(u, H)             # an anchor lagged from an earlier state may couple new pairs
        return [(self.c.dofs, H)]

    def pattern(self) -> list:
        return self.c.pattern()          # a vertex with another piece's facet: the barrier's blocks

    # -- parameters ---------------------------------------------------------------------------------
    def parameters(self) -> dict:
        """[contact]'s coefficients, for the pairs of pieces [contact.pairs] does not list."""
        return {"contact.friction": self.default.kinetic, "contact.friction_static": self.default.static}

    def set_parameter(self, key: str, value) -> None:
        from ..design.objects import Coulomb
        d = self.default
        if key == "contact.friction":            # friction_static follows it unless it was written
            d = Coulomb(float(value), d.static if d.static_given else float(value), d.static_given)
        elif key == "contact.friction_static":
            d = Coulomb(d.kinetic, float(value), True)
        else:
            raise KeyError(key)
        self.default = d
        self.mu_k_pair[self.default_pair] = d.kinetic
        self.mu_s_pair[self.default_pair] = d.static

    # -- lag and history ---------------------------------------------------------------------------
    def _normal_forces(self, y: np.ndarray) -> np.ndarray:
        """N_i: half the magnitude of the barrier's nodal force on vertex i. Each side of a contact carries
        half, so a contact's strength mu N is counted once in all; and the nodal force is continuous in
        the positions, where an attribution by collision type (the vertex of a vertex-edge pair) jumps
        when two facing nodes swap roles, and the lag's fixed point then cycles."""
        cs = self.c.collisions(y)
        if len(cs) == 0:
            return np.zeros(len(self.body_vertices))
        g = np.asarray(self.c.barrier.gradient(cs, self.c.mesh, fortran_array(y))).reshape(y.shape)
        return self._shares(0.5 * self.t * np.linalg.norm(g, axis=1), y)

    def _shares(self, N: np.ndarray, y: np.ndarray) -> np.ndarray:
        """N scaled so that each pair of pieces' anchored vertices carry all of its strength.

        Where a corner presses on a face, the face's nodes carry half of the
        nodal force but lie farther than dhat from the corner's edges and do
        not anchor: without this, the pair would hold by half its mu N
        (measured: a corner on a face slipped at 0.5 mu N). Each vertex that
        carries force is counted with the piece of its anchor edge (else of
        the closest other piece's edge); the anchored ones of a pair share
        its sum. Where both sides anchor (faces on faces) nothing changes."""
        pressed = np.flatnonzero(N > 0)
        anchored = self.facet[pressed] >= 0
        if anchored.all() or not anchored.any():
            return N
        self._y = y
        partner = np.where(anchored, self.facet_piece[np.maximum(self.facet[pressed], 0)], -1)
        loose = ~anchored
        j, _, _ = self._closest(y[self.body_vertices[pressed[loose]]], self.vertex_piece[pressed[loose]])
        partner[loose] = self.facet_piece[j]
        mine = self.vertex_piece[pressed]
        n = len(self.c.pieces)
        pair = np.minimum(mine, partner) * n + np.maximum(mine, partner)
        total = np.bincount(pair, N[pressed], n * n)
        held = np.bincount(pair[anchored], N[pressed][anchored], n * n)
        scale = np.divide(total, held, out=np.ones(n * n), where=held > 0)
        out = N.copy()
        out[pressed[anchored]] *= scale[pair[anchored]]
        return out

    def set_factor(self, a: float) -> None:
        """A new attempt at a step starts from the committed states; a ramp from rest (u = 0) from none."""
        if self.active:
            if not self.c.comm.allreduce(bool(np.any(self.u_fn.x.array)), op=MPI.LOR):
                self.rest()
            else:
                self._begin_step()

    def rest(self) -> None:
        """No history (a run in time from rest): no anchors, slips or lagged forces; the vertices within
        dhat of another piece at rest are anchored there."""
        if self.active:
            self.facet[:], self.N[:], self.run[:], self.sliding[:] = -1, 0.0, 0.0, False
            self._converged = None
            self._N_step = self.N.copy()
            self._begin_step()

    def _begin_step(self) -> None:
        """The start of an attempt at a step: the committed states (a failed attempt's lagged N is
        forgotten), and the vertices within dhat of another piece anchored where they are."""
        self.N = self._N_step.copy()
        self.trial = self.sliding.copy()
        self._relax, self._lag_change = 1.0, None
        self._y0 = self.c.positions(self.u_fn.x.array)
        self._anchor_new(self._y0)
        self.fresh = self.facet >= 0
        self._start_facet = self.facet.copy()
        # the objects that start the step touching no other piece: in a static solve they land in it
        touching = np.zeros(len(self.c.pieces), bool)
        on = self.facet >= 0
        touching[self.vertex_piece[on]] = True
        touching[self.facet_piece[self.facet[on]]] = True
        self._landing = ~touching
        self._landing[:self.c.bodies] = False

    def contact_event(self, u: np.ndarray, static: bool = True) -> bool:
        """Anchor the vertices the barrier presses at u that have no anchor yet (a contact formed during
        the solve), held by a spring that cannot slip until the next lag update gives their N (as the
        contacts a step starts with); True if there were any. Newton stops there and goes on with them
        (Model.contact_event): a frictionless squeeze of a free object has no equilibrium, and Newton
        wandered off with it.

        Landing (a static solve, 2D and 3D): a contact of an object that started the step touching no
        other piece is anchored where it formed, at u. A piece is placed, not thrown: it meets its
        support with no slip, and its normal and tangential loads grow together from there. (A free
        object placed a gap above a tilted support slid off before its contacts carried a normal
        force; anchored where it was when the step began, before it fell, the stuck spring pulled it
        back and that pull became the solve's force scale.) Other contacts (3D only) are anchored
        where they were, relative to the other side, when the step began: in a warm re-solve Newton's
        iterates can stray far (a pinched box 2.3 mm down), and anchoring there held the box there."""
        landing = self._landing if static else None
        if not self.active or not (self.facet < 0).any():
            return False
        if not self.anchor_during_solve and (landing is None or not landing.any()):
            return False
        y = self.c.positions(u)
        cs = self.c.collisions(y)
        if len(cs) == 0:
            return False
        g = np.asarray(self.c.barrier.gradient(cs, self.c.mesh, fortran_array(y))).reshape(y.shape)
        new = (np.linalg.norm(g, axis=1) > 0) & (self.facet < 0)
        if not new.any():
            return False
        before = self.facet >= 0
        self._anchor_new(y, new, start=self._y0, landing=landing, only_landing=not self.anchor_during_solve)
        added = (self.facet >= 0) & ~before
        self.fresh |= added
        return bool(added.any())

    def update_lag(self, model) -> bool:
        if not self.active:
            return False
        u = model.u.x.array
        y = self.c.positions(u)
        N = self._normal_forces(y)
        scale = float(N.max()) if len(N) else 0.0
        change = float(np.abs(N - self.N).max()) if len(N) else 0.0
        changed = change > 1e-7 * scale or bool(self.fresh.any())
        # landing: a contact that formed in this step (held stuck, no N yet) has settled into the barrier's
        # reach; it is anchored where it settled (see _settle)
        landing = None if model.in_time else self._landing
        settled = self.fresh & ~(self.N > 0) & (self.facet >= 0) & self._lands(landing)
        if not self.fresh.any():
            # the lag map can cycle (two nodes passing load back and forth) or crawl: Aitken's relaxation
            # N <- N + w (N_measured - N), w from the last two rounds (same fixed point; a 2-cycle gets
            # w = 1/2 and stops, a slow monotone approach is sped up)
            d = N - self.N
            if self._lag_change is not None and len(d):
                dd = d - self._lag_change
                den = float(dd @ dd)
                if den > 0.0:
                    self._relax = float(np.clip(-self._relax * float(self._lag_change @ dd) / den, 1 / 16, 2.0))
            self._lag_change = d
            N = np.maximum(self.N + self._relax * d, 0.0)
        self.N, self.fresh = N, np.zeros_like(self.fresh)
        new = (N > 0) & (self.facet < 0)              # came into contact during the solve: stuck where they were
        if new.any():                                 # when the step began (landing: where they are)
            before = int(np.count_nonzero(self.facet >= 0))
            self._anchor_new(y, new, start=self._y0, landing=landing)
            changed = changed or int(np.count_nonzero(self.facet >= 0)) > before
        on = self.facet >= 0
        if on.any():
            T = tangents(y, self.facets[self.facet[on]])
            changed = changed or bool(np.abs(T - self.T[on]).max() > 1e-9)
            self.T[on] = T
        self._settle(y, settled & on)
        if (self.mu_s_pair > self.mu_k_pair).any():
            idx, d = self._slip(y)
            broke = np.zeros(len(N), bool)
            broke[idx] = self.run[idx] + np.maximum(np.linalg.norm(d, axis=1) - self.eps, 0.0) > self.dc
            broke &= ~self.trial & (N > 0)
            if broke.any():
                self.trial |= broke
                changed = True
        return changed

    def _lands(self, landing: np.ndarray | None) -> np.ndarray:
        """Per vertex: whether its anchor joins it to a landing piece (False without an anchor)."""
        if landing is None:
            return np.zeros(len(self.facet), bool)
        on = self.facet >= 0
        return on & (landing[self.vertex_piece] | landing[self.facet_piece[np.maximum(self.facet, 0)]])

    def _settle(self, y: np.ndarray, which: np.ndarray) -> None:
        """Anchor the vertices `which` where they are now, on their facet's line or plane (no slip).

        A landing contact is anchored where it formed (contact_event), inside the barrier's reach, and
        held stuck while it settles to its distance in the barrier. The facets under it turn as the
        pieces settle (a soft block dented by a box), and a stuck vertex a distance h off its facet
        then shows a slip of h x the turn that no surface made (the barrier's reach stands for a zero
        gap): measured with the turned tangents, every node of a gel block landed on a soft block
        slipped and the block wandered 1 mm before it came back. So once the lag gives the new contact
        its N, it is anchored where it settled."""
        if which.any():
            idx = np.flatnonzero(which)
            self.b[idx] = plane_coordinates(y[self.body_vertices[idx]], y, self.facets[self.facet[idx]])

    def lags(self):
        if not (self.active and self.N.any()):
            return None
        return self.N.copy(), self.T.copy()

    def set_lags(self, lags) -> None:
        self.N, self.T = lags[0].copy(), lags[1].copy()

    def lags_at(self, u: np.ndarray):
        y = self.c.positions(u)
        T = self.T.copy()
        on = self.facet >= 0
        if on.any():
            T[on] = tangents(y, self.facets[self.facet[on]])
        return self._normal_forces(y), T

    def _slide(self, y: np.ndarray, T: np.ndarray):
        """The return map of the anchored vertices that slipped, at positions y with tangent bases T:
        (vertices, their new anchor facets and barycentric coordinates, |d|). Each anchor slides to eps
        behind its vertex, re-projected onto the other piece's boundary (onto the next facet past a
        facet's end)."""
        self._y = y
        on = np.flatnonzero(self.facet >= 0)
        d = np.einsum("nka,nk->na", T[on], y[self.body_vertices[on]] - self._anchor_points(y, on))
        r = np.linalg.norm(d, axis=1)
        slip = (self._mu()[on] * self.N[on] > 0) & (r > self.eps * (1 + 1e-12))
        idx, r = on[slip], r[slip]
        if not len(idx):
            return idx, idx, np.zeros((0, self.bs)), r
        back = ((r - self.eps) / r)[:, None] * d[slip]                     # (n, dim - 1)
        P = self._anchor_points(y, idx) + np.einsum("nka,na->nk", T[idx], back)
        j, _, _ = self._closest(P, self.vertex_piece[idx])
        # on the facet the slid anchor lands on, the anchor sits exactly eps behind the vertex along the
        # slip carried into that facet's tangent frame (on its line or plane, not clipped to it), so the
        # next step starts with the force this one converged to (F along the slip). The closest point to
        # P, clipped at the facet's end past a corner, was up to dhat off along the tangent: a stuck
        # spring of stiffness mu N / eps pulled there with tens of newtons on one node
        Tn = tangents(y, self.facets[j])
        along = np.einsum("nka,nk->na", Tn, np.einsum("nka,na->nk", T[idx], d[slip]))
        size = np.linalg.norm(along, axis=1)
        along = np.where(size[:, None] > 0, along / np.where(size > 0, size, 1.0)[:, None], 0.0)
        vertex = y[self.body_vertices[idx]]
        b_new = plane_coordinates(vertex - np.einsum("nka,na->nk", Tn, self.eps * along), y, self.facets[j])
        return idx, j, b_new, r

    # -- anchors through time (skelfem.analysis.adjoint): the barycentric coordinates b ---------------
    def stick_anchors(self):
        return self.b.ravel().copy() if self.active else None

    def set_stick_anchors(self, a) -> None:
        self.b = np.asarray(a, float).reshape(self.b.shape).copy()

    def stick_anchor_step(self) -> tuple[float, float]:
        return 1e-3 * self.eps / self._facet_size, 1e-3 * self.eps

    def stick_anchors_in_step(self, a_start, u_start):
        """Vertices anchored during the step (contact_event, update_lag) sit where they were, relative to
        their facet, at u_start; the others keep a_start."""
        b = np.asarray(a_start, float).reshape(self.b.shape).copy()
        new = np.flatnonzero((self.facet >= 0) & (self._start_facet < 0))
        if len(new):
            y0 = self.c.positions(u_start)
            b[new] = closest_on_facets(y0[self.body_vertices[new]], y0, self.facets[self.facet[new]])
        return b.ravel()

    def stick_anchors_after(self, u):
        """end_step's anchors at u: slipping vertices slide (tangents at u, as lags_at), unanchored ones
        within dhat are anchored where they are."""
        y = self.c.positions(u)
        T = self.T.copy()
        on = self.facet >= 0
        if on.any():
            T[on] = tangents(y, self.facets[self.facet[on]])
        b = self.b.copy()
        idx, _, b_new, _ = self._slide(y, T)
        b[idx] = b_new
        free = np.flatnonzero(self.facet < 0)
        if len(free) and len(self.facets):
            _, b_free, dist = self._closest(y[self.body_vertices[free]], self.vertex_piece[free])
            near = dist <= self.c.dhat
            b[free[near]] = b_free[near]
        return b.ravel()

    def end_step(self, model) -> None:
        if not self.active:
            return
        u = model.u.x.array
        self._report = self._measure(u)
        self._converged = (u.copy(), self.vertex_forces(u), self._states(u))   # what this state's read-outs show
        y = self.c.positions(u)
        idx, j, b_new, r = self._slide(y, self.T)
        if len(idx):
            self.facet[idx], self.b[idx] = j, b_new
            self.T[idx] = tangents(y, self.facets[j])
        run = np.zeros(len(self.N))
        run[idx] = self.run[idx] + r - self.eps
        self.run = run
        self.sliding = self.run > self.dc
        # nodes that left the barrier's reach lose their anchor; new ones are anchored where they are
        _, _, dist = self._closest(y[self.body_vertices], self.vertex_piece) if len(self.facets) \
            else (None, None, None)
        if dist is not None:
            gone = dist > self.c.dhat
            self.facet[gone] = -1
            self.run[gone], self.sliding[gone] = 0.0, False
        self._anchor_new(y)
        self._y0 = y
        self._start_facet = self.facet.copy()
        self.trial = self.sliding.copy()
        self.fresh = self.facet >= 0
        self._N_step = self.N.copy()

    # -- read-out ------------------------------------------------------------------------------------
    def vertex_forces(self, u: np.ndarray) -> np.ndarray:
        """The friction force on every boundary vertex (n, dim), N: -T f on an anchored vertex, +b_k T f
        on the nodes of its anchor facet. At the state of the last accepted step, the forces it converged
        to (end_step's return map and new anchors would change the sum into the next step's start)."""
        out = np.zeros((len(self.N), self.bs))
        if not self.active:
            return out
        if self._converged is not None and np.array_equal(u, self._converged[0]):
            return self._converged[1].copy()     # the converged step's forces, not those after its return map
        on, f = self._force(u)
        ft = np.einsum("nka,na->nk", self.T[on], f)
        np.add.at(out, self.body_vertices[on], -ft)
        shares = (self.b[on][:, :, None] * ft[:, None, :]).reshape(-1, self.bs)
        np.add.at(out, self.facets[self.facet[on]].ravel(), shares)
        return out

    def _states(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(anchored, slipping): per boundary vertex, whether it has an anchor on another piece, and whether
        it slipped in this step (|d| > eps, at a converged state before the return map)."""
        anchored, d = self._slip(self.c.positions(u))
        slipping = np.zeros(len(self.N), bool)
        slipping[anchored] = np.linalg.norm(d, axis=1) > self.eps * (1 + 1e-12)
        return self.facet >= 0, slipping

    def vertex_states(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(anchored, slipping, lagged normal force N) per boundary vertex, as the pairs' ``sticking`` counts
        them: at the state of the last accepted step, the step's own (before its return map)."""
        if not self.active:
            n = len(self.N)
            return np.zeros(n, bool), np.zeros(n, bool), np.zeros(n)
        if self._converged is not None and np.array_equal(u, self._converged[0]):
            anchored, slipping = self._converged[2]
        else:
            anchored, slipping = self._states(u)
        return anchored.copy(), slipping.copy(), self.N.copy()

    def _measure(self, u: np.ndarray) -> dict:
        """Per pair of pieces rubbing: the friction force on the first (N) and the share of the normal
        force carried by vertices that did not slip in this step (at a converged state, before the
        return map). A vertex of piece p anchored on a facet of piece q feels -T f; the facet, +T f."""
        on, f = self._force(u)
        _, slipping = self._states(u)
        mine = np.flatnonzero(self.facet >= 0)
        slave, master = self.vertex_piece[mine], self.facet_piece[self.facet[mine]]
        force_on = self.vertex_piece[on], self.facet_piece[self.facet[on]]
        out = {}
        names = self.c.pieces
        for p in range(len(names)):
            for q in range(p + 1, len(names)):
                pair = ((slave == p) & (master == q)) | ((slave == q) & (master == p))
                if not pair.any() or not (self.mu_s_pair[p, q] > 0 or self.mu_s_pair[q, p] > 0):
                    continue
                sign = np.where(force_on[0] == p, -1.0, 1.0)[:, None]         # on p: -T f as vertex, +T f as facet
                rub = ((force_on[0] == p) & (force_on[1] == q)) | ((force_on[0] == q) & (force_on[1] == p))
                force = (sign[rub] * np.einsum("nka,na->nk", self.T[on[rub]], f[rub])).sum(axis=0)
                N = self.N[mine[pair]]
                total = float(N.sum())
                held = float(N[~slipping[mine[pair]]].sum())
                out[f"{names[p]}|{names[q]}"] = {"between": [names[p], names[q]], "friction_force": force,
                                                 "sticking": held / total if total > 0 else 1.0}
        return out

    def readout(self, model) -> dict:
        if not self.active:
            return {}
        return self._report if self._report is not None else self._measure(model.u.x.array)
