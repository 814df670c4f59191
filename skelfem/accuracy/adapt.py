"""Adaptive meshes for --tol: element indicators of the marker error, and a refinement loop.

A *round* solves the design on three meshes of one size field f (mm),
scaled by 4, 2 and 1 in 2D, by 2, sqrt 2 and 1 in 3D (FACTORS: the uniform
ladder's ratio q, accuracy.RATIO; Gmsh's background mesh,
skelfem.mesh.geometry.SizeField): M_4, M_2, M_1 (named by the 2D factors), each
warm-started from the last. Scaling a field by q divides every local size
by q, so the three meshes are a uniform-ratio family and the Richardson
estimate of skelfem.accuracy applies unchanged to the marker positions x_4,
x_2, x_1: with d = max |x_1 - x_2|,

    E = d / (q^r - 1),   r observed from the three (d_{4,2} / d_{2,1}), clipped to [0.5, 2],

is the estimated marker error of the answer (the M_1 solve), with the rate
trusted by the rule of accuracy.trusted read per round (round_trusted: a
rate above 2 only after a round whose rate was at least 1); an untrusted
first round is estimated at r = R_TWO_LEVELS, as the uniform ladder's first
drop (round_judged, accuracy.judged), and a drop right after a round whose
differences did not fall never ends the rounds (round_may_stop). Bones
are chosen as the uniform ladder chooses them, on the first round's first mesh (accuracy.choose_bones):
rigid where MARGIN b <= RIGID_SHARE tol, b then added to every estimate.
The first round is the uniform ladder's first
three meshes (2h, h, h/2 for the design's size h; 2h, sqrt 2 h, h in 3D; graded near finite anchors
and clamped corners as accuracy.ladder_zones says), so the two agree until the estimate asks for more.
(In 3D a factor of 2 per mesh would make each M_1 about 8 times M_2: post3d's second round asked
for 630k DOFs of P2 tetrahedra after 89k.)

Indicators (two meshes, goal-weighted). On the cells K of M_1, with the
coarse solution u_2 interpolated at M_1's nodes (I u_2) and the marker's
adjoint z on M_1 (H z = S^T g: H the Hessian at the equilibrium, S the
marker's interpolation rows, g the direction of the marker's change x_1 - x_2),

    eta_K = ||E(u_1) - E(I u_2)||_{L2(K)} * ||sym(F_1^T grad w)||_{L2(K)},
    w = z - I(I_2 z)   (the part of z that M_2 cannot represent),

with E(u) = sym(grad u) + grad(u)^T grad(u) / 2 the Green-Lagrange strain
and F_1 = I + grad u_1. For a linear problem J(u - u_2) = a(u - u_2, z - I z)
(Galerkin orthogonality), so the product of the local norms of the two
factors bounds the cell's share of the marker error up to the material
constant; Green-Lagrange strains vanish for rigid motions, so turning bones
carry no indicator. The indicators are scaled to sum to the estimated error
of M_2, E_2 = d + E.

New sizes (equidistribution). With the measured rate r, halving the size in
K by rho_K multiplies its share by rho_K^r and its cells by rho_K^-dim.
Minimising the cells subject to sum eta_K rho_K^r = T gives

    rho_K = C eta_K^(-1 / (r + dim)),   C = (T / sum eta_K^(dim / (r + dim)))^(1 / r),

T = q^r tol / (MARGIN AIM) (the next M_2's error, so that the next M_1's
estimate lands at tol / (MARGIN AIM)). rho_K is clipped to [1/SHRINK, GROW],
the new size of K is h_K rho_K (h_K: the edge of an equilateral cell of K's
area or volume) and never above the first round's finest size there (half
the design's [mesh] size in 2D, the size itself in 3D, finer in the ladder's zones at anchors and
clamped corners: first_sizes; the rounds only refine) nor below the lattice spacing
of the finite anchors (anchor_spacing: below it each lattice point is a
point force again, a singularity of the model that refinement would chase;
seen on the finger and the thumb before this floor). A vertex takes the
smallest size of its cells.

From the second round on, the last round's answer is one more mesh: E is
at least cross_round's Richardson estimate between the two rounds' finest
meshes (sizes measured by DOFs), or their difference where they are of
about one size. A field adapted to the indicators can lose accuracy that
the last round had (finger_tapered_fillet: 0.0014 mm off with 14.7k DOFs in
round 1, 0.026 mm off with 14.0k in round 2, while round 2's own three
meshes estimated 0.0025 mm); the two rounds' difference (0.027 mm) shows it.

It stops as the uniform ladder does. When MARGIN E <= tol and the estimate
is trusted, it solves a twin of M_1 (the same field scaled by
accuracy.TWIN, TWIN^2, TWIN^3 where Gmsh makes M_1 again), whose estimate
is max(E, s), s = max |x_twin - x_1|, the scatter a round of three meshes
cannot see (accuracy.twin_level); the twin is the answer, ``met: true``
when MARGIN max(E, s) <= tol, else the rounds go on with that estimate.
It also stops when the next round's finest mesh would pass the DOF limit
(predicted from the field) or after MAX_ROUNDS rounds (``met: false``
with the estimate of the last round). Serial only (the indicators gather
nothing across ranks); under MPI, --tol uses the uniform ladder.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import replace

import numpy as np

from . import ladder as accuracy
from .ladder import AIM, MARGIN, Level
from ..mesh.points import cell_centroids, cell_sizes  # noqa: F401 (used here and by tests)

log = logging.getLogger("skelfem")

SHRINK = 4.0          # a cell's size falls by at most this per round
GROW = 2.0            # ... and grows by at most this
MAX_ROUNDS = 4        # rounds of three meshes (the uniform ladder allows 8 meshes)
FACTORS = {2: (4.0, 2.0, 1.0), 3: (2.0, math.sqrt(2.0), 1.0)}   # a round's field scaled by these: the
                                                                # uniform ladder's ratios (accuracy.RATIO)


# -- sizes ----------------------------------------------------------------------------------------------
def size_field(mesh, sizes: np.ndarray):
    """SizeField on the mesh's cells from one size per cell: each vertex takes the smallest of its cells'."""
    from ..mesh.geometry import SizeField
    dim = mesh.topology.dim
    x = mesh.geometry.x[:, :mesh.geometry.dim]
    nodes = mesh.geometry.dofmap.array.reshape(-1, dim + 1)
    sizes = np.asarray(sizes, dtype=float)
    at_vertex = np.full(len(x), np.inf)
    np.minimum.at(at_vertex, nodes.ravel(), np.repeat(sizes, dim + 1))
    return SizeField(x[nodes].copy(), at_vertex[nodes])


def equidistribute(h: np.ndarray, eta: np.ndarray, target: float, rate: float, dim: int,
                   h_max: float | np.ndarray, h_min: float | np.ndarray) -> np.ndarray:
    """New sizes h_K rho_K with rho_K = C eta_K^(-1/(r+dim)) so that sum eta_K rho_K^r = target (see above).

    rho is clipped to [1/SHRINK, GROW] and the sizes to [h_min, h_max] (numbers or one per cell).
    """
    eta = np.maximum(np.asarray(eta, dtype=float), 1e-300)
    q = 1.0 / (rate + dim)
    C = (target / np.sum(eta ** (dim * q))) ** (1.0 / rate)
    rho = np.clip(C * eta ** (-q), 1.0 / SHRINK, GROW)
    return np.clip(h * rho, h_min, h_max)


# -- fields between meshes ------------------------------------------------------------------------------
def evaluate(V, values: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(n, bs) values of the finite-element function (V, values) at points X; nearest DOF where no cell holds X.

    (Points on a boundary that another mesh of the same polygons puts a
    rounding error outside.)
    """
    from scipy.spatial import cKDTree

    from ..mesh.points import interpolation_matrix, locate_cells
    bs = V.dofmap.index_map_bs
    cells = locate_cells(V.mesh, X)
    inside = cells >= 0
    out = np.empty((len(X), bs))
    if inside.any():
        out[inside] = (interpolation_matrix(V, X[inside], cells[inside]) @ values).reshape(-1, bs)
    if (~inside).any():
        Xd = V.tabulate_dof_coordinates()[:, :X.shape[1]]
        out[~inside] = values.reshape(-1, bs)[cKDTree(Xd).query(X[~inside])[1]]
    return out


