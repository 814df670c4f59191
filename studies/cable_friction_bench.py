"""Cable friction measured: the capstan through a rigid channel, its refinement order, and Newton's cost.

    python studies/cable_friction_bench.py [--out studies/output/cable_friction_bench] [--quick]

1. Capstan. A tendon runs through a channel in a rigid pulley (a bone with
   ``rigid = true``), around an arc of total turning Theta (a circle up to pi,
   a spiral beyond), and on into the silicone beside it (a return spring),
   pulled by its contraction. The tension entering the arc over the tension
   leaving it is compared with e^(mu Theta), Theta measured on the deformed
   via points, for Theta in {pi/2, pi, 2 pi} and mu in {0.1, 0.3}.
2. Order. The same with the arc's via points every 20, 10, 5, 2.5 degrees
   (Theta = 2 pi, mu = 0.3): the error of the log of the ratio and the
   observed order (2 expected: each bend's ratio (1 + mu tan(theta/2)) /
   (1 - mu tan(theta/2)) is e^(mu theta) + O(theta^3)).
3. Cost. Newton iterations and solve time of each bundled finger whose
   tendon is contracted, with every cable's friction 0, 0.1 and 0.3.

Writes capstan.csv, order.csv, iterations.csv and summary.json.
``channel(...)`` builds the capstan design (the tests use it).
"""
from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FINGERS = ("finger", "finger_bones", "finger_knuckles", "finger_tapered", "thumb")


def _turn(v, a):
    return np.array([np.cos(a) * v[0] - np.sin(a) * v[1], np.sin(a) * v[0] + np.cos(a) * v[1]])


