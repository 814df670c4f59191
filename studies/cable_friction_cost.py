"""What cable friction costs against the same solve without it: statics, a load reversal, a run in time.

    python studies/cable_friction_cost.py [--out studies/output/cable_friction_cost] [--repeats 3] [--quick]

1. Statics. Every bundled design with friction under one of its [cables.*]
   (found by reading geometry/*.toml), and the bundled fingers of
   studies/cable_friction_bench.py with every cable's friction set to 0.3,
   each solved from rest as bundled and again with every cable's friction 0:
   Newton iterations and the solve's wall time (the Session is built outside
   the timer; best of ``repeats`` fresh sessions, the machine being shared).
2. Reversal. geometry/finger.toml's flexor contracted 0 -> 8 mm -> 0 in 8
   steps each way (studies/cable_friction.py's cycle, mesh size 2), with
   friction 0 and 0.3: the Newton iterations of a step up (mean), of the
   first step down (the reversal) and of the whole cycle, and its time.
3. In time. geometry/flick.toml (its flexor pulled 8 mm in 50 ms, [dynamics])
   with the flexor's friction 0 and 0.3: Newton iterations and time of the run.

Writes cable_friction_cost.json; docs/performance.md shows it (the
``cable_friction_speed`` table). No 3D bundled design has cable friction.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

FINGERS = ("finger", "finger_bones", "finger_knuckles", "finger_tapered", "thumb")
SET_MU = 0.3           # the friction given to the fingers' cables, and in the reversal and the run in time


def friction_designs() -> list[str]:
    """The bundled designs with friction on some cable (a coefficient or one per material)."""
    from skelfem.design.parse import load_design
    out = []
    for path in sorted((ROOT / "geometry").glob("*.toml")):
        try:
            raw = load_design(path).raw
        except Exception:                      # a partial design (an include) is not a design of its own
            continue
        if any(c.get("friction") or c.get("friction_by_material") for c in raw.get("cables", [])):
            out.append(path.stem)
    return out


def _raw(name: str, mu: float | None):
    """The design as a dict; mu None: as bundled, else every cable's friction mu (per material dropped)."""
    from skelfem.design.parse import load_design
    raw = load_design(ROOT / "geometry" / f"{name}.toml").raw
    if mu is not None:
        for c in raw.get("cables", []):
            c.pop("friction_by_material", None)
            c["friction"] = mu
    return raw


def _timed(raw: dict, repeats: int, run: str = "solve") -> dict:
    """Iterations and the best wall time of `run` over `repeats` fresh sessions."""
    from skelfem.session import Session
    best, r = float("inf"), None
    for _ in range(repeats):
        with Session(raw) as s:
            t0 = time.perf_counter()
            r = getattr(s, run)()
            best = min(best, time.perf_counter() - t0)
    return {"status": r.status, "newton_iterations": r.report.newton_iterations, "time": best}


def statics(repeats: int, quick: bool = False) -> list:
    rows = []
    cases = [(name, None) for name in friction_designs()] + \
        ([] if quick else [(name, SET_MU) for name in FINGERS])
    for name, mu in cases:
        raw = _raw(name, mu)
        mus = sorted({float(c.get("friction") or 0.0) for c in raw.get("cables", [])})
        on, off = _timed(raw, repeats), _timed(_raw(name, 0.0), repeats)
        row = {"design": name, "friction": "as bundled" if mu is None else f"every cable {mu:g}", "mu": mus,
               "with": on, "without": off, "iterations_ratio": on["newton_iterations"] / off["newton_iterations"],
               "time_ratio": on["time"] / off["time"]}
        print(f"{name:>16} {row['friction']:>16}: {on['newton_iterations']:4d} / {off['newton_iterations']:4d} its "
              f"({row['iterations_ratio']:.2f}x), {on['time']:.3f} / {off['time']:.3f} s ({row['time_ratio']:.2f}x)",
              flush=True)
        rows.append(row)
    return rows


def reversal(steps: int = 8, top: float = 8.0, size: float = 2.0) -> list:
    import cable_friction
    rows = []
    for mu in (0.0, SET_MU):
        c = cable_friction.cycle(mu, top=top, steps=steps, size=size)
        up = [r["newton_iterations"] for r in c["rows"] if r["branch"] == "up"]
        down = [r["newton_iterations"] for r in c["rows"] if r["branch"] == "down"]
        row = {"mu": mu, "status": c["status"], "up_mean": sum(up) / max(len(up), 1), "up_max": max(up, default=0),
               "reversal": down[0] if down else None, "down": down, "up": up,
               "cycle_iterations": c["newton_iterations"], "time": c["time"]}
        print(f"reversal mu {mu:g}: up {row['up_mean']:.1f} its/step, first step down {row['reversal']}, "
              f"cycle {row['cycle_iterations']} its, {row['time']:.2f} s", flush=True)
        rows.append(row)
    return rows


def in_time(duration: float | None = None) -> list:
    rows = []
    for mu in (0.0, SET_MU):
        raw = _raw("flick", None)
        for c in raw["cables"]:
            if c["kind"] == "tendon":
                c["friction"] = mu
        if duration is not None:
            raw["dynamics"]["duration"] = duration
        r = _timed(raw, 1, "run_in_time")
        rows.append({"design": "flick", "mu": mu, **r})
        print(f"in time mu {mu:g}: {r['status']}, {r['newton_iterations']} its, {r['time']:.2f} s", flush=True)
    return rows


def run(repeats: int = 3, quick: bool = False) -> dict:
    res = {"statics": statics(1 if quick else repeats, quick),
           "reversal": reversal(steps=2, top=2.0, size=4.0) if quick else reversal(),
           "in_time": in_time(0.01 if quick else None)}
    s = res["statics"]
    rev = {r["mu"]: r for r in res["reversal"]}
    dyn = {r["mu"]: r for r in res["in_time"]}
    res["summary"] = {
        "max_time_ratio_bundled": max((r["time_ratio"] for r in s if r["friction"] == "as bundled"), default=None),
        "max_time_ratio": max((r["time_ratio"] for r in s), default=None),
        "reversal_over_step_up": rev[SET_MU]["reversal"] / rev[SET_MU]["up_mean"] if rev[SET_MU]["reversal"] else None,
        "cycle_ratio": rev[SET_MU]["cycle_iterations"] / rev[0.0]["cycle_iterations"],
        "in_time_ratio": dyn[SET_MU]["newton_iterations"] / dyn[0.0]["newton_iterations"],
        "in_time_time_ratio": dyn[SET_MU]["time"] / dyn[0.0]["time"]}
    return res


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "cable_friction_cost")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="the bundled friction designs once, a tiny cycle and run")
    args = ap.parse_args(argv)
    res = run(args.repeats, args.quick)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "cable_friction_cost.json").write_text(json.dumps(res, indent=1))
    print(json.dumps(res["summary"], indent=1))
    return res


if __name__ == "__main__":
    main()
