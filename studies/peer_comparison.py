"""The tendon strip in skelfem and in scikit-fem, side by side, in the same run.

    python studies/peer_comparison.py [--out studies/output/peer_comparison] [--figures studies/figures]

Problem: the ``strip`` of studies/speed_accuracy.py (100 x 10 mm, E = 1 MPa,
nu = 0.3, 10 mm deep, plane strain, base pinned, a straight tendon at offset
d = 3 mm from the axis anchored in a stiff cap at the tip, k = 1 N/mm,
contraction 0.6 mm). Both codes minimise the same discrete energy

    Pi(u) = t int psi(F) dx + k/2 max(l(u) - L, 0)^2,
    psi   = mu/2 (tr F^T F - 2) - mu ln J + lam/2 (ln J)^2,

on the same triangles (Gmsh via skelfem, exported to a skfem.MeshTri), with
the same Lagrange degree and quadrature degree (8 for the P2 residual, 12
for its Jacobian: UFL's estimates, which skelfem's forms get), and the
same tendon: a polyline through via points where the sketch crosses mesh
edges, l = sum |d_i|. Its equivalent in beam terms is a compressive force T
plus a moment T d at every cross-section; keeping the tendon itself (and not
an end load) makes the two discrete problems identical, so their answers
must agree to solver tolerance and "matched accuracy" means "same mesh".

The scikit-fem side is written here from scikit-fem's public API only:
Neo-Hookean residual P(F) : grad v and tangent dP[grad du] : grad v as
skfem forms, the tendon through ``Basis.probes``, Newton with full steps
(halved only if an element inverts), scipy's default sparse direct solver
(skfem.solve). With an Armijo line search on Pi instead, the peer's Newton
crawls (36 iterations at h = 4, no convergence in 50 at h = 2): it lacks
skelfem's exact-rotation correction, so the stiff cap's linearised rotation
stretches it and Pi rejects long steps.
Times exclude meshing (shared) and, for skelfem, the FFCx JIT (warm cache).
"""
from __future__ import annotations

import argparse
import importlib.util
import math
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from skelfem.io.files import copy_figure, say

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "studies" / "output" / "peer_comparison"
QUADRATURE = {1: (1, 2), 2: (8, 12)}     # (residual, Jacobian) quadrature degree, as UFL estimates


