"""The accuracy of skelfem's time stepping against references (the numbers quoted in the README).

* frequency: a cantilever (80 x 4 mm, plane strain, E = 1 MPa, nu = 0.3,
  rho = 1000 kg/m^3, P2, h = 2 mm) released from rest under a sudden small
  tip load (static deflection 1e-3 L) oscillates about its static
  deflection; the frequency from the zero crossings of the tip displacement
  about the static value (a static solve of the same model) against
  Euler-Bernoulli's f1 = 1.8751^2 / (2 pi L^2) sqrt(E'I / (rho A)), E' = E/(1 - nu^2).
* orders: a 40 x 4 mm cantilever (P1, h = 2 mm) under sudden gravity
  (1 m/s^2, a smooth load that excites little beyond the first mode), tip
  position at T = 0.05 s with dt = T/20, T/40, T/80 against BDF2 at T/640;
  the slope of log error against log dt.
* energy: kinetic + potential energy (the load's potential included) per
  step without damping, from a sudden load at rest (E = 0 at t = 0): its
  largest increase over a step relative to the largest |potential energy|.
* slow schedule: a strip's tendon pulled to 3 mm over 1 s (about 15 periods
  of its first mode), held 0.5 s, BDF2 with dt = 0.01 s and mass damping
  10/s, against the static equilibrium at 3 mm: the tip distance relative
  to the tip's motion.

    python studies/dynamics_checks.py [--out DIR]     # writes dynamics_checks.json
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

E, NU, THICK, RHO = 1.0, 0.3, 10.0, 1000.0
E_PLANE = E / (1.0 - NU ** 2)
MASS_UNIT = 1e-12          # kg/m^3 mm/s^2 -> N/mm^3 (skelfem.terms.inertia.MASS_UNIT)


def cantilever(L=80.0, h=4.0, size=2.0, degree=2, dt=0.003, duration=0.5, integrator="bdf2",
               load=None, gravity=None, damping=None) -> dict:
    """A horizontal strip clamped at x = 0 with a tip marker; a sudden tip load and/or gravity."""
    d = {"format": 1, "name": "cantilever", "dim": 2, "thickness": THICK,
         "mesh": {"size": size, "degree": degree},
         "materials": {"soft": {"E": E, "nu": NU, "density": RHO}},
         "body": {"outline": [[0, 0], [L, 0], [L, h], [0, h]], "material": "soft"},
         "pins": [{"name": "base", "region": [[-1, -1], [1e-6, h + 1]], "kind": "fixed"}],
         "markers": {"tip": [L, h / 2]},
         "dynamics": {"dt": dt, "duration": duration, "integrator": integrator}}
    if load is not None:
        d["loads"] = [{"name": "tip", "at": [L, h / 2], "force": [0.0, -load]}]
    if gravity is not None:
        d["gravity"] = {"acceleration": [0.0, -gravity]}
    if damping is not None:
        d["dynamics"]["damping"] = damping
    return d


def crossings(t: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Times where z changes sign (linear interpolation)."""
    i = np.flatnonzero(np.sign(z[1:]) != np.sign(z[:-1]))
    return t[i] - z[i] * (t[i + 1] - t[i]) / (z[i + 1] - z[i])


def frequency(L=80.0, h=4.0, size=2.0, degree=2, dt=0.003, duration=0.5, integrator="bdf2") -> dict:
    from skelfem import Session
    I, A = THICK * h ** 3 / 12.0, THICK * h
    P = 1e-3 * 3.0 * E_PLANE * I / L ** 2
    f1 = 1.8751 ** 2 / (2 * np.pi * L ** 2) * np.sqrt(E_PLANE * I / (MASS_UNIT * RHO * A))
    with Session(cantilever(L, h, size, degree, dt, duration, integrator, load=P)) as s:
        static = s.solve().markers["tip"]["position"][1]
        run = s.run_in_time()
        dofs = s.dofs
    t = np.array([r["time"] for r in run.report.trajectory])
    y = np.array([r["tip_y"] for r in run.report.trajectory])
    tc = crossings(t, y - static)
    f = (len(tc) - 1) / (2.0 * (tc[-1] - tc[0])) if len(tc) >= 2 else float("nan")
    return {"f_euler_bernoulli": f1, "f_measured": f, "relative_error": f / f1 - 1.0, "crossings": len(tc),
            "swing_up": float(y.max() - static), "swing_down": float(static - y.min()),
            "steps": run.dynamics["steps"], "cuts": run.dynamics["cuts"], "converged": run.converged,
            "dofs": dofs, "dt": dt, "newton_iterations": run.newton_iterations}


def tip_at_end(integrator: str, T: float, Ns) -> list:
    """Tip y at t = T of the gravity-loaded 40 mm cantilever for dt = T/N, N in Ns (one mesh)."""
    from skelfem import Session
    out = []
    with Session(cantilever(L=40.0, size=2.0, degree=1, gravity=1.0, dt=T / Ns[0], duration=T,
                            integrator=integrator)) as s:
        for N in Ns:
            s.set({"dynamics.dt": T / N})
            run = s.run_in_time()
            if not run.converged:
                raise RuntimeError(f"{integrator} dt = T/{N}: {run.status}")
            out.append(run.report.trajectory[-1]["tip_y"])
    return out