def _dof_points(model) -> np.ndarray:
    return model.V.tabulate_dof_coordinates()[:, :model.dim]


def marker_adjoint(model, solver, direction: np.ndarray, index: int) -> np.ndarray:
    """z with H z = S_i^T g at the model's equilibrium (H its Hessian, S_i marker index's rows), local array."""
    from ..analysis.sensitivity import Linearization, global_vector, local_values
    lin = Linearization(model, solver)
    try:
        markers = model.term("markers")
        d = model.dim
        rhs = np.asarray(markers.S[index * d:(index + 1) * d].T @ direction).ravel()
        v = global_vector(model, markers, rhs)
        free = lin.dirichlet_free(v)
        z = lin.solve(free)
        out = local_values(z)
        for vec in (v, free, z):
            vec.destroy()
        return out
    finally:
        lin.destroy()


def tension_adjoint(model, solver, name: str) -> np.ndarray:
    """z with H z = dT/du at the model's equilibrium (T: cable `name`'s tension), local array."""
    from ..analysis.sensitivity import Linearization, local_values
    lin = Linearization(model, solver)
    try:
        term = next(t for t in model.terms if t.section == "cables" and t.name == name)
        v = lin.tension_gradient(term)
        z = lin.solve(v)
        out = local_values(z)
        for vec in (v, z):
            vec.destroy()
        return out
    finally:
        lin.destroy()


