"""``--tol``: solve on the ladder of meshes (uniform, or adaptive rounds) until the estimate meets tol.
"""
from __future__ import annotations

import logging
import time
from dataclasses import replace

from ..design import resources
from ..design.spec import DesignError
from .targets import Targets
from .ladder import (DEGREE, Level, MARGIN, MAX_LEVELS, RATIO, at_size, choose_bones, judged, ladder_zones, may_stop,
                     next_level, next_size, rigid_variant, solve_level, solve_twin, trusted)

log = logging.getLogger("skelfem")


def refine(session, tol, adaptive: bool = False) -> tuple[object, dict]:
    """Solve session's design on the ladder of meshes until the estimate meets tol.

    session: a Session of the design at its first level (DEGREE, size h_0), not
    yet solved. tol: mm for every marker, or the Targets of named observables
    (skelfem.accuracy.targets). Returns (the last solve's Result, the ``accuracy`` dict of
    result.json; its ``levels`` are every solve in order, twins included). The
    session holds the last solve afterwards.
    adaptive: rounds of graded meshes from element indicators instead
    (skelfem.accuracy.adapt; serial runs only, the uniform ladder under MPI).
    """
    targets = tol if isinstance(tol, Targets) else Targets.markers(tol, session.design.dim)
    if adaptive and session.comm.size == 1:
        from .adapt import refine_adaptive
        return refine_adaptive(session, targets, DEGREE)
    result, accuracy = _ladder(session, targets)
    return result, accuracy


def _ladder(session, targets: Targets) -> tuple[object, dict]:
    """refine's uniform ladder, for the rows of ``targets`` against its tol."""
    tol, unit = targets.tol, targets.unit
    rows = None if targets.bare else targets
    design = session.design
    dim, h0 = design.dim, float(design.mesh.size)
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
    result = warning = None
    met_before = None                  # the last level whose estimate met tol (a finer level that fails returns it)

    def fall_back(failed, stop: str):
        """(result, answer, stop, warning) after a failed solve: the last level whose estimate met tol,
        solved again, or the failure as it is."""
        if met_before is None:
            return failed, answer, stop, None
        back = met_before
        session.edit(at_size(design, back.size), size=None if zones is None else zones.scaled(back.size / h0))
        again = session.solve()
        if not again.converged:
            return again, answer, stop, None
        note = (f"{stop}; the answer is the level at h = {back.size:g} mm, whose estimate "
                f"{back.estimate + b:.3g} {unit} met the tolerance")
        log.warning("--tol: %s", note)
        return again, back, note, note

    while True:
        t = time.perf_counter()
        result = solve_level(session)
        if not result.converged:
            result, answer, stop, warning = fall_back(
                result, f"the solve at h = {session.design.mesh.size:g} mm failed ({result.status})")
            stale = stale and warning is None
            break
        if levels and result.dofs == levels[-1].dofs:       # Gmsh made the same mesh: no new level
            log.info("--tol: h = %g mm gives the mesh of h = %g mm again", session.design.mesh.size,
                     levels[-1].size)
            history.remove(levels.pop())
        level = next_level(levels, session.design.mesh.size, result, time.perf_counter() - t, rows)
        levels.append(level)
        untrusted = len(levels) >= 3 and not trusted(levels)
        level = levels[-1] = judged(levels)          # a first drop: r = 1; after a stall: refine on
        _log_level(level, unit, untrusted)
        answer = level
        history.append(level)
        if level.estimate is not None and MARGIN * (level.estimate + b) <= tol:
            met_before = level
        rigid = rigid_variant(design) if len(history) == 1 else None
        if rigid is not None:
            use, probe, _, bones = choose_bones(session, at_size(rigid, level.size), level,
                                                None if zones is None else zones.scaled(level.size / h0), tol, rows)
            if use:
                design, b = rigid, bones["difference"]
                levels[-1] = history[-1] = answer = probe
            stale = not use            # the session holds the probe (or nothing solved) until the next edit
        if may_stop(levels) and MARGIN * (level.estimate + b) <= tol:
            def edit(f, h=level.size):
                session.edit(at_size(design, f * h), size=None if zones is None else zones.scaled(f * h / h0))
            twin, result = solve_twin(session, level, edit, rows)
            if twin is None:
                result, answer, stop, warning = fall_back(
                    result, f"the twin solve at h = {session.design.mesh.size:g} mm failed ({result.status})")
                stale = stale and warning is None
                break
            answer = twin
            history.append(answer)
            log.info("--tol: twin h = %g mm, %d DOFs: scatter %.3g, estimate %.3g (%s)", answer.size,
                     answer.dofs, answer.scatter, answer.estimate, unit)
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
        return result, {"tol": targets.spec(), "met": False, "stop": stop, "levels": []}
    return result, _report(targets, result, levels, history, answer, b, bones, stop, warning,
                           time.perf_counter() - t0)


def _log_level(level: Level, unit: str, untrusted: bool) -> None:
    log.info("--tol: h = %g mm, %d DOFs: change %s, estimate %s%s", level.size, level.dofs,
             "-" if level.change is None else f"{level.change:.3g} {unit}",
             "-" if level.estimate is None else f"{level.estimate:.3g} {unit} (r = {level.rate:.2f})",
             f" (the observed rate {level.observed:.2f} is not trusted)" if untrusted else "")


def _report(targets: Targets, result, levels: list[Level], history: list[Level], answer: Level, b: float,
            bones, stop: str, warning: str | None, seconds: float) -> dict:
    """result.json's ``accuracy`` of a ladder that ended on ``answer`` (b: the rigid bones' difference,
    added to its estimate; met only by a twin that may stop, or a fall-back to a level that met tol)."""
    estimate = None if answer.estimate is None else answer.estimate + b
    met = bool(result.converged and ((answer.twin and may_stop(levels)) or warning is not None)
               and estimate is not None and MARGIN * estimate <= targets.tol)
    return {"tol": targets.spec(), "unit": targets.unit, "targets": targets.per_target(estimate),
            "degree": DEGREE, "size": answer.size, "dofs": answer.dofs,
            "estimated_error": estimate, "rate": answer.rate, "scatter": answer.scatter, "met": met,
            "bones": bones, "stop": stop, "warning": warning, "levels": [lv.to_dict() for lv in history],
            "time": round(seconds, 4)}
