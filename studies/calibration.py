"""Calibration on synthetic measurements: pull, push and tendon experiments, fine-mesh data, coarse-mesh fit.

    python studies/calibration.py [--size-data 1.0] [--size-fit 2.0] [--seeds 20] [--bench-size 1.0]
                                  [--bench-repeats 5] [--out studies/output/calibration] [--figures studies/figures]
                                  [--csv]
    python studies/calibration.py --bench-only [--bench-size 1.0] [--bench-repeats 5]   # the cost per iteration
    python studies/calibration.py --model-error-only [--model-error-seeds 20] [--model-error-rows 8]
    python studies/calibration.py --hysteresis-only [--hysteresis-seeds 6]

The "real" finger is geometry/finger.toml with other material values than the
design file says (TRUE: silicone E 0.125 MPa instead of 0.1, flexor 16 N/mm
instead of 20, every ligament 1.3 N/mm instead of 1.0), measured in three
experiments on one lab rig (the design plus five pull points across the tip
and a force sensor, a ground plane, above it; each experiment a load path from
rest):

    tendon   the flexor contracted 1..8 mm: tip x, y and the flexor tension
    pull     the tip pulled along the finger by 1..5 N, the flexor's spool
             locked at zero contraction (it stretches with the finger): tip y
    push     the base driven 0.4..2 mm toward the sensor (before buckling):
             the sensor force and the tip x

Data are solved on a fine mesh (size_data) with Gaussian noise (tip 0.05 mm,
tension 0.02 N, sensor 0.005 N); the calibration fits silicone E, the flexor
stiffness and the ligament stiffness on a coarse mesh (size_fit) from
the design's values (the ligaments as one shared stiffness: a pattern key).
Reported: each experiment alone (what it can identify)
and all three together, the estimate's bias against the truth (coarse P1 at
nu = 0.45 locks, so E comes out low), and the same fit on the fine mesh
itself (the bias is the mesh's, not the method's).

Coverage: `seeds` noisy copies of the tendon experiment generated on the fit
mesh (no discretisation bias): how often the 95 % interval holds the truth,
and the spread of the estimates against the reported std.

Bench: the cost of one Levenberg-Marquardt iteration (every row solved, with
its sensitivities) for 2 and for 20 fitted parameters (bench_size).

Model error (--model-error-only): a thumb changed from the bundled one (nu 0.40,
so not a design of the repository) measured on a 1.25 mm P2 mesh (truth E 0.065
MPa, flexor 11 N/mm; tip sigma 0.1 mm, tension 0.05 N), fitted on 2.5 mm P1
from the design's values with --model-error inflate and ignore, over seeded
noise: how often each 95 % interval holds the truth, the mean bias against the
mean reported std; studies/output/calibration/model_error.json.

Hysteresis (--hysteresis-only): finger_friction.toml changed (nu 0.42, a 15
N/mm tendon, 4 mm mesh), one loop of the contraction 1 -> 8 -> 1 mm (15 rows:
tip and tension, noise 0.05 mm and 0.02 N) with the tendon's friction 0.2,
the coefficient fitted from 0.1 per seed; studies/output/calibration/hysteresis.json.

run(**params) returns the numbers; main(argv) also writes
studies/output/calibration/{calibration,coverage,bench}.json and
studies/figures/calibration.png, and with --csv the bundled example
geometry/finger_calibration.csv (the tendon experiment's data on finger.toml).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FINGER = ROOT / "geometry" / "finger.toml"
LIGAMENTS = ("lig1_palmar", "lig1_dorsal", "lig2_palmar", "lig2_dorsal")
TRUE = {"materials.ecoflex.E": 0.125, "cables.flexor.stiffness": 16.0, "cables.lig*.stiffness": 1.3}
FIT = list(TRUE)          # the four ligaments: one shared stiffness (one rubber band stock)
NOISE = {"markers.*": 0.05, "cables.flexor.tension": 0.02, "grounds.fsr.force.y": 0.005}
PULL_POINTS = 5
# the model's own error: a thumb changed from the bundled one (nu 0.40), its data on a finer P2 mesh
THUMB = ROOT / "geometry" / "thumb.toml"
THUMB_SET = ["materials.ecoflex.nu=0.40"]
THUMB_TRUE = {"materials.ecoflex.E": 0.065, "cables.flexor.stiffness": 11.0}
THUMB_COLUMNS = ["markers.tip.x", "markers.tip.y", "cables.flexor.tension"]
THUMB_NOISE = {"markers.*": 0.1, "cables.flexor.tension": 0.05}
THUMB_DATA = (1.25, 2)                  # the data's mesh size and degree (the fit's: 2.5 mm, P1)
FAR = 1.0e4                    # the sensor's y when it is not in use, mm
BENCH20 = ["materials.ecoflex.E", "materials.ecoflex.nu", "materials.pla.E", "materials.pla.nu",
           "cables.flexor.stiffness", *[f"cables.{n}.stiffness" for n in LIGAMENTS],
           *[f"cables.{n}.pretension" for n in LIGAMENTS], "cables.flexor.contraction",
           "materials.ecoflex.density", "materials.pla.density", "gravity.acceleration.x",
           "gravity.acceleration.y", "pins.base.move.x", "pins.base.move.y"]


def true_values() -> dict:
    """TRUE with the ligament pattern spelt out: {--set key: value}."""
    out = {k: v for k, v in TRUE.items() if "*" not in k}
    out.update({f"cables.{n}.stiffness": TRUE["cables.lig*.stiffness"] for n in LIGAMENTS})
    return out


def rig(size: float, gravity: bool = False):
    """The lab rig: finger.toml with five pull points at the tip and a force sensor (parked far away)."""
    from skelfem.design import load_design, parse_design
    raw = load_design(FINGER, [f"mesh.size={size}"]).raw
    xs = np.linspace(4.0, 16.0, PULL_POINTS)
    raw["loads"] = [{"name": f"pull{i}", "at": [float(x), 96.0], "force": [0.0, 0.0]} for i, x in enumerate(xs)]
    raw["grounds"] = [{"name": "fsr", "point": [10.0, FAR], "normal": [float(np.sin(np.radians(-1.0))),
                                                                    -float(np.cos(np.radians(-1.0)))],
                       "stiffness": 10.0}]
    if gravity:
        raw["gravity"] = {"acceleration": [0.0, -9.81]}
    return parse_design(raw, str(FINGER))


def experiments(rows: int = 6) -> dict:
    """Conditions, experiment labels and measured columns of the three experiments (one table)."""
    n = int(rows)
    tendon = np.linspace(1.0, 8.0, n)
    pull = np.linspace(1.0, 5.0, n)
    push = np.linspace(0.4, 2.0, n)
    z = np.zeros(n)
    cond = {"cables.flexor.contraction": np.r_[tendon, z, z],
            **{f"loads.pull{i}.force.y": np.r_[z, pull / PULL_POINTS, z] for i in range(PULL_POINTS)},
            "grounds.fsr.point.y": np.r_[np.full(2 * n, FAR), np.full(n, 100.5)],
            "pins.base.move.y": np.r_[z, z, push]}
    labels = ["tendon"] * n + ["pull"] * n + ["push"] * n
    measured = {"tendon": ["markers.tip.x", "markers.tip.y", "cables.flexor.tension"],
                "pull": ["markers.tip.y"], "push": ["markers.tip.x", "grounds.fsr.force.y"]}
    return {"conditions": cond, "experiments": labels, "measured": measured}


def measure(size: float, rows: int, rng, noise: bool = True) -> dict:
    """The "real" finger's data on a mesh of `size`: {column: values} with NaN where not measured."""
    from skelfem import Session
    from skelfem.analysis.calibrate import synthesize
    ex = experiments(rows)
    cols = sorted({c for cs in ex["measured"].values() for c in cs})
    with Session(rig(size)) as s:
        s.set(true_values())
        data = synthesize(s, ex["conditions"], cols, ex["experiments"], NOISE if noise else None, rng)
    for j, lab in enumerate(ex["experiments"]):
        for c in cols:
            if c not in ex["measured"][lab]:
                data[c][j] = np.nan
    return data


