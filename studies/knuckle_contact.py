"""Knuckle cut-outs closing under flexion, with and without IPC self-contact (paper Fig. 4).

    python studies/knuckle_contact.py [--out studies/output/knuckle_contact] [--size 1.5] [--contraction 16]

geometry/finger_knuckles.toml has a wedge notch on the palmar side of each
joint. The flexor curls the finger and the notch faces swing together. With
[contact] self = true the IPC barrier and the collision-free step bound keep
them apart: the smallest distance between non-adjacent boundary parts is
recorded at every accepted Newton iterate and stays > 0. With self-contact
off the same contraction pushes the faces through each other; that is
measured on the final state by the number of crossing boundary-edge pairs
and the area the body covers twice (winding number >= 2).

run(**params) returns the numbers; main(argv) also writes
knuckle_contact.csv (distance per iterate), knuckles.png (both fingers and a
zoom on the first knuckle, side by side) and knuckle_distance.png.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from skelfem.io.files import say

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "finger_knuckles.toml"


def solve(self_contact: bool, size: float, contraction: float) -> dict:
    """Solve the knuckle finger; min boundary distance at every accepted iterate, overlap at the end."""
    from skelfem import Session
    from skelfem.terms.contact import SelfContact, crossing_edges, oriented_edges, overlap_area

    t0 = time.perf_counter()
    session = Session(DESIGN, [f"mesh.size={size}", f"cables.flexor.contraction={contraction}",
                               f"contact.self={'true' if self_contact else 'false'}"])
    model, design = session.model, session.design
    contact = model.terms_in("contact")
    probe = contact[0] if contact else SelfContact(model.V, design.contact.dhat, 1.0, model.thickness)
    history = []                 # (load factor, min distance) at each iterate SNES accepted

    def monitor(snes, it, fnorm):
        history.append((model.factor, probe.min_distance(snes.getSolution().array_r)))
    session.solver.snes.setMonitor(monitor)
    report = session.solve().report
    u = model.u.x.array
    y = probe.positions(u)
    ccw = oriented_edges(probe.X, probe.edges)
    return {"self_contact": self_contact, "converged": report.converged, "status": report.status,
            "newton_iterations": report.newton_iterations, "history": history,
            "min_distance": min(d for _, d in history) if history else float("nan"),
            "final_distance": probe.min_distance(u), "crossing_edges": crossing_edges(y, probe.edges),
            "intersects": probe.intersects(u),
            "overlap_area": overlap_area(y, ccw, np.array([y.min(axis=0), y.max(axis=0)]), 400),
            "tip": model.term("markers").positions(u)[0].tolist(), "session": session, "probe": probe,
            "time": time.perf_counter() - t0}


def run(size: float = 1.5, contraction: float = 16.0, out: Path | None = None) -> dict:
    """Both conditions; writes CSV/PNG into out if given. Keys "on" and "off"."""
    res = {"on": solve(True, size, contraction), "off": solve(False, size, contraction)}
    if out is not None:
        write_outputs(Path(out), res, contraction)
    for r in res.values():
        r.pop("session").close(), r.pop("probe")
    return res


def _notch_box(r, pad=3.0) -> np.ndarray:
    """Box around the deformed first (proximal) knuckle notch."""
    probe = r["probe"]
    X = probe.X
    near = (X[:, 0] < 3.01) & (X[:, 1] > 36.0) & (X[:, 1] < 46.0)
    y = probe.positions(r["session"].model.u.x.array)[near]
    c = 0.5 * (y.min(axis=0) + y.max(axis=0))
    half = 0.5 * (y.max(axis=0) - y.min(axis=0)).max() + pad
    return np.array([c - half, c + half])


def write_outputs(out: Path, res: dict, contraction: float) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skelfem.io.files import atomic_write
    from skelfem.viz.plots import plot_deformed

    out.mkdir(parents=True, exist_ok=True)
    lines = ["self_contact,iterate,load_factor,min_distance_mm"]
    for key in ("on", "off"):
        for i, (a, d) in enumerate(res[key]["history"]):
            lines.append(f"{key},{i},{a:.6g},{d:.6g}")
    atomic_write(out / "knuckle_contact.csv", lambda tmp: Path(tmp).write_text("\n".join(lines) + "\n"))

    fig, axes = plt.subplots(2, 2, figsize=(10, 10), dpi=110, gridspec_kw={"height_ratios": [1.3, 1]})
    for col, key in enumerate(("off", "on")):
        r = res[key]
        label = ("self-contact ON: min distance %.3g mm, no crossing" % r["final_distance"] if key == "on" else
                 "self-contact OFF: %d crossing edge pairs, %.2f mm$^2$ overlap"
                 % (r["crossing_edges"], r["overlap_area"]))
        plot_deformed(None, r["session"].model, f"flexor u = {contraction:g} mm\n{label}", ax=axes[0, col])
        if axes[0, col].get_legend():
            axes[0, col].get_legend().remove()
        zoom = axes[1, col]
        plot_deformed(None, r["session"].model, "", ax=zoom, show_rest=False)
        y = r["probe"].positions(r["session"].model.u.x.array)
        for a, b in r["probe"].edges:
            zoom.plot(y[[a, b], 0], y[[a, b], 1], color="k", lw=1.0)
        box = _notch_box(r)
        zoom.set_xlim(box[0, 0], box[1, 0])
        zoom.set_ylim(box[0, 1], box[1, 1])
        zoom.set_title("proximal knuckle (boundary in black)", fontsize=9)
        if zoom.get_legend():
            zoom.get_legend().remove()
    fig.tight_layout()
    atomic_write(out / "knuckles.png", lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6.4, 3.8), dpi=110)
    for key, style in (("on", "o-"), ("off", "s--")):
        d = np.array([h[1] for h in res[key]["history"]])
        ax.semilogy(np.arange(len(d)), np.maximum(d, 1e-12), style, ms=3, label=f"self-contact {key}")
    ax.axhline(res["on"]["probe"].dhat, color="0.5", lw=0.8, ls=":", label="dhat")
    ax.set_xlabel("accepted Newton iterate (all load steps)")
    ax.set_ylabel("min boundary distance [mm]")
    ax.set_title("Knuckle faces: smallest distance between boundary parts", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_write(out / "knuckle_distance.png", lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "knuckle_contact")
    p.add_argument("--size", type=float, default=1.5, help="mesh size, mm")
    p.add_argument("--contraction", type=float, default=16.0, help="flexor contraction, mm")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    res = run(a.size, a.contraction, a.out)
    for key in ("on", "off"):
        r = res[key]
        say(f"self-contact {key:3s}: {r['status']}, {r['newton_iterations']} Newton its, "
              f"min distance over iterates {r['min_distance']:.3g} mm, final {r['final_distance']:.3g} mm, "
              f"{r['crossing_edges']} crossing edge pairs, overlap {r['overlap_area']:.3f} mm^2 ({r['time']:.1f} s)")
    say(f"wrote {a.out}/knuckle_contact.csv, knuckles.png, knuckle_distance.png in {time.perf_counter() - t0:.1f} s")
    return 0 if all(r["converged"] for r in res.values()) else 2


if __name__ == "__main__":
    raise SystemExit(main())
