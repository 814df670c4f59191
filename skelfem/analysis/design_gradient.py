"""Exact design gradients of a static equilibrium by the adjoint (2D; 3D bone poses).

The design's handles p (skelfem.analysis.handles) move its polygons, cable
sketches and markers; the mesh follows the polygons by the editor's morph
(skelfem.mesh.morph: the same topology, node coordinates X(p) linear in the
polygon vertices), and the equilibrium u(p) solves R(u; X, Q, E) = 0. For an
objective J(u; X, Q, markers):

    dJ/dp = (dJ/dpsi - z^T dR/dpsi) dpsi/dp,     H z = dJ/du,

psi = (X, Q, marker references, E), H the Newton Hessian at the converged
state, factorised once (skelfem.analysis.sensitivity.Linearization, the
same matrix and factorisation as Soft IK), so one back-substitution serves
every handle. z^T dR/dX and dJ/dX are assembled once as vectors over the
nodes (skelfem.analysis.shape) and pulled back to the polygon vertices by the
transpose of the morph (Morph.pull_back: two solves with its Laplacian),
whatever the number of handles.

In 3D the handles are the bones' poses and the materials' E
(skelfem.analysis.handles.PoseHandles3D) and the mesh follows by
skelfem.mesh.morph3d (a posed bone's nodes rigidly, the silicone's by the
harmonic extension, the outer surface fixed): the same formula, with
Morph3D.pull_back for the morph's transpose and the tendons' cuts with the
tetrahedra's facets differentiated through their 3 x 3 systems
(skelfem.analysis.cable_shape).

Exact for the discrete problem on the moved mesh: what the test against
full re-solves on moved meshes (tests/test_design_gradient.py) measures. Not
covered (ValueError): see skelfem.analysis.shape.uncovered.

Through a ground's friction the equilibrium depends on the load path: J(p)
is taken as the equilibrium reached from rest (every design is solved from
rest, the load ramped as ``skelfem simulate`` does), and its derivative along
a path on which no contact node changes between sticking and slipping.
Sticking nodes keep their anchors where they rest, which move with the
design's nodes (skelfem.analysis.shape: the friction's shape derivative);
the lagged normal forces follow the state (J = H + C, the adjoint solves
with J^T). Exact while every contact node sticks (a slipping node's anchor
is set by the load path, which is held).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..mesh.morph import Morph, polygons
from ..mesh.morph3d import Morph3D
from ..terms.friction import GroundFriction
from .cable_shape import mesh_edges
from .handles import DesignHandles, PoseHandles3D
from .sensitivity import Linearization
from .shape import ShapeDerivative, uncovered
from .shape_points import MaterialPoints
from .smooth_step import smooth_step


class MeshDegrades(ValueError):
    """The morph cannot move the mesh to these design values (a triangle would turn over or flatten)."""


# -- a cable's own parameters -----------------------------------------------------------------------------
def cable_parameter(model, name: str, kind: str, z: np.ndarray) -> tuple[float, float]:
    """(z^T dR/dq, dT/dq) for q a frictionless cable's stiffness k or pretension p at fixed u, T its tension.

    R_cable = k s g with s = l - L0 + p (taut, s > 0; zero while slack) and g = grad l:
    dR/dk = s g, dT/dk = s; dR/dp = k g, dT/dp = k."""
    term = model.term("cables", name)
    u = model.u.x.array
    s = term.cable.length(u) - term.rest_length
    if s <= 0.0:
        return 0.0, 0.0
    zg = float(np.dot(z[term.cable.dofs], term.cable.length_gradient(u)))
    if kind == "stiffness":
        return s * zg, s
    return term.cable.k * zg, term.cable.k


# -- objectives -------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MarkerTarget:
    """J = |y - target|^2 (mm^2), y a marker's position at equilibrium."""

    marker: str
    target: tuple

    def _points(self, model):
        try:
            markers = model.term("markers")
        except KeyError:
            raise ValueError(f"markers.{self.marker}: the design has no markers") from None
        if self.marker not in markers.names:
            raise ValueError(f"markers.{self.marker}: no such marker (have: {', '.join(markers.names)})")
        return markers, markers.names.index(self.marker)

    def value(self, model) -> float:
        markers, i = self._points(model)
        r = markers.positions(model.u.x.array)[i] - np.asarray(self.target, dtype=float)
        return float(r @ r)

    def state_gradient(self, model) -> np.ndarray:
        markers, i = self._points(model)
        r = markers.positions(model.u.x.array)[i] - np.asarray(self.target, dtype=float)
        d = model.mesh.geometry.dim
        S = markers.local_operator()[d * i:d * i + d]
        return np.asarray(S.T @ (2.0 * r)).ravel()

    def explicit_parameter(self, cable: str, kind: str, dT: float) -> float:
        """dJ/dq at fixed u for a cable's parameter q (dT: the cable's tension's): a marker does not see it."""
        return 0.0

    def explicit(self, model, shape) -> tuple[np.ndarray, dict, dict]:
        """(dJ/dX, {cable: dJ/dQ}, {marker: dJ/d(reference)}) at fixed u."""
        markers, i = self._points(model)
        u = model.u.x.array
        gy = 2.0 * (markers.positions(u)[i] - np.asarray(self.target, dtype=float))
        pts = MaterialPoints(model.V, markers.X[i:i + 1])
        G = pts.gradients(u)[0]
        return pts.nodes_of(-(G.T @ gy)[None, :]), {}, {self.marker: gy + G.T @ gy}