def subset(data: dict, labels) -> dict:
    keep = np.isin(np.array(data["experiment"]), list(labels))
    return {k: (np.asarray(v)[keep] if not isinstance(v, list) else [x for x, m in zip(v, keep) if m])
            for k, v in data.items() if k == "experiment" or np.isfinite(np.asarray(v, float)[keep]).any()}


def fit(size: float, data: dict, keys, sigma=NOISE, model_error: str = "ignore") -> dict:
    """Calibrate `keys` on the rig at `size` from the design's values; the numbers. model_error: "ignore"
    (these parts measure the bias a fit absorbs; --model-error-only measures what inflate does)."""
    from fnmatch import fnmatchcase

    from skelfem import Session, calibrate
    sigma = {pat: v for pat, v in sigma.items() if any(fnmatchcase(c, pat) for c in data)}
    with Session(rig(size)) as s:
        cal = calibrate(s, data, keys, sigma=sigma, model_error=model_error)
    out = cal.to_dict()
    for k in keys:
        p = out["parameters"][k]
        p["true"] = TRUE.get(k)
        p["bias"] = p["value"] / TRUE[k] - 1.0 if k in TRUE else None
        p["covered"] = bool(p["ci95"] and p["ci95"][0] <= TRUE[k] <= p["ci95"][1]) if k in TRUE else None
    out["model_values"] = cal.model_values.tolist()
    out["data_values"] = cal.data.values.tolist()
    out["columns"] = cal.columns
    out["experiments"] = cal.data.experiments
    return out


