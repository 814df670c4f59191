"""The 3D knuckle finger closing, with and without IPC self-contact on the boundary's triangles.

    python studies/knuckle_contact3d.py [--out studies/output/knuckle_contact3d] [--figures studies/figures]
                                        [--size 3] [--contraction 16] [--full-size 3]

geometry/finger_knuckles3d.toml is the 2D knuckle finger (finger_knuckles.toml)
extruded through its 20 mm depth: a wedge notch on the palmar side of each
joint, through the whole depth. The flexor curls the finger and the notch
faces swing together. Runs of one design:

- ``on``: [contact] self = true as bundled: the smallest distance between
  non-adjacent boundary parts (ipctk) at every accepted Newton iterate, and
  per load step its iterations and the distance where it ends (the step in
  which the knuckles meet is the first that ends within dhat);
- ``projected``: the same with the barrier's Hessian projected at every
  iteration (``settle`` off), to measure what the exact Hessian of settled
  contacts saves;
- ``full`` (on the mesh of size ``full_size``, with its own ``on`` run
  ``grown`` beside it): the matrix pattern holding the whole boundary x
  boundary block from the start instead of the pairs within reach, grown
  when contacts need more;
- ``off``: self-contact off: the same pull passes the notch faces through
  each other (ipctk finds intersecting triangles).

Interpenetration is also measured on the mid-depth section (z = 10): the
boundary triangles cut by that plane give the finger's outline there, on
which the 2D measures apply (crossing edges, area covered twice).

run(**params) returns the numbers; main(argv) also writes knuckle_contact3d.json
into out, and knuckles3d.png (the closed finger, rendered) and
knuckles3d_section.png (the mid-depth outlines with and without contact,
and a zoom on the proximal knuckle) into figures.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "finger_knuckles3d.toml"
MID = 10.0          # mm: the mid-depth plane (the finger is extruded over z = 0..20)


def section(X: np.ndarray, y: np.ndarray, facets: np.ndarray, z0: float = MID):
    """The boundary triangles cut by the plane z = z0 at rest: (rest points (k, 2), deformed points (k, 2),
    segments (m, 2)), one point per cut mesh edge (where the plane cuts it at rest, followed to y)."""
    s = X[:, 2] - z0
    if np.any(np.abs(s) < 1e-9):                     # no node on the plane: every cut is a proper crossing
        return section(X, y, facets, z0 + 1e-6)
    edges = np.stack([facets[:, [0, 1]], facets[:, [1, 2]], facets[:, [2, 0]]], axis=1)   # (m, 3, 2)
    cut = (s[edges[..., 0]] * s[edges[..., 1]]) < 0
    tri = cut.sum(axis=1) == 2
    keys = np.sort(edges[tri][cut[tri]].reshape(-1, 2), axis=1)                         # two per triangle
    unique, index = np.unique(keys, axis=0, return_inverse=True)
    a, b = unique[:, 0], unique[:, 1]
    t = (s[a] / (s[a] - s[b]))[:, None]
    rest = (X[a] + t * (X[b] - X[a]))[:, :2]
    moved = (y[a] + t * (y[b] - y[a]))[:, :2]
    return rest, moved, index.reshape(-1, 2).astype(np.int64)


def solve(variant: str, size: float, contraction: float, keep: bool = False) -> dict:
    """One run: "on", "projected", "full" (self-contact on) or "off"."""
    from skelfem import Session
    from skelfem.terms.contact import SelfContact, crossing_edges, oriented_edges, overlap_area

    t0 = time.perf_counter()
    session = Session(DESIGN, [f"mesh.size={size}", f"cables.flexor.contraction={contraction}",
                               f"contact.self={'false' if variant == 'off' else 'true'}"])
    model, design = session.model, session.design
    contact = model.terms_in("contact")
    probe = contact[0] if contact else SelfContact(model.V, design.contact.dhat, 1.0)
    if variant == "projected":
        probe.settle = False
    if variant == "full":
        probe.widen(math.inf)
    history: list = []           # (load factor, min distance) at each iterate SNES accepted

    def monitor(snes, it, fnorm):
        history.append((model.factor, probe.min_distance(snes.getSolution().array_r)))
    session.solver.snes.setMonitor(monitor)
    t1, c1 = time.perf_counter(), time.process_time()
    r = session.solve()
    solve_time, solve_cpu = time.perf_counter() - t1, time.process_time() - c1
    report = r.report
    u = model.u.x.array
    rest, moved, segments = section(probe.X, probe.positions(u), probe.facets)
    box = np.array([moved.min(axis=0), moved.max(axis=0)])
    steps = [{"factor": a["factor"], "iterations": a["iterations"], "status": a["status"]}
             for a in r.to_dict()["attempts"]]
    ends = [d for k, (_, d) in enumerate(history) if k + 1 == len(history) or history[k + 1][0] != history[k][0]]
    for step, d in zip(steps, ends):
        step["min_distance"] = d
    meet = next((k + 1 for k, st in enumerate(steps) if st.get("min_distance", math.inf) < design.contact.dhat), None)
    out = {"variant": variant, "size": size, "contraction": contraction, "dofs": session.dofs,
           "boundary_nodes": len(probe.nodes), "converged": report.converged, "status": report.status,
           "newton_iterations": report.newton_iterations, "steps": steps, "meet_step": meet,
           "pattern_pairs": int(len(probe.pairs())) if contact else 0, "history": history,
           "min_distance": min(d for _, d in history) if history else float("nan"),
           "final_distance": probe.min_distance(u), "intersects": probe.intersects(u),
           "section_crossing_edges": crossing_edges(moved, segments),
           "section_overlap_area": overlap_area(moved, oriented_edges(rest, segments), box, 400),
           "dhat": design.contact.dhat, "solve_time": solve_time, "solve_cpu": solve_cpu,
           "time": time.perf_counter() - t0,
           "tip": model.term("markers").positions(u)[0].tolist(),
           "contact": r.to_dict().get("contact", {}).get("self", {})}
    if keep:
        out["session"], out["section"] = session, (moved, segments)
    else:
        session.close()
    return out


def run(size: float = 3.0, contraction: float = 16.0, full_size: float | None = 3.0,
        out: Path | None = None, figures: Path | None = None) -> dict:
    """Every variant; writes knuckle_contact3d.json into out and the pictures into figures if given."""
    drawing = figures is not None
    res = {"on": solve("on", size, contraction, keep=drawing), "off": solve("off", size, contraction, keep=drawing),
           "projected": solve("projected", size, contraction)}
    if full_size is not None:
        res["grown"] = solve("on", full_size, contraction)
        res["full"] = solve("full", full_size, contraction)
    if drawing:
        write_figures(Path(figures), res)
    kept = {k: {key: v for key, v in r.items() if key not in ("session", "section")} for k, r in res.items()}
    for r in res.values():
        if "session" in r:
            r.pop("session").close()
            r.pop("section")
    if out is not None:
        from skelfem.io.files import atomic_write
        Path(out).mkdir(parents=True, exist_ok=True)
        atomic_write(Path(out) / "knuckle_contact3d.json",
                     lambda tmp: Path(tmp).write_text(json.dumps(kept, indent=1) + "\n"))
    return kept


def write_figures(figures: Path, res: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skelfem.io.files import atomic_write
    from skelfem.viz.plots import plot_deformed_3d

    figures.mkdir(parents=True, exist_ok=True)
    on = res["on"]
    plot_deformed_3d(figures / "knuckles3d.png", on["session"].model,
                     f"finger_knuckles3d, flexor {on['contraction']:g} mm, self-contact on: "
                     f"min distance {on['final_distance']:.3g} mm", window_size=(900, 900))
    fig, axes = plt.subplots(2, 2, figsize=(10, 10), dpi=110, gridspec_kw={"height_ratios": [1.3, 1]})
    for col, key in enumerate(("off", "on")):
        r = res[key]
        moved, segments = r["section"]
        label = (f"self-contact ON: min distance {r['final_distance']:.3g} mm, no intersection" if key == "on" else
                 f"self-contact OFF: triangles intersect: {r['intersects']}\nmid-depth: "
                 f"{r['section_crossing_edges']} crossing edge pairs, {r['section_overlap_area']:.2f} mm$^2$ overlap")
        for row in (0, 1):
            ax = axes[row, col]
            for a, b in segments:
                ax.plot(moved[[a, b], 0], moved[[a, b], 1], color="#1f77b4" if key == "on" else "#d62728", lw=0.9)
            ax.set_aspect("equal")
            ax.grid(alpha=0.3)
        axes[0, col].set_title(f"mid-depth section (z = {MID:g} mm), flexor {r['contraction']:g} mm\n{label}",
                               fontsize=9)
        near = np.linalg.norm(moved - _knuckle(res["on"]), axis=1) < 6.0
        c = 0.5 * (moved[near].min(axis=0) + moved[near].max(axis=0))
        axes[1, col].set_xlim(c[0] - 5, c[0] + 5)
        axes[1, col].set_ylim(c[1] - 5, c[1] + 5)
        axes[1, col].set_title("proximal knuckle", fontsize=9)
    fig.tight_layout()
    atomic_write(figures / "knuckles3d_section.png", lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


def _knuckle(r: dict) -> np.ndarray:
    """Where the proximal notch's mouth (rest (0, 41), mid-depth) is at the end of run r."""
    model = r["session"].model
    moved, _ = r["section"]
    from skelfem.terms.contact import SelfContact
    probe = model.terms_in("contact")[0] if model.terms_in("contact") else SelfContact(model.V, 0.3, 1.0)
    rest, _, _ = section(probe.X, probe.X, probe.facets)
    k = int(np.argmin(np.linalg.norm(rest - [0.0, 41.0], axis=1)))
    return moved[k]


