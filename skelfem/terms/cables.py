"""Tendons and ligaments: unilateral springs routed through via points.

A cable's sketch (polyline) is cut wherever it crosses a facet of the mesh
(edges in 2D, triangles in 3D); each cut and each sketch vertex is a via
point X_j, a material point that moves with its cell: x_j = X_j + (S u)_j.
With segment vectors d_i = x_{i+1} - x_i = d0_i + (B u)_i (B = D S, D the
difference operator), the cable length is

    l(u) = sum_i |d_i|,

and the cable stores the unilateral spring energy (paper eq. 3)

    U = k Q(l - L),  Q(s) = s^2/2 for s > 0, 0 otherwise,

with rest length L = L0 - u_c for a tendon contracted by u_c and
L = L0 - p for a ligament pretensioned by p (L0: the length at rest). Its
derivatives, with t_i = d_i/|d_i| and s = max(l - L, 0):

    grad U = k s g,                    g = B^T t
    hess U = k [l > L] (g g^T + s B^T W B),   W = blockdiag((I - t_i t_i^T)/|d_i|)

Dropping the curvature term k s B^T W B costs Newton its quadratic
convergence, so it stays. It is sparse: segment i couples only the DOFs of
the cells holding its two via points (one cell, as the sketch is cut at
every facet). The rank-one part k g g^T couples every DOF along the cable;
it never enters the Newton matrix (``low_rank``: the linear solver adds it
with the Sherman-Morrison-Woodbury formula), so a taut cable costs the
matrix a few entries per segment and the solve one extra back-substitution.
A segment at a finite anchor couples every DOF of its disk; above WIDE DOFs
its curvature block, of rank gdim - 1, joins the low-rank parts too.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

from . import cable_slip
from ..mesh.geometry import body_tag_name, bone_tag_name
from ..mesh.points import DofGather, locate_cells
from .base import Context, CooBlock, Term, moved_nodes_only
from .capabilities import Actuator, FiniteAnchors, Follows, History, Lagged
from .cable_route import (MAX_PER_RADIUS, PER_RADIUS, PIECES, anchor_samples, anchor_weights,  # noqa: F401
                          anchored_interpolation, anchors, default_anchor_radius, differences,
                          lattice_density, release_facets, via_points)

TENSION_FLOOR = 1e-14    # tensions below this times k L0 (a strain of 1e-14) are zero
ANDERSON_DEPTH = 5     # (F, G(F)) pairs the friction limits' fixed point mixes


WIDE = 256    # DOFs: a segment coupling more (an anchor disk's) has its curvature as rank-one parts


def _normals(t: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the plane (2D: line) normal to the unit vector t, as rows."""
    if len(t) == 2:
        return np.array([[-t[1], t[0]]])
    a = np.eye(3)[int(np.argmin(np.abs(t)))]
    n1 = np.cross(t, a)
    n1 /= np.linalg.norm(n1)
    return np.array([n1, np.cross(t, n1)])