def channel(theta: float, mu: float, far_in_silicone: bool = False, per_degree: float = 0.2, size: float = 4.0,
            contraction: float = 0.5, k: float = 10.0) -> tuple[dict, np.ndarray]:
    """A tendon through a channel in a rigid pulley: a lead-in, an arc of total turning exactly theta
    (a spiral beyond pi) with a via point every 1 / per_degree degrees, a lead-out; the far end in the
    pulley (blocked) or in the silicone beside it (a return spring). Returns (design dict, arc points)."""
    centre = np.array([40.0, 45.0])
    n = max(int(np.ceil(np.degrees(theta) * per_degree)), 2)
    ang = np.pi + np.linspace(0.0, theta, n + 1)
    rad = np.linspace(16.0, 8.0, n + 1) if theta > np.pi + 1e-9 else np.full(n + 1, 12.0)
    arc = centre + rad[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    chords = np.diff(arc, axis=0)
    unit = chords / np.linalg.norm(chords, axis=1)[:, None]
    inner = np.arctan2(np.cross(unit[:-1], unit[1:]), (unit[:-1] * unit[1:]).sum(1)).sum()
    half = (theta - inner) / 2                                  # the turn at the arc's two ends
    lead_in = arc[0] - 12.0 * _turn(unit[0], -half)
    lead_out = arc[-1] + (30.0 if far_in_silicone else 6.0) * _turn(unit[-1], half)
    pulley = [(centre + 21.0 * np.array([np.cos(a), np.sin(a)])).tolist()
              for a in np.linspace(0, 2 * np.pi, 48, endpoint=False)]
    d = {
        "format": 1, "name": "channel", "dim": 2, "thickness": 10.0,
        "mesh": {"size": size, "degree": 1},
        "materials": {"soft": {"E": 0.1, "nu": 0.45}, "pla": {"E": 3000.0, "nu": 0.35}},
        "body": {"outline": [[0, 0], [80, 0], [80, 95], [0, 95]], "material": "soft"},
        "bones": [{"name": "pulley", "outline": pulley, "material": "pla", "rigid": True}],
        "cables": [{"name": "t", "kind": "tendon", "path": [lead_in.tolist()] + arc.tolist() + [lead_out.tolist()],
                    "stiffness": k, "contraction": contraction, "friction": mu}],
        "pins": [{"name": "base", "region": [[-1, -1], [81, 1e-6]], "kind": "fixed"}],
        "solver": {"steps": 2},
    }
    return d, arc


def arc_tensions(session, arc) -> tuple[float, float, float]:
    """(tension entering the arc, tension leaving it, the turning between them at the current state)."""
    term = session.model.terms_in("cables")[0]
    cab, u = term.cable, session.model.u.x.array
    T = cab.tensions(u, term.rest_length)
    i0 = int(np.argmin(np.linalg.norm(cab.X - arc[0], axis=1)))
    i1 = int(np.argmin(np.linalg.norm(cab.X - arc[-1], axis=1)))
    t = np.diff(cab.positions(u), axis=0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    turning = np.arccos(np.clip((t[:-1] * t[1:]).sum(1), -1, 1))[i0 - 1:i1].sum()
    return float(T[i0 - 1]), float(T[i1]), float(turning)


def capstan(theta: float, mu: float, per_degree: float = 0.2) -> dict:
    from skelfem.session import Session
    d, arc = channel(theta, mu, far_in_silicone=True, per_degree=per_degree, contraction=3.0, k=50.0)
    t0 = time.perf_counter()
    s = Session(d)
    r = s.solve()
    before, after, turning = arc_tensions(s, arc)
    ratio = before / after
    row = {"theta": theta, "mu": mu, "degrees_per_via_point": 1.0 / per_degree, "status": r.status,
           "newton_iterations": r.report.newton_iterations, "time": time.perf_counter() - t0,
           "tension_before": before, "tension_after": after, "turning": turning, "ratio": ratio,
           "capstan": float(np.exp(mu * turning)), "error": float(ratio / np.exp(mu * turning) - 1.0)}
    print(f"capstan theta {theta:6.4f} mu {mu:<4g} every {1 / per_degree:4.1f} deg: {r.status:<10} ratio {ratio:.5f} "
          f"e^(mu Theta) {row['capstan']:.5f} error {row['error']:+.3%} ({row['newton_iterations']} its)", flush=True)
    return row


def order(rows: list) -> list:
    """Observed order of the log error between successive halvings of the via point spacing."""
    e = np.array([abs(np.log1p(r["error"])) for r in rows])
    return [float(np.log2(a / b)) for a, b in zip(e[:-1], e[1:])]


def fingers(mus=(0.0, 0.1, 0.3), names=FINGERS) -> list:
    from skelfem.design.parse import load_design
    from skelfem.session import Session
    rows = []
    for name in names:
        base = None
        for mu in mus:
            d = load_design(ROOT / "geometry" / f"{name}.toml").raw
            for c in d["cables"]:
                c["friction"] = mu
            t0 = time.perf_counter()
            s = Session(d)
            r = s.solve()
            t = time.perf_counter() - t0
            base = base or r.report.newton_iterations
            flexor = next(c for c in r.to_dict()["cables"].values() if c["kind"] == "tendon")
            row = {"design": name, "mu": mu, "status": r.status, "newton_iterations": r.report.newton_iterations,
                   "ratio_to_frictionless": r.report.newton_iterations / base, "time": t,
                   "tension_actuated_end": flexor["tension"], "tension_far_end": flexor["tensions"][-1]}
            print(f"{name:>16} mu {mu:<4g} {r.status:<10} {row['newton_iterations']:4d} its "
                  f"({row['ratio_to_frictionless']:.2f}x) {t:5.1f} s  tendon {row['tension_actuated_end']:.3f} -> "
                  f"{row['tension_far_end']:.3f} N", flush=True)
            rows.append(row)
    return rows


def run(quick: bool = False) -> dict:
    thetas = (np.pi / 2,) if quick else (np.pi / 2, np.pi, 2 * np.pi)
    cap = [capstan(th, mu) for th in thetas for mu in (0.1, 0.3)]
    spacing = (0.05, 0.1) if quick else (0.05, 0.1, 0.2, 0.4)
    ref = [capstan(np.pi if quick else 2 * np.pi, 0.3, per_degree=p) for p in spacing]
    its = fingers(names=FINGERS[:1] if quick else FINGERS)
    friction = [r for r in its if r["mu"] > 0]
    return {"capstan": cap, "refinement": ref, "observed_order": order(ref), "fingers": its,
            "worst_capstan_error": max(abs(r["error"]) for r in cap),
            "worst_iteration_ratio": max(r["ratio_to_frictionless"] for r in friction)}


def _csv(path: Path, rows: list) -> None:
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "cable_friction_bench")
    ap.add_argument("--quick", action="store_true", help="one angle, two spacings, one finger")
    args = ap.parse_args(argv)
    res = run(args.quick)
    args.out.mkdir(parents=True, exist_ok=True)
    _csv(args.out / "capstan.csv", res["capstan"])
    _csv(args.out / "order.csv",
         [dict(r, observed_order=o) for r, o in zip(res["refinement"], [None] + res["observed_order"])])
    _csv(args.out / "iterations.csv", res["fingers"])
    (args.out / "summary.json").write_text(json.dumps(
        {k: res[k] for k in ("observed_order", "worst_capstan_error", "worst_iteration_ratio")}, indent=2) + "\n")
    print(f"observed order {np.round(res['observed_order'], 3).tolist()}; worst capstan error "
          f"{res['worst_capstan_error']:.3%}; worst iteration ratio {res['worst_iteration_ratio']:.2f}x")
    return res


if __name__ == "__main__":
    main()
