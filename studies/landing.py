"""Objects that land: free objects placed a gap above their support, solved from rest in one static solve.

    python studies/landing.py [--out studies/output/landing] [--cases NAME ...]

Each case is a free object placed a gap above what holds it, under gravity
tilted by theta (the slope), with Coulomb friction mu; it is solved from
rest with `[solver] steps` load steps. The object falls along its load
until its contacts form, and they hold from that moment (the guide's
Objects and friction, Landing): it should stay where its fall met the
support if tan(theta) < mu, and be reported not held otherwise, whatever
the gap and the number of steps.

* ``slope``: a 6 x 3 mm PLA box above a ground (a penalty floor), mu = 0.5;
* ``block``: the box above a soft pinned block (the IPC barrier and object
  friction);
* ``stack``: two boxes, one above the other, above the block;
* ``slope3d`` and ``block3d``: a 4 mm cube above a floor and above a block.

Writes landing.json (a row per case: the verdict, the object's displacement,
its part along the slope, gap tan(theta), Newton iterations, solve time and
DOFs); run(**params) returns the rows.
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from skelfem.io.files import say

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "studies" / "output" / "landing"
G = 9.81
MATERIALS = {"soft": {"E": 1.0, "nu": 0.3, "density": 1000.0}, "pla": {"E": 1000.0, "nu": 0.35, "density": 1250.0}}
# (family, theta deg, gap mm, mu, load steps)
CASES = [("slope", 20.0, g, 0.5, 1) for g in (0.01, 0.05, 0.5)] + [
    ("slope", 20.0, 0.05, 0.5, 4), ("slope", 35.0, 0.01, 0.5, 1), ("slope", 35.0, 0.5, 0.5, 4),
    ("slope", 25.0, 0.05, 0.5, 1), ("slope", 27.0, 0.05, 0.5, 1), ("slope", 0.0, 1.0, 0.0, 1),
    ("block", 17.0, 0.5, 1.0, 1), ("block", 17.0, 0.5, 1.0, 4), ("block", 20.0, 0.5, 0.5, 1),
    ("block", 35.0, 0.5, 0.5, 1), ("stack", 15.0, 0.5, 0.5, 1), ("stack", 30.0, 0.5, 0.5, 1),
    ("slope3d", 20.0, 0.05, 0.5, 1), ("slope3d", 20.0, 0.5, 0.5, 1), ("slope3d", 35.0, 0.05, 0.5, 1),
    ("slope3d", 0.0, 1.0, 0.0, 1), ("block3d", 20.0, 0.1, 0.5, 1), ("block3d", 35.0, 0.1, 0.5, 1)]


def _box(name: str, x0: float, y0: float, x1: float, y1: float) -> dict:
    return {"name": name, "outline": [[x0, y0], [x1, y0], [x1, y1], [x0, y1]], "material": "pla"}


def design(family: str, theta: float, gap: float, mu: float, steps: int = 1) -> dict:
    """The design of one case: its object(s) `gap` above the support, gravity tilted by theta along +x."""
    th = math.radians(theta)
    dim = 3 if family.endswith("3d") else 2
    g = [G * math.sin(th), -G * math.cos(th)] + [0.0] * (dim - 2)
    d: dict = {"format": 1, "name": f"landing_{family}", "dim": dim, "materials": MATERIALS,
               "gravity": {"acceleration": g}, "solver": {"steps": steps}}
    if dim == 2:
        d.update(thickness=10.0, mesh={"size": 1.0, "degree": 1},
                 body={"outline": [[0, 0], [10, 0], [10, 10], [0, 10]], "material": "soft"},
                 pins=[{"name": "base", "region": [[-1, -1], [11, 1e-6]], "kind": "fixed"}])
    else:
        width = 4 if family == "slope3d" else 10
        d.update(mesh={"size": 2.0, "degree": 1},
                 body={"solids": [{"box": {"min": [0, 0, 0], "max": [width, 4, width]}}], "material": "soft"},
                 pins=[{"name": "base", "region": [[-1, -1, -1], [width + 1, 1e-6, width + 1]], "kind": "fixed"}])
    friction = {"friction": mu} if mu else {}
    if family == "slope":
        d["objects"] = [_box("box", 20, gap, 26, 3 + gap)]
        d["grounds"] = [{"name": "floor", "point": [0, 0], "normal": [0, 1], "stiffness": 100.0, **friction}]
        d["contact"] = {"dhat": 0.2}
    elif family == "block":
        d["objects"] = [_box("box", 2, 10 + gap, 8, 13 + gap)]
        d["contact"] = {"dhat": 0.2, **friction}
    elif family == "stack":
        d["objects"] = [_box("lower", 2, 10 + gap, 8, 13 + gap), _box("upper", 3, 13 + 2 * gap, 7, 15 + 2 * gap)]
        d["contact"] = {"dhat": 0.2, **friction}
    elif family == "slope3d":
        d["objects"] = [{"name": "cube", "solids": [{"box": {"min": [10, gap, 0], "max": [14, 4 + gap, 4]}}],
                         "material": "pla"}]
        d["grounds"] = [{"name": "floor", "point": [0, 0, 0], "normal": [0, 1, 0], "stiffness": 100.0, **friction}]
    elif family == "block3d":
        d["objects"] = [{"name": "cube", "solids": [{"box": {"min": [3, 4 + gap, 3], "max": [7, 8 + gap, 7]}}],
                         "material": "pla"}]
        d["contact"] = {"dhat": min(0.05, gap / 2), **friction}
    else:
        raise ValueError(f"unknown family {family!r}")
    return d


def solve(family: str, theta: float, gap: float, mu: float, steps: int = 1) -> dict:
    """Solve one case from rest: its row."""
    from skelfem import Session
    with Session(design(family, theta, gap, mu, steps)) as s:
        r = s.solve()
        dofs = int(s.model.u.x.array.size)
        out = r.to_dict() if r.converged else {}
    row = {"family": family, "theta": theta, "gap": gap, "mu": mu, "steps": steps, "converged": bool(r.converged),
           "status": r.status, "held": bool(r.converged), "newton_iterations": int(r.report.newton_iterations),
           "time": float(r.report.time), "dofs": dofs, "fall_along_slope": gap * math.tan(math.radians(theta))}
    if r.converged:
        moved = {name: o["displacement"] for name, o in out["objects"].items()}
        row["displacement"] = moved
        row["along_slope"] = max(abs(v[0]) for v in moved.values())
    return row


def run(cases=None, out: Path | None = OUT, progress=say) -> dict:
    """Solve every case (default CASES); write landing.json into out (None: nothing written)."""
    rows = []
    for case in (CASES if cases is None else cases):
        row = solve(*case)
        rows.append(row)
        if progress:
            where = f", {row['along_slope']:.4f} mm along the slope" if row["held"] else ""
            progress(f"{row['family']:8s} theta {row['theta']:4.1f} gap {row['gap']:5.2f} mu {row['mu']:.1f} "
                     f"steps {row['steps']}: {row['status']}{where} ({row['newton_iterations']} its, "
                     f"{row['time']:.2f} s)")
    res = {"rows": rows}
    if out is not None:
        from skelfem.io.files import write_json
        Path(out).mkdir(parents=True, exist_ok=True)
        write_json(Path(out) / "landing.json", res)
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--cases", nargs="*", help="families to run (default: all)")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    cases = None if not a.cases else [c for c in CASES if c[0] in a.cases]
    run(cases, a.out)
    say(f"wrote {a.out}/landing.json in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