@dataclass(eq=False)
class Cable:
    """One tendon or ligament, with its via points bound to the mesh."""

    name: str
    kind: str                # "tendon" or "ligament"
    k: float                 # spring constant, N/mm
    X: np.ndarray            # via points at rest, (n, gdim)
    dofs: np.ndarray         # global DOF numbers the cable touches, sorted (m,); local = global in serial
    S: sp.csr_matrix         # via point interpolation restricted to dofs, (n*gdim, m)
    B: sp.csr_matrix         # D S restricted to dofs, (n_seg*gdim, m)
    d0: np.ndarray           # rest segment vectors D X, (n_seg, gdim)
    L0: float                # length through the via points at rest
    gather: DofGather        # u (local array) -> u on `dofs`, on every rank
    contraction: float = 0.0
    pretension: float = 0.0
    mu: float = 0.0          # Coulomb friction against its channel at every via point (0: slides freely)
    mu_via: np.ndarray | None = None   # or one coefficient per interior via point (friction by material)

    def __post_init__(self):
        self.BT = self.B.T.tocsr()      # g = B^T t, every gradient evaluation
        self.seg0 = np.linalg.norm(self.d0, axis=1)     # L0_i, the segments' lengths at rest
        self.reset_slip()

    # -- friction state (skelfem.terms.cable_slip) ---------------------------------------------------
    def reset_slip(self) -> None:
        """Back to rest: no material has slipped through any via point, no friction limit yet."""
        m = len(self.d0)
        self.s_hat = np.zeros(m + 1)            # material through each via point since rest (anchors)
        self.s_prev = self.s_hat.copy()         # the anchors before the last accepted step
        self.F = np.zeros(max(m - 1, 0))        # lagged friction limits of the interior via points
        self.slipping = np.zeros(max(m - 1, 0), dtype=bool)   # which slipped in the last accepted step
        self._version = 0
        self._mixing: list = []
        self._cache: Any = None
        self._pattern: np.ndarray | None = None     # the last chain solve's stick/slip pattern (its warm start)

    @property
    def friction(self) -> bool:
        return self.mu > 0.0 or (self.mu_via is not None and bool(self.mu_via.any()))

    def coefficients(self) -> np.ndarray:
        """mu at each interior via point."""
        return self.mu_via if self.mu_via is not None else np.full(max(len(self.d0) - 1, 0), self.mu)

    def compliances(self) -> np.ndarray:
        """c_i = L0_i / (k L0): the cable's compliance 1/k shared out by rest length."""
        return self.seg0 / (self.k * self.L0)

    def _state(self, u: np.ndarray, L: float):
        """(d, |d|, t, b, T) at u for rest length L with the lagged limits: b the stick stretches,
        T the segment tensions (cached for the last u)."""
        v = self.values(u)
        key = (L, self.k, self.mu, id(self.mu_via), self._version)
        if self._cache is not None and self._cache[0] == key and np.array_equal(self._cache[1], v):
            return self._cache[2]
        d = self.d0 + (self.B @ v).reshape(self.d0.shape)
        norm = np.linalg.norm(d, axis=1)
        t = d / norm[:, None]
        s = self.s_hat.copy()
        s[0], s[-1] = self.L0 - L, 0.0                  # the actuator pulls s_0 out; the far end is tied
        b = norm - (self.seg0 + s[1:] - s[:-1])
        T, self._pattern = cable_slip.chain_solve(b, self.compliances(), self.F, self._pattern)
        T[T < TENSION_FLOOR * self.k * self.L0] = 0.0          # round-off of a slack cable, not a force
        out = (d, norm, t, b, T)
        self._cache = (key, v.copy(), out)
        return out

    def tensions(self, u: np.ndarray, L: float) -> np.ndarray:
        """Every segment's tension, from the actuated end (uniform without friction), N."""
        if not self.friction:
            return np.full(len(self.d0), self.tension(u, L))
        return self._state(u, L)[4].copy()

    def relax_limits(self, u: np.ndarray, L: float, rtol: float) -> bool:
        """Move the lagged friction limits towards F_j = mu tan(theta_j / 2)(T_{j-1} + T_j) at u; True if
        they were off by more than rtol times the largest tension (a re-solve is needed).

        The limits that hold at u with their own tensions, G(F) (cable_slip.coulomb_limits: the cable
        alone at u's geometry), move the body, whose new state asks for other limits: the fixed point
        F = G(F) of the whole solve is found by Anderson mixing of the last few (F, G(F)) of this step
        (a soft body in series with the cable makes the plain iteration F <- G(F) converge slowly)."""
        if not self.friction or len(self.F) == 0:
            return False
        _, _, t, b, _ = self._state(u, L)
        G, T = cable_slip.coulomb_limits(b, self.compliances(), self.coefficients() * cable_slip.bend_tangents(t),
                                         self.F, guess=self._pattern)
        G[G < TENSION_FLOOR * self.k * self.L0] = 0.0
        scale = max(float(T.max()), 1e-300)
        same = np.array_equal(np.isfinite(G), np.isfinite(self.F))
        finite = np.isfinite(G) & np.isfinite(self.F)
        if same and (not finite.any() or float(np.abs(G[finite] - self.F[finite]).max()) <= rtol * scale):
            return False
        if same:
            self._mixing = cable_slip.restarted((self._mixing + [(self.F.copy(), G.copy())])[-ANDERSON_DEPTH:])
            self.F = cable_slip.anderson(self._mixing)
        else:                        # a bend locked or unlocked: the rounds before it are another problem
            self._mixing, self.F = [], G
        self._version += 1
        return True

    def accept(self, u: np.ndarray, L: float) -> None:
        """An accepted step: the material that slipped through a via point stays where it went (the
        anchors move by the slips; a sticking via point keeps its material)."""
        if not self.friction:
            return
        _, _, _, b, T = self._state(u, L)
        lam = cable_slip.slips(b, self.compliances(), T, self.F)
        self.s_prev = self.s_hat.copy()
        self.s_hat[1:-1] += lam
        self.slipping = np.abs(lam) > 1e-9 * self.L0
        self._version, self._mixing = self._version + 1, []

    def slide_freely(self, u: np.ndarray, L: float) -> None:
        """The history of a cable that has slid freely to u: every segment stretched by its share of the
        one tension k (length - L) (the anchors s_hat the limit mu -> 0 of friction would hold), no
        friction limit yet. Friction switched on at a state reached without it starts from here, so the
        state holds (it is an equilibrium with friction too) and a later step with friction is the
        limit of one with a vanishing coefficient before it."""
        self.reset_slip()
        _, norm, _, _, _ = self._state(u, L)
        b = self.k * (float(norm.sum()) - L) * self.compliances()
        s = (self.L0 - L) + np.cumsum(norm - self.seg0 - b)       # s_1 .. s_m: s_m = 0 up to round-off
        self.s_hat[1:-1] = s[:-1]
        self.s_prev = self.s_hat.copy()
        self._version += 1

    def changed(self) -> None:
        """Its history (anchors s_hat, s_prev, friction limits F) was set from outside: the state kept for
        the last (u, L) no longer holds."""
        self._version += 1

    @classmethod
    def build(cls, V, spec, anchors: dict | None = None) -> "Cable":
        """The cable through its via points; anchors = {sketch vertex index: radius} makes that vertex
        (an end, or a bend) act on the mean displacement of a disk (2D) or ball (3D) of that radius
        (a finite anchor: the cable runs through the disk's material centroid) instead of a material point."""
        mesh = V.mesh
        X = via_points(mesh, spec.path, PIECES.get(V.ufl_element().degree(), 4))
        path = np.asarray(spec.path, dtype=float)
        at = {}
        for k, r in (anchors or {}).items():       # sketch vertex -> its via point (the sketch's own vertex)
            i = 0 if k == 0 else len(X) - 1 if k in (-1, len(path) - 1) else \
                int(np.argmin(np.linalg.norm(X - path[k], axis=1)))
            at[i] = r
        X, S, gather, owner = anchored_interpolation(V, X, at)
        if np.any(owner == mesh.comm.size):
            raise ValueError(f"cable {spec.name!r} leaves the mesh")
        d0 = np.diff(X, axis=0)
        return cls(spec.name, spec.kind, float(spec.stiffness), X, gather.dofs,
                   S, differences(S, mesh.geometry.dim), d0, float(np.linalg.norm(d0, axis=1).sum()), gather,
                   float(spec.contraction), float(spec.pretension), float(getattr(spec, "friction", 0.0)))

    # -- state ---------------------------------------------------------------
    def rest_length(self, factor: float = 1.0) -> float:
        """L = L0 - u_c (tendon) or L0 - p (ligament), ramped by the load factor."""
        shortening = self.contraction if self.kind == "tendon" else self.pretension
        return self.L0 - factor * shortening

    def values(self, u: np.ndarray) -> np.ndarray:
        """u on the cable's DOFs (`dofs`), from the local array u."""
        return self.gather(u)

    def segments(self, u: np.ndarray) -> np.ndarray:
        """Current segment vectors d_i, (n_seg, gdim)."""
        return self.d0 + (self.B @ self.values(u)).reshape(self.d0.shape)

    def positions(self, u: np.ndarray) -> np.ndarray:
        """Current via point positions, (n, gdim)."""
        return self.X + (self.S @ self.values(u)).reshape(self.X.shape)

    def length(self, u: np.ndarray) -> float:
        return float(np.linalg.norm(self.segments(u), axis=1).sum())

    def tension(self, u: np.ndarray, L: float) -> float:
        """The tension at the actuated end (the first segment's), N."""
        if self.friction:
            return float(self._state(u, L)[4][0])
        return self.k * max(0.0, self.length(u) - L)

    # -- energy and derivatives -------------------------------------------------
    def energy(self, u: np.ndarray, L: float) -> float:
        if self.friction:
            _, _, _, b, T = self._state(u, L)
            return cable_slip.value(b, self.compliances(), T)
        s = max(0.0, self.length(u) - L)
        return 0.5 * self.k * s * s

    def _t_and_g(self, u):
        d = self.segments(u)
        norm = np.linalg.norm(d, axis=1)
        t = d / norm[:, None]
        return d, norm, t, self.BT @ t.ravel()

    def gradient(self, u: np.ndarray, L: float) -> np.ndarray:
        """Gradient on self.dofs: k s g (with friction: sum_i T_i grad l_i)."""
        if self.friction:
            _, _, t, _, T = self._state(u, L)
            return self.BT @ (T[:, None] * t).ravel()
        _, norm, _, g = self._t_and_g(u)
        s = max(0.0, norm.sum() - L)
        return self.k * s * g

    def _segment_blocks(self):
        """Per narrow segment i: B_i densely on the cable DOFs J_i it touches, grouped by |J_i|, and the COO
        indices; and the wide segments (more than WIDE DOFs: an anchored end or bend touches every DOF of
        its anchor disk), whose curvature goes to the low-rank part (`wide_parts`).

        Built once; the curvature part is then sum_i B_i^T W_i B_i evaluated
        for all narrow segments of a group at once (batched matrix products),
        grouped by width rather than padded to the widest. The COO row and
        column arrays are the same objects every call (the model caches their
        map into the Newton matrix). Returns (groups, rows, cols, J, wide)
        with groups = [(segments, B_g, B_g^T)], J[i] the cable DOFs of
        segment i, and wide the wide segments' indices.
        """
        if getattr(self, "_blocks", None) is None:
            C = self.B.tocoo()
            nseg, gdim = self.d0.shape
            m = self.B.shape[1]
            seg, comp = C.row // gdim, C.row % gdim
            keys, inv = np.unique(seg.astype(np.int64) * m + C.col, return_inverse=True)
            useg, ucol = keys // m, keys % m                      # (segment, DOF) pairs, sorted
            start = np.searchsorted(useg, np.arange(nseg))
            pos = np.arange(len(keys)) - start[useg]              # the DOF's slot in its segment
            width = np.bincount(useg, minlength=nseg)
            J = np.split(ucol, start[1:])
            groups, rows, cols = [], [], []
            for w in np.unique(width[(width > 0) & (width <= WIDE)]):
                members = np.flatnonzero(width == w)
                slot = np.full(nseg, -1)
                slot[members] = np.arange(len(members))
                e = width[seg] == w                               # the entries of this group's segments
                Bd = np.zeros((len(members), gdim, w))
                np.add.at(Bd, (slot[seg[e]], comp[e], pos[inv[e]]), C.data[e])
                Jg = np.stack([J[i] for i in members])            # once per cable, not per call
                rows.append(np.broadcast_to(Jg[:, :, None], (len(members), w, w)).ravel())
                cols.append(np.broadcast_to(Jg[:, None, :], (len(members), w, w)).ravel())
                groups.append((members, Bd, np.ascontiguousarray(Bd.transpose(0, 2, 1))))
            cat = (lambda a: np.concatenate(a).astype(np.int32)) if groups else \
                (lambda a: np.zeros(0, dtype=np.int32))
            self._blocks = (groups, cat(rows), cat(cols), J, np.flatnonzero(width > WIDE))
        return self._blocks

    def _weights(self, u: np.ndarray, L: float):
        """(t, |d|, per-segment tension, per-segment axial stiffness, zones) for the Hessian:
        W_i = T_i (I - t_i t_i^T) / |d_i| + a_i t_i t_i^T. Without friction T_i = k s and a_i = 0 (the
        axial part k g g^T is one rank-one part); with friction a_i = 1 / c_i for a taut segment that is
        a zone of its own (a sticking via point at both its ends), zones of several segments being
        rank-one parts g_z g_z^T / C_z. None if the cable is slack."""
        if not self.friction:
            _, norm, t, _ = self._t_and_g(u)
            s = norm.sum() - L
            if s <= 0.0:
                return None
            return t, norm, np.full(len(norm), self.k * s), np.zeros(len(norm)), None
        _, norm, t, _, T = self._state(u, L)
        if not T.any():
            return None
        label, taut = cable_slip.zones(T, self.F)
        size = np.bincount(label)
        alone = (size[label] == 1) & taut[label]
        axial = np.where(alone, 1.0 / self.compliances(), 0.0)
        return t, norm, T, axial, (label, taut, size)

    def curvature(self, u: np.ndarray, L: float) -> CooBlock:
        """Sparse part of the Hessian on self.dofs: B_i^T W_i B_i of the narrow segments, W_i from
        :meth:`_weights` (COO, duplicates summed later)."""
        m = len(self.dofs)
        w = self._weights(u, L)
        if w is None:
            return CooBlock(np.zeros(0), np.zeros(0, np.int32), np.zeros(0, np.int32), (m, m))
        t, norm, T, axial, _ = w
        groups, rows, cols, _, _ = self._segment_blocks()
        gdim = t.shape[1]
        tt = t[:, :, None] * t[:, None, :]
        W = (T / norm)[:, None, None] * (np.eye(gdim)[None] - tt) + axial[:, None, None] * tt
        parts = [np.matmul(BdT, np.matmul(W[members], Bd)).ravel() for members, Bd, BdT in groups]
        data = np.concatenate(parts) if parts else np.zeros(0)
        return CooBlock(data, rows, cols, (m, m))

    def wide_parts(self, u: np.ndarray, L: float) -> list[tuple[float, np.ndarray]]:
        """The wide segments' curvature T_i B_i^T W_i B_i as rank-one parts [(c, g)] on self.dofs.

        W_i = (I - t_i t_i^T) / |d_i| = sum_j n_j n_j^T / |d_i| over an orthonormal
        basis n_j of the plane normal to t_i (one vector in 2D, two in 3D), so
        the block is sum_j (T_i / |d_i|) (B_i^T n_j)(B_i^T n_j)^T: gdim - 1 rank-one
        parts per wide segment instead of a dense block over its disk's DOFs
        in the Newton matrix (whose factorisation fills in with it); with
        friction a wide segment that is a zone of its own adds (1 / c_i) t_i t_i^T.
        """
        w = self._weights(u, L)
        return [] if w is None else self._wide(*w[:4])

    def _wide(self, t: np.ndarray, norm: np.ndarray, T: np.ndarray, axial: np.ndarray) -> list:
        wide = self._segment_blocks()[4]
        gdim = t.shape[1]
        out = []
        for i in wide:                                   # a few per cable: its anchored ends and bends
            Bi = self.B[i * gdim:(i + 1) * gdim]
            if T[i] > 0.0:
                for n in _normals(t[i]):
                    out.append((T[i] / norm[i], np.asarray(Bi.T @ n).ravel()))
            if axial[i] > 0.0:
                out.append((axial[i], np.asarray(Bi.T @ t[i]).ravel()))
        return out

    def low_rank_parts(self, u: np.ndarray, L: float) -> list[tuple[float, np.ndarray]]:
        """[(c, g)] on self.dofs: k g g^T (g = B^T t) when taut, or with friction g_z g_z^T / C_z per taut
        zone of several segments (g_z = sum_{i in z} B_i^T t_i, C_z = sum_{i in z} c_i); and the wide
        segments' curvature."""
        w = self._weights(u, L)
        if w is None:
            return []
        t, norm, T, axial, zone = w
        if zone is None:
            return [(self.k, self.BT @ t.ravel())] + self._wide(t, norm, T, axial)
        label, taut, size = zone
        c = self.compliances()
        C = np.bincount(label, weights=c)
        out = []
        for z in np.flatnonzero(taut & (size > 1)):
            on = (label == z)[:, None]
            out.append((1.0 / C[z], self.BT @ (on * t).ravel()))
        return out + self._wide(t, norm, T, axial)

    def contraction_gradient(self, u: np.ndarray, L: float) -> np.ndarray:
        """dR/du_c on self.dofs, R = grad of this cable's energy: k g when taut (g = grad l); with friction
        g_z / C_z of the zone that holds the actuated end, if taut (0 if slack). Lagged limits held."""
        if not self.friction:
            return self.k * self.length_gradient(u) if self.length(u) > L else np.zeros(len(self.dofs))
        w = self._weights(u, L)
        if w is None:
            return np.zeros(len(self.dofs))
        t, _, _, _, (label, taut, _) = w
        if not taut[label[0]]:
            return np.zeros(len(self.dofs))
        on = label == label[0]
        return self.BT @ (on[:, None] * t).ravel() / self.compliances()[on].sum()

    def length_gradient(self, u: np.ndarray) -> np.ndarray:
        """g = grad l = B^T t on self.dofs."""
        return self._t_and_g(u)[3]

    def hessian(self, u: np.ndarray, L: float) -> np.ndarray:
        """Dense Hessian on self.dofs, k [s > 0] (g g^T + s B^T W B) without friction (for tests)."""
        H = self.curvature(u, L).toarray()
        for c, w in self.low_rank_parts(u, L):
            H += c * np.outer(w, w)
        return H

    def segment_nodes(self, bs: int) -> list[np.ndarray]:
        """Global node numbers each narrow segment's curvature block couples (one array per segment; a
        node may repeat, once per component: the matrix pattern takes repeats)."""
        nodes = self.dofs // bs
        _, _, _, J, wide = self._segment_blocks()
        narrow = np.ones(len(J), dtype=bool)
        narrow[wide] = False
        return [nodes[j] for j, keep in zip(J, narrow) if keep]


