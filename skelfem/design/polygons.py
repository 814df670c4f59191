"""Planar polygon predicates used to validate 2D designs (vectorised numpy).

A polygon is an (n, 2) array of vertices, closed implicitly. "Inside" means
the closed region: points on the boundary count as inside, within a tolerance
`tol` relative to the polygon's size.

Every predicate that compares many edges with many edges or points goes
through :func:`candidate_pairs`, a bucketing of bounding boxes on a grid that
is refined recursively where boxes crowd together. Only pairs whose boxes
overlap are tested exactly, in bounded chunks, so a 20,000-vertex outline is
checked in well under a second and a few tens of MB instead of an
n x n matrix.
"""
from __future__ import annotations

import math

import numpy as np

LEAF = 24                 # a grid cell with at most this many boxes is tested pairwise, vectorised
MEDIUM = 256              # ... up to this many, pairwise cell by cell; more: the cell is refined
CHUNK = 1 << 20           # pairs (or point-edge products) per vectorised batch
SMALL = 4096              # point-edge products tested directly, without the strips' bookkeeping
MAX_DEPTH = 12


def loops_of(bodies) -> list:
    """The outlines and holes of 2D bodies (anything with ``outline`` and ``holes``), body by body."""
    return [loop for b in bodies for loop in (b.outline, *b.holes)]


