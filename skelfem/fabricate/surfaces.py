"""Triangle surfaces: ray hits, inside tests, point-triangle distances; binary STL files and their checks.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


FORMAT = 1
GRAZING = 0.5          # sin of the smallest angle (30 degrees) at which a channel may enter a bone
CURVATURE = 40         # triangles per full turn of a curved face in the STL files
PROBE_CURVATURE = 24   # ... in the planning pass
MIN_EDGE = 0.25        # mm: the shortest triangle edge asked for (a 1.2 mm channel gets 15 sides)
RAY = np.array([0.5377, 0.8315, 0.1402]) / np.linalg.norm([0.5377, 0.8315, 0.1402])  # off-axis, for parity


class FabricationError(ValueError):
    """A design that cannot be fabricated as asked; key names the design key to change."""

    def __init__(self, key: str, message: str):
        super().__init__(f"{key}: {message}")
        self.key, self.message = key, message


# -- triangle surfaces -----------------------------------------------------------------------------------
@dataclass
class Surface:
    """A closed triangulated surface: points (k, 3), triangles (m, 3) and the CAD face of each triangle."""

    points: np.ndarray
    tris: np.ndarray
    faces: np.ndarray

    @property
    def corners(self) -> np.ndarray:
        return self.points[self.tris]

    @property
    def normals(self) -> np.ndarray:
        c = self.corners
        n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
        return n / np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]


def _candidates(origins: np.ndarray, d: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ray, triangle) pairs whose shadows along the common direction d can overlap.

    Rays and triangles are projected onto a plane normal to d; the plane is
    cut into about one cell per triangle, each triangle listed in every cell
    its bounding box touches, and a ray meets only the triangles of its cell.
    """
    a = np.cross(d, np.eye(3)[int(np.argmin(np.abs(d)))])
    a /= np.linalg.norm(a)
    basis = np.column_stack([a, np.cross(d, a)])
    P, C = origins @ basis, corners @ basis
    lo, hi = C.min(axis=1), C.max(axis=1)
    g0, g1 = lo.min(axis=0), hi.max(axis=0)
    h = max(float(np.sqrt(np.prod(np.maximum(g1 - g0, 1e-12)) / max(len(C), 1))), 1e-12)
    shape = np.maximum(np.ceil((g1 - g0) / h).astype(int), 1)
    i0 = np.clip(((lo - g0) / h).astype(int), 0, shape - 1)
    i1 = np.clip(((hi - g0) / h).astype(int), 0, shape - 1)
    nx, ny = i1[:, 0] - i0[:, 0] + 1, i1[:, 1] - i0[:, 1] + 1
    count = nx * ny
    tri = np.repeat(np.arange(len(C)), count)
    k = np.arange(len(tri)) - np.repeat(np.cumsum(count) - count, count)
    cx, cy = i0[tri, 0] + k % nx[tri], i0[tri, 1] + k // nx[tri]
    cell = cx * shape[1] + cy
    order = np.argsort(cell, kind="stable")
    cell, tri = cell[order], tri[order]
    r = np.floor((P - g0) / h).astype(int)
    inside_grid = np.all((r >= 0) & (r < shape), axis=1)
    rc = np.where(inside_grid, r[:, 0] * shape[1] + r[:, 1], -1)
    first, last = np.searchsorted(cell, rc, "left"), np.searchsorted(cell, rc, "right")
    n = np.where(inside_grid, last - first, 0)
    ray = np.repeat(np.arange(len(P)), n)
    j = np.arange(len(ray)) - np.repeat(np.cumsum(n) - n, n)
    return ray, tri[np.repeat(first, n) + j]


