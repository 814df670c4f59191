"""Coulomb friction on grounds, anchored in displacement (no creep while sticking).

A ground (:mod:`.grounds`) pushes each boundary node i (current position
y_i = X_i + u_i) back along its normal n with the nodal force

    N_i = k t w_i max(-gap_i, 0),      gap_i = (y_i - p) . n,

w_i the node's Gauss-Lobatto weight on the boundary (the ground's own
quadrature, so N_i is exactly the ground's nodal force). Friction acts in
the tangent plane (T: the dim x (dim - 1) orthonormal tangent basis). Each
node keeps a *stick anchor* s_i, a tangential position, and within a load
step has the dissipation potential of a Coulomb slider of strength
F_i = mu_i N_i, regularised only over a tiny slip length eps:

    d_i = T^T y_i - s_i,   r = |d_i|,
    e_i = F_i r^2 / (2 eps)          if r <= eps   (sticking)
          F_i (r - eps / 2)          otherwise     (slipping),

    Pi_f(u) = sum_i e_i,

convex and C^1 in y_i, with the tangential force min(r / eps, 1) F_i d / r
(the force the node drags the plane with). Every contact node sticks within
the same distance eps, so a rigid block starts to slide when, and only when,
its tangential load reaches mu_s sum N_i, however its normal load is
distributed (a tangential spring of one stiffness for all nodes would let
lightly loaded nodes slip first). After every accepted step (``end_step``)
the return map moves the anchor of a node that slipped to eps behind it; a
sticking node keeps its anchor. So a sticking contact does not creep: its
offset from where it stuck stays below eps (``slip_length`` times the size
of the body, 1e-6 by default), whatever the number of steps. Re-anchoring
every node at the start of each step instead (``anchored = False``) is a
friction regularised on the step's increment, the quasi-static counterpart
of a velocity mollifier: it slips by up to eps at every step and drifts
without bound; it is kept to measure that drift.

Newton uses the exact Hessian (none along the slip of a slipping node), so
a block that slides is carried to its new place in a step or two;
``project = True`` replaces it with the secant stiffness F_i / r in every
tangential direction (positive; it slows a long slide to a crawl and is
kept for comparison).

N_i is *lagged* (held fixed while Newton solves), which keeps Pi_f a
potential, and the lag is iterated to a fixed point: after Newton
converges, ``update_lag`` recomputes N_i(u) and asks for a re-solve until
no N_i changes by more than ``lag_rtol`` times the largest one. The first
solve of a step holds every node that touches the plane at its start by a
tangential spring that cannot slip (its N is not known yet; a lagged N from
the last step would let a contact whose load grows slide away before N
caught up): of the last lag's stiffness mu N_i / eps, so that the solve
starts where the last step ended, or of the ground's penalty k t w_i for a
new contact. A node resists with mu_s until it has slipped by more than a
breakaway distance D_c (``breakaway`` times the body's size, 1e-4 by
default; checked in the same fixed-point loop) since it last stuck, and with
mu_k from then on, until a step ends with it sticking again: a step
function of slip, the limit of linear slip-weakening. (Switching at the
first micro-slip instead lets the few micrometres of partial slip that an
elastic body shows at its edges well below the threshold drop those nodes
to mu_k, and the load they shed breaks the rest away.)

Landing (static solves). A free object that touches this ground nowhere
when a step begins lands on it in the step: a contact of its nodes that
forms during the solve is taken up at once (``contact_event``), anchored
where the node crossed the plane along the last Newton step and held stuck,
like the contacts a step starts with, until the lag gives its N. A piece is
placed, not thrown: it reaches its support with no speed, and from then on
its normal and tangential loads grow together, so it slips only if their
ratio exceeds mu. (Without this a free object placed a gap above a tilted
ground slid along it under the tangential load, which only its tether
resists, before its contact carried a normal force, and no load step
converged.) A Newton step also stops where a node of such an object that is
off the plane first reaches it (``max_step``; in a run in time too, for an
object that touched the plane nowhere when the time step began): a free
object's first step, which only its tether resists, would otherwise sink it
a quarter of its size into the penalty, and the force of that overshoot
became the solve's force scale. Other new contacts (bodies, objects
already on the ground, any node in a run in time) are taken up when the
solve has converged, anchored where their nodes were when the step began.

Parameters ``grounds.NAME.friction`` (mu_k) and ``.friction_static`` (mu_s)
change live (with ``.point`` and ``.stiffness``, shared with the ground).
Read-out beside the ground's ``force``: ``friction_force`` (the tangential
force the body exerts on the plane, N) and ``sticking`` (the share of the
normal force carried by nodes that did not slip in the last step; 1
without contact).
"""
from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