def edges(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points of the polygon's edges, each (n, 2)."""
    return poly, np.roll(poly, -1, axis=0)


def signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    # shifted to the first vertex: no cancellation for far-away polygons
    x, y = x - x[0], y - y[0]
    with np.errstate(over="ignore", invalid="ignore"):
        return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


# -- candidate pairs of overlapping boxes -------------------------------------------------------
def _boxes(p: np.ndarray, q: np.ndarray, pad: float) -> np.ndarray:
    """(n, 4) boxes [xmin, ymin, xmax, ymax] of segments p->q, padded by pad."""
    return np.concatenate([np.minimum(p, q) - pad, np.maximum(p, q) + pad], axis=1)


def _overlapping(box: np.ndarray, I: np.ndarray, J: np.ndarray) -> np.ndarray:
    a, b = box[I], box[J]
    return ((a[:, 0] <= b[:, 2]) & (b[:, 0] <= a[:, 2]) & (a[:, 1] <= b[:, 3]) & (b[:, 1] <= a[:, 3]))


def _emit(box, labels, I, J):
    """Normalised (i < j), box-overlapping, differently labelled pairs."""
    keep = I != J
    if labels is not None:
        keep &= labels[I] != labels[J]
    I, J = I[keep], J[keep]
    keep = _overlapping(box, I, J)
    I, J = I[keep], J[keep]
    return np.minimum(I, J), np.maximum(I, J)


def _all_pairs(box, labels, ids):
    """Every pair within ids (a crowded cell), in chunks."""
    k = len(ids)
    rows = max(1, CHUNK // max(k, 1))
    for start in range(0, k - 1, rows):
        r = np.arange(start, min(start + rows, k - 1))
        counts = k - 1 - r
        I = np.repeat(r, counts)
        J = np.arange(len(I)) - np.repeat(np.cumsum(counts) - counts, counts) + np.repeat(r + 1, counts)
        I, J = _emit(box, labels, ids[I], ids[J])
        if len(I):
            yield I, J


def _memberships(i0, span, gx):
    """Cell ids of every (box, cell) membership: boxes cover span cells from i0."""
    counts = span[:, 0] * span[:, 1]
    total = int(counts.sum())
    seg = np.repeat(np.arange(len(i0)), counts)
    local = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    w = span[seg, 0]
    return seg, (i0[seg, 1] + local // w) * gx + i0[seg, 0] + local % w


def _choose_grid(lo, hi, region, n):
    """Columns and rows of the grid over region that make the fewest memberships and pairs.

    Powers of two per axis (only occupied cells cost anything); memberships and pairs are estimated on a
    sample of the boxes,
    so long thin boxes favour cells stretched along them and a crowded
    corner favours finer cells.
    """
    ext = region[2:] - region[:2]
    kmax = max(1, min(40, 2 * int(math.log2(n)) + 2))
    step = max(1, n // 1024)
    sample = np.arange(0, n, step)
    rho = len(sample) / n
    slo, shi = lo[sample], hi[sample]
    def cost(a, b):
        if (ext[0] <= 0 and a) or (ext[1] <= 0 and b) or a + b > kmax:
            return None
        g = np.array([1 << a, 1 << b])
        cell = np.where(ext > 0, ext / g, 1.0)
        i0 = np.clip(((slo - region[:2]) // cell).astype(np.int64), 0, g - 1)
        i1 = np.clip(((shi - region[:2]) // cell).astype(np.int64), 0, g - 1)
        span = i1 - i0 + 1
        ms = int(np.prod(span, axis=1).sum())
        if ms > 64 * len(sample):
            return None
        _, cid = _memberships(i0, span, int(g[0]))
        _, occ = np.unique(cid, return_counts=True)
        pairs = float(np.sum(occ * (occ - 1.0))) / (2.0 * rho * rho)
        return (ms / rho + pairs, g, cell)

    # greedy descent from one cell: refine columns, rows or both while it pays
    best, at = cost(0, 0), (0, 0)
    while True:
        trials = [(c, ab) for ab in ((at[0] + 1, at[1]), (at[0], at[1] + 1), (at[0] + 1, at[1] + 1))
                  if (c := cost(*ab)) is not None]
        if not trials:
            break
        c, ab = min(trials, key=lambda t: t[0][0])
        if c[0] >= best[0]:
            break
        best, at = c, ab
    if best is None:
        g, cell = np.array([1, 1]), np.where(ext > 0, ext, 1.0)
    else:
        _, g, cell = best
    i0 = np.clip(((lo - region[:2]) // cell).astype(np.int64), 0, g - 1)
    i1 = np.clip(((hi - region[:2]) // cell).astype(np.int64), 0, g - 1)
    span = np.maximum(i1 - i0 + 1, 1)
    return g, cell, i0, span


def _grid_pairs(box, labels, ids, region, depth):
    n = len(ids)
    if n < 2:
        return
    if n <= LEAF or depth >= MAX_DEPTH:
        yield from _all_pairs(box, labels, ids)
        return
    b = box[ids]
    lo = np.maximum(b[:, :2], region[:2])          # the boxes clipped to this region
    hi = np.minimum(b[:, 2:], region[2:])
    g, cell, i0, span = _choose_grid(lo, hi, region, n)
    if g[0] * g[1] == 1:
        yield from _all_pairs(box, labels, ids)
        return
    seg, cid = _memberships(i0, span, int(g[0]))
    order = np.argsort(cid, kind="stable")
    cid, seg = cid[order], seg[order]
    starts = np.flatnonzero(np.r_[True, cid[1:] != cid[:-1]])
    sizes = np.diff(np.r_[starts, len(cid)])
    small = np.repeat(sizes <= LEAF, sizes)
    # small cells: pairs at offsets 1 .. LEAF - 1 within the sorted run
    cs, ss = cid[small], ids[seg[small]]

    def offsets():
        for d in range(1, min(LEAF, len(cs))):
            m = cs[:-d] == cs[d:]
            if not m.any():
                return
            yield _emit(box, labels, ss[:-d][m], ss[d:][m])
    yield from _chunked(offsets())
    # crowded cells: pairwise up to MEDIUM boxes, else recurse into the cell
    # (or pairwise if that makes no progress)
    medium = (sizes > LEAF) & (sizes <= MEDIUM)
    yield from _chunked(_emit(box, labels, *(ids[seg[s:s + k]][ij] for ij in np.triu_indices(k, 1)))
                        for s, k in zip(starts[medium], sizes[medium]))
    for s, k in zip(starts[sizes > MEDIUM], sizes[sizes > MEDIUM]):
        members = ids[seg[s:s + k]]
        c = cid[s]
        x0 = region[0] + (c % g[0]) * cell[0]
        y0 = region[1] + (c // g[0]) * cell[1]
        sub = np.array([x0, y0, x0 + cell[0], y0 + cell[1]])
        if k < n:
            yield from _grid_pairs(box, labels, members, sub, depth + 1)
        else:
            yield from _all_pairs(box, labels, members)


def _chunked(pairs):
    """The (I, J) arrays of pairs merged and made unique, a chunk every CHUNK pairs (memory stays bounded)."""
    out_I, out_J, count = [], [], 0
    for I, J in pairs:
        out_I.append(I)
        out_J.append(J)
        count += len(I)
        if count >= CHUNK:
            yield _unique_pairs(out_I, out_J)
            out_I, out_J, count = [], [], 0
    if count:
        yield _unique_pairs(out_I, out_J)


def _unique_pairs(Is, Js):
    I, J = np.concatenate(Is), np.concatenate(Js)
    if len(I) == 0:
        return I, J
    key = np.unique(I.astype(np.int64) * (int(J.max()) + 1) + J)
    return key // (int(J.max()) + 1), key % (int(J.max()) + 1)


def candidate_pairs(box: np.ndarray, labels: np.ndarray | None = None):
    """Yield chunks (I, J), I < J, of the pairs of boxes that overlap (each at least once).

    box is (n, 4) [xmin, ymin, xmax, ymax]; with labels, only pairs of different
    labels are produced. Memory stays bounded by the chunk size.
    """
    box = np.asarray(box, float)
    n = len(box)
    if n < 2:
        return
    region = np.r_[box[:, :2].min(axis=0), box[:, 2:].max(axis=0)]
    yield from _grid_pairs(box, labels, np.arange(n), region, 0)


# -- segment predicates ---------------------------------------------------------------------------
def segments_intersect(p, q, a, b, tol: float) -> np.ndarray:
    """Whether segments p->q and a->b (broadcast arrays of shape (..., 2)) share a point."""
    r, s = q - p, b - a
    den = _cross(r, s)
    ap = a - p
    lr = np.linalg.norm(r, axis=-1)
    ls = np.linalg.norm(s, axis=-1)
    par = np.abs(den) <= 1e-12 * lr * ls + 1e-300
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _cross(ap, s) / den
        w = _cross(ap, r) / den
    et, ew = tol / np.maximum(lr, 1e-300), tol / np.maximum(ls, 1e-300)
    crossing = ~par & (t >= -et) & (t <= 1 + et) & (w >= -ew) & (w <= 1 + ew)
    # parallel: collinear (within tol) and overlapping projections
    with np.errstate(divide="ignore", invalid="ignore"):
        collinear = par & (np.abs(_cross(ap, r)) <= tol * np.maximum(lr, 1e-300))
        t0 = np.einsum("...i,...i->...", a - p, r) / lr ** 2
        t1 = np.einsum("...i,...i->...", b - p, r) / lr ** 2
    overlap = collinear & (np.maximum(t0, t1) >= -et) & (np.minimum(t0, t1) <= 1 + et)
    # and, whatever the angle, an end point within tol of the other segment
    near = (_point_segment_distance(a, p, q) <= tol) | (_point_segment_distance(b, p, q) <= tol) \
        | (_point_segment_distance(p, a, b) <= tol) | (_point_segment_distance(q, a, b) <= tol)
    return crossing | overlap | near


def _point_segment_distance(x, p, q):
    e = q - p
    ee = np.einsum("...i,...i->...", e, e)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(ee > 0, np.einsum("...i,...i->...", x - p, e) / np.where(ee > 0, ee, 1.0), 0.0)
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(x - (p + t[..., None] * e), axis=-1)


def is_simple(poly: np.ndarray, tol: float) -> bool:
    """No two non-adjacent edges meet, and no two adjacent edges fold back onto each other.

    Collinear vertices on a straight edge are fine.
    """
    n = len(poly)
    p, q = edges(poly)
    e = q - p
    prev = np.roll(e, 1, axis=0)
    le, lp = np.linalg.norm(e, axis=1), np.linalg.norm(prev, axis=1)
    # adjacent edges folding back onto each other (a zero-angle spike)
    spike = (np.abs(_cross(prev, e)) <= tol * np.maximum(le, lp)) & (np.einsum("ij,ij->i", e, prev) < 0)
    if np.any(spike):
        return False
    if n < 4:
        return True
    for I, J in candidate_pairs(_boxes(p, q, tol)):
        adjacent = (J - I == 1) | ((I == 0) & (J == n - 1))
        I, J = I[~adjacent], J[~adjacent]
        if len(I) and np.any(segments_intersect(p[I], q[I], p[J], q[J], tol)):
            return False
    return True


# -- many loops at once ------------------------------------------------------------------------------
def _loop_edges(loops):
    ps, qs, lab = [], [], []
    for i, loop in enumerate(loops):
        p, q = edges(np.asarray(loop, float))
        ps.append(p)
        qs.append(q)
        lab.append(np.full(len(p), i))
    if not ps:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, int)
    return np.vstack(ps), np.vstack(qs), np.concatenate(lab)


def meeting_loops(loops, tol: float) -> set:
    """Pairs (i, j), i < j, of loops (polygons) whose boundaries touch or cross."""
    p, q, lab = _loop_edges(loops)
    out: set = set()
    for I, J in candidate_pairs(_boxes(p, q, tol), lab):
        hit = segments_intersect(p[I], q[I], p[J], q[J], tol)
        if hit.any():
            a, b = lab[I[hit]], lab[J[hit]]
            out.update(zip(np.minimum(a, b).tolist(), np.maximum(a, b).tolist()))
    return out


def near_boundary(points: np.ndarray, loops, tol: float) -> np.ndarray:
    """Whether each point lies within tol of an edge of any loop."""
    points = np.atleast_2d(np.asarray(points, float))
    p, q, _ = _loop_edges(loops)
    m, n = len(points), len(p)
    out = np.zeros(m, bool)
    if m == 0 or n == 0:
        return out
    box = np.vstack([_boxes(p, q, tol), _boxes(points, points, 0.0)])
    labels = np.r_[np.zeros(n, int), np.ones(m, int)]
    for I, J in candidate_pairs(box, labels):
        # I < J: edges come first
        hit = _point_segment_distance(points[J - n], p[I], q[I]) <= tol
        out[J[hit] - n] = True
    return out


def parity(points: np.ndarray, loops) -> np.ndarray:
    """Even-odd rule over the edges of all loops: True where a ray to +x crosses an odd number.

    Edges are bucketed in horizontal strips, so each point meets only the
    edges that can straddle its height.
    """
    points = np.atleast_2d(np.asarray(points, float))
    p, q, _ = _loop_edges(loops)
    m, n = len(points), len(p)
    out = np.zeros(m, bool)
    if m == 0 or n == 0:
        return out
    if m * n <= SMALL:                  # a few points and edges (a design's markers): all pairs at once
        return _crossings_odd(points, p, q)
    ylo, yhi = np.minimum(p[:, 1], q[:, 1]), np.maximum(p[:, 1], q[:, 1])
    y0, y1 = float(ylo.min()), float(yhi.max())
    inside_y = (points[:, 1] >= y0) & (points[:, 1] <= y1)
    strips = max(1, int(math.sqrt(n)))
    for _ in range(8):
        h = (y1 - y0) / strips if y1 > y0 else 1.0
        s0 = np.clip(((ylo - y0) // h).astype(np.int64), 0, strips - 1)
        s1 = np.clip(((yhi - y0) // h).astype(np.int64), 0, strips - 1)
        counts = s1 - s0 + 1
        if counts.sum() <= 8 * n or strips == 1:
            break
        strips = max(1, strips // 2)
    total = int(counts.sum())
    edge = np.repeat(np.arange(n), counts)
    strip = np.repeat(s0, counts) + np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    order = np.argsort(strip, kind="stable")
    strip, edge = strip[order], edge[order]
    bounds = np.searchsorted(strip, np.arange(strips + 1))
    ps = np.clip(((points[:, 1] - y0) // h).astype(np.int64), 0, strips - 1)
    for s in np.unique(ps[inside_y]):
        pts_idx = np.flatnonzero(inside_y & (ps == s))
        e = edge[bounds[s]:bounds[s + 1]]
        if len(e) == 0:
            continue
        a, b = p[e], q[e]
        rows = max(1, CHUNK // len(e))
        for start in range(0, len(pts_idx), rows):
            idx = pts_idx[start:start + rows]
            out[idx] = _crossings_odd(points[idx], a, b)
    return out


def _crossings_odd(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether a ray from each point to +x crosses an odd number of the edges a -> b (every pair at once)."""
    x, y = points[:, 0:1], points[:, 1:2]
    straddle = (a[None, :, 1] > y) != (b[None, :, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        xc = a[None, :, 0] + (y - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / (b[None, :, 1] - a[None, :, 1])
    return np.sum(straddle & (x < xc), axis=1) % 2 == 1


def region_contains(loops, points: np.ndarray, tol: float) -> np.ndarray:
    """Whether each point lies in the closed region bounded by the loops (even-odd; boundary included).

    For an outline and holes strictly inside it, disjoint, this is the
    outline minus the holes' interiors.
    """
    return parity(points, loops) | near_boundary(points, loops, tol)


def contains(poly: np.ndarray, points: np.ndarray, tol: float) -> np.ndarray:
    """Whether each point lies in the closed polygon (even-odd rule, boundary included)."""
    return region_contains([poly], points, tol)


def on_boundary(points: np.ndarray, poly: np.ndarray, tol: float) -> np.ndarray:
    """Whether each point lies within tol of the polygon's boundary."""
    return near_boundary(points, [poly], tol)


def strictly_inside(poly: np.ndarray, points: np.ndarray, tol: float) -> np.ndarray:
    points = np.atleast_2d(points)
    return parity(points, [poly]) & ~near_boundary(points, [poly], tol)


def boundaries_meet(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """Whether the boundaries of polygons a and b touch or cross."""
    return bool(meeting_loops([a, b], tol))


def overlap(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """Whether two closed polygons share any point (touching counts)."""
    return (boundaries_meet(a, b, tol) or bool(np.any(contains(a, b[:1], tol)))
            or bool(np.any(contains(b, a[:1], tol))))


# -- polylines against loops ------------------------------------------------------------------------
def polyline_samples(path: np.ndarray, loops, tol: float = 0.0) -> np.ndarray:
    """Points along a polyline: its vertices, where it meets any loop's edges, and midpoints between.

    Between two consecutive samples the polyline crosses no edge, so it lies
    wholly inside or wholly outside the region: testing the midpoints decides.
    """
    path = np.asarray(path, float)
    a, b = path[:-1], path[1:]
    ns = len(a)
    p, q, _ = _loop_edges(loops)
    ts = [np.zeros(ns), np.ones(ns)]
    segs = [np.arange(ns), np.arange(ns)]
    if len(p) and ns:
        box = np.vstack([_boxes(a, b, tol), _boxes(p, q, tol)])
        labels = np.r_[np.zeros(ns, int), np.ones(len(p), int)]
        for I, J in candidate_pairs(box, labels):
            s, e = I, J - ns                      # path segments come first
            P, R = a[s], b[s] - a[s]
            A, S = p[e], q[e] - p[e]
            den = _cross(R, S)
            rr = np.einsum("ij,ij->i", R, R)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = _cross(A - P, S) / den
                w = _cross(A - P, R) / den
                ta = np.einsum("ij,ij->i", A - P, R) / rr          # the edge's ends projected
                tb = np.einsum("ij,ij->i", A + S - P, R) / rr
            ok = np.isfinite(t) & (t >= 0) & (t <= 1) & (w >= 0) & (w <= 1)
            ts += [t[ok], np.clip(ta, 0, 1), np.clip(tb, 0, 1)]
            segs += [s[ok], s, s]
    t = np.concatenate(ts)
    s = np.concatenate(segs)
    good = np.isfinite(t)
    t, s = np.clip(t[good], 0.0, 1.0), s[good]
    order = np.lexsort((t, s))
    t, s = t[order], s[order]
    keep = np.r_[True, (s[1:] != s[:-1]) | (t[1:] != t[:-1])]
    t, s = t[keep], s[keep]
    same = s[1:] == s[:-1]
    mids_t = 0.5 * (t[:-1] + t[1:])[same]
    mids_s = s[:-1][same]
    T = np.r_[t, mids_t]
    Sg = np.r_[s, mids_s]
    order = np.lexsort((T, Sg))
    T, Sg = T[order], Sg[order]
    return a[Sg] + T[:, None] * (b[Sg] - a[Sg])


def sample_polyline(path: np.ndarray, loops: list, tol: float = 0.0) -> np.ndarray:
    """Points along a polyline: its vertices, where it meets any loop, and midpoints between."""
    return polyline_samples(path, loops, tol)


def crossing_parameters(p: np.ndarray, q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Parameters t in [0, 1] where segment p->q meets the edges of poly (and its vertices' projections)."""
    pts = polyline_samples(np.array([p, q], float), [poly])
    r = np.asarray(q, float) - np.asarray(p, float)
    rr = float(r @ r)
    return (pts - p) @ r / rr if rr > 0 else np.zeros(len(pts))