def _speed_accuracy():
    spec = importlib.util.spec_from_file_location("speed_accuracy", Path(__file__).with_name("speed_accuracy.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def have_skfem() -> bool:
    return importlib.util.find_spec("skfem") is not None


# -- skelfem ----------------------------------------------------------------------------------------------
def skelfem_solve(size: float, degree: int) -> tuple[dict, dict]:
    """Mesh and solve the strip with skelfem; returns (numbers, the problem for the peer)."""
    from skelfem import Session
    from skelfem.design import parse_design
    from skelfem.terms.elasticity import lame

    sa = _speed_accuracy()
    raw = sa.strip_dict(size, degree)
    design = parse_design(raw, "strip.toml")
    session = Session(design)                  # mesh, then model and Newton solver
    setup = session.timings["compile"]         # set-up without meshing, as for the peer
    t1 = time.perf_counter()
    result = session.solve(1)
    t2 = time.perf_counter()
    session.close()
    report = result.report
    row = {"code": "skelfem", "size": size, "degree": degree, "converged": bool(report.converged),
           "status": report.status, "dofs": session.dofs,
           "newton_iterations": report.newton_iterations, "time_setup": setup, "time_solve": t2 - t1,
           "time": setup + t2 - t1,
           "final_residual": report.residual_history[-1][-1] if report.residual_history else 0.0}
    if report.converged:
        tip = result.markers["tip"]["position"]
        tension = result.cables[raw["cables"][0]["name"]]["tension"]
        row.update(tip_x=float(tip[0]), tip_y=float(tip[1]), tension=float(tension))
    # the same problem, as plain arrays
    mesh, tm = session.model.mesh, session.model.tm
    x = mesh.geometry.x[:, :2]
    cells = mesh.geometry.dofmap.array.reshape(-1, 3)
    region = np.zeros(len(cells), dtype=np.int32)
    region[tm.cell_tags.indices] = tm.cell_tags.values
    mu = np.zeros(len(cells))
    lam = np.zeros(len(cells))
    materials = {tm.tags["body"]: raw["body"]["material"],
                 **{tm.tags[f"bone:{b['name']}"]: b["material"] for b in raw.get("bones", [])}}
    for tag, name in materials.items():
        m = raw["materials"][name]
        mu[region == tag], lam[region == tag] = lame(m["E"], m["nu"])
    cable = raw["cables"][0]
    problem = {"points": x.copy(), "cells": cells.copy(), "mu": mu, "lam": lam, "thickness": raw["thickness"],
               "path": np.asarray(cable["path"], float), "k": cable["stiffness"],
               "contraction": cable["contraction"], "marker": np.asarray(raw["markers"]["tip"], float),
               "pinned_y": raw["pins"][0]["region"][1][1], "degree": degree,
               "rtol": design.solver.rtol, "atol": effective_atol(design)}
    return row, problem


def effective_atol(design) -> float:
    """The Newton atol skelfem uses for the design: its own, or relative to its force scale."""
    from skelfem.design.spec import ATOL_RELATIVE, force_scale
    return design.solver.atol if design.solver.atol is not None else ATOL_RELATIVE * force_scale(design)


# -- scikit-fem -------------------------------------------------------------------------------------------
def _neo_hookean_forms():
    """Pi, R = dPi/du and H = d2Pi/du2 of t psi(F) as scikit-fem forms.

    P(F)      = mu (F - F^-T) + lam ln J F^-T
    dP[dF]    = mu dF + (mu - lam ln J) F^-T dF^T F^-T + lam (F^-T : dF) F^-T
    """
    from skfem import BilinearForm, Functional, LinearForm
    from skfem.helpers import ddot, det, grad, identity, inv, transpose

    def kinematics(w):
        du = w["u"].grad
        F = du + identity(du)
        J = det(F)
        return F, J, transpose(inv(F))

    @Functional
    def energy(w):
        F, J, _ = kinematics(w)
        with np.errstate(invalid="ignore", divide="ignore"):
            lnJ = np.log(J)
        return w["t"] * (w["mu"] / 2 * (ddot(F, F) - 2) - w["mu"] * lnJ + w["lam"] / 2 * lnJ ** 2)

    @LinearForm
    def residual(v, w):
        F, J, FinvT = kinematics(w)
        P = w["mu"] * (F - FinvT) + w["lam"] * np.log(J) * FinvT
        return w["t"] * ddot(P, grad(v))

    @BilinearForm
    def tangent(du, v, w):
        F, J, FinvT = kinematics(w)
        dF = grad(du)
        A = np.einsum("ik...,lk...,lj...->ij...", FinvT, dF, FinvT)      # F^-T dF^T F^-T
        dP = (w["mu"] * dF + (w["mu"] - w["lam"] * np.log(J)) * A
              + w["lam"] * ddot(FinvT, dF) * FinvT)
        return w["t"] * ddot(dP, grad(v))

    return energy, residual, tangent


def _via_points(points, edges, path, pieces: int = 1) -> np.ndarray:
    """Sketch vertices plus every crossing with a mesh edge, in order along the path; each piece
    between them cut into `pieces` equal chords (skelfem's P2 cables take 4 per cell)."""
    out = []
    a, b = points[edges[0]], points[edges[1]]
    for p, q in zip(path[:-1], path[1:]):
        r, e = q - p, b - a
        den = r[0] * e[:, 1] - r[1] * e[:, 0]
        ok = np.abs(den) > 1e-14 * np.linalg.norm(r) * np.linalg.norm(e, axis=1)
        ap = a - p
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (ap[:, 0] * e[:, 1] - ap[:, 1] * e[:, 0]) / den
            s = (ap[:, 0] * r[1] - ap[:, 1] * r[0]) / den
        hit = ok & (t > -1e-10) & (t < 1 + 1e-10) & (s > -1e-10) & (s < 1 + 1e-10)
        ts = np.unique(np.round(np.clip(np.concatenate([[0.0], t[hit], [1.0]]), 0, 1), 12))
        ts = np.concatenate([np.linspace(t0, t1, pieces, endpoint=False) for t0, t1 in zip(ts[:-1], ts[1:])])
        out.append(p + ts[:, None] * r)
    pts = np.vstack(out + [path[-1:]])
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
    return pts[keep]


class PeerTendon:
    """k/2 max(l - L, 0)^2 with l = sum |d_i|, d = d0 + B u, B = D S, S from Basis.probes."""

    def __init__(self, basis, X: np.ndarray, k: float, contraction: float):
        n = len(X)
        P = basis.probes(X.T).tocsr()                   # rows: component-major (all x, then all y)
        order = np.arange(2 * n).reshape(2, n).T.ravel()  # -> point-major (x0, y0, x1, y1, ...)
        S = P[order]
        D = sp.kron(sp.diags([-np.ones(n - 1), np.ones(n - 1)], [0, 1], shape=(n - 1, n)), sp.identity(2))
        self.B = (D @ S).tocsr()
        self.d0 = np.diff(X, axis=0)
        self.k = k
        self.L = float(np.linalg.norm(self.d0, axis=1).sum()) - contraction

    def _state(self, u):
        d = self.d0 + (self.B @ u).reshape(self.d0.shape)
        norm = np.linalg.norm(d, axis=1)
        return d, norm, norm.sum() - self.L

    def energy(self, u) -> float:
        s = max(self._state(u)[2], 0.0)
        return 0.5 * self.k * s * s

    def tension(self, u) -> float:
        return self.k * max(self._state(u)[2], 0.0)

    def gradient(self, u) -> np.ndarray:
        d, norm, s = self._state(u)
        if s <= 0:
            return np.zeros(self.B.shape[1])
        return self.k * s * (self.B.T @ (d / norm[:, None]).ravel())

    def hessian(self, u) -> sp.csr_matrix:
        """k (g g^T + s B^T W B), W = blockdiag((I - t t^T) / |d_i|)."""
        d, norm, s = self._state(u)
        if s <= 0:
            return sp.csr_matrix((self.B.shape[1],) * 2)
        t = d / norm[:, None]
        g = sp.csr_matrix(self.B.T @ t.ravel()).T
        blocks = (np.eye(2)[None] - t[:, :, None] * t[:, None, :]) / norm[:, None, None]
        W = sp.block_diag(list(blocks), format="csr")
        return (self.k * (g @ g.T + s * (self.B.T @ W @ self.B))).tocsr()


def _step_length(energy, u, du, r, line_search: str) -> float:
    """Full Newton step, halved while the trial state inverts an element (Pi = inf);
    with line_search="energy" also until Armijo's condition on Pi holds."""
    alpha, e0, slope = 1.0, energy(u), float(r @ du)
    while alpha > 1e-8:
        e = energy(u + alpha * du)
        if np.isfinite(e) and (line_search == "none" or e <= e0 + 1e-4 * alpha * slope
                               or abs(e - e0) < 1e-13 * abs(e0)):
            break
        alpha *= 0.5
    return alpha


def skfem_solve(problem: dict, max_iterations: int = 50, line_search: str = "none") -> dict:
    """Newton on the same discrete energy with scikit-fem; numbers in the skelfem row's format.

    line_search "none" (default): full steps, halved only when an element
    inverts. "energy": Armijo backtracking on Pi, which, without skelfem's
    exact-rotation correction for stiff parts, crawls: the stiff cap's
    linearised rotation stretches it, so Pi rejects long steps.
    """
    from skfem import Basis, ElementTriP0, ElementTriP1, ElementTriP2, ElementVector, MeshTri, condense, solve

    t0 = time.perf_counter()
    p, cells = problem["points"], problem["cells"]
    v0, v1, v2 = p[cells[:, 0]], p[cells[:, 1]], p[cells[:, 2]]
    area2 = (v1[:, 0] - v0[:, 0]) * (v2[:, 1] - v0[:, 1]) - (v1[:, 1] - v0[:, 1]) * (v2[:, 0] - v0[:, 0])
    cells = np.where((area2 < 0)[:, None], cells[:, [0, 2, 1]], cells)          # counter-clockwise
    mesh = MeshTri(p.T.copy(), cells.T.copy())
    degree = problem["degree"]
    element = ElementVector(ElementTriP2() if degree == 2 else ElementTriP1())
    q_r, q_j = QUADRATURE[degree]
    basis_r, basis_j = Basis(mesh, element, intorder=q_r), Basis(mesh, element, intorder=q_j)
    consts = {}
    for name, basis in (("r", basis_r), ("j", basis_j)):
        dg0 = basis.with_element(ElementTriP0())
        consts[name] = {"mu": dg0.interpolate(problem["mu"]), "lam": dg0.interpolate(problem["lam"]),
                        "t": problem["thickness"]}
    fixed = basis_r.get_dofs(lambda x: x[1] <= problem["pinned_y"]).all()
    cable = PeerTendon(basis_r, _via_points(mesh.p.T, mesh.facets, problem["path"], 4 if degree == 2 else 1),
                       problem["k"],
                       problem["contraction"])
    marker = basis_r.probes(problem["marker"][:, None]).tocsr()
    energy_form, residual_form, tangent_form = _neo_hookean_forms()
    t1 = time.perf_counter()

    def energy(u):
        e = energy_form.assemble(basis_r, u=basis_r.interpolate(u), **consts["r"])
        return e + cable.energy(u) if np.isfinite(e) else math.inf

    def residual(u):
        r = residual_form.assemble(basis_r, u=basis_r.interpolate(u), **consts["r"]) + cable.gradient(u)
        r[fixed] = 0.0
        return r

    u = np.zeros(basis_r.N)
    r = residual(u)
    r0 = np.linalg.norm(r)
    history, status, its = [r0], "max_iterations", 0
    t_assembly = t_linear = 0.0
    for its in range(1, max_iterations + 1):
        if np.linalg.norm(r) <= max(problem["atol"], problem["rtol"] * r0):
            status, its = "converged", its - 1
            break
        ta = time.perf_counter()
        K = tangent_form.assemble(basis_j, u=basis_j.interpolate(u), **consts["j"]) + cable.hessian(u)
        tb = time.perf_counter()
        du = solve(*condense(K, -r, D=fixed))
        t_assembly, t_linear = t_assembly + tb - ta, t_linear + time.perf_counter() - tb
        alpha = _step_length(energy, u, du, r, line_search)
        u = u + alpha * du
        r = residual(u)
        history.append(float(np.linalg.norm(r)))
    else:
        if np.linalg.norm(r) <= max(problem["atol"], problem["rtol"] * r0):
            status = "converged"
    t2 = time.perf_counter()
    row = {"code": "scikit-fem", "degree": degree, "line_search": line_search, "converged": status == "converged",
           "status": status,
           "dofs": int(basis_r.N), "newton_iterations": its, "time_setup": t1 - t0, "time_solve": t2 - t1,
           "time": t2 - t0, "final_residual": history[-1],
           "time_jacobian": t_assembly, "time_linear_solve": t_linear}
    if row["converged"]:
        tip = problem["marker"] + marker @ u
        row.update(tip_x=float(tip[0]), tip_y=float(tip[1]), tension=cable.tension(u))
    return row


# -- driver ---------------------------------------------------------------------------------------------------------
def run(sizes=(2.0, 1.0, 0.5), degree: int = 2, out: Path | None = None, progress=print) -> dict:
    """Both codes on each mesh; accuracy measured against the finest skelfem solution."""
    if not have_skfem():
        raise RuntimeError("scikit-fem is not installed: pip install scikit-fem")
    skelfem_solve(max(sizes), degree)                # warm-up: FFCx cache
    rows = []
    for h in sorted(sizes, reverse=True):
        ours, problem = skelfem_solve(h, degree)
        peer = skfem_solve(problem)
        peer["size"] = h
        for r in (ours, peer):
            rows.append(r)
        if ours["converged"] and peer["converged"]:
            ours["difference"] = peer["difference"] = float(np.hypot(ours["tip_x"] - peer["tip_x"],
                                                                     ours["tip_y"] - peer["tip_y"]))
        if progress:
            progress(f"h={h:<5g} P{degree} {ours['dofs']:7d} DOFs  skelfem {ours['time']:6.2f} s "
                     f"({ours['newton_iterations']} its)  scikit-fem {peer['time']:6.2f} s "
                     f"({peer['newton_iterations']} its)  tip difference {ours.get('difference', math.nan):.2e} mm")
    finest = min((r for r in rows if r["code"] == "skelfem" and r["converged"]), key=lambda r: r["size"])
    for r in rows:
        r["error"] = float(np.hypot(r["tip_x"] - finest["tip_x"], r["tip_y"] - finest["tip_y"])) \
            if r["converged"] and r["size"] != finest["size"] else float("nan")
    summary = {"degree": degree, "reference_size": finest["size"], "cases": []}
    for h in sorted(sizes, reverse=True):
        pair = {r["code"]: r for r in rows if r["size"] == h}
        a, b = pair["skelfem"], pair["scikit-fem"]
        summary["cases"].append({
            "size": h, "dofs": a["dofs"], "both_converged": a["converged"] and b["converged"],
            "tip_skelfem": [a.get("tip_x"), a.get("tip_y")], "tip_scikit_fem": [b.get("tip_x"), b.get("tip_y")],
            "tip_difference": a.get("difference"), "tension_skelfem": a.get("tension"),
            "tension_scikit_fem": b.get("tension"), "error_vs_finest": a["error"],
            "time_skelfem": a["time"], "time_scikit_fem": b["time"], "speedup": b["time"] / a["time"],
            "scikit_fem_jacobian_time": b.get("time_jacobian"),
            "scikit_fem_linear_solve_time": b.get("time_linear_solve"),
            "iterations": [a["newton_iterations"], b["newton_iterations"]]})
    result = {"rows": rows, "summary": summary}
    if out is not None:
        write_outputs(Path(out), result)
    return result


CSV_FIELDS = ("code", "size", "degree", "dofs", "converged", "status", "newton_iterations", "time_setup",
              "time_solve", "time", "time_jacobian", "time_linear_solve", "tip_x", "tip_y", "tension", "difference",
              "error", "final_residual")


def write_outputs(out: Path, result: dict) -> None:
    from skelfem.io.files import write_csv, write_json

    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "cases.csv", CSV_FIELDS, result["rows"])
    write_json(out / "summary.json", result["summary"])
    plot(out / "peer_comparison.png", result)


def plot(path: Path, result: dict) -> None:
    """Error (vs the finest mesh) against wall time for both codes; labels are mesh sizes."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skelfem.io.files import atomic_write

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 4.2), dpi=110)
    style = {"skelfem": dict(marker="o", color="#1f5fbf"), "scikit-fem": dict(marker="s", color="#d9822b")}
    for code, st in style.items():
        mine = sorted((r for r in result["rows"] if r["code"] == code and np.isfinite(r["error"])),
                      key=lambda r: r["time"])
        ax.loglog([r["time"] for r in mine], [r["error"] for r in mine], label=code, **st)
        for r in mine:
            ax.annotate(f"h={r['size']:g}", (r["time"], r["error"]), textcoords="offset points",
                        xytext=(4, 3), fontsize=7, color=st["color"])
        allr = sorted((r for r in result["rows"] if r["code"] == code), key=lambda r: r["dofs"])
        bx.loglog([r["dofs"] for r in allr], [r["time"] for r in allr], label=code, **st)
    ax.set_xlabel("wall time: set-up + Newton solve [s]")
    ax.set_ylabel(f"tip error vs finest mesh (h={result['summary']['reference_size']:g}) [mm]")
    ax.set_title("same mesh, same energy: equal accuracy per mesh", fontsize=9)
    bx.set_xlabel("DOFs")
    bx.set_ylabel("wall time [s]")
    diffs = [c["tip_difference"] for c in result["summary"]["cases"] if c["tip_difference"] is not None]
    bx.set_title(f"tendon strip, P{result['summary']['degree']}: tips differ by <= "
                 f"{max(diffs):.1e} mm" if diffs else "", fontsize=9)
    for a in (ax, bx):
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=OUT, help="output folder")
    ap.add_argument("--figures", type=Path, default=None, help="also copy peer_comparison.png here (README)")
    ap.add_argument("--sizes", type=float, nargs="+", default=[2.0, 1.0, 0.5], help="mesh sizes, mm")
    ap.add_argument("--degree", type=int, choices=(1, 2), default=2)
    a = ap.parse_args(argv)
    if not have_skfem():
        say("scikit-fem is not installed: pip install scikit-fem")
        return 1
    res = run(a.sizes, a.degree, a.out)
    for c in res["summary"]["cases"]:
        say(f"h={c['size']:<5g} {c['dofs']:7d} DOFs: "
            f"tip skelfem ({c['tip_skelfem'][0]:.6f}, {c['tip_skelfem'][1]:.6f}) "
              f"scikit-fem ({c['tip_scikit_fem'][0]:.6f}, {c['tip_scikit_fem'][1]:.6f}), difference "
              f"{c['tip_difference']:.1e} mm; time {c['time_skelfem']:.2f} s vs {c['time_scikit_fem']:.2f} s "
              f"(scikit-fem / skelfem = {c['speedup']:.1f}; "
              f"scikit-fem Jacobians {c['scikit_fem_jacobian_time']:.2f} s, "
              f"sparse LU {c['scikit_fem_linear_solve_time']:.2f} s)")
    copy_figure(a.out / "peer_comparison.png", a.figures)
    say(f"outputs in {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