def target_adjoint(model, solver, targets, row: int, direction: np.ndarray) -> np.ndarray | None:
    """The adjoint that weights the indicators for the ladder's worst row: a marker's (along the row's
    change) or a cable tension's; None (strain differences alone) for the other observables."""
    name, index = targets.owner(row, len(model.design.markers))
    if name is None:
        return marker_adjoint(model, solver, direction, index)
    section, entry = name.split(".")[:2]
    if section == "markers":
        return marker_adjoint(model, solver, direction, list(model.design.markers).index(entry))
    if section == "cables":
        return tension_adjoint(model, solver, entry)
    log.info("--tol (adaptive): %s has no adjoint yet; indicators of the strain differences alone", name)
    return None


def indicators(model, coarse_V, coarse_u: np.ndarray, z: np.ndarray | None) -> np.ndarray:
    """eta_K on model's (the fine mesh's) local cells; see the module docstring.

    coarse_V, coarse_u: the coarse mesh's space and solution; z: the marker's
    adjoint on the fine mesh (None: the strain factor alone).
    """
    import ufl
    from dolfinx import fem

    V = model.V
    X = _dof_points(model)
    uI = fem.Function(V)
    uI.x.array[:] = evaluate(coarse_V, coarse_u, X).ravel()
    u1 = model.u
    Q = fem.FunctionSpace(model.mesh, ("DG", 0))
    q = ufl.TestFunction(Q)
    dx = ufl.dx(metadata={"quadrature_degree": 4})

    def green(u):
        G = ufl.grad(u)
        return ufl.sym(G) + 0.5 * G.T * G

    def per_cell(expr) -> np.ndarray:
        vec = fem.assemble_vector(fem.form(ufl.inner(expr, expr) * q * dx))
        n = model.mesh.topology.index_map(model.mesh.topology.dim).size_local
        return np.sqrt(np.maximum(vec.array[:n], 0.0))

    eta = per_cell(green(u1) - green(uI))
    if z is not None:
        zI = evaluate(coarse_V, np.ascontiguousarray(
            evaluate(V, z, coarse_V.tabulate_dof_coordinates()[:, :model.dim]).ravel()), X).ravel()
        w = fem.Function(V)
        w.x.array[:] = z - zI
        F1 = ufl.Identity(model.dim) + ufl.grad(u1)
        eta = eta * per_cell(ufl.sym(F1.T * ufl.grad(w)))
    return eta


def anchor_spacing(model) -> float | None:
    """The finest lattice spacing the model's finite anchors can take (radius / MAX_PER_RADIUS), or None.

    An anchor's force acts on lattice points at least two per local cell
    size (skelfem.terms.cables.lattice_density), so refining near an anchor
    refines its lattice too, up to MAX_PER_RADIUS points per radius; on cells
    smaller than that spacing each point would be a point force again, whose
    2D displacement is log-singular: refining below it would chase a
    singularity of the model, not an error. The sizes of a round stay at or above it.
    """
    from ..terms.cables import MAX_PER_RADIUS
    radii = [float(r) for _, r in model.finite_anchors() if r and r > 0]
    return min(radii) / MAX_PER_RADIUS[model.dim] if radii else None


def round_trusted(ladder: list[Level], before: float | None) -> bool:
    """accuracy.trusted for a round of three meshes: its observed rate, or above R_MAX only after a round whose
    rate (before) was at least 1 (a drop faster than the elements converge right at the start is not trusted)."""
    last = ladder[-1] if len(ladder) >= 3 else None
    if last is None or last.observed is None:
        return False
    return last.observed <= accuracy.R_MAX or (before is not None and before >= 1.0)