def coverage(size: float, seeds: int, rows: int) -> dict:
    """Noisy tendon data generated on the fit mesh: CI coverage and spread of E and the flexor stiffness."""
    from skelfem import Session, calibrate
    from skelfem.analysis.calibrate import synthesize
    keys = ["materials.ecoflex.E", "cables.flexor.stiffness"]
    cols = ["markers.tip.x", "markers.tip.y", "cables.flexor.tension"]
    sigma = {"markers.*": 0.2, "cables.flexor.tension": 0.05}
    true = np.array([TRUE[k] for k in keys])
    with Session(FINGER, [f"mesh.size={size}"]) as s:
        s.set(dict(zip(keys, true)))
        clean = synthesize(s, {"cables.flexor.contraction": np.linspace(1.0, 8.0, rows)}, cols)
        s.set({k: v for k, v in zip(keys, [0.1, 20.0])})
        est, std, inside, its = [], [], [], []
        for seed in range(seeds):
            rng = np.random.default_rng(1000 + seed)
            data = {k: (v + rng.normal(0.0, 0.2 if k.startswith("markers") else 0.05, rows)
                        if k in cols else v) for k, v in clean.items()}
            cal = calibrate(s, data, keys, sigma=sigma, model_error="ignore")      # data of the fit's own mesh
            est.append(cal.values)
            std.append(cal.std)
            inside.append((cal.ci95[:, 0] <= true) & (true <= cal.ci95[:, 1]))
            its.append(cal.iterations)
    est, std, inside = np.array(est), np.array(std), np.array(inside)
    spread = est.std(axis=0, ddof=1) if seeds > 1 else np.full(len(keys), np.nan)
    return {"keys": keys, "true": true.tolist(), "seeds": seeds, "rows": rows,
            "inside_fraction": float(inside.mean()), "inside_per_parameter": inside.mean(axis=0).tolist(),
            "spread": spread.tolist(), "mean_std": std.mean(axis=0).tolist(),
            "spread_over_std": (spread / std.mean(axis=0)).tolist(),
            "mean_bias": (est.mean(axis=0) / true - 1).tolist(), "iterations_max": int(max(its)),
            "estimates": est.tolist(), "std": std.tolist()}


