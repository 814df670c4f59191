"""The geometry of boundary facets (edges in 2D, triangles in 3D) that friction anchors on: tangent
bases, closest points, and the closest facet of another piece."""
from __future__ import annotations

import numpy as np

CHUNK = 1 << 20         # 2D: entries of a (points x edges) array at a time (a few of them, 8 MB each)


def tangents(y: np.ndarray, facets: np.ndarray) -> np.ndarray:
    """(n, dim, dim - 1) orthonormal tangent bases of facets (rows of vertex indices into y): 2D, the
    edge's unit direction; 3D, the first edge's direction and the in-plane normal to it."""
    t1 = y[facets[:, 1]] - y[facets[:, 0]]
    t1 = t1 / np.linalg.norm(t1, axis=1)[:, None]
    if facets.shape[1] == 2:
        return t1[:, :, None]
    n = np.cross(t1, y[facets[:, 2]] - y[facets[:, 0]])
    t2 = np.cross(n / np.linalg.norm(n, axis=1)[:, None], t1)
    return np.stack([t1, t2], axis=2)


def closest_on_facets(P: np.ndarray, y: np.ndarray, facets: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (n, dim) of the points of facets (n, dim) closest to points P (n, dim).

    2D: the clipped parameter along the edge. 3D: the point of the triangle
    closest to P (its projection if inside, else the closest of its edges)."""
    a, b = y[facets[:, 0]], y[facets[:, 1]]
    if facets.shape[1] == 2:
        ab = b - a
        s = np.clip(np.einsum("nk,nk->n", P - a, ab) / np.einsum("nk,nk->n", ab, ab), 0.0, 1.0)
        return np.column_stack([1.0 - s, s])
    best = plane_coordinates(P, y, facets)          # the plane's projection, kept if inside
    inside = (best >= 0.0).all(axis=1)
    if inside.all():
        return best
    dist = np.where(inside, np.linalg.norm(P - np.einsum("nj,njk->nk", best, y[facets]), axis=1), np.inf)
    for i, j in ((0, 1), (1, 2), (0, 2)):                 # outside: the closest point of the three edges
        pa, pb = y[facets[:, i]], y[facets[:, j]]
        ab = pb - pa
        s = np.clip(np.einsum("nk,nk->n", P - pa, ab) / np.einsum("nk,nk->n", ab, ab), 0.0, 1.0)
        dd = np.linalg.norm(P - pa - s[:, None] * ab, axis=1)
        better = ~inside & (dd < dist)
        bary = np.zeros((len(P), 3))
        bary[:, i], bary[:, j] = 1.0 - s, s
        best[better], dist[better] = bary[better], dd[better]
    return best


def plane_coordinates(P: np.ndarray, y: np.ndarray, facets: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (n, dim) of the orthogonal projections of points P (n, dim) onto the lines
    (2D) or planes (3D) of facets (n, dim), not clipped to the facet: an anchor placed there has no
    tangential offset from P (a clipped closest point beside a facet's end has one, up to dhat)."""
    a, b = y[facets[:, 0]], y[facets[:, 1]]
    if facets.shape[1] == 2:
        ab = b - a
        s = np.einsum("nk,nk->n", P - a, ab) / np.einsum("nk,nk->n", ab, ab)
        return np.column_stack([1.0 - s, s])
    e1, e2, q = b - a, y[facets[:, 2]] - a, P - a
    d11, d12, d22 = (np.einsum("nk,nk->n", u, v) for u, v in ((e1, e1), (e1, e2), (e2, e2)))
    q1, q2 = np.einsum("nk,nk->n", q, e1), np.einsum("nk,nk->n", q, e2)
    det = d11 * d22 - d12 ** 2
    v = (d22 * q1 - d12 * q2) / det
    w = (d11 * q2 - d12 * q1) / det
    return np.column_stack([1.0 - v - w, v, w])


def closest_facet(P: np.ndarray, piece: np.ndarray, y: np.ndarray, F: np.ndarray, facet_piece: np.ndarray,
              candidates: int = 16, tie_break: float = 1e-3):
    """For points P (n, dim) of pieces `piece`: (facet, barycentric coordinates, distance) of the
    closest facet of another piece (F: the facets' vertex indices into the positions y, facet_piece:
    the piece of each facet). 2D: every edge is tried; 3D: the `candidates` facets of each other
    piece whose centroids lie nearest. Facets that share the closest point (a vertex facing another
    piece's corner) are told apart by the part of the offset along the facet, added with weight
    `tie_break`: the facet the point faces across its normal wins. (By distance alone the choice
    among them was round-off: a side edge whose tangent points at the vertex made its friction act
    along the normal, 6 % of a stacked box's weight.)"""
    if F.shape[1] == 2:
        a, b = y[F[:, 0]], y[F[:, 1]]
        ab = b - a
        length2 = np.einsum("ek,ek->e", ab, ab)
        normal = np.column_stack([-ab[:, 1], ab[:, 0]]) / np.sqrt(length2)[:, None]
        j = np.zeros(len(P), dtype=np.int64)
        s_j = np.zeros(len(P))
        d_j = np.zeros(len(P))
        chunk = max(1, CHUNK // max(len(F), 1))         # points x edges arrays of at most CHUNK entries
        for lo in range(0, len(P), chunk):
            p = P[lo:lo + chunk, None, :]
            s = np.clip(np.einsum("nek,ek->ne", p - a[None], ab) / length2, 0, 1)
            off = p - (a[None] + s[..., None] * ab[None])
            dist = np.linalg.norm(off, axis=2)
            rank = dist + tie_break * (dist - np.abs(np.einsum("nek,ek->ne", off, normal)))
            rank[piece[lo:lo + chunk, None] == facet_piece[None, :]] = np.inf
            pick = np.argmin(rank, axis=1)
            at = np.arange(len(pick))
            j[lo:lo + chunk], s_j[lo:lo + chunk], d_j[lo:lo + chunk] = pick, s[at, pick], dist[at, pick]
        return j, np.column_stack([1.0 - s_j, s_j]), d_j
    from scipy.spatial import cKDTree
    centroid = y[F].mean(axis=1)
    best_j = np.full(len(P), -1)
    best_b = np.zeros((len(P), 3))
    best_d = np.full(len(P), np.inf)          # the rank (distance and tie-break) of the best so far
    best_r = np.full(len(P), np.inf)          # its distance
    for q in np.unique(facet_piece):
        mine = np.flatnonzero(facet_piece == q)
        who = np.flatnonzero(piece != q)
        if not len(who):
            continue
        k = min(candidates, len(mine))
        _, near = cKDTree(centroid[mine]).query(P[who], k=k)
        cand = mine[np.asarray(near).reshape(len(who), k)]                 # (n, k) facets
        pts = np.repeat(P[who], k, axis=0)
        tri = y[F[cand.ravel()]]
        bary = closest_on_facets(pts, y, F[cand.ravel()])
        off = pts - np.einsum("nj,njk->nk", bary, tri)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        across = np.abs(np.einsum("nk,nk->n", off, n)) / np.linalg.norm(n, axis=1)
        dd = np.linalg.norm(off, axis=1)
        d = dd.reshape(len(who), k)
        rank = (dd + tie_break * (dd - across)).reshape(len(who), k)
        pick = np.argmin(rank, axis=1)
        rows = np.arange(len(who))
        better = rank[rows, pick] < best_d[who]
        w = who[better]
        best_j[w] = cand[rows, pick][better]
        best_b[w] = bary.reshape(len(who), k, 3)[rows, pick][better]
        best_d[w] = rank[rows, pick][better]
        best_r[w] = d[rows, pick][better]
    return best_j, best_b, best_r