def orders(T=0.05, Ns=(20, 40, 80), N_ref=640) -> dict:
    ref = tip_at_end("bdf2", T, [N_ref])[0]
    out = {"T": T, "N": list(Ns), "reference": f"bdf2, dt = T/{N_ref}"}
    for integrator in ("euler", "bdf2"):
        err = np.abs(np.array(tip_at_end(integrator, T, list(Ns))) - ref)
        out[integrator] = {"errors_mm": err.tolist(), "slope": float(-np.polyfit(np.log(Ns), np.log(err), 1)[0])}
    return out


def energy(integrator="bdf2", damping=None, dt=0.002, duration=0.15) -> dict:
    from skelfem import Session
    with Session(cantilever(L=40.0, size=2.0, degree=1, gravity=9.81, dt=dt, duration=duration,
                            integrator=integrator, damping=damping)) as s:
        run = s.run_in_time()
    hist = run.dynamics["energy_history"]
    total = np.array(hist["total"])
    scale = float(np.abs(hist["potential"]).max())
    return {"integrator": integrator, "damping": damping, "initial": float(total[0]), "final": float(total[-1]),
            "scale": scale, "max_increase_relative": float(np.diff(total).max() / scale),
            "lost_relative": float(-total[-1] / scale), "converged": run.converged}


def slow_schedule(u_end=3.0, ramp=1.0, hold=0.5, dt=0.01, mass_damping=10.0) -> dict:
    from skelfem import Session
    d = {"format": 1, "name": "strip", "dim": 2, "thickness": THICK, "mesh": {"size": 3.0, "degree": 1},
         "materials": {"soft": {"E": 0.5, "nu": 0.3, "density": RHO}},
         "body": {"outline": [[0, 0], [10, 0], [10, 60], [0, 60]], "material": "soft"},
         "cables": [{"name": "flexor", "kind": "tendon", "path": [[8, 0], [8, 60]], "stiffness": 5.0}],
         "pins": [{"name": "base", "region": [[-1, -1], [11, 1e-6]], "kind": "fixed"}],
         "markers": {"tip": [5, 60]}}
    static = json.loads(json.dumps(d))
    static["cables"][0]["contraction"] = u_end
    d["cables"][0]["schedule"] = [[0.0, 0.0], [ramp, u_end]]
    d["dynamics"] = {"dt": dt, "duration": ramp + hold, "integrator": "bdf2", "damping": {"mass": mass_damping}}
    with Session(d) as s:
        run = s.run_in_time()
    with Session(static) as s:
        ref = s.solve()
    motion = float(np.linalg.norm(ref.markers["tip"]["displacement"]))
    gap = float(np.linalg.norm(np.subtract(run.markers["tip"]["position"], ref.markers["tip"]["position"])))
    return {"gap_mm": gap, "motion_mm": motion, "relative": gap / motion, "converged": run.converged and ref.converged,
            "contraction": run.cables["flexor"]["contraction"]}


def run(**params) -> dict:
    t0 = time.perf_counter()
    out = {"frequency": frequency(**params.get("frequency", {})),
           "orders": orders(**params.get("orders", {})),
           "energy": [energy("euler"), energy("bdf2"), energy("bdf2", {"mass": 20.0}),
                      energy("bdf2", {"stiffness": 0.002})],
           "slow_schedule": slow_schedule(**params.get("slow_schedule", {}))}
    out["time"] = time.perf_counter() - t0
    return out


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "output" / "dynamics")
    args = p.parse_args(argv)
    res = run()
    f, o, s = res["frequency"], res["orders"], res["slow_schedule"]
    print(f"frequency: {f['f_measured']:.4f} Hz against Euler-Bernoulli {f['f_euler_bernoulli']:.4f} Hz "
          f"({100 * f['relative_error']:+.2f} %), {f['dofs']} DOFs, dt {f['dt']} s")
    for integrator in ("euler", "bdf2"):
        print(f"order {integrator}: slope {o[integrator]['slope']:.2f}, errors "
              + ", ".join(f"{e:.2e}" for e in o[integrator]["errors_mm"]) + f" mm at dt = T/{o['N']}")
    for e in res["energy"]:
        print(f"energy {e['integrator']} damping {e['damping']}: largest step increase "
              f"{e['max_increase_relative']:+.1e}, lost {100 * e['lost_relative']:.2f} % of max |Pi|")
    print(f"slow schedule: {s['gap_mm']:.2e} mm from the static tip "
          f"({s['relative']:.1e} of its {s['motion_mm']:.2f} mm motion)")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "dynamics_checks.json").write_text(json.dumps(res, indent=2) + "\n")
    print(f"{res['time']:.1f} s; wrote {args.out / 'dynamics_checks.json'}")
    return res


if __name__ == "__main__":
    main()