def thumb_data(rows: int, size: float = THUMB_DATA[0], degree: int = THUMB_DATA[1]) -> dict:
    """The changed thumb's noise-free measurements at THUMB_TRUE on a mesh of `size` and `degree`."""
    from skelfem import Session
    from skelfem.analysis.calibrate import synthesize
    with Session(THUMB, THUMB_SET + [f"mesh.size={size}", f"mesh.degree={degree}"]) as s:
        s.set(THUMB_TRUE)
        return synthesize(s, {"cables.flexor.contraction": np.linspace(0.8, 8.0, rows)}, THUMB_COLUMNS)


def model_error_coverage(seeds: int, rows: int = 10, modes=("inflate", "ignore"), size_fit: float = 2.5,
                         data_mesh=None, first_seed: int = 0) -> dict:
    """Coverage with the model's own error: the changed thumb's data on a finer P2 mesh plus noise, the fit
    on a coarse P1 mesh from the design's values, with each --model-error mode: how often the 95 %
    interval holds the truth, the mean bias against the mean reported std, the model error / sigma.
    Seeds first_seed ... first_seed + seeds - 1 (merge() joins runs over other seeds)."""
    from skelfem import Session, calibrate
    keys = list(THUMB_TRUE)
    clean = thumb_data(rows, *(data_mesh or THUMB_DATA))
    out = {"keys": keys, "true": [THUMB_TRUE[k] for k in keys], "seeds": seeds, "rows": rows,
           "noise": THUMB_NOISE, "design": f"thumb.toml with {', '.join(THUMB_SET)}",
           "data_mesh": list(data_mesh or THUMB_DATA), "fit_mesh": [size_fit, 1], "modes": {}}
    with Session(THUMB, THUMB_SET + [f"mesh.size={size_fit}", "mesh.degree=1"]) as s:
        out["fit_dofs"] = s.dofs
        for mode in modes:
            runs, t0 = [], time.perf_counter()
            for seed in range(first_seed, first_seed + seeds):
                rng = np.random.default_rng(2000 + seed)
                data = {k: (v + rng.normal(0.0, THUMB_NOISE["markers.*" if k.startswith("markers") else k], rows)
                            if k in THUMB_COLUMNS else v) for k, v in clean.items()}
                cal = calibrate(s, data, keys, sigma=THUMB_NOISE, model_error=mode)
                runs.append({"seed": seed, "values": cal.values.tolist(), "std": cal.std.tolist(),
                             "ci95": cal.ci95.tolist(), "max_over_sigma": cal.model_error["max_over_sigma"],
                             "corrections": cal.model_error["corrections"], "iterations": cal.iterations,
                             "converged": bool(cal.converged)})
            out["modes"][mode] = {"runs": runs, "seconds": time.perf_counter() - t0}
    return summarise(out)


def summarise(out: dict) -> dict:
    """Each mode's coverage numbers from its runs: truth inside the 95 % interval (count per parameter),
    mean bias, mean reported std and their ratio, relative bias."""
    true = np.array(out["true"])
    for v in out["modes"].values():
        runs = v["runs"]
        est = np.array([r["values"] for r in runs])
        std = np.array([r["std"] for r in runs])
        ci = np.array([r["ci95"] for r in runs])
        inside = (ci[:, :, 0] <= true) & (true <= ci[:, :, 1])
        bias = est.mean(axis=0) - true
        v.update({"seeds": len(runs), "inside": inside.sum(axis=0).tolist(),
                  "inside_fraction": inside.mean(axis=0).tolist(), "mean_bias": bias.tolist(),
                  "mean_relative_bias": (bias / true).tolist(), "mean_std": std.mean(axis=0).tolist(),
                  "bias_over_std": (np.abs(bias) / std.mean(axis=0)).tolist(),
                  "model_error_over_sigma_max": float(max(r["max_over_sigma"] for r in runs)),
                  "iterations_max": int(max(r["iterations"] for r in runs)),
                  "corrections_max": int(max(r["corrections"] for r in runs)),
                  "converged": int(sum(r["converged"] for r in runs))})
    out["seeds"] = max(len(v["runs"]) for v in out["modes"].values())
    return out


