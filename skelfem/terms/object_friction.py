"""Coulomb friction between the body and rigid objects (2D), anchored on the object's surface.

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
point with the solver, ``update_lag``), mu the pair's coefficient
(``[contact.pairs]``, else ``[contact] friction``). After each accepted step
the return map slides the anchor of a slipping node along the object's
boundary to eps behind it (onto the next edge past an edge's end), a
sticking node keeps it, a node that has left the barrier's reach loses it
and a node that enters it is anchored where it is. As on grounds, a step's
first solve holds every anchored node by a stiff spring (E t w_i / eps:
it then starts the lag iteration inside the sticking zone, where Newton
converges fast) until the lag gives its N, and mu_s drops to mu_k once a node has slipped
by more than D_c.

Newton uses the exact Hessian (zero along the slip of a slipping node in
2D). ``project = True`` replaces it with the secant stiffness F_i / |d_i|
(positive, like self-contact's projected barrier Hessian); measured on the
pinch near its limit it is ten times slower (359 Newton iterations against
31) and it slows a sliding object to a crawl, so it is off.

Limits: friction acts at the body's nodes on the objects' edges; an
object's corner pressing into the body's surface has the barrier's normal
force but no friction.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .base import Term


class ObjectFriction(Term):
    """Friction of every body boundary node against the objects' boundary edges."""

    section, name = "contacts", "friction"
    slip_length = 1e-6      # eps, as a fraction of the body's size
    project = False         # True: Newton's Hessian of a slipping node is its secant F / |d| (exact: 0)
    breakaway = 1e-4        # D_c, as a fraction of the body's size

    def __init__(self, ctx, contact, objects):
        design = ctx.design
        self.u_fn = ctx.u
        self.c = contact
        self.t = contact.t
        self.bs = contact.bs
        X = contact.X
        size = float(np.linalg.norm(np.ptp(X, axis=0)))
        self.eps, self.dc = self.slip_length * size, self.breakaway * size
        self.body_vertices = np.flatnonzero(contact.label == 0)
        edges = contact.edges
        obj = (contact.label[edges[:, 0]] > 0) & (contact.label[edges[:, 1]] > 0)
        self.obj_edges = edges[obj]                          # (m, 2) vertex indices
        self.edge_piece = contact.label[self.obj_edges[:, 0]]
        body_mat = design.body.material
        mats = [design.materials[o.spec.material].name for o in objects]
        coeff = [design.friction.between(body_mat, m) for m in mats]
        self.mu_k_piece = np.array([0.0] + [c.kinetic for c in coeff])
        self.mu_s_piece = np.array([0.0] + [c.static for c in coeff])
        # the body vertices' boundary weights (half their edges' lengths): the fresh springs' areas
        L = np.linalg.norm(X[edges[:, 1]] - X[edges[:, 0]], axis=1)
        w = np.zeros(len(X))
        np.add.at(w, edges.ravel(), np.repeat(0.5 * L, 2))
        self.w = w[self.body_vertices]
        self.k_fresh = design.materials[body_mat].E * self.t / self.eps      # stuck within eps: N/mm per mm
        n = len(self.body_vertices)
        self.edge = np.full(n, -1)                           # anchor edge (row of obj_edges), -1: none
        self.s = np.zeros(n)                                 # anchor parameter on it
        self.T = np.zeros((n, 2))                            # lagged unit tangent of the anchor edge
        self.N = np.zeros(n)                                 # lagged normal force
        self.fresh = np.zeros(n, bool)
        self.sliding = np.zeros(n, bool)
        self.trial = np.zeros(n, bool)
        self.run = np.zeros(n)
        self._report = None

    @property
    def active(self) -> bool:
        return bool(self.mu_s_piece.max() > 0.0)

    # -- geometry -------------------------------------------------------------------------------
    def _closest(self, P: np.ndarray):
        """For points P (n, 2): (object edge, parameter s in [0, 1], distance) of the closest object edge."""
        y = self._y
        a, b = y[self.obj_edges[:, 0]], y[self.obj_edges[:, 1]]
        ab = b - a
        s = np.clip(np.einsum("nek,ek->ne", P[:, None, :] - a[None], ab) / np.einsum("ek,ek->e", ab, ab), 0, 1)
        q = a[None] + s[..., None] * ab[None]
        dist = np.linalg.norm(P[:, None, :] - q, axis=2)
        j = np.argmin(dist, axis=1)
        k = np.arange(len(P))
        return j, s[k, j], dist[k, j]

    def _tangents(self, y: np.ndarray, edge: np.ndarray) -> np.ndarray:
        e = self.obj_edges[edge]
        t = y[e[:, 1]] - y[e[:, 0]]
        return t / np.linalg.norm(t, axis=1)[:, None]

    def _anchor_new(self, y: np.ndarray, which: np.ndarray | None = None) -> None:
        """Anchor the unanchored body nodes (of which, default all) within dhat of an object where they are."""
        if not len(self.obj_edges):
            return
        self._y = y
        free = np.flatnonzero((self.edge < 0) & (True if which is None else which))
        if not len(free):
            return
        j, s, dist = self._closest(y[self.body_vertices[free]])
        near = dist <= self.c.dhat
        idx = free[near]
        self.edge[idx], self.s[idx] = j[near], s[near]
        self.T[idx] = self._tangents(y, j[near])

    def _slip(self, y: np.ndarray):
        """(anchored nodes, d) at positions y."""
        on = np.flatnonzero(self.edge >= 0)
        e = self.obj_edges[self.edge[on]]
        s = self.s[on][:, None]
        P = (1 - s) * y[e[:, 0]] + s * y[e[:, 1]]
        d = np.einsum("nk,nk->n", self.T[on], y[self.body_vertices[on]] - P)
        return on, d

    # -- the potential ----------------------------------------------------------------------------
    def _mu(self) -> np.ndarray:
        piece = np.where(self.edge >= 0, self.edge_piece[np.maximum(self.edge, 0)], 0)
        return np.where(self.trial, self.mu_k_piece[piece], self.mu_s_piece[piece])

    def _parts(self, u: np.ndarray):
        y = self.c.positions(u)
        on, d = self._slip(y)
        F = np.where(self.fresh[on], np.inf, self._mu()[on] * self.N[on])
        keep = F > 0
        on, d, F = on[keep], d[keep], F[keep]
        K = np.where(self.fresh[on], self.k_fresh * self.w[on], F / self.eps)
        r = np.abs(d)
        stick = K * r <= F
        F = np.where(stick & np.isinf(F), K * r, F)
        return on, d, K, F, stick

    def _dofs(self, on: np.ndarray) -> np.ndarray:
        """(n, 3 vertices x 2) DOFs: the body node, then the anchor edge's two nodes."""
        e = self.obj_edges[self.edge[on]]
        verts = np.column_stack([self.body_vertices[on], e[:, 0], e[:, 1]])
        nodes = self.c.nodes[verts]
        return (nodes[:, :, None] * self.bs + np.arange(self.bs)).reshape(len(on), -1)

    def _coefficients(self, on: np.ndarray) -> np.ndarray:
        """dd/dy for the 3 nodes: (n, 6) = [T, -(1 - s) T, -s T]."""
        T, s = self.T[on], self.s[on][:, None]
        return np.hstack([T, -(1 - s) * T, -s * T])

    def energy(self, u: np.ndarray) -> float:
        if not self.active:
            return 0.0
        on, d, K, F, stick = self._parts(u)
        r = np.abs(d)
        return float(np.sum(np.where(stick, 0.5 * K * r ** 2, F * r - 0.5 * F ** 2 / np.where(stick, 1.0, K))))

    def _force(self, u: np.ndarray):
        on, d, K, F, stick = self._parts(u)
        return on, np.where(stick, K * d, F * np.sign(d))          # de/dd

    def gradient(self, u: np.ndarray):
        if not self.active:
            return None
        on, f = self._force(u)
        if not len(on):
            return None
        return self._dofs(on).ravel(), (f[:, None] * self._coefficients(on)).ravel()

    def hessian(self, u: np.ndarray) -> list:
        if not self.active:
            return []
        on, d, K, F, stick = self._parts(u)
        if self.project:                                             # slipping: F / |d| instead of 0
            K = np.where(stick, K, F / np.where(stick, 1.0, np.abs(d)))
        else:
            on, K = on[stick], K[stick]
        if not len(on):
            return []
        g = self._coefficients(on)
        H = sp.block_diag(list(K[:, None, None] * g[:, :, None] * g[:, None, :]), format="coo")
        return [(self._dofs(on).ravel(), H)]

    def pattern(self) -> list:
        return [(self.c.nodes, self.c.nodes)]

    # -- lag and history ---------------------------------------------------------------------------
    def _normal_forces(self, y: np.ndarray) -> np.ndarray:
        c = self.c.collisions(y)
        if len(c) == 0:
            return np.zeros(len(self.body_vertices))
        g = self.t * np.asarray(self.c.barrier.gradient(c, self.c.mesh, np.asfortranarray(y))).reshape(-1, 2)
        return np.linalg.norm(g[self.body_vertices], axis=1)

    def set_factor(self, a: float) -> None:
        if self.active:
            self.trial = self.sliding.copy()
            self._anchor_new(self.c.positions(self.u_fn.x.array))
            self.fresh = self.edge >= 0

    def update_lag(self, model) -> bool:
        if not self.active:
            return False
        u = model.u.x.array
        y = self.c.positions(u)
        N = self._normal_forces(y)
        scale = float(N.max()) if len(N) else 0.0
        changed = bool(np.abs(N - self.N).max() > 1e-7 * scale) if len(N) else False
        changed = changed or bool(self.fresh.any())
        self.N, self.fresh = N, np.zeros_like(self.fresh)
        new = (N > 0) & (self.edge < 0)              # came into contact during the solve: stuck where they are
        if new.any():
            before = int(np.count_nonzero(self.edge >= 0))
            self._anchor_new(y, new)
            changed = changed or int(np.count_nonzero(self.edge >= 0)) > before
        on = self.edge >= 0
        if on.any():
            T = self._tangents(y, self.edge[on])
            changed = changed or bool(np.abs(T - self.T[on]).max() > 1e-9)
            self.T[on] = T
        if (self.mu_s_piece > self.mu_k_piece).any():
            idx, d = self._slip(y)
            broke = np.zeros(len(N), bool)
            broke[idx] = self.run[idx] + np.maximum(np.abs(d) - self.eps, 0.0) > self.dc
            broke &= ~self.trial & (N > 0)
            if broke.any():
                self.trial |= broke
                changed = True
        return changed

    def end_step(self, model) -> None:
        if not self.active:
            return
        u = model.u.x.array
        self._report = self._measure(u)
        y = self.c.positions(u)
        self._y = y
        on, d = self._slip(y)
        F = self._mu()[on] * self.N[on]
        slip = (F > 0) & (np.abs(d) > self.eps * (1 + 1e-12))
        # slide the anchors of slipping nodes to eps behind them (re-projected onto the object's boundary)
        idx = on[slip]
        if len(idx):
            e = self.obj_edges[self.edge[idx]]
            s = self.s[idx][:, None]
            P = (1 - s) * y[e[:, 0]] + s * y[e[:, 1]]
            back = (np.abs(d[slip]) - self.eps) * np.sign(d[slip])
            j, s_new, _ = self._closest(P + back[:, None] * self.T[idx])
            self.edge[idx], self.s[idx] = j, s_new
            self.T[idx] = self._tangents(y, j)
        run = np.zeros(len(self.N))
        run[idx] = self.run[idx] + np.abs(d[slip]) - self.eps
        self.run = run
        self.sliding = self.run > self.dc
        # nodes that left the barrier's reach lose their anchor; new ones are anchored where they are
        _, _, dist = self._closest(y[self.body_vertices]) if len(self.obj_edges) else (None, None, None)
        if dist is not None:
            gone = dist > self.c.dhat
            self.edge[gone] = -1
            self.run[gone], self.sliding[gone] = 0.0, False
        self._anchor_new(y)
        self.trial = self.sliding.copy()
        self.fresh = self.edge >= 0

    # -- read-out ------------------------------------------------------------------------------------
    def _measure(self, u: np.ndarray) -> dict:
        """Per object touched: the friction force on the body (N) and the share of the normal force
        carried by nodes that did not slip in this step (at a converged state, before the return map)."""
        on, f = self._force(u)
        anchored, d = self._slip(self.c.positions(u))
        slipping = np.zeros(len(self.N), bool)
        slipping[anchored] = np.abs(d) > self.eps * (1 + 1e-12)
        out = {}
        piece = self.edge_piece[self.edge[on]] if len(on) else np.zeros(0, int)
        mine_all = np.flatnonzero(self.edge >= 0)
        for k in range(1, len(self.c.pieces)):
            mine = mine_all[self.edge_piece[self.edge[mine_all]] == k]
            if not len(mine):
                continue
            sel = piece == k
            force = -(f[sel][:, None] * self.T[on[sel]]).sum(axis=0)        # on the body's nodes
            N = self.N[mine]
            total = float(N.sum())
            held = float(N[~slipping[mine]].sum())
            out[f"{self.c.pieces[0]}|{self.c.pieces[k]}"] = {
                "between": [self.c.pieces[0], self.c.pieces[k]], "friction_force": force,
                "sticking": held / total if total > 0 else 1.0}
        return out

    def readout(self, model) -> dict:
        if not self.active:
            return {}
        return self._report if self._report is not None else self._measure(model.u.x.array)