def ray_hits(origins: np.ndarray, direction: np.ndarray, corners: np.ndarray, tol: float,
             chunk: int = 2_000_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where rays o + t d (t > -tol) cross triangles: (ray index, t, triangle index), sorted by ray then t.

    Moller-Trumbore with triple products: for a triangle a, b, c with
    e1 = b - a, e2 = c - a, det = (d x e2).e1 and s = o - a,
    u = s.(d x e2)/det, v = s.(e1 x d)/det, t = s.(e1 x e2)/det; a hit has
    u, v >= 0 and u + v <= 1 (a little slack, so that a ray through a shared
    edge hits both triangles; such repeats, within tol along the ray, are
    merged). direction is one vector for all rays (then only the pairs that
    _candidates finds are tested) or one per ray (r, 3).
    """
    origins = np.atleast_2d(np.asarray(origins, float))
    direction = np.asarray(direction, float)
    if direction.ndim == 1:
        rays, tris = _candidates(origins, direction / np.linalg.norm(direction), corners)
        d = np.broadcast_to(direction, (len(rays), 3))
    else:
        rays = np.repeat(np.arange(len(origins)), len(corners))
        tris = np.tile(np.arange(len(corners)), len(origins))
        d = direction[rays]
    R, T, I = [np.zeros(0, int)], [np.zeros(0)], [np.zeros(0, int)]
    for i0 in range(0, len(rays), chunk):
        r, k, dd = rays[i0:i0 + chunk], tris[i0:i0 + chunk], d[i0:i0 + chunk]
        a = corners[k, 0]
        e1, e2 = corners[k, 1] - a, corners[k, 2] - a
        p = np.cross(dd, e2)
        det = (p * e1).sum(1)
        ok = np.abs(det) > 1e-12 * np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = origins[r] - a
        u = (s * p).sum(1) * inv
        v = (s * np.cross(e1, dd)).sum(1) * inv
        t = (s * np.cross(e1, e2)).sum(1) * inv
        eps = 1e-9
        hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t > -tol)
        R.append(r[hit]), T.append(t[hit]), I.append(k[hit])
    r, t, k = np.concatenate(R), np.concatenate(T), np.concatenate(I)
    order = np.lexsort((t, r))
    r, t, k = r[order], t[order], k[order]
    keep = np.ones(len(r), bool)
    keep[1:] = (r[1:] != r[:-1]) | (t[1:] - t[:-1] > tol)
    return r[keep], t[keep], k[keep]


def inside(points: np.ndarray, surface: Surface, tol: float) -> np.ndarray:
    """Which points lie inside a closed surface: the parity of crossings of an off-axis ray."""
    points = np.atleast_2d(points)
    r, t, _ = ray_hits(points, RAY, surface.corners, tol)
    r = r[t > tol]
    return np.bincount(r, minlength=len(points)) % 2 == 1


def point_triangle_distance(points: np.ndarray, corners: np.ndarray, chunk: int = 400_000) -> np.ndarray:
    """Exact distances (p, t) from points to triangles.

    The point's projection onto the triangle's plane, w = p - a = s e1 + t e2
    + h n, lies inside when s, t >= 0 and s + t <= 1: the distance is |h|.
    Otherwise the nearest point lies on an edge: min over the three segments
    of |p - x - clip((p - x).e / e.e, 0, 1) e|.
    """
    points = np.atleast_2d(points)
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    e1, e2 = b - a, c - a
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    den = np.maximum(d11 * d22 - d12 ** 2, 1e-300)
    n = np.cross(e1, e2)
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    out = np.empty((len(points), len(a)))
    step = max(1, chunk // max(len(a), 1))
    for i0 in range(0, len(points), step):
        p = points[i0:i0 + step, None, :]
        w = p - a
        w1, w2 = np.einsum("ptk,tk->pt", w, e1), np.einsum("ptk,tk->pt", w, e2)
        s, t = (d22 * w1 - d12 * w2) / den, (d11 * w2 - d12 * w1) / den
        face = np.abs(np.einsum("ptk,tk->pt", w, n))
        edge = np.full(face.shape, np.inf)
        for x, e in ((a, e1), (b, c - b), (a, e2)):
            y = p - x
            f = np.clip(np.einsum("ptk,tk->pt", y, e) / np.maximum((e * e).sum(1), 1e-300), 0.0, 1.0)
            edge = np.minimum(edge, np.linalg.norm(y - f[..., None] * e, axis=2))
        out[i0:i0 + step] = np.where((s >= 0) & (t >= 0) & (s + t <= 1), face, edge)
    return out


def face_distances(points: np.ndarray, surface: Surface) -> tuple[np.ndarray, np.ndarray]:
    """Distances (p, f) from points to each CAD face of a surface, and the face ids (f,)."""
    order = np.argsort(surface.faces, kind="stable")
    faces, starts = np.unique(surface.faces[order], return_index=True)
    d = point_triangle_distance(points, surface.corners[order])
    return np.minimum.reduceat(d, starts, axis=1), faces


# -- STL files and their checks ----------------------------------------------------------------------------
STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def signed_volume(points: np.ndarray, tris: np.ndarray) -> float:
    """Volume enclosed by an outward-oriented closed surface (divergence theorem): sum a.(b x c) / 6."""
    a, b, c = points[tris[:, 0]], points[tris[:, 1]], points[tris[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _edges(tris: np.ndarray):
    """Half-edges (3m, 2) of the triangles, their triangle, and undirected edge ids with counts."""
    half = tris[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    owner = np.repeat(np.arange(len(tris)), 3)
    key = np.sort(half, axis=1)
    _, edge, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return half, owner, edge.ravel(), count


def orient(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """The triangles of a closed 2-manifold, reordered so that every shared edge is used once each way
    and every connected part encloses positive volume, except a part inside an odd number of others:
    it bounds a cavity and encloses negative volume.

    Neighbours across an edge agree when they use it in opposite
    directions. A breadth-first tree over the triangles (scipy) gives each
    triangle a parent; whether it must flip is the parity of disagreements on
    its path to the root, found for all triangles at once by pointer doubling
    (log depth numpy steps). Raises ValueError if an edge is not shared by
    exactly two triangles.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    m = len(tris)
    half, owner, edge, count = _edges(tris)
    if np.any(count != 2):
        raise ValueError(f"{int(np.sum(count != 2))} edges are not shared by exactly two triangles")
    order = np.argsort(edge, kind="stable")
    i, j = order[0::2], order[1::2]                       # the two half-edges of each edge
    same = np.all(half[i] == half[j], axis=1)             # used the same way: the triangles disagree
    ti, tj = owner[i], owner[j]
    w = coo_matrix((np.r_[same, same] + 1.0, (np.r_[ti, tj], np.r_[tj, ti])), shape=(m, m)).tocsr()
    ncomp, label = connected_components(w, directed=False)
    parent = np.arange(m)
    for comp in range(ncomp):
        root = int(np.flatnonzero(label == comp)[0])
        _, pred = breadth_first_order(w, root, directed=False, return_predecessors=True)
        members = np.flatnonzero(label == comp)
        members = members[members != root]
        parent[members] = pred[members]
    flip = (np.asarray(w[np.arange(m), parent]).ravel() == 2.0)
    flip[parent == np.arange(m)] = False
    jump = parent.copy()
    while np.any(jump != jump[jump]):
        flip = flip ^ flip[jump]
        jump = jump[jump]
    flip = flip ^ flip[jump]                              # the last step up to the root (root's flip is 0)
    out = tris.copy()
    out[flip] = out[flip][:, [0, 2, 1]]
    for comp in range(ncomp):
        sel = label == comp
        if signed_volume(points, out[sel]) < 0:
            out[sel] = out[sel][:, [0, 2, 1]]
    if ncomp > 1:                   # a part inside an odd number of others bounds a cavity: inward
        scale = float(np.ptp(points, axis=0).max())
        for comp in range(ncomp):
            sel = label == comp
            probe = points[tris[np.flatnonzero(sel)[0], :1]]
            depth = sum(bool(inside(probe, Surface(points, out[label == other], None), 1e-9 * scale)[0])
                        for other in range(ncomp) if other != comp)
            if depth % 2:
                out[sel] = out[sel][:, [0, 2, 1]]
    return out


def write_stl(path, points: np.ndarray, tris: np.ndarray, name: str) -> None:
    """Binary STL: 80-byte header, uint32 count, per triangle its unit normal and corners (float32)."""
    c = points[tris].astype(np.float32).astype(float)    # the corners as written: a reader's normal of a
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])      # sliver follows its float32 corners
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    # Readers that guess ASCII or binary from the bytes after the header (admesh: any byte > 127 means
    # binary) are sure to see one if the first triangle's normal has a negative component.
    first = int(np.argmin(n.min(axis=1))) if len(n) else 0
    n, c = np.roll(n, -first, axis=0), np.roll(c, -first, axis=0)
    rec = np.zeros(len(tris), STL_RECORD)
    rec["normal"], rec["corners"] = n, c
    header = f"skelfem fabricate: {name} (mm)".encode("utf-8", "replace")[:80].ljust(80, b" ")
    with open(path, "wb") as f:
        f.write(header)
        f.write(np.uint32(len(tris)).tobytes())
        f.write(rec.tobytes())


