"""How far a design can move along a direction before its discrete energy has a kink (2D).

The energy on a moved mesh is smooth in the node coordinates and the cable
sketches while the combinatorics hold. A cable's via points are the
sketch's cuts with the mesh edges and its vertices (or an anchor's lattice
points), each a material point x = X + u(X) with u piecewise linear (P1) or
quadratic (P2) across cells: the energy has a kink, its derivative a jump
proportional to the strain's jump between the cells, where

* a mesh node crosses a sketch segment (the sketch now cuts other edges), or
* a sketch vertex, an anchor's lattice point or a marker crosses a mesh edge (it changes cells).

``smooth_step`` returns the smallest positive step h at which either
happens along (node velocities, point velocities), each pair's distance
followed as the quadratic it is. Between kinks the design gradient is exact;
a gradient-based optimiser sees the kinks as small jumps of the gradient
(their size shrinks with the mesh size, their number grows).
"""
from __future__ import annotations

import numpy as np

MARGIN = 0.02      # a crossing within this fraction beyond a segment's ends counts (the ends move too)


def _first_root(c0, c1, c2) -> np.ndarray:
    """The smallest h > 0 with c0 + c1 h + c2 h^2 = 0, inf where none (vectorised)."""
    out = np.full(np.shape(c0), np.inf)
    lin = np.abs(c2) <= 1e-14 * (np.abs(c1) + np.abs(c0) + 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -c0 / c1
        out = np.where(lin & (h > 0), h, out)
        disc = c1 * c1 - 4 * c0 * c2
        sq = np.sqrt(np.maximum(disc, 0.0))
        for root in ((-c1 - sq) / (2 * c2), (-c1 + sq) / (2 * c2)):
            ok = ~lin & (disc >= 0) & (root > 0)
            out = np.where(ok, np.minimum(out, root), out)
    return out


def crossing_step(P, vP, A, vA, B, vB) -> float:
    """The first h > 0 at which a point P + h vP crosses the segment (A + h vA, B + h vB); pairs
    broadcast (points against segments) and only crossings near the segment's extent count."""
    e, d = B - A, P - A
    ve, vd = vB - vA, vP - vA
    c0 = e[..., 0] * d[..., 1] - e[..., 1] * d[..., 0]
    c1 = ve[..., 0] * d[..., 1] - ve[..., 1] * d[..., 0] + e[..., 0] * vd[..., 1] - e[..., 1] * vd[..., 0]
    c2 = ve[..., 0] * vd[..., 1] - ve[..., 1] * vd[..., 0]
    h = _first_root(c0, c1, c2)
    finite = np.isfinite(h)
    hh = np.where(finite, h, 0.0)[..., None]
    e_h, d_h = e + hh * ve, d + hh * vd                        # where the crossing happens
    t = np.sum(e_h * d_h, axis=-1) / np.maximum(np.sum(e_h * e_h, axis=-1), 1e-300)
    h = np.where(finite & (t >= -MARGIN) & (t <= 1 + MARGIN), h, np.inf)
    return float(h.min()) if h.size else np.inf


def smooth_step(nodes, node_velocity, edges, segments, segment_velocity, points, point_velocity,
                chunk: int = 4096) -> float:
    """The first kink along the direction: nodes (n, 2) against sketch segments (m, 2, 2), and points
    (sketch vertices, lattice points, markers; k, 2) against mesh edges (node index pairs (e, 2))."""
    step = np.inf
    if len(segments):
        A, B = segments[None, :, 0], segments[None, :, 1]
        vA, vB = segment_velocity[None, :, 0], segment_velocity[None, :, 1]
        for lo in range(0, len(nodes), chunk):
            P, vP = nodes[lo:lo + chunk, None], node_velocity[lo:lo + chunk, None]
            step = min(step, crossing_step(P, vP, A, vA, B, vB))
    if len(points):
        ea, eb = edges[:, 0], edges[:, 1]
        for lo in range(0, len(points), max(chunk // 64, 1)):
            P, vP = points[lo:lo + chunk // 64, None], point_velocity[lo:lo + chunk // 64, None]
            step = min(step, crossing_step(P, vP, nodes[ea][None], node_velocity[ea][None],
                                           nodes[eb][None], node_velocity[eb][None]))
    return step
