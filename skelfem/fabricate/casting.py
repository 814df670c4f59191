"""Where the silicone goes in and the air goes out, and whether the halves come off: pour, vents, air
traps under bones, undercuts.

The mould is filled with its top half up (the mould's normal n up). Sites
are the points of a grid over the parting plane; along the line through a
site parallel to n, the body's top is its last crossing.

- **Pour hole**: among the sites where the body's top is flat enough for
  the hole (a ring of its radius meets the top within a radius of the same
  height, with body beneath) and clear of the top pegs and posts and of
  the removable rods, those
  whose hole's column down to the parting plane meets no bone (the silicone
  falls to the bottom, not onto a bone), then the highest, then the nearest
  the body's middle. If every site's column meets a bone, the best one is
  taken and a note says so.
- **Vents**: air rises to the local high points of the cavity's roof, the
  body's top: the sites whose top is at least as high as every neighbour's
  (within a tolerance), grouped into connected plateaus. Each plateau
  without the pour hole gets a vent (where it is flattest, farthest from
  the pour); then, up to ``vents``, more vents as far from the pour and from
  each other as possible (on a flat 2D slab every site is one plateau, and
  the vents go to its far ends). A high point that cannot take a vent is a
  note: air stays there.
- **Air under bones**: a bone's faces that look down (their outward normal
  within 30 degrees of -n) are ceilings in the rising silicone where air
  clings; their area per bone is reported, with a note to pour in layers
  (the bottom layer up to the bones first, as the paper does) or degas.
- **Undercuts**: each half pulls off along its side of n. From each
  triangle of the body's surface on that side, a ray along the pull
  direction (started just outside the body) that meets the body again
  crosses mould material that is locked in: the triangle's area counts as
  undercut. Silicone forgives small ones; their area per half is reported,
  with a note.
"""
from __future__ import annotations

import numpy as np
from .parts import Tool, where_text
from .surfaces import FabricationError, Surface, inside, orient, ray_hits

CEILING = np.cos(np.radians(30.0))       # a face looks down if its normal is this close to -n


