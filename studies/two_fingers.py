"""Two soft bodies pressing on each other: geometry/two_fingers.toml, contraction by contraction.

One Session contracts both flexors together from 0 to ``contraction`` mm in
``steps`` steps (the load path: friction remembers it). At each step it reads
the contact between the fingers (normal and friction force on the left
finger, the sticking share) and each finger's balance: its pin's reaction
plus the contact force on it, which must vanish because the tendons pull
inside each finger. Writes studies/output/two_fingers/two_fingers.json, the
deformed picture two_fingers.png (contact forces on the right finger as
arrows) and two_fingers_forces.png (forces against contraction).

    python studies/two_fingers.py [--contraction 6] [--steps 6] [--size 2]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
OUT = ROOT / "studies" / "output" / "two_fingers"
FIGURES = ROOT / "studies" / "figures"
DESIGN = ROOT / "geometry" / "two_fingers.toml"
TENDONS = ("left_flexor", "right_flexor")


def _row(result, u: float) -> dict:
    pins = result.pins
    pair = next((c for c in result.contacts if c["between"] == ["left", "right"]), None)
    f = np.zeros(2)
    row = {"contraction": u, "newton_iterations": int(result.newton_iterations), "touching": pair is not None}
    if pair is not None:
        f = np.asarray(pair["normal_force"]) + np.asarray(pair.get("friction_force", np.zeros(2)))
        row.update(normal=float(np.linalg.norm(pair["normal_force"])),
                   friction=float(np.linalg.norm(pair.get("friction_force", np.zeros(2)))),
                   sticking=float(pair.get("sticking", 1.0)), min_distance=float(pair["min_distance"]))
    left = np.asarray(pins["left_base"]["reaction"]) + f           # the contact force on the left is f
    right = np.asarray(pins["right_base"]["reaction"]) - f
    row["balance"] = float(max(np.linalg.norm(left), np.linalg.norm(right)))
    row["reaction"] = float(np.linalg.norm(pins["left_base"]["reaction"]))
    return row


def run(contraction: float = 6.0, steps: int = 6, size: float | None = None, out: Path | None = OUT,
        figures: Path | None = FIGURES) -> dict:
    from skelfem import Session
    from skelfem.design import load_design
    from skelfem.io.files import write_json
    from skelfem.viz.plots import plot_deformed

    overrides = [f"{t}.contraction=0" for t in ("cables.left_flexor", "cables.right_flexor")]
    if size is not None:
        overrides.append(f"mesh.size={size}")
    design = load_design(DESIGN, overrides)
    rows = []
    with Session(design) as s:
        for u in np.linspace(0.0, contraction, steps + 1)[1:]:
            s.set({f"cables.{t}.contraction": float(u) for t in TENDONS})
            r = s.solve()
            if not r.converged:
                raise SystemExit(f"error: the solve at {u:g} mm failed ({r.status})")
            rows.append(_row(r, float(u)))
            print(f"u = {u:5.2f} mm: " + (f"N = {rows[-1]['normal']:.4f} N, friction {rows[-1]['friction']:.4f} N, "
                                          f"sticking {rows[-1]['sticking']:.2f}" if rows[-1]["touching"] else "apart")
                  + f", balance {rows[-1]['balance']:.1e} N", flush=True)
        if figures is not None:
            figures.mkdir(parents=True, exist_ok=True)
            plot_deformed(figures / "two_fingers.png", s.model,
                          f"two bodies: flexors at {contraction:g} mm, contact forces on the right finger")
    res = {"design": DESIGN.name, "dofs": int(r.dofs), "rows": rows,
           "max_balance": max(row["balance"] for row in rows),
           "max_reaction": max(row["reaction"] for row in rows)}
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "two_fingers.json", res)
    if figures is not None:
        _chart(figures / "two_fingers_forces.png", rows)
    return res


def _chart(path: Path, rows: list) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from skelfem.io.files import atomic_write
    fig = Figure(figsize=(5.5, 3.4), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    u = [r["contraction"] for r in rows]
    ax.plot(u, [r.get("normal", 0.0) for r in rows], "o-", label="normal force between the fingers")
    ax.plot(u, [r.get("friction", 0.0) for r in rows], "s-", label="friction force")
    ax.plot(u, [r["reaction"] for r in rows], "k--", lw=0.8, label="left pin's reaction")
    ax.set_xlabel("both flexors' contraction [mm]")
    ax.set_ylabel("force [N]")
    ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--contraction", type=float, default=6.0)
    p.add_argument("--steps", type=int, default=6)
    p.add_argument("--size", type=float, default=None)
    a = p.parse_args(argv)
    run(a.contraction, a.steps, a.size)


if __name__ == "__main__":
    main()