class CableTerm(Term, History, Lagged, FiniteAnchors, Actuator, Follows):
    """One cable as an energy term; its rest length follows the load factor.

    Parameters: ``cables.NAME.contraction`` (tendons) or ``.pretension``
    (ligaments), ``.stiffness`` and ``.friction``. Read-out: kind, contraction,
    rest length, length, tension (at the actuated end), every segment's
    tension and, with friction, which via points slipped in the last step.

    With friction (:mod:`skelfem.terms.cable_slip`) the cable keeps a history:
    the material that slipped through each via point, from rest (``rest``: a
    solve from rest starts from no history) and across every accepted step
    after it.
    """

    LAG_RTOL = 1e-5      # friction limits converged when no F_j moves by more than this times max T

    section = "cables"

    def __init__(self, ctx: Context, spec):
        try:
            self.anchors = anchors(ctx, spec)
            self.cable = Cable.build(ctx.V, spec, self.anchors)
        except ValueError as exc:
            from ..design.spec import DesignError
            raise DesignError(f"{ctx.design.source}: cables.{spec.name}.path: {exc}") from None
        self.name, self.kind, self.bs = spec.name, spec.kind, ctx.bs
        self.actuated = spec.kind == "tendon"
        self.disks = [(np.asarray(spec.path[k], dtype=float), r) for k, r in self.anchors.items()]   # (centre, r)
        self.gather = self.cable.gather
        self.u = ctx.u                 # the model's displacement: where friction switched on live starts
        self.factor = 0.0
        self.unknown_history = True    # built on a state it did not see: set at the first set_factor
        self.notes: dict = {}          # take_notes: {key: warning} for the next result
        self.by_material = dict(getattr(spec, "friction_by_material", ()))
        if self.by_material:
            self.cable.mu_via = via_coefficients(ctx, self.cable, self.by_material)

    def finite_anchors(self) -> list:
        return list(self.disks)

    def follow(self, ctx: Context, changed: set) -> bool:
        """A draft on moved nodes only (a 3D bone moved or turned, skelfem.mesh.morph3d; a 2D outline's or
        hole's vertices dragged, skelfem.mesh.morph: terms.base.moved_nodes_only): the cable keeps its via
        points in the cells they were cut in (a preview's approximation: 25-60 ms of a frame at 10k DOFs in
        3D, 0.4 s at 49k, about half of a 2D frame on finger.toml, not spent; the release re-meshes and
        builds the cable anew). Anything else: anew."""
        return moved_nodes_only(ctx, changed)

    @property
    def rest_length(self) -> float:
        return self.cable.rest_length(self.factor)

    def set_factor(self, a: float) -> None:
        """The load factor; the first one after this term was built on a state it did not reach (an edit's
        carried-over state) gives the friction history of that state: none at rest, else that of a cable
        that slid freely there (Cable.slide_freely), not one that stuck since rest."""
        self.factor = float(a)
        if self.unknown_history:
            self.unknown_history = False
            if self.cable.friction and np.any(self.cable.values(self.u.x.array)):
                self._slid_freely()

    def _slid_freely(self) -> None:
        """Friction's history from the present state, as if the cable had slid freely to it (the state holds);
        noted for the next result when the state is a loaded one."""
        u = self.u.x.array
        self.cable.slide_freely(u, self.rest_length)
        if np.any(self.cable.values(u)):
            self.notes[f"cables.{self.name}.friction"] = (
                f"cables.{self.name}.friction: its history starts at a loaded state (friction switched on "
                "there, or the cable built anew by an edit), as if the cable had slid freely to it; friction "
                "depends on the load path: the same loads with friction from rest give another state (solve "
                "from rest for that)")

    def take_notes(self) -> list:
        notes, self.notes = list(self.notes.values()), {}
        return notes

    def rest(self) -> None:
        self.unknown_history, self.notes = False, {}
        self.cable.reset_slip()

    def update_lag(self, model) -> bool:
        return self.cable.relax_limits(model.u.x.array, self.rest_length, self.LAG_RTOL)

    def lags_follow_the_step(self) -> bool:
        return self.cable.friction

    def end_step(self, model) -> None:
        self.cable.accept(model.u.x.array, self.rest_length)

    def history(self):
        c = self.cable
        if not c.friction:
            return None
        return {"s_hat": c.s_hat.copy(), "s_prev": c.s_prev.copy(), "F": c.F.copy(),
                "slipping": c.slipping.copy(), "_mixing": list(c._mixing)}

    def set_history(self, history) -> None:
        c = self.cable
        for k, v in (history or {}).items():
            setattr(c, k, v.copy() if hasattr(v, "copy") else v)
        c.changed()

    def energy(self, u):
        return self.cable.energy(u, self.rest_length)

    def gradient(self, u):
        return self.cable.dofs, self.cable.gradient(u, self.rest_length)

    def hessian(self, u):
        return [(self.cable.dofs, self.cable.curvature(u, self.rest_length))]

    def low_rank(self, u):
        return [(c, self.cable.dofs, g) for c, g in self.cable.low_rank_parts(u, self.rest_length)]

    def pattern(self):
        return [(n, n) for n in self.cable.segment_nodes(self.bs)]

    def parameters(self) -> dict:
        c = self.cable
        which = "contraction" if self.kind == "tendon" else "pretension"
        return {f"cables.{self.name}.{which}": getattr(c, which), f"cables.{self.name}.stiffness": c.k,
                f"cables.{self.name}.friction": c.mu}

    def set_parameter(self, key: str, value) -> None:
        which = key.rsplit(".", 1)[1]
        if which not in self.parameters() and key not in self.parameters():
            raise KeyError(key)
        if which == "stiffness":
            self.cable.k = float(value)
        elif which == "friction":             # one coefficient for the whole cable from now on
            if not float(value) >= 0.0:
                raise ValueError(f"cables.{self.name}.friction: must be >= 0, got {value!r}")
            sliding = not self.cable.friction
            self.cable.mu, self.cable.mu_via, self.by_material = float(value), None, {}
            if sliding and self.cable.friction:       # switched on: from where the cable slid freely to
                self._slid_freely()
        else:
            setattr(self.cable, which, float(value))

    def readout(self, model) -> dict:
        u, c, L = model.u.x.array, self.cable, self.rest_length
        T = c.tensions(u, L)
        slipping = c.slipping if c.friction else np.full(max(len(T) - 1, 0), bool(T[0] > 0.0))
        return {self.name: {"kind": self.kind, "contraction": float(c.contraction), "rest_length": L,
                            "length": c.length(u), "tension": float(T[0]),
                            "friction": dict(self.by_material) if self.by_material else c.mu,
                            "tensions": [float(x) for x in T], "slipping": [bool(x) for x in slipping]}}