from ..mesh.geometry import body_box
from .base import Context, Term
from .capabilities import ContactEvents, Follows, History, Lagged, StepBounds, StickAnchors
from .grounds import nodal_ds


def tangent_basis(normal: np.ndarray) -> np.ndarray:
    """Orthonormal (dim, dim - 1) basis of the plane normal to a unit vector."""
    n = np.asarray(normal, float)
    if len(n) == 2:
        return np.array([[-n[1]], [n[0]]])
    a = np.eye(3)[int(np.argmin(np.abs(n)))]
    t1 = np.cross(n, a)
    t1 /= np.linalg.norm(t1)
    return np.column_stack([t1, np.cross(n, t1)])


def boundary_weights(V) -> np.ndarray:
    """Gauss-Lobatto boundary weight of every owned node (0 off the boundary), mm^(dim-1)."""
    v = ufl.TestFunction(V)
    dim = V.mesh.geometry.dim
    u = fem.Function(V)
    b = fem_petsc.assemble_vector(fem.form(ufl.inner(ufl.as_vector([1.0] * dim), v) * nodal_ds(u)))
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    w = b.array_r.reshape(-1, V.dofmap.index_map_bs)[:, 0].copy()
    b.destroy()
    return w


class GroundFriction(Term, StepBounds, Follows, History, Lagged, ContactEvents, StickAnchors):
    """Coulomb friction between the body's boundary and one ground."""

    section = "grounds"
    touch_tol = 1e-9           # a node within this fraction of the contact's size from the plane touches it
    lag_rtol = 1e-7            # fixed point of the lagged normal forces: relative change below this
    anchored = True            # False: re-anchor every node at every step (regularised, creeps)
    slip_length = 1e-6         # eps, as a fraction of the body's size
    project = False            # True: Newton's Hessian of a slipping node is its secant F / r along d too
    breakaway = 1e-4           # D_c: slip (fraction of the body's size) after which mu_s drops to mu_k
    history_fields = ("anchor", "run", "sliding", "trial", "N", "fresh", "_report", "nodal", "_y_last", "landing",
                      "caught")

    def __init__(self, ctx: Context, spec, coulomb):
        self.ctx, self.name = ctx, spec.name
        self.normal = np.asarray(spec.normal, float)
        self.point = np.asarray(spec.point, float).copy()
        self.k = float(spec.stiffness)
        self.mu_k, self.mu_s = float(coulomb.kinetic), float(coulomb.static)
        self.static_given = bool(coulomb.static_given)
        self.inherits = spec.name not in ctx.design.friction.grounds     # [contact]'s coefficients
        self.t = float(ctx.thickness.value)
        self.T = tangent_basis(self.normal)
        self._ready = False
        self._notes: dict = {}     # take_notes: {key: warning} for the next result
        self._y_last: Any = None   # node positions at the last iterate seen (contact_event: where contacts form)
        self.owner: Any = None     # per node: the index of the free object it lies on, -1 on a body
        self.landing: Any = None   # per node: its object touched this ground nowhere when the step began
        self.caught: Any = None    # per node: taken up by contact_event in this step
        self.bounds_steps = bool(ctx.design.objects)          # max_step: free objects land on the plane
        self._report: Any = None   # read-out at the last accepted step
        self.nodal: Any = None     # (nodes, friction force on the plane, slipping, N) at the last accepted step
        if self.active:
            self._setup()

    # -- set-up (only once friction is switched on: designs without it build nothing) --------------
    def _setup(self) -> None:
        if self._ready:
            return
        ctx = self.ctx
        w = boundary_weights(ctx.V)
        self.nodes = np.flatnonzero(w > 0.0).astype(np.int32)       # owned boundary nodes
        self.w = w[self.nodes]
        bs = ctx.bs
        self.dofs = (self.nodes[:, None] * bs + np.arange(bs)).astype(np.int32)
        self.X = ctx.V.tabulate_dof_coordinates()[self.nodes, :ctx.dim]
        u = ctx.u.x.array
        self.anchor = self.positions(u) @ self.T     # stick anchors s_i (tangential): where the nodes are (at
        #                                              rest, or where friction switched on live found them)
        if ctx.comm.allreduce(bool(np.any(u)), op=MPI.LOR):
            self._notes[f"grounds.{self.name}.friction"] = (
                f"grounds.{self.name}.friction: its history starts at a loaded state (friction switched on "
                "there, or the ground built anew by an edit), as if the body had slid freely to it; friction "
                "depends on the load path: the same loads with friction from rest give another state (solve "
                "from rest for that)")
        lo, hi = body_box(ctx.tagged, ctx.design)                     # the body's size, never an object's
        size = np.linalg.norm(hi - lo)
        self.eps = self.slip_length * float(size)                      # mm
        self.dc = self.breakaway * float(size)                          # mm
        self.run = np.zeros(len(self.nodes))                            # slip since the node last stuck, mm
        self.sliding = np.zeros(len(self.nodes), bool)               # committed: kinetic (slid past D_c)
        self.trial = self.sliding.copy()                              # this step's kinetic nodes
        self.N = np.zeros(len(self.nodes))                            # lagged normal forces
        self.fresh = self._touching(self.ctx.u.x.array)                # stuck in a step's first solve
        self._y_last = self.positions(u)
        self.owner = self._object_nodes()
        self.landing = self._landing(self.fresh)
        self.caught = np.zeros(len(self.nodes), bool)      # taken up by contact_event in this step
        self._ready = True
        self._unknown_history = not ctx.comm.allreduce(bool(np.any(u)), op=MPI.LOR)   # built at u = 0

    @property
    def active(self) -> bool:
        return self.mu_s > 0.0 or self.mu_k > 0.0

    def _object_nodes(self) -> np.ndarray:
        """Per node: the index of the free object (region ``object:NAME``) it lies on, -1 on a body."""
        from ..mesh.geometry import object_tag_name
        ctx = self.ctx
        tm = ctx.tagged
        owner = np.full(len(self.nodes), -1)
        for k, spec in enumerate(ctx.design.objects):
            cells = tm.cell_tags.find(tm.tags[object_tag_name(spec.name)])
            owner[np.isin(self.nodes, fem.locate_dofs_topological(ctx.V, ctx.mesh.topology.dim, cells))] = k
        return owner

    def _landing(self, touching: np.ndarray) -> np.ndarray:
        """Per node: whether it lies on a free object none of whose nodes touches the plane (same on every
        rank: an object's nodes may lie on several)."""
        count = len(self.ctx.design.objects)
        if not count:
            return np.zeros(len(self.nodes), bool)
        down = np.zeros(count, bool)
        down[self.owner[touching & (self.owner >= 0)]] = True
        if self.ctx.comm.size > 1:
            down = self.ctx.comm.allreduce(down.astype(np.int64)) > 0
        return (self.owner >= 0) & ~down[np.maximum(self.owner, 0)]

    # -- kinematics ----------------------------------------------------------------------------
    def positions(self, u: np.ndarray) -> np.ndarray:
        return self.X + u[self.dofs]

    def normal_forces(self, u: np.ndarray) -> np.ndarray:
        """N_i(u) = k t w_i max(-gap_i, 0), N: the ground's nodal forces on the body."""
        gap = (self.positions(u) - self.point) @ self.normal
        return self.k * self.t * self.w * np.maximum(-gap, 0.0)

    def _stiffness(self, F: np.ndarray) -> np.ndarray:
        """K_i = F_i / eps. A node held stuck in a step's first solve keeps the stiffness of the last lag
        (so that the solve starts where the last one ended), or k t w_i (the ground's penalty) if new."""
        last = np.where(self.trial, self.mu_k, self.mu_s) * self.N / self.eps
        return np.where(self.fresh, np.where(last > 0, last, self.k * self.t * self.w), F / self.eps)

    def _strength(self) -> np.ndarray:
        """F_i = mu_i N_i; inf (held by the spring alone) on the nodes that start the solve stuck."""
        F = np.where(self.trial, self.mu_k, self.mu_s) * self.N
        return np.where(self.fresh, np.inf, F)

    def _touching(self, u: np.ndarray) -> np.ndarray:
        """Nodes that touch or cross the plane at u. A step's first solve holds them stuck (a lagged N
        from the last step would let a contact whose load grows slide off before N catches up); the
        lag iteration then limits them to mu N."""
        return self._gaps(self.positions(u)) <= self._touch()

    def _gaps(self, y: np.ndarray) -> np.ndarray:
        return (y - self.point) @ self.normal

    def _touch(self) -> float:
        """The gap (mm) at or below which a node touches the plane."""
        return self.touch_tol * max(1.0, self.eps / self.slip_length)

    # -- landing (static solves) -------------------------------------------------------------------
    def max_step(self, u0: np.ndarray, p: np.ndarray) -> float:
        """alpha <= 1 at which the first node of a landing object (touching this ground nowhere when the
        step began) that is off the plane at u0 reaches it: the object lands on the plane (its contact
        then forms stuck, contact_event) instead of sinking into the penalty by as far as its trust
        region lets its first step go."""
        if not (self.active and self._ready and self.landing.any()):
            return 1.0
        gap = self._gaps(self.positions(u0))[self.landing]
        rate = p[self.dofs[self.landing]] @ self.normal
        falling = (gap > self._touch()) & (rate < 0.0)
        if not falling.any():
            return 1.0
        return float(min(1.0, (gap[falling] / -rate[falling]).min()))

    def contact_event(self, u: np.ndarray, static: bool = True) -> bool:
        """In a static solve, take up the nodes of landing objects (touching this ground nowhere when the
        step began) that press on the plane at u and carry no friction yet: anchored where they crossed
        the plane along the step from the last iterate seen, held stuck until the next lag update gives
        their N (as the contacts a step starts with). True if there were any: Newton stops there and
        goes on with them (Model.contact_event). Other nodes, and every node in a run in time, are taken
        up when the solve has converged (update_lag), anchored where they were when the step began:
        Newton's iterates can stray far (a nearly free body's first one turned it through the plane),
        and anchoring there held the body there."""
        if not (static and self.active and self._ready and self.landing.any()):
            return False
        y = self.positions(u)
        last, self._y_last = self._y_last, y
        gap = self._gaps(y)
        new = self.landing & (gap <= self._touch()) & ~self.fresh & ~(self.N > 0.0) & ~self.caught
        if not new.any():
            return False
        before = self._gaps(last[new])
        s = np.where(before > gap[new], np.clip(before / np.where(before > gap[new], before - gap[new], 1.0),
                                                 0.0, 1.0), 1.0)       # the crossing along the step
        self.anchor[new] = (last[new] + s[:, None] * (y[new] - last[new])) @ self.T
        self.fresh |= new
        self.caught |= new
        return True

    def _parts(self, u: np.ndarray):
        """(active nodes, d, r, K, F, sticking) at u for the nodes with F > 0 (F finite where slipping)."""
        F = self._strength()
        on = np.flatnonzero(F > 0.0)
        d = self.positions(u)[on] @ self.T - self.anchor[on]
        r = np.linalg.norm(d, axis=1)
        K = self._stiffness(F)[on]
        stick = K * r <= F[on]
        return on, d, r, K, np.where(stick & np.isinf(F[on]), K * r, F[on]), stick

    # -- energy ----------------------------------------------------------------------------------
    def energy(self, u: np.ndarray) -> float:
        if not (self.active and self._ready):
            return 0.0
        _, _, r, K, F, stick = self._parts(u)
        local = float(np.sum(np.where(stick, 0.5 * K * r ** 2, F * r - 0.5 * F ** 2 / K)))
        return self.ctx.comm.allreduce(local) if self.ctx.comm.size > 1 else local     # Pi is global

    def _forces(self, u: np.ndarray):
        """(active nodes, tangential force min(K r, F) d / r as (n, dim-1))."""
        on, d, r, K, F, stick = self._parts(u)
        scale = np.where(stick, K, F / np.where(stick, 1.0, r))
        return on, scale[:, None] * d

    def gradient(self, u: np.ndarray):
        if not (self.active and self._ready):
            return None
        on, f = self._forces(u)
        return self.dofs[on].ravel(), (f @ self.T.T).ravel()

    def hessian(self, u: np.ndarray) -> list:
        """One block-diagonal (per node) sparse block: K T T^T sticking, F/r T (I - e e^T) T^T slipping."""
        if not (self.active and self._ready):
            return []
        on, d, r, K, F, stick = self._parts(u)
        if not len(on):
            return []
        m = self.T.shape[1]
        e = d / np.where(r > 0, r, 1.0)[:, None]
        along = np.where(stick | self.project, 0.0, 1.0)                 # exact: no stiffness along the slip
        P = np.eye(m)[None] - along[:, None, None] * e[:, :, None] * e[:, None, :]
        c = np.where(stick, K, F / np.where(stick, 1.0, r))
        H = np.einsum("ia,nab,jb->nij", self.T, c[:, None, None] * P, self.T)        # (n, dim, dim)
        H = sp.block_diag(list(H), format="coo")
        return [(self.dofs[on].ravel(), H)]

    def pattern(self) -> list:
        if not self._ready:
            return []
        return [(self.nodes[i:i + 1], self.nodes[i:i + 1]) for i in range(len(self.nodes))]

    # -- lag and history ---------------------------------------------------------------------------
    def take_notes(self) -> list:
        notes, self._notes = list(self._notes.values()), {}
        return notes

    def set_factor(self, a: float) -> None:
        """A new attempt at a step starts from the committed slip states; a ramp from rest (u = 0
        everywhere) from no history at all; the first attempt after this term was built on a state it did
        not reach (an edit's carried-over state) from that state: every node anchored where it is."""
        if self._ready:
            u = self.ctx.u.x.array
            if not self.ctx.comm.allreduce(bool(np.any(u)), op=MPI.LOR):
                self.rest()
            elif self._unknown_history:
                self._unknown_history = False
                self._ready = False
                self._setup()
            self.trial = self.sliding.copy()
            self.fresh = self._touching(u)
            self._y_last = self.positions(u)
            self.landing = self._landing(self.fresh)
            self.caught = np.zeros(len(self.nodes), bool)

    def rest(self) -> None:
        """No history: every node anchored at its rest place, none slipped (a run in time from rest)."""
        self._notes = {}
        if self._ready:
            self._unknown_history = False
            self.anchor = self.X @ self.T
            self.N, self.run, self.sliding = np.zeros(len(self.nodes)), np.zeros(len(self.nodes)), \
                np.zeros(len(self.nodes), bool)
            self.trial = self.sliding.copy()
            self.fresh = self._touching(self.ctx.u.x.array)
            self._y_last = self.positions(self.ctx.u.x.array)
            self.landing = self._landing(self.fresh)
            self.caught = np.zeros(len(self.nodes), bool)

    def update_lag(self, model) -> bool:
        """Lagged normal forces (and breakaways past mu_s) to the state u; True if a re-solve is needed."""
        if not self.active:
            return False
        self._setup()
        comm = self.ctx.comm
        u = model.u.x.array
        N = self.normal_forces(u)
        scale = comm.allreduce(float(N.max()) if len(N) else 0.0, op=MPI.MAX)
        change = comm.allreduce(float(np.abs(N - self.N).max()) if len(N) else 0.0, op=MPI.MAX)
        changed = change > self.lag_rtol * scale or bool(self.fresh.any())
        self.N, self.fresh = N, np.zeros_like(self.fresh)
        if self.mu_s > self.mu_k:             # a sticking node pulled past mu_s N slides from now on
            r = np.linalg.norm(self.positions(u) @ self.T - self.anchor, axis=1)
            broke = ~self.trial & (N > 0.0) & (self.run + np.maximum(r - self.eps, 0.0) > self.dc)
            if broke.any():
                self.trial |= broke
                changed = True
        return bool(comm.allreduce(changed, op=MPI.LOR))

    def history(self):
        return super().history() if self._ready else None

    def lags(self):
        return self.N.copy() if (self.active and self._ready and self.N.any()) else None

    def set_lags(self, lags) -> None:
        self.N = np.array(lags, dtype=float)

    def lags_at(self, u: np.ndarray):
        return self.normal_forces(u)

    def _return_map(self, u: np.ndarray):
        """(anchors after the step, slipping nodes, r) at u: a node that slipped gets its anchor eps
        behind it, sticking nodes keep theirs, nodes off the plane take their current place."""
        s = self.positions(u) @ self.T
        d = s - self.anchor
        r = np.linalg.norm(d, axis=1)
        F = self._strength()
        slip = (F > 0.0) & (r > self.eps * (1 + 1e-12))
        if not self.anchored:
            return s.copy(), slip, r
        keep = np.where(slip, self.eps / np.where(slip, r, 1.0), 1.0)         # |d| -> eps on slipping nodes
        anchor = np.where(slip[:, None], s - keep[:, None] * d, self.anchor)
        return np.where((F > 0.0)[:, None], anchor, s), slip, r

    def stick_anchors(self):
        return self.anchor.ravel().copy() if (self.active and self._ready) else None

    def set_stick_anchors(self, a) -> None:
        self.anchor = np.asarray(a, float).reshape(self.anchor.shape).copy()

    def stick_anchor_step(self) -> tuple[float, float]:
        return 1e-3 * self.eps, 1e-3 * self.eps

    def stick_anchors_after(self, u):
        return self._return_map(u)[0].ravel()

    def end_step(self, model) -> None:
        """Return map: a node that slipped keeps its anchor eps behind it; sticking nodes keep theirs,
        nodes off the plane take their current place."""
        if not (self.active and self._ready):
            return
        u = model.u.x.array
        self._report = self._measure(u)
        self.anchor, slip, r = self._return_map(u)
        self.run = np.where(slip, self.run + np.maximum(r - self.eps, 0.0), 0.0)
        self.sliding = self.run > self.dc
        self.trial = self.sliding.copy()
        self.fresh = self._touching(u)
        self._y_last = self.positions(u)
        self.landing = self._landing(self.fresh)          # the next step's (a run in time sets no factor)
        self.caught = np.zeros(len(self.nodes), bool)

    # -- parameters, following, read-out -------------------------------------------------------------
    def parameters(self) -> dict:
        p = f"grounds.{self.name}"
        out = {f"{p}.friction": self.mu_k, f"{p}.friction_static": self.mu_s,
               f"{p}.point": self.point.copy(), f"{p}.stiffness": self.k}
        if self.inherits:                        # a ground without coefficients of its own follows [contact]
            out.update({"contact.friction": self.mu_k, "contact.friction_static": self.mu_s})
        return out

    def set_parameter(self, key: str, value) -> None:
        which = key.rsplit(".", 1)[1]
        if key.startswith("grounds.") and which.startswith("friction") and self.inherits:
            self.inherits, self.static_given = False, False     # its own coefficients from now on
        if which == "friction":                  # friction_static follows it unless it was written
            self.mu_k = float(value)
            self.mu_s = self.mu_s if self.static_given else self.mu_k
        elif which == "friction_static":
            self.mu_s, self.static_given = float(value), True
        elif which == "point":
            self.point = np.asarray(value, float).copy()
        elif which == "stiffness":
            self.k = float(value)
        else:
            raise KeyError(key)

    def follow(self, ctx: Context, changed: set) -> bool:
        """Built anew on every edit (it has no UFL energy): its node positions and weights may have moved."""
        return False

    def _measure(self, u: np.ndarray) -> dict:
        """The read-out at a converged state u (before the return map moves the anchors)."""
        comm = self.ctx.comm
        on, f = self._forces(u)
        force = comm.allreduce((f @ self.T.T).sum(axis=0) if len(on) else np.zeros(self.ctx.dim))
        _, _, r, _, _, _ = self._parts(u)
        slipping = np.zeros(len(self.N), bool)
        slipping[on] = r > self.eps * (1 + 1e-12)
        total = comm.allreduce(float(self.N.sum()))
        held = comm.allreduce(float(self.N[~slipping].sum()))
        nodal = np.zeros((len(self.N), self.ctx.dim))
        nodal[on] = f @ self.T.T
        self.nodal = (self.nodes, nodal, slipping, self.N.copy())   # per node, for per-piece read-outs
        return {"friction_force": force, "sticking": held / total if total > 0 else 1.0}

    def readout(self, model) -> dict:
        if not (self.active and self._ready):
            return {}                  # frictionless: result.json as before friction existed
        return {self.name: dict(self._report or self._measure(model.u.x.array))}


def build(ctx: Context) -> list[Term]:
    friction = ctx.design.friction
    return [GroundFriction(ctx, spec, friction.ground(spec.name)) for spec in ctx.design.grounds]