def merge(parts) -> dict:
    """One model_error_coverage result from runs over disjoint seeds (their runs joined per mode)."""
    out = {k: v for k, v in parts[0].items() if k != "modes"}
    out["modes"] = {}
    for part in parts:
        for mode, v in part["modes"].items():
            m = out["modes"].setdefault(mode, {"runs": [], "seconds": 0.0})
            m["runs"] += v["runs"]
            m["seconds"] += v["seconds"]
    for m in out["modes"].values():
        m["runs"].sort(key=lambda r: r["seed"])
    return summarise(out)


FRICTION = ROOT / "geometry" / "finger_friction.toml"
FRICTION_SET = ["materials.ecoflex.nu=0.42", "cables.flexor.stiffness=15"]      # not the bundled design
FRICTION_NOISE = {"markers.*": 0.05, "cables.flexor.tension": 0.02}


def hysteresis(seeds: int, size: float = 4.0, first_seed: int = 0, true: float = 0.2, start: float = 0.1) -> dict:
    """A cable's friction from one loading/unloading loop (contraction 1 -> 8 -> 1 mm, 15 rows: tip x, y and
    the tension) of the changed finger_friction design with mu = true plus seeded noise, fitted from start on
    the same mesh: the estimate, its interval, whether it holds the truth, per seed."""
    from skelfem import Session, calibrate
    from skelfem.analysis.calibrate import synthesize
    loop = np.r_[np.linspace(1.0, 8.0, 8), np.linspace(7.0, 1.0, 7)]
    cols = ["markers.tip.x", "markers.tip.y", "cables.flexor.tension"]
    runs = []
    for seed in range(first_seed, first_seed + seeds):
        with Session(FRICTION, FRICTION_SET + [f"mesh.size={size}", f"cables.flexor.friction={true}"]) as s:
            data = synthesize(s, {"cables.flexor.contraction": loop}, cols, noise=FRICTION_NOISE,
                              rng=np.random.default_rng(3000 + seed))
            s.set({"cables.flexor.friction": start})
            t0 = time.perf_counter()
            cal = calibrate(s, data, ["cables.flexor.friction"], sigma=FRICTION_NOISE, model_error="ignore")
        lo, hi = (float(v) for v in cal.ci95[0])
        runs.append({"seed": seed, "mu": float(cal.values[0]), "ci95": [lo, hi], "inside": lo <= true <= hi,
                     "relative_error": float(cal.values[0] / true - 1), "iterations": cal.iterations,
                     "converged": bool(cal.converged), "seconds": time.perf_counter() - t0})
    return {"true": true, "start": start, "size": size, "rows": len(loop), "noise": FRICTION_NOISE,
            "design": f"finger_friction.toml with {', '.join(FRICTION_SET)}", "runs": runs,
            "max_relative_error": max(abs(r["relative_error"]) for r in runs),
            "inside": sum(r["inside"] for r in runs)}


