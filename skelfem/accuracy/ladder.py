"""The uniform --tol ladder's rules: levels, observed rates, Richardson estimates, when to stop, graded zones.

Model no more than the design needs: refine the design's own mesh until its error estimate meets --tol.

``skelfem simulate DESIGN --tol ABS_MM`` solves the design itself with P2 on
a ladder of uniform meshes h_0 > h_1 > ... (each solve warm-started from the
last) and estimates the marker error of each by Richardson extrapolation on
the design itself, not on curves fitted to another design:

    with x_k the marker positions on h_k, d_k = max_markers |x_k - x_{k-1}|
    and e(h) = C h^r, the error of level k is   E_k = d_k / (rho_k^r - 1),
    rho_k = h_{k-1} / h_k, and the rate r is observed from the last three
    levels (d_{k-1} / d_k = rho^r for equal ratios), clipped to [R_MIN, R_MAX].

The sizes h_k in these formulas are measured on the meshes, by their DOFs
N_k: h_k = h_{k-1} (N_{k-1} / N_k)^(1/dim), h_0 the first level's [mesh]
size. Gmsh honours the size it is asked for only on bodies much larger than
it: on a small 3D body, h = 4 and 2.83 gave the same mesh and h = 2 one
with 1.46x the DOFs (a ratio of 1.13, not 1.41). A level whose mesh is the
last one's again replaces it.

Near finite anchors (cable ends and bends in silicone), at the 2D
clamped corners (where a fixed pin's stretch of boundary meets the free
boundary: a displacement singularity) and along the 3D clamped edges (the
same, along a curve: on a 3D post, P2 at 18k DOFs graded there was closer
to the limit than 100k DOFs uniform) every mesh of the ladder is finer, by
one graded field scaled with h (``ladder_zones``: ``anchor_zones``,
``corner_zones``), so that even the first level resolves the anchor's load,
and the corner's error, which on uniform meshes depends on how each mesh
happens to lie there, is small on every level.

It starts from h_0 = 2x the design's [mesh] size, halves h twice (three levels:
the rate needs them; in 3D the ratio is sqrt 2), and then, while
MARGIN E_k > tol, jumps to the size the model predicts for tol / (MARGIN AIM).
E_k uses the observed rate where it is ``trusted``; a pre-asymptotic drop
as the first rate gets the two-level rate R_TWO_LEVELS instead (``judged``),
and a drop right after differences that did not fall never ends the ladder
(``may_stop``).
When MARGIN E_k <= tol, a twin mesh of size TWIN h_k is solved too
(``twin``): Richardson's model e = C h^r has one C, but on unstructured
meshes C scatters from mesh to mesh (a 2D finger's tip: a standard
deviation of 0.0046 mm over nine meshes of h = 0.80 ... 0.88, larger than
the Richardson estimate from h = 4, 2, 1), and no ladder can see that
scatter: the twin measures it, s = max_markers |x_twin - x_k|. The twin's
estimate is max(E_k, s) and it is the answer (the finer of the two).
It stops when MARGIN max(E_k, s) <= tol (``met: true``: the error is below tol even
if the estimate is low by up to a factor MARGIN); else the ladder goes on from
level k with that estimate, or it stops when the next mesh would pass the DOF limit
of skelfem.design.resources or MAX_LEVELS (``met: false``: the estimate on the
finest mesh is reported, never a promise it does not keep). The answer is the
last solve itself: the twin where the tolerance is met.

Bones: where the design has elastic bones, the first level is solved again
with every bone rigid (``rigid_variant``; skelfem.terms.rigid: fewer
unknowns and cells). Their difference b = max_markers |x_rigid - x_elastic|
is what the bones' own strain does to the markers (it falls like 1/E_bone).
If MARGIN b <= RIGID_SHARE tol the ladder goes on with rigid bones and b is
added to every estimate it reports and checks; else with elastic bones
(``accuracy.bones`` in result.json says which, and b).

What it assumes: the finest levels are in the asymptotic range, where the
marker error falls like h^r. Where the continuum answer does not exist (a
point force in 2D: a cable *bending* inside silicone, see docs/model.md, finite anchors), the
differences do not fall, the observed rate is small, and the estimate stays
large: ``met: false``, which is the truth.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np


log = logging.getLogger("skelfem")

DEGREE = 2
RATIO = {2: 2.0, 3: math.sqrt(2.0)}   # h_{k-1} / h_k of the first levels
R_MIN, R_MAX = 0.5, 2.0               # the observed rate is clipped to this range (P2 with corners:
                                      # faster rates seen over three levels were noise, not convergence)
R_TWO_LEVELS = 1.0                    # the rate assumed before three levels exist
MARGIN = 2.0                          # met: MARGIN x estimate <= tol (the estimate may be low by 2x)
AIM = 1.5                             # the size jump aims at tol / (MARGIN AIM)
MAX_LEVELS = 8
MAX_JUMP = 2.0                        # h_{k-1} / h_k is at most this
ZONE_SIZE = 0.5                       # the first level's size near a finite anchor, in anchor radii ...
ZONE_RADIUS = 1.5                     # ... within this many anchor radii of its centre
CORNER_RADIUS = 0.25                  # a clamped corner's zone: within this x h_0 of it ...
CORNER_SIZE = 0.125                   # ... the size is this x h (h/8) ...
CORNER_GRADING = 1.0                  # ... growing to h by this many mm per mm beyond
RIGID_SHARE = 0.1                     # rigid bones when MARGIN x their difference from elastic ones <= this x tol
TWIN = 0.95                           # the twin mesh's size, in the level's it checks (0.95^2, 0.95^3
                                      # where Gmsh makes the same mesh again)


@dataclass
class Level:
    size: float
    dofs: int
    iterations: int
    seconds: float
    markers: np.ndarray = field(repr=False)     # (n_markers, dim) positions, mm
    h: float | None = None                      # the size measured by the DOFs (None: the size asked for)
    change: float | None = None                 # d_k = max |x_k - x_{k-1}|, mm
    rate: float | None = None                   # r used for the estimate
    observed: float | None = None               # the three-level rate before clipping (up to 10)
    estimate: float | None = None               # E_k, mm
    twin: bool = False                          # a twin (``TWIN``): a second mesh of about the last size
    scatter: float | None = None                # a twin's max |x_twin - x_k|, mm

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("markers")
        return d


def observed_rate(h: tuple[float, float, float], d: tuple[float, float], lo: float = R_MIN,
                  hi: float = R_MAX) -> float:
    """r with d_{k-1} / d_k = (h_{k-2}^r - h_{k-1}^r) / (h_{k-1}^r - h_k^r) for h = (h_{k-2}, h_{k-1}, h_k).

    (e = C h^r gives d_k = C (h_{k-1}^r - h_k^r).) Clipped to [lo, hi]
    (default [R_MIN, R_MAX]); lo where the differences do not fall.
    """
    h0, h1, h2 = h
    d1, d2 = d
    if not (d1 > 0 and d2 > 0):
        return hi if d2 == 0 and d1 > 0 else lo

    def f(r):
        return math.log((h0 ** r - h1 ** r) / (h1 ** r - h2 ** r)) - math.log(d1 / d2)
    if f(lo) >= 0:
        return lo
    if f(hi) <= 0:
        return hi
    for _ in range(60):                              # f increases with r: bisection
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if f(mid) < 0 else (lo, mid)
    return 0.5 * (lo + hi)


def _h(level: Level) -> float:
    return level.size if level.h is None else level.h


def richardson(levels: list[Level]) -> tuple[float, float]:
    """(E_k, r) for the last of at least two levels: Richardson's estimate, or the oscillation's
    half-spread (``oscillation``) where that is larger."""
    a, b = levels[-2], levels[-1]
    d = float(np.max(np.linalg.norm(b.markers - a.markers, axis=1)))
    r = R_TWO_LEVELS if len(levels) < 3 else observed_rate(
        (_h(levels[-3]), _h(a), _h(b)), (levels[-2].change, d))
    rho = _h(a) / _h(b)
    return max(d / (rho ** r - 1.0), oscillation(levels)), r


def oscillation(levels: list[Level]) -> float:
    """Half the spread of the last three levels' positions of every marker whose two last changes
    point against each other (0 where none does, or with fewer than three levels).

    Richardson's estimate assumes the answers approach their limit from one
    side, e = C h^r. On unstructured, non-nested meshes the sign of C can
    change from mesh to mesh (a marker that moves +0.0077 mm, then -0.0104 mm
    on the next halving): the last change then says little about the error,
    which can be larger than it. For such oscillatory convergence the
    uncertainty is bounded by the amplitude of the oscillation, half the
    spread of the last three answers (Stern, Wilson, Coleman & Paterson,
    J. Fluids Eng. 123 (2001) 793), which is used wherever it is larger.
    """
    if len(levels) < 3:
        return 0.0
    x = np.stack([lv.markers for lv in levels[-3:]])                     # (3, n_markers, dim)
    reverse = np.einsum("md,md->m", x[2] - x[1], x[1] - x[0]) < 0.0
    if not reverse.any():
        return 0.0
    pairs = [np.linalg.norm(x[i] - x[j], axis=1) for i, j in ((0, 1), (1, 2), (0, 2))]
    return 0.5 * float(np.max(np.max(pairs, axis=0)[reverse]))


def trusted(levels: list[Level]) -> bool:
    """Whether the last level's observed rate may be used for its estimate.

    Three levels at least. A rate observed above R_MAX (differences falling
    faster than P2 converges) right after differences that did not fall (a
    rate below 1, or no earlier rate) is a pre-asymptotic drop: a feature
    the meshes have only just resolved, after which the differences may grow
    again. It is not trusted (``judged``).
    """
    if len(levels) < 3:
        return False
    last = levels[-1]
    if last.observed is None or last.observed <= R_MAX:
        return True
    before = levels[-2].observed
    return before is not None and before >= 1.0


def first_drop(levels: list[Level]) -> bool:
    """Whether the last level's rate is untrusted as the ladder's first rate (no earlier rate: the
    coarsest mesh far from the asymptotic range), not right after differences that did not fall."""
    return len(levels) >= 3 and not trusted(levels) and levels[-2].observed is None


def may_stop(levels: list[Level]) -> bool:
    """Whether the last level's estimate may end the ladder: three levels, and not a drop right after
    differences that did not fall (a feature only just resolved: on the sharp-cornered tapered finger
    0.54, 0.53, then 0.039 mm, and then 0.18 mm again). A first drop may (``judged``)."""
    return len(levels) >= 3 and (trusted(levels) or first_drop(levels))


def judged(levels: list[Level]) -> Level:
    """The last level, with the estimate of its last two levels alone (the rate R_TWO_LEVELS, as before
    three levels exist; the oscillation bound where larger) where its rate is a ``first_drop``.

    A first drop says nothing about the rate, so the rate P2 keeps even at a
    clamped corner is assumed (about 1 for the markers). On a 3D post graded
    at its clamped edges the drop 0.0068 -> 0.0026 mm (an observed rate of
    3.9) was followed by 0.0029 mm: the rate-1 estimate 0.0075 mm bounded the
    error (about 0.005 mm); the observed rate (clipped to 2) said 0.0034, and
    the next level's rate-0.5 estimate 0.018.
    """
    return at_two_level_rate(levels) if first_drop(levels) else levels[-1]


def at_two_level_rate(levels: list[Level]) -> Level:
    """The last level with the estimate of its last two levels at the rate R_TWO_LEVELS (the oscillation
    bound where larger)."""
    last = levels[-1]
    rho = _h(levels[-2]) / _h(last)
    return replace(last, rate=R_TWO_LEVELS,
                   estimate=max(last.change / (rho ** R_TWO_LEVELS - 1.0), oscillation(levels)))


def next_size(level: Level, tol: float, dim: int) -> float:
    """The size the error model e = C h^r predicts for tol / (MARGIN AIM), between one ratio and 2x finer.

    (In 2D the ratio is 2: every level halves h. A larger jump would leave
    the estimate with one pair of widely spaced meshes, and the last mesh
    could be much finer than the tolerance needs.)"""
    ratio = (tol / (MARGIN * AIM * level.estimate)) ** (1.0 / level.rate)    # of the measured size
    return float(level.size * min(max(ratio, 1.0 / MAX_JUMP), 1.0 / RATIO[dim]))


def anchor_zones(model, h0: float):
    """A ZoneField of size h0 with zones of ZONE_SIZE r within ZONE_RADIUS r of every finite anchor
    (radius r) that h0 does not resolve; None if there is none.

    An anchor's load density (skelfem.terms.cables.anchor_weights) varies
    over its radius r: on cells larger than r the meshes see it as a point
    load and their answers are not yet in the asymptotic range, so Richardson
    extrapolation from them is low (a strip whose tendon ends in a 0.41 mm
    anchor: estimated 0.004 mm for an error of 0.011 mm on uniform meshes of
    h = 4, 2, 1). The ladder's meshes are this field scaled with h: each level
    resolves the anchors at least as well as the first.
    """
    from ..mesh.geometry import ZoneField
    disks = [(c, r) for c, r in model.finite_anchors() if ZONE_SIZE * r < h0]
    if not disks:
        return None
    return ZoneField.around([c for c, _ in disks], [ZONE_RADIUS * r for _, r in disks],
                            [ZONE_SIZE * r for _, r in disks], h0)


def clamp_corners(design) -> np.ndarray:
    """(n, 2) points where a fixed pin's box cuts the 2D body's outline (or a hole's): the ends of every
    clamped stretch of boundary, where it meets the free boundary. (0, 2) in 3D or without fixed pins.

    There the displacement is singular, u ~ r^lambda with lambda < 1 (a
    clamped edge meeting a free one): on uniform meshes the error there
    pollutes the whole solution and depends on how each mesh happens to lie
    at the corner (on finger_tapered_fillet, P2 at h = 0.59, 0.5 and 0.42:
    tip x = -4.0150, -3.9936, -4.0171 mm; with ``corner_zones``
    -4.0292, -4.0233, -4.0235 mm, for 1.6-6 % more DOFs).
    """
    if design.dim != 2:
        return np.zeros((0, 2))
    rings = [np.asarray(loop, dtype=float) for loop in design.body_loops]
    points = []
    for pin in design.pins:
        if pin.kind != "fixed":
            continue
        lo, hi = np.asarray(pin.region, dtype=float)
        for ring in rings:
            points += _box_crossings(ring, np.roll(ring, -1, axis=0), lo, hi)
    if not points:
        return np.zeros((0, 2))
    points = np.array(points)
    keep = [i for i in range(len(points)) if not np.any(np.linalg.norm(points[:i] - points[i], axis=1) < 1e-6)]
    return points[keep]


def _box_crossings(p: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list:
    """Where segments p_i -> q_i enter or leave the box [lo, hi] strictly between their ends (clipping)."""
    r = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lo - p) / r, (hi - p) / r                     # the slabs' parameters, per axis
    flat = r == 0.0
    inside = np.all(~flat | ((p >= lo) & (p <= hi)), axis=1)   # a segment parallel to a slab lies within it
    t_in = np.max(np.where(flat, -np.inf, np.minimum(a, b)), axis=1)
    t_out = np.min(np.where(flat, np.inf, np.maximum(a, b)), axis=1)
    out = []
    for i in np.flatnonzero(inside & (t_in < t_out) & (t_out > 0.0) & (t_in < 1.0)):
        for t in (t_in[i], t_out[i]):
            if 0.0 < t < 1.0:
                out.append(p[i] + t * r[i])
    return out


def clamp_edges(model, design) -> np.ndarray:
    """(m, 2, 3) segments along which a fixed pin's box cuts the 3D body's surface: the clamped edges,
    where the clamped surface meets the free one (in 3D the singular set is a curve, not a point).
    (0, 2, 3) in 2D or without fixed pins.

    Found on the model's mesh, for any body: each boundary triangle with some
    vertices inside the box and some outside holds one segment, from where
    one of its edges leaves the box to where another does (on a flat face,
    exactly the box's cut; on a curved one, its chord). Gathered over MPI ranks.
    """
    if design.dim != 3 or model is None:
        return np.zeros((0, 2, 3))
    from dolfinx import mesh as dmesh
    from dolfinx.cpp.mesh import entities_to_geometry
    mesh = model.mesh
    fdim = mesh.topology.dim - 1
    mesh.topology.create_connectivity(fdim, fdim + 1)
    facets = dmesh.exterior_facet_indices(mesh.topology)
    nodes = entities_to_geometry(mesh._mesh, fdim, facets, False)[:, :3]
    x = mesh.geometry.x[nodes]                                             # (n, 3 vertices, 3)
    tol = 1e-8 * float(np.abs(mesh.geometry.x).max() + 1.0)               # as the pins' own boxes
    segments = []
    for pin in design.pins:
        if pin.kind != "fixed":
            continue
        lo, hi = np.asarray(pin.region, dtype=float) + [[-tol], [tol]]
        inside = np.all((x >= lo) & (x <= hi), axis=2)                     # (n, 3)
        cut = inside.any(axis=1) & ~inside.all(axis=1)
        ends = [_leaves(x[cut, i], x[cut, j], inside[cut, i], lo, hi)
                for i, j in ((0, 1), (1, 2), (2, 0))]
        crossing = np.stack([inside[cut, i] != inside[cut, j] for i, j in ((0, 1), (1, 2), (2, 0))], axis=1)
        points = np.stack(ends, axis=1)[crossing].reshape(-1, 2, 3)        # two crossing edges per triangle
        segments.append(points)
    local = np.concatenate(segments) if segments else np.zeros((0, 2, 3))
    return np.concatenate(mesh.comm.allgather(local))


def _leaves(p: np.ndarray, q: np.ndarray, p_in: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Where each edge p_i q_i leaves the box [lo, hi], going from its inside end (p_i where p_in) out."""
    a = np.where(p_in[:, None], p, q)
    r = np.where(p_in[:, None], q, p) - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(r > 0, (hi - a) / r, np.where(r < 0, (lo - a) / r, np.inf))
    return a + np.clip(t.min(axis=1), 0.0, 1.0)[:, None] * r


def along(segments: np.ndarray, spacing: float) -> np.ndarray:
    """(n, 3) points along segments (m, 2, 3), at most ``spacing`` apart on each, duplicates (closer than
    spacing / 4) dropped."""
    if not len(segments):
        return np.zeros((0, segments.shape[-1]))
    length = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)
    count = np.ceil(length / spacing).astype(int) + 1
    first = np.repeat(np.cumsum(count) - count, count)
    t = (np.arange(count.sum()) - first) / np.repeat(count - 1, count)
    start = np.repeat(segments[:, 0], count, axis=0)
    points = start + t[:, None] * (np.repeat(segments[:, 1], count, axis=0) - start)
    _, keep = np.unique(np.round(points / (0.25 * spacing)), axis=0, return_index=True)
    return points[np.sort(keep)]


def corner_zones(design, h0: float, model=None):
    """A ZoneField of size h0 with zones of CORNER_SIZE h0 within CORNER_RADIUS h0 of every clamped
    corner (2D: ``clamp_corners``) or clamped edge (3D: ``clamp_edges`` of the model's mesh, as balls
    CORNER_RADIUS h0 / 2 apart along it); None if there is none. Scaled with h, as the anchor zones are."""
    from ..mesh.geometry import ZoneField
    if design.dim == 2:
        c = clamp_corners(design)
    else:
        c = along(clamp_edges(model, design), 0.5 * CORNER_RADIUS * h0)
    if not len(c):
        return None
    inner = CORNER_SIZE * h0
    return ZoneField(c, np.full(len(c), CORNER_RADIUS * h0), np.full(len(c), inner), float(h0),
                     (h0 - inner) / CORNER_GRADING)


def ladder_zones(model, design, h0: float):
    """The graded field of the ladder's first level (size h0): anchor zones and clamped-corner zones
    (``anchor_zones``, ``corner_zones``); None if there is neither."""
    anchors, corners = anchor_zones(model, h0), corner_zones(design, h0, model)
    if anchors is None:
        return corners
    return anchors.merged(corners)


def at_size(design, h: float):
    """The design meshed at size h with P2 (validated as any --set)."""
    from ..design.parse import parse_design
    return parse_design(design.raw, design.source, [f"mesh.size={round(float(h), 6)!r}", f"mesh.degree={DEGREE}"])


def first_level(design):
    """The design at the first size of the ladder: twice its own [mesh] size."""
    return at_size(design, 2.0 * float(design.mesh.size))


def _positions(result, targets=None) -> np.ndarray:
    """The rows the ladder measures: the markers' positions (mm), or the rows of --tol's named targets
    (skelfem.accuracy.targets.Targets.rows: each in units of its tolerance)."""
    if targets is not None:
        return targets.rows(result)
    return np.array([m["position"] for m in result.markers.values()], dtype=float)


def next_level(levels: list[Level], size: float, result, seconds: float, targets=None) -> Level:
    """The Level of a solve on a mesh of size h after ``levels`` (same family): its measured size, its
    change d_k, its Richardson estimate and rate, and the observed three-level rate, from result."""
    level = Level(float(size), int(result.dofs), int(result.newton_iterations), seconds,
                  _positions(result, targets))
    level.h = level.size
    if levels:
        last = levels[-1]
        level.h = _h(last) * ((last.dofs / level.dofs) ** (1.0 / level.markers.shape[1])
                              if level.dofs != last.dofs and last.dofs > 0 else level.size / last.size)
        level.estimate, level.rate = richardson(levels + [level])
        level.change = float(np.max(np.linalg.norm(level.markers - last.markers, axis=1)))
        if len(levels) >= 2:
            level.observed = observed_rate((_h(levels[-2]), _h(last), level.h),
                                           (last.change, level.change), R_MIN, 10.0)
    return level


def twin_level(level: Level, size: float, result, seconds: float, targets=None) -> Level:
    """The twin of ``level`` (solved on a mesh of size TWIN h_k): its scatter s = max |x_twin - x_k| and
    its estimate max(E_k, s)."""
    twin = Level(float(size), int(result.dofs), int(result.newton_iterations), seconds,
                 _positions(result, targets),
                 h=_h(level) * (level.dofs / result.dofs) ** (1.0 / level.markers.shape[1]),
                 rate=level.rate, twin=True)
    twin.scatter = twin.change = float(np.max(np.linalg.norm(twin.markers - level.markers, axis=1)))
    twin.estimate = max(level.estimate, twin.scatter)
    return twin


def solve_level(session):
    """session.solve() on a level's new mesh; a start carried over from the last level that fails (it can
    invert elements on the new mesh) is followed by a solve from rest (Session.solve retries once)."""
    result = session.solve()
    retried = getattr(result, "retried_from_rest", None)
    if retried:
        log.info("--tol: h = %g mm from the last level's state failed (%s); solved from rest",
                 session.design.mesh.size, retried["warm_status"])
    return result


def solve_twin(session, level: Level, edit, targets=None) -> tuple[Level | None, object]:
    """Solve the twin of ``level``: edit(f) puts the session on the level's mesh family at f times its
    size, for f = TWIN, TWIN^2, TWIN^3 until Gmsh makes another mesh. (the twin's Level, or None if its
    solve failed; the Result)."""
    t = time.perf_counter()
    for f in TWIN ** np.arange(1, 4):
        edit(float(f))
        result = solve_level(session)
        if not result.converged:
            return None, result
        if result.dofs != level.dofs:
            break
    else:
        log.warning("--tol: %g ... %g times the size of %d DOFs give one mesh: the scatter is not measured",
                    TWIN, f, level.dofs)
    return twin_level(level, level.size * f, result, time.perf_counter() - t, targets), result


def rigid_variant(design):
    """design with every elastic bone ``rigid = true``; None if it has none or refuses rigid bones."""
    from ..design.spec import DesignError
    from ..design.parse import parse_design
    names = [b.name for b in design.bones if not b.rigid]
    if not names:
        return None
    try:
        return parse_design(design.raw, design.source, [f"bones.{n}.rigid=true" for n in names])
    except DesignError:
        return None


def choose_bones(session, rigid, level: Level, size, tol: float,
                 targets=None) -> tuple[bool, Level | None, object, dict | None]:
    """The first mesh again with every bone rigid: rigid is that design at the level's size, size its graded
    field. Returns (use, the rigid Level, its Result, ``accuracy.bones``): use when MARGIN b <= RIGID_SHARE tol,
    b = max |x_rigid - x_elastic|; (False, None, None, None) if the model refuses rigid bones or their solve
    fails. Either way the session no longer holds the elastic solve."""
    from ..design.spec import DesignError
    t = time.perf_counter()
    try:
        session.edit(rigid, size=size)
        result = session.solve()
    except DesignError as exc:                   # e.g. a fixed pin holds a bone
        log.info("--tol: rigid bones refused (%s)", exc)
        return False, None, None, None
    if not result.converged:
        log.info("--tol: the solve with rigid bones failed (%s); elastic bones", result.status)
        return False, None, None, None
    probe = Level(level.size, int(result.dofs), int(result.newton_iterations), time.perf_counter() - t,
                  _positions(result, targets), h=level.h)
    b = float(np.max(np.linalg.norm(probe.markers - level.markers, axis=1)))
    use = MARGIN * b <= RIGID_SHARE * tol
    log.info("--tol: rigid bones move the markers by %.3g mm: %s bones", b, "rigid" if use else "elastic")
    return use, probe, result, {"rigid": use, "difference": b, "elastic_seconds": level.seconds,
                                "rigid_seconds": probe.seconds}


