"""Planar polygon predicates used to validate 2D designs (vectorised numpy).

A polygon is an (n, 2) array of vertices, closed implicitly. "Inside" means
the closed region: points on the boundary count as inside, within a tolerance
`tol` relative to the polygon's size.
"""
from __future__ import annotations

import numpy as np


def edges(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points of the polygon's edges, each (n, 2)."""
    return poly, np.roll(poly, -1, axis=0)


def signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def segments_intersect(p, q, a, b, tol: float) -> np.ndarray:
    """Whether segments p->q and a->b (broadcast arrays of shape (..., 2)) share a point."""
    r, s = q - p, b - a
    den = _cross(r, s)
    ap = a - p
    par = np.abs(den) <= tol * np.linalg.norm(r, axis=-1) * np.linalg.norm(s, axis=-1) + 1e-300
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _cross(ap, s) / den
        w = _cross(ap, r) / den
    lr = np.linalg.norm(r, axis=-1)
    ls = np.linalg.norm(s, axis=-1)
    et, ew = tol / np.maximum(lr, 1e-300), tol / np.maximum(ls, 1e-300)
    crossing = ~par & (t >= -et) & (t <= 1 + et) & (w >= -ew) & (w <= 1 + ew)
    # parallel: collinear and overlapping projections
    collinear = par & (np.abs(_cross(ap, r)) <= tol * np.maximum(lr, 1e-300))
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = np.einsum("...i,...i->...", a - p, r) / lr ** 2
        t1 = np.einsum("...i,...i->...", b - p, r) / lr ** 2
    overlap = collinear & (np.maximum(t0, t1) >= -et) & (np.minimum(t0, t1) <= 1 + et)
    return crossing | overlap


def is_simple(poly: np.ndarray, tol: float) -> bool:
    """No two non-adjacent edges meet (adjacent edges share only their common vertex)."""
    n = len(poly)
    p, q = edges(poly)
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))           # first and last edges are adjacent
    i, j = i[keep], j[keep]
    if np.any(segments_intersect(p[i], q[i], p[j], q[j], tol)):
        return False
    # adjacent edges folding back onto each other (a zero-angle spike)
    e = q - p
    prev = np.roll(e, 1, axis=0)
    cos = np.einsum("ij,ij->i", e, prev) / (np.linalg.norm(e, axis=1) * np.linalg.norm(prev, axis=1))
    return not np.any(np.abs(_cross(prev, e)) <= tol * np.linalg.norm(e, axis=1)
                      * (cos < 0))


def on_boundary(points: np.ndarray, poly: np.ndarray, tol: float) -> np.ndarray:
    """Whether each point lies within tol of the polygon's boundary."""
    p, q = edges(poly)
    e = q - p
    rel = points[:, None, :] - p[None]
    t = np.clip(np.einsum("mni,ni->mn", rel, e) / np.einsum("ni,ni->n", e, e), 0.0, 1.0)
    dist = np.linalg.norm(rel - t[..., None] * e[None], axis=2)
    return dist.min(axis=1) <= tol


def contains(poly: np.ndarray, points: np.ndarray, tol: float) -> np.ndarray:
    """Whether each point lies in the closed polygon (even-odd rule, boundary included)."""
    points = np.atleast_2d(points)
    p, q = edges(poly)
    x, y = points[:, 0:1], points[:, 1:2]
    straddle = (p[None, :, 1] > y) != (q[None, :, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = p[None, :, 0] + (y - p[None, :, 1]) * (q[None, :, 0] - p[None, :, 0]) / (q[None, :, 1] - p[None, :, 1])
    inside = np.sum(straddle & (x < xc), axis=1) % 2 == 1
    return inside | on_boundary(points, poly, tol)


def strictly_inside(poly: np.ndarray, points: np.ndarray, tol: float) -> np.ndarray:
    points = np.atleast_2d(points)
    return contains(poly, points, tol) & ~on_boundary(points, poly, tol)


def boundaries_meet(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """Whether the boundaries of polygons a and b touch or cross."""
    pa, qa = edges(a)
    pb, qb = edges(b)
    return bool(np.any(segments_intersect(pa[:, None], qa[:, None], pb[None], qb[None], tol)))


def overlap(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """Whether two closed polygons share any point (touching counts)."""
    return (boundaries_meet(a, b, tol) or bool(np.any(contains(a, b[:1], tol)))
            or bool(np.any(contains(b, a[:1], tol))))


def crossing_parameters(p: np.ndarray, q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Parameters t in [0, 1] where segment p->q meets the edges of poly."""
    a, b = edges(poly)
    r, s = q - p, b - a
    den = _cross(r[None], s)
    ap = a - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _cross(ap, s) / den
        w = _cross(ap, r[None]) / den
    ok = np.isfinite(t) & (t >= 0) & (t <= 1) & (w >= 0) & (w <= 1)
    # also the projections of the polygon's vertices that lie on the segment
    rr = float(r @ r)
    tv = (poly - p) @ r / rr if rr > 0 else np.zeros(len(poly))
    return np.concatenate([t[ok], np.clip(tv, 0.0, 1.0)])


def sample_polyline(path: np.ndarray, loops: list) -> np.ndarray:
    """Points along a polyline: its vertices, where it meets any loop, and midpoints between."""
    out = []
    for p, q in zip(path[:-1], path[1:]):
        t = np.concatenate([[0.0, 1.0]] + [crossing_parameters(p, q, loop) for loop in loops])
        t = np.unique(np.clip(t, 0.0, 1.0))
        mids = 0.5 * (t[:-1] + t[1:])
        t = np.sort(np.concatenate([t, mids]))
        out.append(p + t[:, None] * (q - p))
    return np.vstack(out)
