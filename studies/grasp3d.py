"""A 3D gripper holds a sphere by friction: close with gravity off, then weigh it near its friction limit.

    python studies/grasp3d.py [--mu 0.8] [--ratio 0.5 0.9 1.1] [--contraction 3] [--size 2.5]
                              [--out studies/output/grasp3d] [--figures studies/figures]

geometry/gripper3d.toml: a palm with two skeleton fingers (12 x 12 mm, three
PLA bones each, a flexor on the inner side, ligaments across the joints) and a
PLA sphere (radius 11 mm) 5 mm from each fingertip. One Session closes the
hand (both flexors contracted, gravity off: the fingertips squeeze the
sphere), reads the sum of the normal forces on the sphere (``contacts``'
``normal_magnitude``, sum N), then switches gravity on and gives the sphere
the density whose weight is ``ratio`` times the friction limit mu sum N, for
each ratio in ascending order (warm re-solves, the friction history kept).
Analytically a two-pad pinch holds iff W <= mu sum N, that is iff ratio <= 1
(mu_min = W / sum N, margin mu / mu_min = 1 / ratio); once the sphere is
lost the heavier ones are skipped.

run(**params) returns the numbers; main(argv) also writes grasp3d.json into
out and grasp3d.png (the heaviest sphere held) into figures.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "gripper3d.toml"
G = [0.0, -9.81, 0.0]
FLEXORS = ("cables.left_flexor.contraction", "cables.right_flexor.contraction")
DENSITY = "materials.ball_pla.density"


def _contact(d: dict) -> dict:
    pairs = [c for c in d.get("contacts", []) if c["between"] == ["body", "ball"]]
    return pairs[0] if pairs else {}


def grasp(mu: float, ratios, contraction: float = 3.0, size: float | None = None,
          picture: Path | None = None) -> dict:
    """Close at mu, then weigh the sphere at each ratio of its friction limit (ascending)."""
    from skelfem import Session
    overrides = [f"contact.friction={mu}"] + ([f"mesh.size={size}"] if size else [])
    out = {"mu": mu, "contraction": contraction, "weighings": []}
    with Session(DESIGN, overrides) as s:
        out["dofs"] = s.dofs
        t0, its = time.perf_counter(), 0
        for c in np.linspace(0.0, contraction, 4)[1:]:          # closed in three steps
            s.set({k: float(c) for k in FLEXORS})
            r = s.solve()
            its += r.report.newton_iterations
            if not r.converged:
                break
        d = r.to_dict()
        c = _contact(d)
        out["close"] = {"converged": r.converged, "status": r.status, "newton_iterations": its,
                        "time": time.perf_counter() - t0, "normal_magnitude": c.get("normal_magnitude", 0.0),
                        "min_distance": c.get("min_distance"),
                        "ball_position": d.get("objects", {}).get("ball", {}).get("position")}
        print(f"mu {mu:g}: closed ({r.status}, {its} Newton iterations, "
              f"{out['close']['time']:.1f} s), sum N = {out['close']['normal_magnitude']:.4f} N", flush=True)
        N0 = out["close"]["normal_magnitude"]
        if not r.converged or not N0 > 0:
            return out
        ball = s.model.term("objects", "ball")
        rho0 = float(s.model.parameters()[DENSITY])
        s.set({"gravity.acceleration": G})
        w_per_rho = float(np.linalg.norm(ball.weight())) / rho0          # N per kg/m^3
        lost = False
        for ratio in ratios:
            entry = {"ratio": float(ratio)}
            if lost:
                out["weighings"].append({**entry, "status": "skipped"})
                continue
            rho = ratio * mu * N0 / w_per_rho
            s.set({"gravity.acceleration": G, DENSITY: rho})
            t0 = time.perf_counter()
            r = s.solve()
            d = r.to_dict()
            c = _contact(d)
            W = float(np.linalg.norm(ball.weight()))
            entry.update(density=rho, weight=W, status=r.status, newton_iterations=r.report.newton_iterations,
                         time=time.perf_counter() - t0)
            if not (r.converged or r.status.startswith("no equilibrium")):
                out["weighings"].append(entry)          # neither held nor lost: the solver failed
                lost = True
                continue
            entry.update(held=bool(r.converged), mu_min=W / N0, margin=mu * N0 / W,
                         normal_magnitude=c.get("normal_magnitude"), normal_force=c.get("normal_force"),
                         friction_force=c.get("friction_force"),
                         sticking=c.get("sticking"), min_distance=c.get("min_distance"),
                         ball_displacement=d.get("objects", {}).get("ball", {}).get("displacement"))
            out["weighings"].append(entry)
            print(f"  W = {W:.4f} N ({ratio:g} mu sum N): {'held' if r.converged else 'lost'} "
                  f"({r.report.newton_iterations} its, {entry['time']:.1f} s)", flush=True)
            if r.converged and picture is not None:
                _draw(picture, s, f"mu = {mu:g}: a {W * 1e3:.0f} mN sphere held "
                                  f"(mu_min = {entry['mu_min']:.2f}), flexors {contraction:g} mm")
            lost = not r.converged
    return out


def _draw(path: Path, session, title: str) -> None:
    """The deformed gripper and the sphere (opaque, as bones), rendered off-screen."""
    from skelfem.viz.plots import plot_deformed_3d
    path.parent.mkdir(parents=True, exist_ok=True)
    plot_deformed_3d(path, session.model, title, window_size=(800, 800))


def run(mu: float = 0.8, ratios=(0.5, 0.9, 1.1), contraction: float = 3.0, size: float | None = None,
        out: Path | None = None, figures: Path | None = None) -> dict:
    """The weighings; writes grasp3d.json into out and grasp3d.png into figures if given."""
    from skelfem.io.files import atomic_write
    ratios = sorted(float(r) for r in ratios)
    res = grasp(float(mu), ratios, contraction, size, Path(figures) / "grasp3d.png" if figures is not None else None)
    agree = [w["held"] == (w["ratio"] <= 1.0) for w in res["weighings"] if "held" in w]
    summary = {"design": str(DESIGN.relative_to(ROOT)), **res,
               "agree_with_mu_min": int(sum(agree)), "weighed": len(agree)}
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write(out / "grasp3d.json", lambda tmp: Path(tmp).write_text(json.dumps(summary, indent=1) + "\n"))
    return summary


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--mu", type=float, default=0.8)
    p.add_argument("--ratio", type=float, nargs="+", default=[0.5, 0.9, 1.1])
    p.add_argument("--contraction", type=float, default=3.0)
    p.add_argument("--size", type=float, default=None)
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "grasp3d")
    p.add_argument("--figures", type=Path, default=ROOT / "studies" / "figures")
    a = p.parse_args(argv)
    s = run(a.mu, a.ratio, a.contraction, a.size, a.out, a.figures)
    print(f"{s['agree_with_mu_min']} of {s['weighed']} weighings agree with mu_min")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