def bench(size: float, rows: int = 8, counts=(2, 20), repeats: int = 5) -> dict:
    """Seconds per LM iteration (every row solved with its sensitivities) against the number of parameters."""
    from skelfem import Session
    from skelfem.analysis.caldata import prepare_data
    from skelfem.analysis.calibrate import Rows, synthesize
    cols = ["markers.tip.x", "markers.tip.y", "cables.flexor.tension"]
    out = {"size": size, "rows": rows, "columns": cols, "per_iteration": {}, "solves_only": {}}
    with Session(rig(size, gravity=True)) as s:
        out["dofs"] = s.dofs
        data = synthesize(s, {"cables.flexor.contraction": np.linspace(1.0, 8.0, rows)}, cols)
        runs = {}
        for n in counts:
            prepared = prepare_data(s.design, data, BENCH20[:n])
            r = Rows(s, prepared)
            theta = np.array([p.initial for p in prepared.parameters])
            r.states = r.run(theta)[2]
            runs[n] = (r, theta, theta * 1e-3 + 1e-3 * (theta == 0), [], [])
        for k in range(repeats):             # interleaved, the minimum of each: a shared machine's noise
            for n, (r, theta, step, times, plain) in runs.items():
                t = time.perf_counter()
                r.run(theta + (k + 1) * step)
                times.append(time.perf_counter() - t)
                t = time.perf_counter()
                r.run(theta + (k + 1) * step, jacobian=False)
                plain.append(time.perf_counter() - t)
        for n, (_, _, _, times, plain) in runs.items():
            out["per_iteration"][str(n)] = min(times)
            out["solves_only"][str(n)] = min(plain)
    a, b = (out["per_iteration"][str(n)] for n in (counts[0], counts[-1]))
    out["ratio"] = b / a
    return out