def read_stl(path) -> tuple[np.ndarray, np.ndarray]:
    """A binary STL as (points, triangles), corners merged where their float32 coordinates are equal."""
    data = Path(path).read_bytes()
    count = int(np.frombuffer(data, "<u4", 1, 80)[0])
    if len(data) != 84 + count * STL_RECORD.itemsize:
        raise ValueError(f"{path}: not a binary STL of {count} triangles ({len(data)} bytes)")
    corners = np.frombuffer(data, STL_RECORD, count, 84)["corners"].reshape(-1, 3)
    points, index = np.unique(corners, axis=0, return_inverse=True)
    return points.astype(float), index.reshape(-1, 3)


def check_mesh(points: np.ndarray, tris: np.ndarray) -> dict:
    """Is the triangle surface a closed, consistently oriented solid? Counts of what is wrong.

    open_edges: edges of one triangle only; nonmanifold_edges: of three or
    more; misoriented_edges: shared edges that both triangles run the same
    way; degenerate: triangles with a repeated corner or zero area; parts:
    connected pieces (through shared edges), of which outer_shells enclose positive volume and
    cavities negative (a solid with voids: one outer shell, a cavity per void); volume: divergence theorem.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    half, owner, edge, count = _edges(tris)
    order = np.argsort(edge, kind="stable")
    pairs = np.flatnonzero(count[edge[order]] == 2)
    i, j = order[pairs[0::2]], order[pairs[1::2]]
    misoriented = int(np.sum(np.all(half[i] == half[j], axis=1)))
    c = points[tris]
    area = 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
    scale = float(np.ptp(points, axis=0).max()) if len(points) else 1.0
    repeated = (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2])
    degenerate = int(np.sum(repeated | (area <= 1e-14 * scale ** 2)))
    m = len(tris)
    ti, tj = owner[i], owner[j]
    graph = coo_matrix((np.ones(len(ti)), (ti, tj)), shape=(m, m))
    parts, label = connected_components(graph, directed=False) if m else (0, np.zeros(0, int))
    shells = np.array([signed_volume(points, tris[label == k]) for k in range(parts)])
    report = {"triangles": m, "open_edges": int(np.sum(count == 1)), "nonmanifold_edges": int(np.sum(count > 2)),
              "misoriented_edges": misoriented, "degenerate": degenerate, "parts": int(parts),
              "outer_shells": int(np.sum(shells > 0)), "cavities": int(np.sum(shells < 0)),
              "volume": signed_volume(points, tris), "area": float(area.sum())}
    report["closed"] = report["open_edges"] == 0 and report["nonmanifold_edges"] == 0
    report["oriented"] = report["closed"] and misoriented == 0 and report["volume"] > 0
    return report


