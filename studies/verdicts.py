"""How long a "not held" verdict takes: the bundled grippers weighed with too little friction, and held.

    python studies/verdicts.py [--cases NAME ...] [--label after] [--out studies/output/verdicts]

Each case is one Session on a bundled design: the hand is closed with
gravity off (geometry/gripper.toml: both flexors 4 mm in one solve;
geometry/gripper3d.toml: 3 mm in three solves), then gravity is switched on
(with the box's density when given) in one warm re-solve, the weighing
whose verdict is timed: held (converged) or lost (``no equilibrium: object
NAME is not held``). The frictionless gripper (mu = 0) has no equilibrium
once the curling fingers squeeze the box: its close is the verdict. Every
lost case has a held counterpart with more friction (or a lighter box), so
that a faster verdict is seen not to lose a grasp that holds.

run(**params) returns the rows; main(argv) writes them into verdicts.json
under ``label`` (other labels kept: "before" and "after" a change side by side).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GRIPPER, GRIPPER3D = ROOT / "geometry" / "gripper.toml", ROOT / "geometry" / "gripper3d.toml"
FLEXORS = ("cables.left_flexor.contraction", "cables.right_flexor.contraction")

# name: (design, mu, contraction (mm), closing solves, density of the object (None: the design's), expected)
CASES = {
    "gripper_mu0.3_lost": (GRIPPER, 0.3, 4.0, 1, 1240.0, "lost"),
    "gripper_mu0.3_held": (GRIPPER, 0.3, 4.0, 1, 620.0, "held"),
    "gripper_mu0.6_lost": (GRIPPER, 0.6, 4.0, 1, 1860.0, "lost"),
    "gripper_mu0.6_held": (GRIPPER, 0.6, 4.0, 1, 1240.0, "held"),
    "gripper_2mm_mu0.8_lost": (GRIPPER, 0.8, 2.0, 1, None, "lost"),
    "gripper_2mm_mu0.8_held": (GRIPPER, 0.8, 2.0, 1, 310.0, "held"),
    "gripper_frictionless": (GRIPPER, 0.0, 4.0, 1, None, "lost"),
    "gripper3d_mu0.8_lost": (GRIPPER3D, 0.8, 3.0, 3, 4980.0, "lost"),     # about 1.5 mu sum N
    "gripper3d_mu0.8_held": (GRIPPER3D, 0.8, 3.0, 3, 3650.0, "held"),     # about 1.1 mu sum N (cradled)
}
SMALL = ("gripper_mu0.3_lost", "gripper_mu0.3_held", "gripper_frictionless")


def _verdict(r) -> str:
    if r.converged:
        return "held"
    return "lost" if r.status.startswith("no equilibrium") else "failed"


def case(name: str) -> dict:
    """Close, then weigh: the verdict of the weighing (of the close for a frictionless grasp), its time."""
    from skelfem import Session
    design, mu, contraction, closes, density, expected = CASES[name]
    row = {"case": name, "design": str(design.relative_to(ROOT)), "mu": mu, "contraction": contraction,
           "density": density, "expected": expected}
    box = "box" if design == GRIPPER else "ball"
    with Session(design, [f"contact.friction={mu}"]) as s:
        row["dofs"] = s.dofs
        its, t0 = 0, time.perf_counter()
        for c in [contraction * (k + 1) / closes for k in range(closes)]:
            s.set({k: c for k in FLEXORS})
            r = s.solve()
            its += r.report.newton_iterations
            if not r.converged:
                break
        row["close"] = {"status": r.status, "newton_iterations": its, "time": time.perf_counter() - t0}
        if r.converged and mu > 0:
            g = [0.0, -9.81] + ([0.0] if s.model.dim == 3 else [])
            change: dict = {"gravity.acceleration": g}
            if density is not None:
                change[f"materials.{box}_pla.density"] = density
            s.set(change)
            t0 = time.perf_counter()
            r = s.solve()
            row["weigh"] = {"status": r.status, "newton_iterations": r.report.newton_iterations,
                            "time": time.perf_counter() - t0}
            stage = row["weigh"]
        else:
            stage = row["close"]
    row.update(verdict=_verdict(r), status=stage["status"], newton_iterations=stage["newton_iterations"],
               time=stage["time"])
    print(f"{name:<26} {row['verdict']:<6} (expected {expected}) {row['newton_iterations']:5d} its "
          f"{row['time']:7.1f} s   {row['status']}", flush=True)
    return row


def run(cases=tuple(CASES), label: str = "after", out: Path | None = None) -> dict:
    """The cases' rows under label; merged into out/verdicts.json (its other labels kept) if out is given."""
    from skelfem.io.files import atomic_write
    rows = [case(name) for name in cases]
    result = {label: rows}
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        path = out / "verdicts.json"
        old = json.loads(path.read_text()) if path.exists() else {}
        result = {**old, label: rows}
        atomic_write(path, lambda tmp: Path(tmp).write_text(json.dumps(result, indent=1) + "\n"))
    return result


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    p.add_argument("--label", default="after")
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "verdicts")
    a = p.parse_args(argv)
    run(a.cases, a.label, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