@dataclass(frozen=True)
class Tension:
    """J = the tension of a cable, k max(l - L, 0) (N)."""

    cable: str

    def value(self, model) -> float:
        term = model.term("cables", self.cable)
        return float(term.cable.tension(model.u.x.array, term.rest_length))

    def state_gradient(self, model) -> np.ndarray:
        term = model.term("cables", self.cable)
        u = model.u.x.array
        out = np.zeros(len(u))
        if term.cable.length(u) > term.rest_length:
            np.add.at(out, term.cable.dofs, term.cable.k * term.cable.length_gradient(u))
        return out

    def explicit_parameter(self, cable: str, kind: str, dT: float) -> float:
        return dT if cable == self.cable else 0.0

    def explicit(self, model, shape) -> tuple[np.ndarray, dict, dict]:
        gX, gQ = shape.cables[self.cable].tension_gradient(model.u.x.array)
        return gX, {self.cable: gQ}, {}


# -- the gradient ------------------------------------------------------------------------------------------
class DesignGradient:
    """A session's design with handles, solved at p and differentiated there.

    Make it while the session's mesh is the one generated for its design (before any morphing edit):
    the morph's linear map starts from it. Cables whose ends or bends pull on a disk of the default
    radius (1 % of the mesh's bounding box, which has kinks where nodes tie for an extreme) get that
    radius written into the design (``cables.C.anchor_radius``), the same value: the start's answer
    does not change, and the optimised design file keeps it.
    """

    def __init__(self, session, keys):
        why = uncovered(session.model)
        if why:
            raise ValueError(why)
        self.session = session
        self.dim = session.design.dim
        self.handles = DesignHandles(session.design, keys) if self.dim == 2 else \
            PoseHandles3D(session.design, keys, session.model.tm)
        self.frictional = any(isinstance(t, GroundFriction) and t.active for t in session.model.terms)
        self.morph = Morph(session.model.tm, session.design) if self.dim == 2 else \
            Morph3D(session.model.tm, session.design)
        self.p = np.zeros(len(self.handles.keys))
        self._shape = None
        self.timings: dict = {}
        # a cable end or bend in silicone pulls on a disk whose default radius is 1 % of the mesh's
        # bounding box: a kink wherever several nodes share an extreme (a straight side of the body).
        # The moved designs keep the start's radius, written out (the start's answer is unchanged).
        for term in session.model.terms_in("cables"):
            if term.anchors and session.design.cable(term.name).anchor_radius is None:
                self.handles.anchor_radii[term.name] = float(next(iter(term.anchors.values())))
        if self.handles.anchor_radii:
            session.edit(self.handles.raw(self.p), morph=True)

    @property
    def keys(self) -> list[str]:
        return list(self.handles.keys)

    def solve(self, p=None, overrides=()):
        """Move the design to p (the mesh by the morph, same topology), with --set overrides (live parameters:
        a target's contraction), and solve; returns the Result."""
        if p is not None or overrides:
            from ..design.parse import parse_design
            p = self.p if p is None else np.asarray(p, dtype=float)
            design = parse_design(self.handles.raw(p), self.session.design.source, list(overrides))  # DesignError
            if self.morph.moved(design) is None:          # asked first: a refused morph would re-mesh the session
                raise MeshDegrades("the moved mesh degrades at these design values (the morph refused it): "
                                   "re-mesh and start again from there")
            how = self.session.edit(design, morph=True)
            if how == "re-meshed":
                raise MeshDegrades("the session re-meshed the moved design: the gradient's mesh is gone")
            self.p = p.copy()
        t0 = time.perf_counter()
        if self.frictional:              # friction's answer depends on the load path: every design from rest
            self.session.solved = False
        result = self.session.solve()
        self.timings["solve"] = time.perf_counter() - t0
        return result

    def shape(self) -> ShapeDerivative:
        """The shape derivative of the present model (forms compiled once per model; cables traced anew)."""
        model = self.session.model
        key = (id(model), tuple(id(t) for t in model.terms if t.has_ufl_energy()))
        if self._shape is None or self._shape[0] != key:
            self._shape = (key, ShapeDerivative(model))
        else:
            self._shape[1].trace_cables()
        return self._shape[1]

    def check_mesh(self) -> None:
        """The mesh is where the morph puts it for the handles' present values (else the gradient would be
        of another discrete problem)."""
        model = self.session.model
        if self.dim == 3:
            X = self.morph.moved(self.session.design)
            if X is None or not np.allclose(model.mesh.geometry.x, X, rtol=0.0,
                                            atol=1e-9 * (1.0 + float(np.abs(X).max()))):
                raise ValueError("the mesh is not the start mesh moved by the morph (was the session re-meshed?)")
            return
        polys, _, _ = self.handles.split(self.handles.points(self.p))
        X = self.morph.X0 + self.morph.displacement([a - b for a, b in zip(polys, self.morph.polys0)])
        scale = 1.0 + float(np.abs(X).max())
        if not np.allclose(model.mesh.geometry.x[:, :2], X, rtol=0.0, atol=1e-9 * scale):
            raise ValueError("the mesh is not the start mesh moved by the morph (was the session re-meshed?)")
        if len(polygons(self.session.design)) != len(polys):
            raise ValueError("the design's polygons changed")

    def gradient(self, objective) -> tuple[float, np.ndarray]:
        """(J, dJ/dp) at the present solved state, by one adjoint solve."""
        t0 = time.perf_counter()
        if not self.session.solved:
            raise ValueError("the design is not solved: call solve() first")
        self.check_mesh()
        model, solver = self.session.model, self.session.solver
        J = objective.value(model)
        lin = Linearization(model, solver)
        t1 = time.perf_counter()
        try:
            rhs = objective.state_gradient(model)
            rhs[model.fixed] = 0.0
            b = model.u.vector.duplicate()
            b.array_w[:] = rhs[:len(b.array_w)]
            z_vec = lin.solve_transposed(b)
            z = z_vec.array_r.copy()
            b.destroy()
            z_vec.destroy()
        finally:
            lin.destroy()
        t2 = time.perf_counter()
        shape = self.shape()
        rX, rQ = shape.adjoint(z)
        eX, eQ, eM = objective.explicit(model, shape)
        gQ = {c: eQ.get(c, 0.0) - rQ[c] for c in rQ}
        g_polys = self.morph.pull_back(eX - rX)
        g_points = self.handles.join(g_polys, gQ, eM)
        dJ = np.einsum("ni,nij->j", g_points, self.handles.velocities(self.p))
        for j, h in enumerate(self.handles.handles):
            if h.kind == "modulus":
                dJ[j] -= shape.modulus(z, h.material)
            elif h.kind in ("stiffness", "pretension"):
                dR, dJ_explicit = cable_parameter(model, h.cable, h.kind, z)
                dJ[j] += objective.explicit_parameter(h.cable, h.kind, dJ_explicit) - dR
        t3 = time.perf_counter()
        self.timings.update(factorise=t1 - t0, adjoint_solve=t2 - t1, assemble=t3 - t2, gradient=t3 - t0)
        return J, dJ

    def smooth_step(self, dp) -> float:
        """The largest step h along dp before the discrete energy has a kink (a mesh node crosses a cable's
        sketch, a sketch vertex, anchor lattice point or marker crosses a mesh edge: skelfem.analysis.
        smooth_step), followed to second order in h: where J(p + h dp) is smooth and its Taylor remainder
        falls as h^2."""
        if self.dim != 2:
            raise ValueError("smooth_step: 2D designs")
        dp = np.asarray(dp, dtype=float)
        h = self.handles
        V = h.velocities(self.p) @ dp                       # (points, 2)
        polys_v, paths_v, markers_v = h.split(V)
        polys, paths, markers = h.split(h.points(self.p))
        mesh = self.session.model.mesh
        nodes = mesh.geometry.x[:, :2]
        W = self.morph.displacement(polys_v)
        segments = [np.stack([q[:-1], q[1:]], axis=1) for q in paths.values()]
        seg_v = [np.stack([v[:-1], v[1:]], axis=1) for v in paths_v.values()]
        pts = [q for q in paths.values()] + [np.atleast_2d(m) for m in markers.values()]
        pts_v = [v for v in paths_v.values()] + [np.atleast_2d(m) for m in markers_v.values()]
        for name, c in self.shape().cables.items():
            for samples, k in c.lattice:
                pts.append(samples)
                pts_v.append(np.broadcast_to(paths_v[name][k], samples.shape))
        edges = mesh_edges(mesh)[0]
        return smooth_step(nodes, W, edges, np.concatenate(segments) if segments else np.zeros((0, 2, 2)),
                           np.concatenate(seg_v) if seg_v else np.zeros((0, 2, 2)),
                           np.vstack(pts) if pts else np.zeros((0, 2)),
                           np.vstack(pts_v) if pts_v else np.zeros((0, 2)))
