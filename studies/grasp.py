"""The gripper holds a box by friction: close with gravity off, then weigh; held above mu_min, lost below.

    python studies/grasp.py [--mu 0.3 0.6 0.9] [--density 620 1240 1860] [--contraction 4]
                            [--size 2] [--out studies/output/grasp] [--figures studies/figures]

geometry/gripper.toml: a palm with two skeleton fingers hanging down, a
flexor tendon on the inner side of each, a PLA box between the fingertips.
For each friction coefficient mu (``contact.friction``, body-box) one
Session closes the hand (both flexors contracted, gravity off: the pads
squeeze the box, nothing loads it), then switches gravity on and makes the
box heavier step by step (``materials.box_pla.density``, ascending; each a
warm re-solve from the last equilibrium, its friction history kept). The
analytic limit of a two-pad pinch is mu_min = W / (sum of the normal forces),
the sum read from the closed grip (``contacts[0].normal_magnitude``): the box
should be held when mu > mu_min and lost when mu < mu_min. Once a box is
lost, the heavier ones are not tried (recorded as ``skipped``).

run(**params) returns the numbers; main(argv) also writes grasp.json into
out, grasp.png (the heaviest box held at the largest mu, with its contact
forces) and grasp_margin.png (held and lost against mu / mu_min) into figures.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "gripper.toml"
G = [0.0, -9.81]
FLEXORS = ("cables.left_flexor.contraction", "cables.right_flexor.contraction")


def _contact(d: dict) -> dict:
    pairs = [c for c in d.get("contacts", []) if c["between"] == ["body", "box"]]
    return pairs[0] if pairs else {}


def grasp(mu: float, densities, contraction: float = 4.0, size: float | None = None,
          picture: Path | None = None) -> dict:
    """One mu: close, then weigh each density in turn. picture: draw the heaviest box held there."""
    from skelfem import Session
    overrides = [f"contact.friction={mu}"] + ([f"mesh.size={size}"] if size else [])
    out = {"mu": mu, "contraction": contraction, "weighings": []}
    with Session(DESIGN, overrides) as s:
        out["dofs"] = s.dofs
        s.set({k: contraction for k in FLEXORS})
        t0 = time.perf_counter()
        r = s.solve()
        d = r.to_dict()
        c = _contact(d)
        out["close"] = {"converged": r.converged, "status": r.status, "newton_iterations": r.report.newton_iterations,
                        "time": time.perf_counter() - t0, "normal_magnitude": c.get("normal_magnitude", 0.0),
                        "box_position": d.get("objects", {}).get("box", {}).get("position")}
        if not r.converged:
            return out
        N0 = out["close"]["normal_magnitude"]
        lost = False
        for rho in densities:
            entry = {"density": float(rho)}
            if lost:
                entry["status"] = "skipped"
                out["weighings"].append(entry)
                continue
            s.set({"gravity.acceleration": G, "materials.box_pla.density": float(rho)})
            t0 = time.perf_counter()
            r = s.solve()
            d = r.to_dict()
            box = d.get("objects", {}).get("box", {})
            c = _contact(d)
            W = float(np.linalg.norm(s.model.term("objects", "box").weight()))        # N
            if not (r.converged or r.status.startswith("no equilibrium")):
                entry.update(status=r.status, newton_iterations=r.report.newton_iterations)
                out["weighings"].append(entry)       # neither held nor lost: the solver failed
                lost = True
                continue
            entry.update(status=r.status, held=bool(r.converged), weight=W, mu_min=W / N0 if N0 > 0 else np.inf,
                         newton_iterations=r.report.newton_iterations, time=time.perf_counter() - t0,
                         normal_magnitude=c.get("normal_magnitude"), friction_force=c.get("friction_force"),
                         sticking=c.get("sticking"), box_displacement=box.get("displacement"))
            entry["margin"] = mu / entry["mu_min"]
            out["weighings"].append(entry)
            if r.converged and picture is not None:
                _draw(picture, s, f"mu = {mu:g}, box {W:.3g} N held (mu_min = {entry['mu_min']:.2f}); "
                               f"flexors {contraction:g} mm")
            lost = not r.converged
    return out


def _draw(path: Path, session, title: str) -> None:
    from matplotlib.figure import Figure

    from skelfem.io.files import atomic_write
    from skelfem.viz.plots import plot_deformed
    fig = Figure(figsize=(6.4, 7.2), dpi=120)
    ax = fig.subplots()
    plot_deformed(None, session.model, title, ax=ax)
    handles, labels = ax.get_legend_handles_labels()
    keep = [(h, lab) for h, lab in zip(handles, labels) if "flexor" in lab or "force" in lab]
    ax.legend([h for h, _ in keep], [lab for _, lab in keep], loc="upper center", bbox_to_anchor=(0.5, -0.09),
              ncol=2, fontsize=7, frameon=False)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


def plot_margin(path: Path, results: list) -> None:
    """Every weighing in the (mu_min, mu) plane: held (filled) above mu = mu_min, lost (cross) below."""
    from matplotlib.figure import Figure

    from skelfem.io.files import atomic_write
    fig = Figure(figsize=(5.6, 4.6), dpi=120)
    ax = fig.subplots()
    top = 0.0
    for res in results:
        for w in res["weighings"]:
            if "held" not in w:
                continue
            top = max(top, w["mu_min"], res["mu"])
            ax.plot(w["mu_min"], res["mu"], "o" if w["held"] else "x", ms=8, mfc="#1e8449" if w["held"] else "none",
                    mec="#1e8449" if w["held"] else "#c0392b", color="#c0392b")
    top *= 1.15
    ax.plot([0, top], [0, top], "k--", lw=1, label="mu = mu_min = W / sum N (analytic)")
    ax.fill_between([0, top], [0, top], [top, top], color="#1e8449", alpha=0.08, label="held predicted")
    ax.plot([], [], "o", color="#1e8449", label="simulated: held")
    ax.plot([], [], "x", color="#c0392b", label="simulated: not held")
    ax.set_xlim(0, top)
    ax.set_ylim(0, top)
    ax.set_xlabel("mu_min = W / (sum of normal forces of the closed grip)")
    ax.set_ylabel("friction coefficient mu")
    ax.set_title("gripper: holding margin", fontsize=10)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


def run(mus=(0.3, 0.6, 0.9), densities=(620.0, 1240.0, 1860.0), contraction: float = 4.0,
        size: float | None = None, out: Path | None = None, figures: Path | None = None) -> dict:
    """The sweep; writes grasp.json into out and the two figures into figures if given."""
    from skelfem.io.files import atomic_write
    mus, densities = sorted(float(m) for m in mus), sorted(float(r) for r in densities)
    results = []
    for mu in mus:
        pic = Path(figures) / "grasp.png" if figures is not None and mu == mus[-1] else None
        results.append(grasp(mu, densities, contraction, size, pic))
    agree = [w["held"] == (res["mu"] > w["mu_min"]) for res in results for w in res["weighings"] if "held" in w]
    summary = {"design": str(DESIGN.relative_to(ROOT)), "results": results,
               "agree_with_mu_min": int(sum(agree)), "weighings": len(agree)}
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write(out / "grasp.json", lambda tmp: Path(tmp).write_text(json.dumps(summary, indent=1) + "\n"))
    if figures is not None:
        plot_margin(Path(figures) / "grasp_margin.png", results)
    return summary


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--mu", type=float, nargs="+", default=[0.3, 0.6, 0.9])
    p.add_argument("--density", type=float, nargs="+", default=[620.0, 1240.0, 1860.0])
    p.add_argument("--contraction", type=float, default=4.0)
    p.add_argument("--size", type=float, default=None)
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "grasp")
    p.add_argument("--figures", type=Path, default=ROOT / "studies" / "figures")
    a = p.parse_args(argv)
    s = run(a.mu, a.density, a.contraction, a.size, a.out, a.figures)
    for res in s["results"]:
        c = res["close"]
        print(f"mu {res['mu']:.2f}: closed in {c['newton_iterations']} Newton iterations, {c['time']:.1f} s, "
              f"sum N = {c['normal_magnitude']:.4f} N")
        for w in res["weighings"]:
            if "held" in w:
                print(f"  density {w['density']:g}: W = {w['weight']:.4f} N, mu_min = {w['mu_min']:.3f}, "
                      f"{'held' if w['held'] else 'lost'} ({w['newton_iterations']} its, {w['time']:.1f} s)")
            else:
                print(f"  density {w['density']:g}: skipped (a lighter box was lost)")
    print(f"{s['agree_with_mu_min']} of {s['weighings']} weighings agree with mu_min")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
