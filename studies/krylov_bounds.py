"""Krylov iterations per Newton step of the iterative solver: over mesh refinement, stiffness
contrast and Poisson's ratio.

    python studies/krylov_bounds.py [--design geometry/arm3d.toml] [--sizes 6 3 1.5]
                                    [--contrast-size 6] [--contrast-degree 2]
                                    [--contrasts 1 10 100 1000 10000 30000]
                                    [--nus 0.3 0.4 0.45 0.49] [--out studies/output/krylov_bounds]
                                    [--figures studies/figures]

Every case is one solve from rest with ``[solver] linear = "iterative"``
(CG, GAMG with the rigid-body near-nullspace, stiff elastic bones balanced
against their own rigid motions), in this process:

* refinement: the design as bundled at P1, mesh sizes ``sizes`` (two halvings), its bones
  elastic (as bundled) and rigid;
* contrast: P2 (``contrast_degree``) at ``contrast_size``, every bone material's E set to
  ``contrast`` times the body's (1: a homogeneous body), and rigid bones;
* Poisson's ratio: P2 at ``contrast_size``, the body's nu in ``nus``.

Read from each result: DOFs, Newton iterations, the Krylov iterations of
each Newton step (their mean and maximum), fallbacks to MUMPS, steps taken
from a stalled Krylov solve (loose_steps) and the solve's wall time. An
inexact Newton step is solved only as far as its forcing term asks, and its
multigrid may be an earlier step's (lagged), so a step's iterations depend
on where it is on the path and on the steps before it. Each case therefore
also solves its last Newton step's tangent once more, with a multigrid made
afresh, to FRESH_RTOL from a seeded random right-hand side
(``krylov_fresh``): the multigrid's own quality at a fixed tolerance.
``ratios`` of a sweep is its largest mean over its smallest,
``fresh_ratios`` the same of ``krylov_fresh``. run(**params) returns the
rows; main(argv) also writes krylov_bounds.json into out and
krylov_bounds.png into figures.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "arm3d.toml"
FRESH_RTOL = 1e-8       # the fixed-tolerance solve of the converged tangent (LowRankSolver.fresh_iterations)


def _bones(design: Path) -> list[tuple[str, str]]:
    from skelfem.design import load_design
    d = load_design(design)
    return [(b.name, b.material) for b in d.bones], d.bodies[0].material, d


def case(design: Path, overrides: list[str]) -> dict:
    """One solve from rest: its numbers."""
    from skelfem import Session
    with Session(design, overrides=["solver.linear=iterative"] + overrides) as s:
        t0 = time.perf_counter()
        r = s.solve()
        wall = time.perf_counter() - t0
        d = r.to_dict()
        fresh = s.solver.lin.fresh_iterations(FRESH_RTOL) if r.converged else None
    its = [k for step in d.get("linear_iterations", []) for k in step]
    return {"overrides": overrides, "dofs": d["dofs"], "status": d["status"],
            "newton_iterations": d["newton_iterations"], "krylov_per_newton": its,
            "krylov_mean": sum(its) / max(len(its), 1), "krylov_max": max(its, default=0),
            "fallbacks": d.get("linear_fallbacks", 0), "loose_steps": d.get("linear_loose_steps", 0),
            "solve_s": wall, "krylov_fresh": fresh}


def _ratio(rows: list[dict], key: str = "krylov_mean") -> float:
    means = [r[key] for r in rows if r["status"] == "converged" and r.get(key) is not None]
    return max(means) / min(means) if means and min(means) > 0 else float("inf")


def run(design: Path = DESIGN, sizes=(6.0, 3.0, 1.5), contrast_size: float = 6.0,
        contrasts=(1, 10, 100, 1000, 10000, 30000), nus=(0.3, 0.4, 0.45, 0.49), progress=print,
        contrast_degree: int = 2) -> dict:
    bones, body, d = _bones(Path(design))
    rigid = [f"bones.{name}.rigid=true" for name, _ in bones]
    E_body = float(d.materials[body].E)
    sweeps: dict = {"refinement": [], "refinement_rigid": [], "contrast": [], "nu": []}

    def add(sweep: str, overrides: list[str], **tags) -> None:
        row = {**tags, **case(Path(design), overrides)}
        sweeps[sweep].append(row)
        progress(f"{sweep} {tags}: {row['dofs']} DOFs, {row['newton_iterations']} Newton, Krylov mean "
                 f"{row['krylov_mean']:.1f} max {row['krylov_max']}, {row['solve_s']:.1f} s, {row['status']}")

    for h in sizes:
        add("refinement", [f"mesh.size={h}", "mesh.degree=1"], size=h)
        add("refinement_rigid", [f"mesh.size={h}", "mesh.degree=1"] + rigid, size=h)
    p2 = [f"mesh.size={contrast_size}", f"mesh.degree={contrast_degree}"]
    for c in contrasts:
        add("contrast", p2 + [f"materials.{m}.E={c * E_body}" for m in sorted({m for _, m in bones})],
            contrast=c)
    add("contrast", p2 + rigid, contrast="rigid")
    for nu in nus:
        add("nu", p2 + [f"materials.{body}.nu={nu}"], nu=nu)
    return {"design": Path(design).name, "sweeps": sweeps, "contrast_degree": contrast_degree,
            "ratios": {name: _ratio(rows) for name, rows in sweeps.items() if rows},
            "fresh_ratios": {name: _ratio(rows, "krylov_fresh") for name, rows in sweeps.items() if rows},
            "fresh_rtol": FRESH_RTOL}


def figure(data: dict, path: Path) -> None:
    import matplotlib.pyplot as plt
    s = data["sweeps"]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    a = axes[0]
    for k, (name, label) in enumerate((("refinement", "elastic bones"), ("refinement_rigid", "rigid bones"))):
        rows = s[name]
        a.semilogx([r["dofs"] for r in rows], [r["krylov_mean"] for r in rows], "o-", color=f"C{k}",
                   label=f"{label}: mean per Newton step")
        fresh = [(r["dofs"], r["krylov_fresh"]) for r in rows if r.get("krylov_fresh") is not None]
        if fresh:
            a.semilogx(*zip(*fresh), "s:", color=f"C{k}",
                       label=f"{label}: tangent to {data.get('fresh_rtol', 1e-8):g}, fresh multigrid")
    a.xaxis.set_minor_formatter(plt.NullFormatter())
    a.set_xlabel("DOFs (P1)")
    a.set_title("refinement")
    a.legend(fontsize=7)
    a = axes[1]
    rows = [r for r in s["contrast"] if r["contrast"] != "rigid"]
    a.semilogx([r["contrast"] for r in rows], [r["krylov_mean"] for r in rows], "o-", label="elastic bones")
    rigid = [r for r in s["contrast"] if r["contrast"] == "rigid"]
    if rigid:
        a.axhline(rigid[0]["krylov_mean"], ls="--", color="C1", label="rigid bones")
    a.set_xlabel(f"E_bone / E_body (P{data.get('contrast_degree', 2)})")
    a.set_title("stiffness contrast")
    a.legend()
    a = axes[2]
    a.plot([r["nu"] for r in s["nu"]], [r["krylov_mean"] for r in s["nu"]], "o-")
    a.set_xlabel(f"Poisson's ratio of the body (P{data.get('contrast_degree', 2)})")
    a.set_title("Poisson's ratio")
    for ax in axes:
        ax.set_ylabel("Krylov iterations per Newton step (mean)")
        ax.set_ylim(bottom=0)
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"{data['design']}: CG + multigrid (GAMG; at P2 under a P2 smoothing level) iterations")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--design", type=Path, default=DESIGN)
    p.add_argument("--sizes", type=float, nargs="+", default=[6.0, 3.0, 1.5])
    p.add_argument("--contrast-size", type=float, default=6.0)
    p.add_argument("--contrasts", type=float, nargs="+", default=[1, 10, 100, 1000, 10000, 30000])
    p.add_argument("--contrast-degree", type=int, choices=(1, 2), default=2)
    p.add_argument("--nus", type=float, nargs="*", default=[0.3, 0.4, 0.45, 0.49])
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "krylov_bounds")
    p.add_argument("--figures", type=Path, default=ROOT / "studies" / "figures")
    a = p.parse_args(argv)
    data = run(a.design, a.sizes, a.contrast_size, a.contrasts, a.nus, contrast_degree=a.contrast_degree)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "krylov_bounds.json").write_text(json.dumps(data, indent=1))
    figure(data, a.figures / "krylov_bounds.png")
    return data


if __name__ == "__main__":
    main()