def round_judged(ladder: list[Level], before: float | None) -> Level:
    """A round's last mesh as accuracy.judged sees it: its estimate at the rate R_TWO_LEVELS (the oscillation
    bound where larger) where ``round_trusted`` does not trust the first round's rate (before is None)."""
    first = before is None and not round_trusted(ladder, before)
    return accuracy.at_two_level_rate(ladder) if first else ladder[-1]


def round_may_stop(ladder: list[Level], before: float | None) -> bool:
    """accuracy.may_stop for a round: its rate trusted, or untrusted as the first round's (``round_judged``);
    never a drop right after a round whose differences did not fall."""
    return round_trusted(ladder, before) or before is None


def _choose_bones(session, base, ladder: list[Level], result, size: float, degree: int, field, tol: float,
                  rows=None):
    """accuracy.refine's choice of bones, on the first round's first mesh (accuracy.choose_bones): returns
    (the design the rounds go on with, b, ``accuracy.bones``, the Result the session holds). With elastic
    bones that mesh is solved again, so the session holds the answer its Level reports."""
    rigid = accuracy.rigid_variant(base)
    if rigid is None:
        return base, 0.0, None, result
    use, probe, rigid_result, bones = accuracy.choose_bones(session, _design(rigid, size, degree), ladder[-1],
                                                            field, tol, rows)
    if use:
        ladder[-1] = probe
        return rigid, bones["difference"], bones, rigid_result
    session.edit(_design(base, size, degree), size=field)
    return base, 0.0, bones, session.solve()


# -- the loop ------------------------------------------------------------------------------------------
def first_sizes(zones, h_cap: float, mesh) -> np.ndarray | float:
    """The first round's finest sizes at the mesh's cells: h_cap, finer in the ladder's fixed zones
    (accuracy.ladder_zones of the first size h0, scaled to h_cap / h0 as that mesh was). No round's field is
    coarser: the rounds only refine, so the clamped corners and anchors stay resolved where the marker's
    adjoint, small near a clamp, would let the indicators coarsen them."""
    if zones is None:
        return h_cap
    return np.minimum(zones.scaled(h_cap / zones.outer).at(cell_centroids(mesh)), h_cap)


def cross_round(previous: list[Level], level: Level, dim: int) -> float:
    """The estimate that the last round's answer gives for this round's M_1 (``level``).

    The two rounds' finest meshes are two more meshes of one problem, of
    sizes measured by their DOFs, rho = (N / N_prev)^(1/dim): Richardson
    between them, d / (rho^r - 1), with d = max |x_1 - x_1,prev|, dividing by
    no less than 1. Meshes of about one size (rho^r < 2) are then a twin, and
    their difference is the scatter between two different meshes of one
    resolution, which a round's own three meshes cannot see.
    """
    last = [lv for lv in previous if not lv.twin][-1]
    d = float(np.max(np.linalg.norm(level.markers - last.markers, axis=1)))
    rho = (level.dofs / last.dofs) ** (1.0 / dim)
    return d / max(rho ** level.rate - 1.0, 1.0)


def _design(design, h: float, degree: int):
    from ..design.parse import parse_design
    return parse_design(design.raw, design.source, [f"mesh.size={round(float(h), 9)!r}", f"mesh.degree={degree}"])


def predicted_dofs(model, new_sizes: np.ndarray) -> float:
    """DOFs of a mesh of the new sizes: today's DOFs times sum over cells (h_K / h_new,K)^dim / cells."""
    dim = model.dim
    h = cell_sizes(model.mesh)
    dofs = model.V.dofmap.index_map.size_global * model.bs
    return float(dofs * np.sum((h / new_sizes) ** dim) / len(h))


def _record(rnd: int, mesh, level: Level, result, session) -> dict:
    """One solve's row of ``accuracy.levels`` (mesh: 1, 2, 3 or "twin")."""
    h_cells = cell_sizes(session.model.mesh)
    return {"round": rnd, "mesh": mesh, "dofs": level.dofs, "cells": int(result.cells),
            "min_size": float(h_cells.min()), "max_size": float(h_cells.max()),
            "iterations": level.iterations, "seconds": round(level.seconds, 4),
            "change": level.change, "estimate": level.estimate, "rate": level.rate, "twin": level.twin}