def via_coefficients(ctx: Context, cable: Cable, by_material: dict) -> np.ndarray:
    """mu at each interior via point from {material: mu}: each segment lies in one cell (the sketch is cut
    at every facet), whose region gives its material; a via point takes the larger mu of its two
    segments (a bend where the cable leaves a bone for silicone presses on both). Materials not
    named: 0. The same on every rank."""
    design, tm = ctx.design, ctx.tagged
    material_of_tag = {tm.tags[body_tag_name(b)]: b.material for b in design.bodies}
    material_of_tag.update({tm.tags[bone_tag_name(b.name)]: b.material for b in design.bones
                            if bone_tag_name(b.name) in tm.tags})
    mu_of_tag = np.zeros(max(tm.tags.values()) + 1)
    for tag, material in material_of_tag.items():
        mu_of_tag[tag] = by_material.get(material, 0.0)
    n_owned = ctx.mesh.topology.index_map(ctx.mesh.topology.dim).size_local
    cells = locate_cells(ctx.mesh, 0.5 * (cable.X[1:] + cable.X[:-1]), below=n_owned)
    tag_of_cell = np.zeros(n_owned, dtype=np.int64)
    owned = tm.cell_tags.indices < n_owned
    tag_of_cell[tm.cell_tags.indices[owned]] = tm.cell_tags.values[owned]
    mu_seg = np.where(cells >= 0, mu_of_tag[tag_of_cell[np.maximum(cells, 0)]], -1.0)
    if ctx.comm.size > 1:
        ctx.comm.Allreduce(MPI.IN_PLACE, mu_seg, op=MPI.MAX)
    mu_seg = np.maximum(mu_seg, 0.0)
    return np.maximum(mu_seg[:-1], mu_seg[1:])

def build(ctx: Context) -> list[Term]:
    terms: list[Term] = [CableTerm(ctx, spec) for spec in ctx.design.cables]
    release_facets(ctx.mesh)
    return terms