def run(size_data: float = 1.0, size_fit: float = 2.0, rows: int = 6, seeds: int = 20, coverage_rows: int = 8,
        coverage_size: float | None = None, bench_size: float | None = 1.0, seed: int = 0,
        bench_repeats: int = 5) -> dict:
    """Every part of the study; returns its numbers (nothing written)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    data = measure(size_data, rows, rng)
    parts = {"tendon": (["tendon"], ["materials.ecoflex.E", "cables.flexor.stiffness"]),
             "pull": (["pull"], ["materials.ecoflex.E", "cables.lig*.stiffness"]),
             "push": (["push"], ["materials.ecoflex.E"]),
             "all": (["tendon", "pull", "push"], FIT)}
    fits = {}
    for name, (labels, keys) in parts.items():
        fits[name] = fit(size_fit, subset(data, labels), keys)
    exact = fit(size_data, measure(size_data, rows, rng, noise=False), FIT)      # same mesh, no noise
    res = {"params": dict(size_data=size_data, size_fit=size_fit, rows=rows, seeds=seeds, seed=seed,
                          noise=NOISE, true=TRUE),
           "data": {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in data.items()},
           "fits": fits, "same_mesh_noise_free": exact}
    res["coverage"] = coverage(coverage_size or size_fit, seeds, coverage_rows) if seeds else None
    res["bench"] = bench(bench_size, repeats=bench_repeats) if bench_size else None
    res["time"] = time.perf_counter() - t0
    return res


# -- files ------------------------------------------------------------------------------------------------
def figure(path: Path, res: dict) -> None:
    """calibration.png: the joint fit against the data, the bias per parameter, the coverage."""
    from matplotlib.figure import Figure

    from skelfem.io.files import atomic_write
    fig = Figure(figsize=(13, 4.2), dpi=110)
    ax, bx, cx = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1.4, 1.2, 1]})
    f = res["fits"]["all"]
    Y, D = np.array(f["model_values"]), np.array(f["data_values"], float)
    labels = np.array(f["experiments"])
    colors = {"tendon": "#4c72b0", "pull": "#55a868", "push": "#c44e52"}
    for col, marker in (("markers.tip.y", "o"), ("markers.tip.x", "s")):
        j = f["columns"].index(col)
        for lab, c in colors.items():
            m = (labels == lab) & np.isfinite(D[:, j])
            if m.any():
                x = np.flatnonzero(labels == lab)
                x = np.flatnonzero(m) - x[0] + 1
                ax.plot(x, Y[m, j] - D[m, j], marker + "-", color=c, ms=4, lw=0.8,
                        label=f"{lab}: {col.split('.')[-1]}")
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xlabel("row of the experiment")
    ax.set_ylabel("model - data, tip [mm]")
    ax.set_title(f"joint fit on h = {res['params']['size_fit']:g} mm, data on h = {res['params']['size_data']:g}",
                 fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    keys = list(f["parameters"])
    short = [k.replace("materials.", "").replace("cables.", "").replace(".stiffness", " k") for k in keys]
    for i, (name, mk, dx) in enumerate((("all", "o", -0.15), ("same_mesh_noise_free", "x", 0.15))):
        p = (res["fits"][name] if name in res["fits"] else res[name])["parameters"]
        b = [100 * p[k]["bias"] for k in keys]
        err = [100 * p[k]["std"] / p[k]["true"] if p[k]["std"] else 0 for k in keys]
        bx.errorbar(np.arange(len(keys)) + dx, b, yerr=1.96 * np.array(err), fmt=mk, capsize=3,
                    label="coarse fit, noisy fine data" if i == 0 else "fine fit, noise-free")
    bx.axhline(0, color="k", lw=0.6)
    bx.set_xticks(range(len(keys)), short, rotation=30, fontsize=7, ha="right")
    bx.set_ylabel("estimate / truth - 1 [%] (95 % interval)")
    bx.set_title("bias of the joint fit", fontsize=9)
    bx.legend(fontsize=7)
    cov = res.get("coverage")
    if cov:
        est, std = np.array(cov["estimates"]), np.array(cov["std"])
        t = cov["true"][0]
        order = np.arange(len(est))
        cx.errorbar(order, est[:, 0] / t, yerr=1.96 * std[:, 0] / t, fmt="o", ms=3, capsize=2)
        cx.axhline(1.0, color="k", lw=0.6)
        cx.set_xlabel("noise seed")
        cx.set_ylabel("silicone E / truth (95 % interval)")
        cx.set_title(f"coverage {100 * cov['inside_fraction']:.0f} %, spread/std "
                     + ", ".join(f"{v:.2f}" for v in cov["spread_over_std"]), fontsize=9)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


def example_csv(path: Path, size: float = 1.0, rows: int = 8, seed: int = 7) -> None:
    """geometry/finger_calibration.csv: the tendon experiment on finger.toml, fine mesh, noisy."""
    from skelfem import Session
    from skelfem.analysis.calibrate import synthesize
    from skelfem.io.files import write_text
    cols = ["markers.tip.x", "markers.tip.y", "cables.flexor.tension"]
    with Session(FINGER, [f"mesh.size={size}"]) as s:
        s.set(true_values())
        d = synthesize(s, {"cables.flexor.contraction": np.linspace(1.0, 8.0, rows)}, cols,
                       noise={"markers.*": 0.05, "cables.flexor.tension": 0.02}, rng=np.random.default_rng(seed))
    header = ["cables.flexor.contraction"] + cols
    lines = [",".join(header)] + [",".join(f"{float(d[h][i]):.4f}" for h in header) for i in range(rows)]
    write_text(path, "\n".join(lines) + "\n")


def _bench_line(b: dict) -> str:
    return (f"bench ({b['dofs']} DOFs, {b['rows']} rows): "
            + ", ".join(f"{n} parameters {t:.3f} s" for n, t in b["per_iteration"].items())
            + f" per iteration (x{b['ratio']:.2f}); solves alone "
            + ", ".join(f"{t:.3f} s" for t in b["solves_only"].values()))


def main(argv=None) -> int:
    from skelfem.io.files import say, write_json
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "calibration")
    p.add_argument("--figures", type=Path, default=ROOT / "studies" / "figures")
    p.add_argument("--size-data", type=float, default=1.0)
    p.add_argument("--size-fit", type=float, default=2.0)
    p.add_argument("--rows", type=int, default=6, help="rows per experiment")
    p.add_argument("--seeds", type=int, default=20)
    p.add_argument("--bench-size", type=float, default=1.0, help="mesh size of the bench (0: no bench)")
    p.add_argument("--bench-repeats", type=int, default=5, help="timings per parameter count (the minimum is kept)")
    p.add_argument("--csv", action="store_true", help="also write geometry/finger_calibration.csv")
    p.add_argument("--bench-only", action="store_true", help="only time an iteration for 2 and 20 parameters")
    p.add_argument("--model-error-only", action="store_true",
                   help="only the coverage with the model's own error (the changed thumb)")
    p.add_argument("--model-error-seeds", type=int, default=20)
    p.add_argument("--model-error-rows", type=int, default=8)
    p.add_argument("--hysteresis-only", action="store_true",
                   help="only a cable's friction from a loading/unloading loop (changed finger_friction)")
    p.add_argument("--hysteresis-seeds", type=int, default=6)
    a = p.parse_args(argv)
    if a.hysteresis_only:
        h = hysteresis(a.hysteresis_seeds)
        a.out.mkdir(parents=True, exist_ok=True)
        write_json(a.out / "hysteresis.json", h)
        say(f"mu {h['true']:g} from {h['start']:g}: " + ", ".join(f"{r['mu']:.4f}" for r in h["runs"])
            + f"; largest error {100 * h['max_relative_error']:.1f} %, truth inside {h['inside']} of {len(h['runs'])}")
        return 0
    if a.model_error_only:
        m = model_error_coverage(a.model_error_seeds, a.model_error_rows)
        a.out.mkdir(parents=True, exist_ok=True)
        write_json(a.out / "model_error.json", m)
        for mode, v in m["modes"].items():
            say(f"{mode}: inside {v['inside']} of {v['seeds']}; bias / std "
                + ", ".join(f"{b:.2f}" for b in v["bias_over_std"])
                + "; relative bias " + ", ".join(f"{100 * b:+.1f} %" for b in v["mean_relative_bias"]))
        say(f"wrote {a.out / 'model_error.json'}")
        return 0
    if a.bench_only:
        b = bench(a.bench_size or 1.0, repeats=a.bench_repeats)
        say(_bench_line(b))
        return 0
    res = run(size_data=a.size_data, size_fit=a.size_fit, rows=a.rows, seeds=a.seeds,
              bench_size=a.bench_size or None, bench_repeats=a.bench_repeats)
    a.out.mkdir(parents=True, exist_ok=True)
    write_json(a.out / "calibration.json", {k: v for k, v in res.items() if k not in ("coverage", "bench")})
    if res["coverage"]:
        write_json(a.out / "coverage.json", res["coverage"])
    if res["bench"]:
        write_json(a.out / "bench.json", res["bench"])
    figure(a.figures / "calibration.png", res)
    for name, f in list(res["fits"].items()) + [("same mesh", res["same_mesh_noise_free"])]:
        say(f"{name}: {f['iterations']} iterations, {f['status']}; unidentifiable {f['unidentifiable'] or 'none'}")
        for k, q in f["parameters"].items():
            std = f"{q['std']:.3g}" if q["std"] is not None else "-"
            say(f"  {k:32s} {q['value']:.5g} +- {std}  (truth {q['true']:g}, bias {100 * q['bias']:+.2f} %)")
    c = res["coverage"]
    if c:
        say(f"coverage over {c['seeds']} seeds: {100 * c['inside_fraction']:.0f} % inside the 95 % intervals; "
            f"spread / std = {', '.join(f'{v:.2f}' for v in c['spread_over_std'])}")
    if res["bench"]:
        say(_bench_line(res["bench"]))
    if a.csv:
        example_csv(ROOT / "geometry" / "finger_calibration.csv", size=a.size_data)
        say("wrote geometry/finger_calibration.csv")
    say(f"wrote {a.out}/ and {a.figures / 'calibration.png'} in {res['time']:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