def refine_adaptive(session, tol, degree: int = accuracy.DEGREE, weighted: bool = True,
                    max_rounds: int = MAX_ROUNDS, on_level=None, reduction: float | None = None,
                    graded: bool = True) -> tuple[object, dict]:
    """Rounds of three meshes of an adapted size field until the marker-error estimate meets tol.

    session: a Session of the design at the first size (2x its [mesh] size,
    uniform), not yet solved; degree: the element degree of every mesh.
    weighted: indicators weighted by the marker's adjoint (else strain
    differences alone). on_level(level_dict, session): called after each
    solve (studies time and read it). reduction: aim each round at this
    fraction of the last estimate instead of at tol (a convergence curve for
    studies; tol then only stops). graded=False starts from uniform meshes, without the ladder's zones
    at anchors and clamped corners (studies: what the indicators find on their own). Returns (the last Result, the
    ``accuracy`` dict of result.json); the session holds the last mesh.
    """
    from ..design import resources
    from .targets import Targets

    if session.comm.size != 1:
        raise ValueError("adaptive refinement runs serially (use the uniform ladder under MPI)")
    targets = tol if isinstance(tol, Targets) else Targets.markers(tol, session.design.dim)
    tol, rows = targets.tol, (None if targets.bare else targets)
    t0 = time.perf_counter()
    base = session.design                     # at the first size, 2 h
    h_design = 0.5 * float(base.mesh.size)
    dim = base.dim
    factors = FACTORS[dim]
    h_cap = float(base.mesh.size) / factors[0]    # the first round's finest size: rounds only refine
    zones = accuracy.ladder_zones(session.model, base, float(base.mesh.size)) if graded else None
    records, rounds = [], []
    field = result = level = None
    before = before_last = None           # the observed rate of the round before (and of the one before it)
    bones, b = None, 0.0                  # accuracy.bones; b: the rigid bones' difference (added to estimates)
    stop = "estimate met the tolerance"
    for rnd in range(max_rounds):
        ladder: list[Level] = []
        coarse = None
        for i, factor in enumerate(factors):
            first = None if zones is None else zones.scaled(factor / factors[0])
            if rnd > 0 or i > 0 or zones is not None:
                design = _design(base, h_cap * factor, degree)
                if i > 0:
                    coarse = (session.model.V, session.model.u.x.array.copy(), session.model)
                session.edit(design, size=first if field is None else field.scaled(factor))
            t = time.perf_counter()
            result = session.solve()
            if not result.converged:
                stop = f"the solve of round {rnd + 1}, mesh {i + 1} failed ({result.status})"
                break
            ladder.append(accuracy.next_level(ladder, factor, result, time.perf_counter() - t, rows))
            if not rounds and i == 0:
                base, b, bones, result = _choose_bones(session, base, ladder, result, h_cap * factor, degree,
                                                       first, tol, rows)
                if not result.converged:
                    stop = f"the elastic solve of round 1, mesh 1 failed again ({result.status})"
                    break
            level = ladder[-1] = round_judged(ladder, before) if i == len(factors) - 1 else ladder[-1]
            if rounds and i == len(factors) - 1:
                level = ladder[-1] = _bounded_by(rounds[-1], level, dim, rnd)
            rec = _record(rnd + 1, i + 1, level, result, session)
            records.append(rec)
            _log_level(rnd + 1, i + 1, level, rec)
            if on_level is not None:
                on_level(dict(rec), session)
        else:
            rounds.append(ladder)
            before_last = before
            if round_may_stop(ladder, before) and MARGIN * (level.estimate + b) <= tol:
                size = field if field is not None else zones
                scale = 1.0 if field is not None else 1.0 / factors[0]
                twin, result = _twin(session, level, rows, rnd, records,
                                     lambda f: session.edit(_design(base, f * h_cap, degree),
                                                            size=None if size is None else size.scaled(f * scale)))
                if twin is None:
                    stop = f"the twin solve of round {rnd + 1} failed ({result.status})"
                    break
                ladder.append(twin)
                if MARGIN * (twin.estimate + b) <= tol:
                    break
                level = ladder[-2] = replace(level, estimate=twin.estimate)   # go on with what the twin saw
            before = level.observed
            if rnd + 1 >= max_rounds:
                stop = f"{max_rounds} rounds"
                break
            goal = tol / (MARGIN * AIM) if reduction is None else reduction * level.estimate
            model = session.model
            new = _next_sizes(session, targets, ladder, level, coarse, weighted,
                              (factors[-2] / factors[-1]) ** level.rate * goal, zones, h_cap, h_design)
            dofs = predicted_dofs(model, new)
            if dofs * 1.05 > resources.limit(base, dofs * 1.05)[0] and not resources.FORCED:
                stop = f"the next round's finest mesh (about {dofs:.3g} DOFs) would pass the DOF limit"
                break
            field = size_field(model.mesh, new)
            coarse = None
            continue
        break
    if not rounds:
        return result, {"tol": targets.spec(), "adaptive": True, "met": False, "stop": stop, "levels": records}
    return result, _summary(session, targets, rounds, records, result, before_last, b, bones, stop, degree, t0)


