"""Newton iterations and solve times of frictional grasps against the same grasps without friction.

    python studies/grasp_bench.py [--contraction 2 4] [--out studies/output/grasp_bench]

Cases: the gripper (geometry/gripper.toml) closed from rest by both flexors
(one solve), then weighed (gravity on, one warm re-solve); the two-pad pinch
of tests/test_objects.py (pads moved in by 0.45 mm, then weighed). Each with
friction (the design's mu) and without (mu = 0: a closed grip is then only
an equilibrium while nothing loads the box, and a weighing has none).
Prints one line per solve and writes grasp_bench.json.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GRIPPER = ROOT / "geometry" / "gripper.toml"
G = [0.0, -9.81]


def pinch_design(mu: float) -> dict:
    """The pinch of tests/test_objects.py: an inverted U whose prongs press two bumps on a box."""
    box = [[7.5, 2], [32.5, 2], [32.5, 22], [7.5, 22]]
    return {"format": 1, "name": "pinch", "dim": 2, "thickness": 10.0, "mesh": {"size": 1.5, "degree": 1},
            "materials": {"soft": {"E": 0.01, "nu": 0.3, "density": 1000.0},
                          "pla": {"E": 1000.0, "nu": 0.35, "density": 500.0}},
            "body": {"outline": [[0, 0], [6, 0], [6, 8], [7, 8], [7, 16], [6, 16], [6, 30], [34, 30], [34, 16],
                                 [33, 16], [33, 8], [34, 8], [34, 0], [40, 0], [40, 36], [0, 36]],
                     "material": "soft"},
            "pins": [{"name": "top", "region": [[-1, 35.99], [41, 37]], "kind": "fixed"},
                     {"name": "left", "region": [[-1, -1], [0.01, 30]], "kind": "fixed", "move": [0.45, 0]},
                     {"name": "right", "region": [[39.99, -1], [41, 30]], "kind": "fixed", "move": [-0.45, 0]}],
            "objects": [{"name": "box", "outline": box, "material": "pla"}],
            "gravity": {"acceleration": [0.0, 0.0]}, "contact": {"dhat": 0.2, "friction": mu},
            "solver": {"steps": 4, "max_iterations": 300}}


def _row(case: str, mu: float, stage: str, r, t: float) -> dict:
    row = {"case": case, "mu": mu, "stage": stage, "status": r.status,
           "newton_iterations": r.report.newton_iterations, "time": t}
    print(f"{case:>8} {stage:<16} mu {mu:<4g} {r.status:<40} {r.report.newton_iterations:5d} its {t:6.1f} s",
          flush=True)
    return row


def gripper(mu: float, contraction: float) -> list:
    from skelfem import Session
    rows = []
    with Session(GRIPPER, [f"contact.friction={mu}"]) as s:
        s.set({"cables.left_flexor.contraction": contraction, "cables.right_flexor.contraction": contraction})
        t0 = time.perf_counter()
        r = s.solve()
        rows.append(_row("gripper", mu, f"close {contraction:g} mm", r, time.perf_counter() - t0))
        if r.converged and mu > 0:
            s.set({"gravity.acceleration": G})
            t0 = time.perf_counter()
            r = s.solve()
            rows.append(_row("gripper", mu, "weigh", r, time.perf_counter() - t0))
    return rows


def pinch(mu: float) -> list:
    from skelfem import Session
    rows = []
    with Session(pinch_design(mu)) as s:
        t0 = time.perf_counter()
        r = s.solve()
        rows.append(_row("pinch", mu, "squeeze", r, time.perf_counter() - t0))
        if r.converged and mu > 0:
            s.set({"gravity.acceleration": G})
            t0 = time.perf_counter()
            r = s.solve()
            rows.append(_row("pinch", mu, "weigh", r, time.perf_counter() - t0))
    return rows


def run(contractions=(2.0, 4.0), mu: float = 0.8, out: Path | None = None) -> dict:
    rows = []
    for c in contractions:
        for m in (mu, 0.0):
            rows += gripper(m, c)
    for m in (0.6, 0.0):
        rows += pinch(m)
    result = {"rows": rows}
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "grasp_bench.json").write_text(json.dumps(result, indent=1) + "\n")
    return result


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--contraction", type=float, nargs="+", default=[2.0, 4.0])
    p.add_argument("--mu", type=float, default=0.8)
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "grasp_bench")
    a = p.parse_args(argv)
    run(a.contraction, a.mu, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