def main(argv=None) -> int:
    from skelfem.io.files import say
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "knuckle_contact3d")
    p.add_argument("--figures", type=Path, default=ROOT / "studies" / "figures")
    p.add_argument("--size", type=float, default=3.0, help="mesh size, mm")
    p.add_argument("--contraction", type=float, default=16.0, help="flexor contraction, mm")
    p.add_argument("--full-size", type=float, default=3.0,
                   help="mesh size of the whole-block pattern run and its growing-pattern twin, mm")
    a = p.parse_args(argv)
    res = run(a.size, a.contraction, a.full_size, a.out, a.figures)
    for key, r in res.items():
        say(f"{key:9s} size {r['size']:g} mm, {r['dofs']} DOFs: {r['status']}, {r['newton_iterations']} Newton its "
            f"(per step {[s['iterations'] for s in r['steps']]}), meet in step {r['meet_step']}, "
            f"min distance over iterates {r['min_distance']:.3g} mm, final {r['final_distance']:.3g} mm, "
            f"intersects {r['intersects']}, pattern {r['pattern_pairs']} node pairs, solve {r['solve_time']:.1f} s "
            f"({r['solve_cpu']:.1f} s CPU)")
    say(f"wrote {a.out}/knuckle_contact3d.json, {a.figures}/knuckles3d.png, knuckles3d_section.png")
    return 0 if all(r["converged"] for r in res.values()) else 2


if __name__ == "__main__":
    raise SystemExit(main())