def _bounded_by(last_round: list, level, dim: int, rnd: int):
    """level, its estimate raised to its distance from the last round's answer if that is larger."""
    cross = cross_round(last_round, level, dim)
    if cross > level.estimate:
        log.info("--tol (adaptive) round %d: %.3g mm from the last round's answer", rnd + 1, cross)
        return replace(level, estimate=cross)
    return level


def _twin(session, level, rows, rnd: int, records: list, edit):
    """The round's twin solve (accuracy.solve_twin: meshes edited by edit(f)), recorded and logged:
    (twin level or None if its solve failed, its Result)."""
    twin, result = accuracy.solve_twin(session, level, edit, rows)
    if twin is not None:
        rec = _record(rnd + 1, "twin", twin, result, session)
        rec["scatter"] = twin.scatter
        records.append(rec)
        log.info("--tol (adaptive) round %d twin: %d DOFs: scatter %.3g mm, estimate %.3g mm", rnd + 1,
                 twin.dofs, twin.scatter, twin.estimate)
    return twin, result


def _next_sizes(session, targets, ladder, level, coarse, weighted: bool, target: float, zones, h_cap: float,
                h_design: float) -> np.ndarray:
    """The next round's cell sizes on the finest mesh: indicators of M_2's error on M_1's cells (weighted
    by the adjoint of the marker that moved most, unless weighted is False), scaled to the round's change
    and estimate, equidistributed to target within the first round's sizes and the anchors' floor."""
    model, dim = session.model, session.design.dim
    m1, m2 = [lv for lv in ladder if not lv.twin][-2:][::-1]
    i_max = int(np.argmax(np.linalg.norm(m1.markers - m2.markers, axis=1)))
    g = m1.markers[i_max] - m2.markers[i_max]
    g = g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.eye(dim)[0]
    z = target_adjoint(model, session.solver, targets, i_max, g) if weighted else None
    eta = indicators(model, coarse[0], coarse[1], z)
    eta *= (level.change + level.estimate) / max(float(np.sum(eta)), 1e-300)
    h_cells = cell_sizes(model.mesh)
    cap = first_sizes(zones, h_cap, model.mesh)
    floor = max(1e-3 * h_design, anchor_spacing(model) or 0.0)
    return equidistribute(h_cells, eta, target, level.rate, dim, cap, np.minimum(floor, cap))


def _log_level(rnd: int, i: int, level, rec: dict) -> None:
    log.info("--tol (adaptive) round %d mesh %d: %d DOFs, h %.3g..%.3g mm: change %s, estimate %s",
             rnd, i, level.dofs, rec["min_size"], rec["max_size"],
             "-" if level.change is None else f"{level.change:.3g} mm",
             "-" if level.estimate is None else f"{level.estimate:.3g} mm (r = {level.rate:.2f})")


def _summary(session, targets, rounds: list, records: list, result, before_last, b: float, bones, stop: str,
             degree: int, t0: float) -> dict:
    """The ``accuracy`` dict of result.json after the rounds: met only if the last round's twin holds
    the estimate (plus the rigid bones' difference b) within tol."""
    tol = targets.tol
    last = rounds[-1][-1]
    estimate = None if last.estimate is None else last.estimate + b
    three = [lv for lv in rounds[-1] if not lv.twin]
    met = bool(result.converged and last.twin and round_may_stop(three, before_last) and estimate is not None
               and MARGIN * estimate <= tol)
    h_final = cell_sizes(session.model.mesh)
    return {"tol": targets.spec(), "unit": targets.unit, "targets": targets.per_target(estimate),
            "adaptive": True, "degree": degree, "dofs": last.dofs,
            "min_size": float(h_final.min()), "max_size": float(h_final.max()),
            "size": float(h_final.max()), "rounds": len(rounds),
            "estimated_error": estimate, "rate": last.rate, "scatter": last.scatter,
            "met": met, "bones": bones, "stop": stop, "levels": records,
            "time": round(time.perf_counter() - t0, 4)}