def _neighbours(shape: tuple[int, int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(i, j) index pairs of the 8-neighbourhood on a grid of this shape, per offset."""
    out = []
    a, b = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di == dj == 0:
                continue
            ok = (a + di >= 0) & (a + di < shape[0]) & (b + dj >= 0) & (b + dj < shape[1])
            out.append((np.ravel_multi_index((a[ok], b[ok]), shape),
                        np.ravel_multi_index((a[ok] + di, b[ok] + dj), shape)))
    return out


def cavity_intervals(planner, sites: np.ndarray) -> list[list[tuple[float, float, bool]]]:
    """Per site, the stretches (lo, hi, is the body's top) of its line along n inside the body and
    outside every bone: the cavity the silicone fills, column by column."""
    surfaces = [planner.body] + list(planner.bones.values())
    hits = planner.column(sites, surfaces)
    out = []
    for i in range(len(sites)):
        body = hits[0][i]
        zs = np.unique(np.concatenate([h[i] for h in hits]))
        pieces = []
        for a, b in zip(zs[:-1], zs[1:]):
            m = 0.5 * (a + b)
            in_body = np.sum(body < m) % 2 == 1
            in_bone = any(np.sum(h[i] < m) % 2 == 1 for h in hits[1:])
            if in_body and not in_bone:
                if pieces and abs(pieces[-1][1] - a) <= planner.tol:
                    pieces[-1][1] = b
                else:
                    pieces.append([a, b])
        top = body[-1] if len(body) else np.nan
        out.append([(float(a), float(b), bool(abs(b - top) <= planner.tol)) for a, b in pieces])
    return out


def high_points(intervals: list, shape: tuple[int, int], tol: float) -> list[list[tuple[int, int]]]:
    """The cavity's local high points, where rising air is trapped: plateaus of stretches (site, k) whose
    tops are equal (within tol) across neighbouring sites' overlapping stretches, none of which has an
    overlapping neighbour reaching higher. Each plateau a list of (site, stretch index)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    ids = {}
    for i, pieces in enumerate(intervals):
        for k in range(len(pieces)):
            ids[(i, k)] = len(ids)
    top = np.array([intervals[i][k][1] for i, k in ids])
    higher = np.zeros(len(ids), bool)
    rows, cols = [], []
    for ii, jj in _neighbours(shape):
        for i, j in zip(ii.tolist(), jj.tolist()):
            for k, (alo, ahi, _) in enumerate(intervals[i]):
                for m, (blo, bhi, _) in enumerate(intervals[j]):
                    if min(ahi, bhi) - max(alo, blo) <= tol:
                        continue                                  # not connected through the cavity
                    u, v = ids[(i, k)], ids[(j, m)]
                    if top[v] > top[u] + tol:
                        higher[u] = True
                    elif abs(top[v] - top[u]) <= tol:
                        rows.append(u), cols.append(v)
    n = len(ids)
    _, label = connected_components(coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)), directed=False)
    keys = list(ids)
    out = []
    for lab in np.unique(label):
        members = np.flatnonzero(label == lab)
        if not higher[members].any():
            out.append([keys[u] for u in members])
    return out


def openings(planner, blockers: list) -> tuple[list[Tool], dict, list[str]]:
    """The pour hole and vents (Tools), the report's ``mould.flow`` entries and notes; see the module doc."""
    spec, f = planner.spec, planner.frame
    from .routes import dense
    top_tools = np.array([f.local(p.points[0])[:2] for p in blockers if p.side == "top"] +    # pegs', posts' tips
                         [y[:2] for p in blockers if p.kind == "rod" for y in f.local(dense(p.points, 1.0))]
                         ).reshape(-1, 2)                                # a rod anywhere across the top half
    uv = f.local(planner.body.points)[:, :2]
    sites, shape, h = planner.lattice(uv, 600)
    q = len(sites)
    body = planner.column(sites, [planner.body])[0]
    notes = []

    def usable(radius):
        rings = np.stack([planner.ring(p, radius) for p in sites])
        ring_hits = planner.column(rings.reshape(-1, 2), [planner.body])[0]
        good, tops = [], []
        for i in range(q):
            ax = body[i]
            if len(ax) < 2 or ax[-1] - ax[-2] < radius or ax[-1] - f.c < radius:
                continue
            ring = [ring_hits[8 * i + k] for k in range(8)]
            if any(not len(r) or abs(r[-1] - ax[-1]) > 0.5 * radius for r in ring):
                continue
            if len(top_tools) and np.linalg.norm(top_tools - sites[i], axis=1).min() < \
                    radius + planner.r_peg + spec.clearance + planner.wall:
                continue
            good.append(i), tops.append(ax[-1] - min(radius, 0.5 * (ax[-1] - ax[-2])))
        return np.array(good, int), np.array(tops)

    r_pour = spec.pour_diameter / 2
    good, tops = usable(r_pour)
    if not len(good):
        raise FabricationError("fabrication.pour_diameter", f"no place on the top of the body (above the parting "
                                                            f"plane) fits a pour hole of {spec.pour_diameter:g} mm")
    # the pour's column, down to the parting plane, clear of every bone (a ring of its radius)
    rings = np.concatenate([sites[good], np.stack([planner.ring(p, r_pour) for p in sites[good]]).reshape(-1, 2)])
    bone_hits = planner.column(rings, list(planner.bones.values())) if planner.bones else []
    m = len(good)
    clear = np.ones(m, bool)
    for hits in bone_hits:
        for k in range(m):
            lines = [hits[k]] + [hits[m + 8 * k + r] for r in range(8)]
            if any(len(x) and x.max() > f.c - planner.tol for x in lines):
                clear[k] = False
    mid = uv.mean(axis=0)
    tol = 1e-6 * planner.scale
    choice = np.flatnonzero(clear) if clear.any() else np.arange(m)
    highest = tops[choice].max()
    choice = choice[tops[choice] >= highest - max(tol, 0.05 * r_pour)]
    k = int(choice[np.argmin(np.linalg.norm(sites[good[choice]] - mid, axis=1))])
    pour = sites[good[k]]
    if not clear.any():
        notes.append("every place for the pour hole lies over a bone: pour slowly, down the side of the cavity")
    tools = [Tool("pour", f.world([[*pour, tops[k]], [*pour, f.hi[2]]]), r_pour, extend=(0.0, 1.0))]
    body_stretches = cavity_intervals(planner, sites)
    peaks = high_points(body_stretches, shape, max(tol, 0.02 * h))
    pour_i = int(good[k])
    report = {"pour": {"site": [float(v) for v in pour], "clear_of_bones": bool(clear[k])},
              "high_points": [], "vents": []}
    chosen = []
    r_vent = spec.vent_diameter / 2
    vgood, vtops = usable(r_vent)
    index = {int(i): n for n, i in enumerate(vgood)}
    for plateau in peaks:
        at = np.array([i for i, _ in plateau])
        entry = {"site": [float(v) for v in sites[at].mean(axis=0)], "sites": len(plateau),
                 "height": float(max(body_stretches[i][k][1] for i, k in plateau))}
        if pour_i in set(at.tolist()):
            entry["vented_by"] = "pour"
            report["high_points"].append(entry)
            continue
        cand = [i for i, k in plateau if i in index and body_stretches[i][k][2]]   # on the body's top
        if not cand:
            entry["vented_by"] = None
            notes.append(f"the cavity's high point near ({', '.join(f'{v:.3g}' for v in entry['site'])}) in the "
                         "parting plane has no room for a vent: air stays there")
            report["high_points"].append(entry)
            continue
        far = [float(np.linalg.norm(sites[i] - pour)) for i in cand]
        chosen.append(cand[int(np.argmax(far))])
        entry["vented_by"] = "vent"
        report["high_points"].append(entry)
    _more_vents(planner, sites, vgood, pour, chosen)
    for i in chosen:
        t = vtops[index[i]]
        tools.append(Tool("vent", f.world([[*sites[i], t], [*sites[i], f.hi[2]]]), r_vent, extend=(0.0, 1.0)))
        report["vents"].append([float(v) for v in sites[i]])
    return tools, report, notes


def _more_vents(planner, sites: np.ndarray, vgood: np.ndarray, pour: np.ndarray, chosen: list) -> None:
    """Add vents to chosen (site indices), up to spec.vents, each as far from the pour and from the
    other vents as possible among the sites vgood that fit one."""
    spec = planner.spec
    d_pour = np.linalg.norm(sites[vgood] - pour, axis=1) if len(vgood) else np.zeros(0)
    d_vent = np.full(len(vgood), np.inf)
    for i in chosen:
        d_vent = np.minimum(d_vent, np.linalg.norm(sites[vgood] - sites[i], axis=1))
    while len(chosen) < spec.vents:
        ok = (d_pour >= (spec.pour_diameter + spec.vent_diameter) / 2 + 2 * planner.wall) & \
             (d_vent >= spec.vent_diameter + 2 * planner.wall)
        if not ok.any():
            raise FabricationError("fabrication.vents", f"room for only {len(chosen)} vent(s) of "
                                                        f"{spec.vent_diameter:g} mm on the top of the body")
        j = int(np.flatnonzero(ok)[np.argmax(np.minimum(d_pour, d_vent)[ok])])
        chosen.append(int(vgood[j]))
        d_vent = np.minimum(d_vent, np.linalg.norm(sites[vgood] - sites[vgood[j]], axis=1))


def ceilings(planner) -> tuple[dict, list[str]]:
    """Per bone, the area of its faces that look down in the rising silicone (air clings there)."""
    n = planner.frame.n
    out, notes = {}, []
    for name, s in planner.bones.items():
        s = Surface(s.points, orient(s.points, s.tris), s.faces)        # outward normals
        c = s.corners
        area = 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
        down = s.normals @ n < -CEILING
        out[name] = float(area[down].sum())
    big = {k: v for k, v in out.items() if v > 0}
    if big:
        notes.append("air can cling under the downward faces of bone(s) " + ", ".join(sorted(big)) +
                     " as the silicone rises: pour in layers (the bottom layer up to the bones first) or degas")
    return out, notes


def _rays(planner) -> dict:
    """What the undercut test needs of the body's triangles, whatever the parting plane: centres, areas,
    heights along n, the ray starts just outside each, and whether those starts are outside the body."""
    f, body = planner.frame, planner.body
    body = Surface(body.points, orient(body.points, body.tris), body.faces)   # outward normals
    corners = body.corners
    centre = corners.mean(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    start = centre + 1e-4 * planner.scale * body.normals
    return {"centre": centre, "area": area, "height": f.local(centre)[:, 2], "start": start,
            "outside": ~inside(start, body, planner.tol)}


def _locked(planner, rays: dict, c: float) -> dict:
    """Per half (parting plane n . x = c): the mask over the body's triangles whose mould material is
    locked in against the half's pull."""
    f, eps = planner.frame, 1e-4 * planner.scale
    out = {}
    for side, sign in (("bottom", -1.0), ("top", 1.0)):
        mine = sign * (rays["height"] - c) > eps        # this half's side of the parting plane
        r, t, _ = ray_hits(rays["start"][mine], sign * f.n, planner.body.corners, planner.tol)
        hit = np.zeros(int(mine.sum()), bool)
        hit[r[t > planner.tol]] = True              # a face looking down, on its own, is locked too
        locked = np.zeros(len(mine), bool)
        locked[np.flatnonzero(mine)[hit]] = True
        out[side] = locked & rays["outside"]
    return out


def least_undercut(planner) -> float:
    """The parting plane's offset c along n with the least undercut of both halves together.

    Candidates: the middle of the body's extent along n, and the quantiles
    (10 % to 90 %) of the middles of the body's stretches along n over a grid
    of the plane (a body of round parts parts best through their axes, where
    those middles gather). Ties (within 1e-4 of the body's area) go to the
    candidate nearest the middle."""
    f = planner.frame
    sites = planner.grid(f.local(planner.body.points)[:, :2], 400)
    hits = planner.column(sites, [planner.body])[0]
    mids = np.concatenate([0.5 * (h[0::2] + h[1::2]) for h in hits if len(h) >= 2 and len(h) % 2 == 0] or
                          [np.zeros(0)])
    middle = 0.5 * (f.lo[2] + f.hi[2])
    candidates = [middle] + (list(np.quantile(mids, np.linspace(0.1, 0.9, 9))) if len(mids) else [])
    rays = _rays(planner)
    scores = [sum(float(rays["area"][m].sum()) for m in _locked(planner, rays, c).values()) for c in candidates]
    best = min(scores)
    good = [c for c, a in zip(candidates, scores) if a <= best + 1e-4 * float(rays["area"].sum())]
    return float(min(good, key=lambda c: abs(c - middle)))


def undercuts(planner) -> tuple[dict, list[str]]:
    """Per half, the body surface area whose mould material is locked in against the half's pull."""
    rays = _rays(planner)
    out, notes = {}, []
    for side, locked in _locked(planner, rays, planner.frame.c).items():
        out[side] = float(rays["area"][locked].sum())
        if out[side] > 0:
            where = rays["centre"][locked][np.argmax(rays["area"][locked])]
            notes.append(f"the {side} half has {out[side]:.3g} mm^2 of undercut (near {where_text(where)}): "
                         "it comes off "
                         "only as far as the silicone bends; another fabrication.split avoids it")
    return out, notes


CLAMP_BOLTS = (("M3", 3.4), ("M2.5", 2.9), ("M2", 2.4))     # metric bolts and their clearance holes, mm
CLAMP_MARGIN = 1.0              # mm of mould wall at least on each side of a clamp hole
CLAMP_FRACTIONS = (1 / 3, 2 / 3, 1 / 4, 3 / 4, 1 / 6, 5 / 6, 1 / 2)   # along a long side, in order of preference


def clamps(planner, avoid: list) -> tuple[list[Tool], list[str]]:
    """Bolt holes that clamp the halves together: along n through both halves, in the wall beyond the body
    (the middle of the wall band, wall/2 in from the block's face), two on each of the block's longer
    sides, a third of the side apart or more. The thickest metric bolt whose clearance hole leaves
    CLAMP_MARGIN of wall on each side; none (a note: clips or tape) where the wall is too thin. A site
    whose hole would come within CLAMP_MARGIN of a registration pin, a tendon exit, a pry slot or a rod
    (their axes projected on the parting plane) is skipped."""
    f, w = planner.frame, planner.spec.wall
    bolt = next(((name, d) for name, d in CLAMP_BOLTS if d + 2 * CLAMP_MARGIN <= w), None)
    if bolt is None:
        return [], [f"the mould's wall ({w:g} mm) is too thin for clamp bolts (an M2 needs "
                    f"{CLAMP_BOLTS[-1][1] + 2 * CLAMP_MARGIN:g} mm): hold the halves with clips or tape"]
    name, d = bolt
    r = d / 2
    from .routes import dense
    blockers = [(f.local(dense(t.points, 0.5))[:, :2], t.radius) for t in avoid]
    k = int(np.argmax(f.hi[:2] - f.lo[:2]))              # along the longer in-plane axis
    other = 1 - k
    tools = []
    for line in (f.lo[other] + w / 2, f.hi[other] - w / 2):
        chosen = []
        for frac in CLAMP_FRACTIONS:
            site = np.zeros(2)
            site[k], site[other] = f.lo[k] + frac * (f.hi[k] - f.lo[k]), line
            if any(abs(frac - c) < 1 / 3 - 1e-9 for c in chosen):
                continue
            if any(np.linalg.norm(pts - site, axis=1).min() < r + rad + CLAMP_MARGIN for pts, rad in blockers):
                continue
            chosen.append(frac)
            tools.append(Tool("clamp", f.world([[*site, f.lo[2] - 1.0], [*site, f.hi[2] + 1.0]]), r, side=name))
            if len(chosen) == 2:
                break
    notes = [] if len(tools) == 4 else [f"only {len(tools)} of 4 clamp holes found room (tendon exits, pry "
                                        "slots and pins are in the way): add clips"]
    return tools, notes
