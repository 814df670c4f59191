"""accuracy/tol (from accuracy.py)

Model no more than the scene needs: refine the design's own mesh until its error estimate meets --tol.

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
of skelfem.resources or MAX_LEVELS (``met: false``: the estimate on the
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
point force in 2D: a cable *bending* inside silicone, see the README), the
differences do not fall, the observed rate is small, and the estimate stays
large: ``met: false``, which is the truth.
"""
from __future__ import annotations

import logging
import time
from dataclasses import replace

from .ladder import DEGREE, Level, MARGIN, MAX_LEVELS, RATIO, at_size, choose_bones, judged, ladder_zones, may_stop, next_level, next_size, rigid_variant, solve_twin, trusted

log = logging.getLogger("skelfem")


def refine(session, tol: float, adaptive: bool = False) -> tuple[object, dict]:
    """Solve session's design on the ladder of meshes until the estimate meets tol.

    session: a Session of the design at its first level (DEGREE, size h_0), not
    yet solved. Returns (the last solve's Result, the ``accuracy`` dict of
    result.json; its ``levels`` are every solve in order, twins included). The
    session holds the last solve afterwards.
    adaptive: rounds of graded meshes from element indicators instead
    (skelfem.adapt; serial runs only, the uniform ladder under MPI).
    """
    if adaptive and session.comm.size == 1:
        from .adapt import refine_adaptive
        return refine_adaptive(session, tol, DEGREE)
    from ..design import resources
    from ..design.spec import DesignError

    design = session.design
    dim = design.dim
    h0 = float(design.mesh.size)
    zones = ladder_zones(session.model, design, h0)
    if zones is not None:
        session.edit(design, size=zones)
    levels: list[Level] = []           # the ladder (Richardson's)
    history: list[Level] = []          # every solve in order: the ladder's and the twins
    answer = None                      # the Level of the last solve
    bones, b = None, 0.0               # accuracy.bones; b: the rigid bones' difference (added to estimates)
    stale = False                      # the session does not hold the first level's elastic solve
    t0 = time.perf_counter()
    stop = "estimate met the tolerance"
    result = None
    while True:
        t = time.perf_counter()
        result = session.solve()
        if not result.converged:
            stop = f"the solve at h = {session.design.mesh.size:g} mm failed ({result.status})"
            break
        if levels and result.dofs == levels[-1].dofs:       # Gmsh made the same mesh: no new level
            log.info("--tol: h = %g mm gives the mesh of h = %g mm again", session.design.mesh.size,
                     levels[-1].size)
            history.remove(levels.pop())
        level = next_level(levels, session.design.mesh.size, result, time.perf_counter() - t)
        levels.append(level)
        untrusted = len(levels) >= 3 and not trusted(levels)
        level = levels[-1] = judged(levels)          # a first drop: r = 1; after a stall: refine on
        log.info("--tol: h = %g mm, %d DOFs: change %s, estimate %s%s", level.size, level.dofs,
                 "-" if level.change is None else f"{level.change:.3g} mm",
                 "-" if level.estimate is None else f"{level.estimate:.3g} mm (r = {level.rate:.2f})",
                 f" (the observed rate {level.observed:.2f} is not trusted)" if untrusted else "")
        answer = level
        history.append(level)
        rigid = rigid_variant(design) if len(history) == 1 else None
        if rigid is not None:
            use, probe, _, bones = choose_bones(session, at_size(rigid, level.size), level,
                                                None if zones is None else zones.scaled(level.size / h0), tol)
            if use:
                design, b = rigid, bones["difference"]
                levels[-1] = history[-1] = answer = probe
            stale = not use            # the session holds the probe (or nothing solved) until the next edit
        if may_stop(levels) and MARGIN * (level.estimate + b) <= tol:
            def edit(f, h=level.size):
                session.edit(at_size(design, f * h), size=None if zones is None else zones.scaled(f * h / h0))
            twin, result = solve_twin(session, level, edit)
            if twin is None:
                stop = f"the twin solve at h = {session.design.mesh.size:g} mm failed ({result.status})"
                break
            answer = twin
            history.append(answer)
            log.info("--tol: twin h = %g mm, %d DOFs: scatter %.3g mm, estimate %.3g mm", answer.size,
                     answer.dofs, answer.scatter, answer.estimate)
            if MARGIN * (answer.estimate + b) <= tol:
                break
            level = replace(level, estimate=answer.estimate)     # go on with what the twin measured
        if len(levels) >= MAX_LEVELS:
            stop = f"{MAX_LEVELS} levels"
            break
        h = level.size / RATIO[dim] if len(levels) < 3 else next_size(level, tol, dim)
        finer = at_size(design, h)
        try:
            resources.check(finer)
        except DesignError:
            stop = f"the next mesh (h = {h:.3g} mm) would pass the DOF limit"
            break
        session.edit(finer, size=None if zones is None else zones.scaled(h / h0))
        stale = False
    if stale:                          # the ladder ended on its first level: solve its elastic answer again
        session.edit(at_size(design, answer.size), size=None if zones is None else zones.scaled(answer.size / h0))
        result = session.solve()
    if not levels:
        return result, {"tol": tol, "met": False, "stop": stop, "levels": []}
    last = answer
    estimate = None if last.estimate is None else last.estimate + b
    met = bool(result.converged and last.twin and may_stop(levels) and MARGIN * estimate <= tol)
    accuracy = {"tol": tol, "degree": DEGREE, "size": last.size, "dofs": last.dofs,
                "estimated_error": estimate, "rate": last.rate, "scatter": last.scatter, "met": met,
                "bones": bones,
                "stop": stop, "levels": [lv.to_dict() for lv in history],
                "time": round(time.perf_counter() - t0, 4)}
    return result, accuracy
