"""Cable friction: the finger's hysteresis loop over a contraction cycle, and the push test driven down and back.

    python studies/cable_friction.py [--out studies/output/cable_friction] [--size 2] [--top 8] [--steps 8]
                                     [--mu 0 0.1 0.3] [--width-mu 0 0.05 0.1 0.2 0.3] [--width-steps 8]
                                     [--push-mu 0 0.1 0.3] [--pre 2] [--travel 6] [--push-steps 24]

geometry/finger.toml, its flexor with Coulomb friction ``friction = mu``
against its channel at every via point (skelfem.terms.cable_slip; the
ligaments keep friction 0). Three parts:

a. Contraction cycle. One Session per mu: a solve at rest, then the flexor's
   contraction goes 0 -> `top` mm in `steps` equal steps and back to 0 in as
   many (``s.set({"cables.flexor.contraction": c})`` + ``s.solve()``: every
   step a warm re-solve from the last equilibrium, its friction history
   kept). Recorded per step: the tip marker (x, y), the tension at the
   actuated end (first segment) and at the far end (last segment, in the
   distal bone). Pulling, friction holds tension back from the far end
   (T_far < T_actuated); paying out, it holds it in (T_far > T_actuated).
   With the contraction imposed, the tip is further palmar than without
   friction on the way up and less on the way down.
b. Push test (paper Figs. 7/8; studies/push_test.py pushes the same finger
   with its flexor removed). Here the flexor stays, held at a fixed length,
   and the base is driven up to `travel` mm into the sensor and back to 0 in
   `push_steps` steps each way (``pins.base.move`` set live per step). Held at
   contraction 0 the flexor carries no tension in this test: it is exactly
   its rest length at rest, and the axial push shortens the finger and
   bends it to the palmar side, where the tendon runs, so its path only gets
   shorter and it goes slack; a slack cable has no friction to give. So the
   flexor is first pre-contracted by `pre` mm (default 2: about 1.2-1.3 N
   at rest) and held at that length while the base moves. The push takes
   that up too: the flexor stays taut for the first ~1.75 mm of travel (the
   sensor is touched after 0.5 mm) and is slack beyond, so the force loop
   lies in the first 2 mm and above them every mu gives the same force (a
   larger `pre` keeps it taut longer but bends the finger before the push).
   The sensor and its 1 degree tilt are push_test's (push_test.add_sensor,
   place_sensor, sensor_force).
c. Loop width against mu: the largest difference of tip x between the up and
   down branches of part a at the same contraction, for each mu in
   `width_mu` (cycles of `width_steps` steps each way for the mu values not
   already run in part a).

run(**params) returns the numbers; main(argv) also writes into out:
cable_friction.json (everything), cable_friction_cycle.csv and
cable_friction_push.csv (one row per solve), cable_friction.png (tip x and
tensions over the cycle), cable_friction_push.png (sensor force and flexor
tension against travel, both ways) and cable_friction_width.png (loop width
against mu).
"""
from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "finger.toml"
CABLE = "flexor"
COLORS = ("#4c72b0", "#dd8452", "#55a868", "#c44e52", "#8172b2", "#937860")


def _push_test():
    """studies/push_test.py (a script, not a package): its sensor and its drive."""
    spec = importlib.util.spec_from_file_location("push_test", Path(__file__).resolve().parent / "push_test.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def design(mu: float, size: float | None, contraction: float = 0.0) -> dict:
    """finger.toml as a dict: the flexor with friction mu at `contraction` mm (ligaments unchanged)."""
    from skelfem.design import load_design

    raw = load_design(DESIGN, [f"mesh.size={size}"] if size else []).raw
    raw["cables"] = [dict(c, friction=float(mu), contraction=float(contraction)) if c["name"] == CABLE else dict(c)
                     for c in raw["cables"]]
    return raw


def _session(raw: dict):
    from skelfem import Session
    from skelfem.design import parse_design
    return Session(parse_design(raw, str(DESIGN)))


def _state(r) -> dict:
    """Tip, the flexor's two end tensions and how many of its via points slipped, from a converged Result."""
    c = r.to_dict()["cables"][CABLE]
    tip = r.marker("tip")
    return {"tip_x": float(tip[0]), "tip_y": float(tip[1]), "tension_actuated": float(c["tensions"][0]),
            "tension_far": float(c["tensions"][-1]), "slipping": int(sum(c["slipping"])),
            "via_points": len(c["slipping"])}


# -- a: the contraction cycle ------------------------------------------------------------------------
def cycle(mu: float, top: float = 8.0, steps: int = 8, size: float | None = 2.0) -> dict:
    """One Session: rest, contraction 0 -> top -> 0 in `steps` steps each way; one row per solve."""
    t0 = time.perf_counter()
    out = {"mu": float(mu), "top": float(top), "steps": int(steps), "rows": [], "status": "converged"}
    with _session(design(mu, size)) as s:
        out["dofs"] = s.dofs
        r = s.solve()
        plan = [("rest", 0.0)] + [("up", top * k / steps) for k in range(1, steps + 1)] + \
               [("down", top * k / steps) for k in range(steps - 1, -1, -1)]
        for i, (branch, c) in enumerate(plan):
            if i > 0:
                s.set({f"cables.{CABLE}.contraction": c})
                r = s.solve()
            if not r.converged:                      # a failed solve is never an equilibrium
                out["status"] = f"{branch} {c:g} mm: {r.status}"
                break
            out["rows"].append(dict(branch=branch, contraction=c, newton_iterations=r.report.newton_iterations,
                                    **_state(r)))
    out["time"] = time.perf_counter() - t0
    out["newton_iterations"] = sum(row["newton_iterations"] for row in out["rows"])
    out["loop_width"], out["loop_width_at"] = loop_width(out["rows"])
    full = [row for row in out["rows"] if row["branch"] == "up" and row["contraction"] == top]
    out["full"] = {k: full[0][k] for k in ("tip_x", "tip_y", "tension_actuated", "tension_far")} if full else None
    return out


def loop_width(rows: list) -> tuple[float, float]:
    """(largest |tip x up - tip x down| at the same contraction, where); the rest point counts as up."""
    up = {row["contraction"]: row["tip_x"] for row in rows if row["branch"] in ("rest", "up")}
    down = {row["contraction"]: row["tip_x"] for row in rows if row["branch"] == "down"}
    both = sorted(set(up) & set(down))
    if not both:
        return float("nan"), float("nan")
    gaps = [abs(up[c] - down[c]) for c in both]
    k = int(np.argmax(gaps))
    return float(gaps[k]), float(both[k])


# -- b: the push test, down and back ------------------------------------------------------------------
def push_cycle(mu: float, size: float | None = 2.0, travel: float = 6.0, steps: int = 12, pre: float = 2.0,
               gap: float = 0.5, stiffness: float = 10.0, tilt_deg: float = -1.0) -> dict:
    """The flexor pre-contracted by `pre` mm and held; the base driven 0 -> travel -> 0 into the sensor."""
    pt = _push_test()
    t0 = time.perf_counter()
    out = {"mu": float(mu), "pre": float(pre), "travel_max": float(travel), "steps": int(steps), "rows": [],
           "status": "converged"}
    raw = design(mu, size, contraction=pre)
    pt.add_sensor(raw, gap, stiffness, tilt_deg)
    with _session(raw) as s:
        r = s.solve()                                          # the flexor taut, the base at rest
        plan = [("rest", 0.0)] + [("up", travel * k / steps) for k in range(1, steps + 1)] + \
               [("down", travel * k / steps) for k in range(steps - 1, -1, -1)]
        for i, (branch, t) in enumerate(plan):
            if i == 0 and r.converged:
                pt.place_sensor(s.model, gap)                  # `gap` above the pre-bent tip
            elif i > 0:
                s.set({"pins.base.move": [0.0, t]})
                r = s.solve()
            if not r.converged:
                out["status"] = f"{branch} {t:g} mm: {r.status}"
                break
            out["rows"].append(dict(branch=branch, travel=t, force=pt.sensor_force(s.model),
                                    newton_iterations=r.report.newton_iterations, **_state(r)))
    out["time"] = time.perf_counter() - t0
    out["newton_iterations"] = sum(row["newton_iterations"] for row in out["rows"])
    f = [row["force"] for row in out["rows"]]
    out["peak_force"] = max(f) if f else float("nan")
    up = {row["travel"]: row["force"] for row in out["rows"] if row["branch"] in ("rest", "up")}
    down = {row["travel"]: row["force"] for row in out["rows"] if row["branch"] == "down"}
    both = sorted(set(up) & set(down))
    out["force_gap"] = max((abs(up[t] - down[t]) for t in both), default=float("nan"))
    return out


# -- the study ------------------------------------------------------------------------------------------
def run(size: float | None = 2.0, top: float = 8.0, steps: int = 8, mus=(0.0, 0.1, 0.3),
        width_mus=(0.0, 0.05, 0.1, 0.2, 0.3), width_steps: int | None = None, push_mus=(0.0, 0.1, 0.3),
        pre: float = 2.0, travel: float = 6.0, push_steps: int = 24, out: Path | None = None) -> dict:
    """Parts a, b and c; writes JSON, CSV and PNG files into out if given."""
    mus = sorted(float(m) for m in mus)
    cycles = {mu: cycle(mu, top, steps, size) for mu in mus}
    widths = {}
    for mu in sorted(float(m) for m in width_mus):
        c = cycles.get(mu)
        if c is None or (width_steps and width_steps != steps):
            c = cycle(mu, top, width_steps or steps, size)
        widths[mu] = {"loop_width": c["loop_width"], "at": c["loop_width_at"], "steps": c["steps"],
                      "status": c["status"], "newton_iterations": c["newton_iterations"], "time": c["time"],
                      "full": c["full"]}
    pushes = {float(mu): push_cycle(float(mu), size, travel, push_steps, pre) for mu in sorted(push_mus)}
    res = {"design": str(DESIGN.relative_to(ROOT)), "cable": CABLE,
           "params": dict(size=size, top=top, steps=steps, width_steps=width_steps or steps, pre=pre, travel=travel,
                          push_steps=push_steps),
           "cycles": [cycles[mu] for mu in mus], "widths": [dict(mu=mu, **w) for mu, w in widths.items()],
           "push": [pushes[mu] for mu in sorted(pushes)]}
    res["converged"] = all(c["status"] == "converged" for c in res["cycles"] + res["widths"] + res["push"])
    if out is not None:
        write_outputs(Path(out), res)
    return res


# -- files ----------------------------------------------------------------------------------------------
CYCLE_FIELDS = ["mu", "branch", "contraction", "tip_x", "tip_y", "tension_actuated", "tension_far", "slipping",
                "via_points", "newton_iterations"]
PUSH_FIELDS = ["mu", "branch", "travel", "force", "tip_x", "tip_y", "tension_actuated", "tension_far", "slipping",
               "via_points", "newton_iterations"]


def _label(ax, xlabel: str, ylabel: str, title: str, ncol: int = 1) -> None:
    """Axis labels, a title, a grid and (if anything is drawn) the legend."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if ax.lines:
        ax.legend(fontsize=7, ncol=ncol)


def _fig(path: Path, fig) -> None:
    from skelfem.io.files import atomic_write
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


def _branches(rows: list, x: str, y: str):
    """(x, y) of the up branch (from rest) and of the down branch (from the top)."""
    up = [r for r in rows if r["branch"] in ("rest", "up")]
    down = up[-1:] + [r for r in rows if r["branch"] == "down"]
    return ([r[x] for r in up], [r[y] for r in up]), ([r[x] for r in down], [r[y] for r in down])


def write_outputs(out: Path, res: dict) -> None:
    from matplotlib.figure import Figure

    from skelfem.io.files import write_csv, write_json

    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "cable_friction_cycle.csv", CYCLE_FIELDS,
              [dict(mu=c["mu"], **r) for c in res["cycles"] for r in c["rows"]])
    write_csv(out / "cable_friction_push.csv", PUSH_FIELDS,
              [dict(mu=p["mu"], **r) for p in res["push"] for r in p["rows"]])

    cycles = {c["mu"]: c for c in res["cycles"]}
    fig = Figure(figsize=(15, 4.4), dpi=110)
    ax, dx, bx = fig.subplots(1, 3)
    for color, c in zip(COLORS, res["cycles"]):
        (xu, yu), (xd, yd) = _branches(c["rows"], "contraction", "tip_x")
        ax.plot(xu, yu, "o-", ms=3, color=color, label=f"mu = {c['mu']:g}: up")
        ax.plot(xd, yd, "s--", ms=3, color=color, mfc="none", label=f"mu = {c['mu']:g}: down "
                f"(width {c['loop_width']:.2f} mm)")
        if 0.0 in cycles:                  # the loop, against the frictionless tip at the same contraction
            ref = {r["contraction"]: r["tip_x"] for r in cycles[0.0]["rows"]}
            for (x, y), style in ((_branches(c["rows"], "contraction", "tip_x")[0], "o-"),
                                  (_branches(c["rows"], "contraction", "tip_x")[1], "s--")):
                keep = [(a, b - ref[a]) for a, b in zip(x, y) if a in ref]
                dx.plot([a for a, _ in keep], [b for _, b in keep], style, ms=3, color=color,
                        mfc=None if style == "o-" else "none", label=f"mu = {c['mu']:g}" if style == "o-" else None)
        for key, style in (("tension_actuated", "o-"), ("tension_far", "s:")):
            xs = [r["contraction"] for r in c["rows"]]
            bx.plot(xs, [r[key] for r in c["rows"]], style, ms=3, color=color,
                    label=f"mu = {c['mu']:g}: {'actuated end' if key == 'tension_actuated' else 'far end'}")
    _label(ax, "flexor contraction [mm]", "tip x [mm]", "Tip over a contraction cycle (up: filled, down: open)")
    _label(dx, "flexor contraction [mm]", "tip x - tip x (mu = 0) [mm]",
           "The loop: tip x against the frictionless finger's")
    if not dx.lines:
        dx.set_axis_off()
    _label(bx, "flexor contraction [mm]", "flexor tension [N]", "Tension at both ends of the flexor, 0 - top - 0",
           ncol=2)
    _fig(out / "cable_friction.png", fig)

    fig = Figure(figsize=(15, 4.4), dpi=110)
    ax, dx, bx = fig.subplots(1, 3)
    for color, p in zip(COLORS, res["push"]):
        (xu, yu), (xd, yd) = _branches(p["rows"], "travel", "force")
        ax.plot(xu, yu, "o-", ms=3, color=color, label=f"mu = {p['mu']:g}: down onto the sensor")
        ax.plot(xd, yd, "s--", ms=3, color=color, mfc="none", label=f"mu = {p['mu']:g}: back")
        up = dict(zip(xu, yu))
        gap = sorted((t, f - up[t]) for t, f in zip(xd, yd) if t in up)
        dx.plot([t for t, _ in gap], [g for _, g in gap], "o-", ms=3, color=color, label=f"mu = {p['mu']:g}")
        (xu, yu), (xd, yd) = _branches(p["rows"], "travel", "tension_actuated")
        bx.plot(xu, yu, "o-", ms=3, color=color, label=f"mu = {p['mu']:g}: actuated end")
        bx.plot(xd, yd, "s--", ms=3, color=color, mfc="none")
        (xu, yu), (xd, yd) = _branches(p["rows"], "travel", "tension_far")
        bx.plot(xu + xd, yu + yd, ":", color=color, label=f"mu = {p['mu']:g}: far end")
    pre = res["params"]["pre"]
    _label(ax, "stage travel [mm]", "force on the sensor [N]", f"Push test, flexor held at {pre:g} mm contraction")
    _label(dx, "stage travel [mm]", "force back - force down [N]", "The force loop: way back against way down")
    _label(bx, "stage travel [mm]", "flexor tension [N]", "Flexor tension during the push (open: back)")
    _fig(out / "cable_friction_push.png", fig)

    fig = Figure(figsize=(5.4, 4.2), dpi=110)
    ax = fig.subplots()
    w = res["widths"]
    ax.plot([x["mu"] for x in w], [x["loop_width"] for x in w], "o-", color=COLORS[0])
    for x in w:
        ax.annotate(f"{x['loop_width']:.2f}", (x["mu"], x["loop_width"]), textcoords="offset points",
                    xytext=(0, 6), ha="center", fontsize=7)
    ax.set_xlabel("flexor friction mu")
    ax.set_ylabel("loop width: max |tip x up - tip x down| [mm]")
    ax.set_title(f"Hysteresis of the finger's tip, contraction 0 - {res['params']['top']:g} - 0 mm", fontsize=9)
    ax.grid(alpha=0.3)
    _fig(out / "cable_friction_width.png", fig)

    write_json(out / "cable_friction.json", res)      # last: its presence means the others are complete


def main(argv=None) -> int:
    from skelfem.io.files import say
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "cable_friction")
    p.add_argument("--size", type=float, default=2.0, help="mesh size, mm")
    p.add_argument("--top", type=float, default=8.0, help="largest contraction of the cycle, mm")
    p.add_argument("--steps", type=int, default=8, help="contraction steps each way")
    p.add_argument("--mu", type=float, nargs="+", default=[0.0, 0.1, 0.3], help="friction of the cycles drawn")
    p.add_argument("--width-mu", type=float, nargs="+", default=[0.0, 0.05, 0.1, 0.2, 0.3])
    p.add_argument("--width-steps", type=int, default=None, help="steps each way of the extra cycles (default --steps)")
    p.add_argument("--push-mu", type=float, nargs="+", default=[0.0, 0.1, 0.3])
    p.add_argument("--pre", type=float, default=2.0, help="flexor pre-contraction held during the push, mm")
    p.add_argument("--travel", type=float, default=6.0, help="largest stage travel, mm")
    p.add_argument("--push-steps", type=int, default=24, help="travel steps each way")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    res = run(size=a.size, top=a.top, steps=a.steps, mus=a.mu, width_mus=a.width_mu, width_steps=a.width_steps,
              push_mus=a.push_mu, pre=a.pre, travel=a.travel, push_steps=a.push_steps, out=a.out)
    for c in res["cycles"]:
        f = c["full"] or {}
        say(f"cycle mu {c['mu']:<5g} loop width {c['loop_width']:.4f} mm at {c['loop_width_at']:g} mm; at "
            f"{c['top']:g} mm: tip x {f.get('tip_x', float('nan')):.3f} mm, tension "
            f"{f.get('tension_actuated', 0):.4f} N (actuated) / {f.get('tension_far', 0):.4f} N (far)  "
            f"({c['status']}, {c['newton_iterations']} its, "
            f"{c['time']:.1f} s)")
    for w in res["widths"]:
        say(f"width  mu {w['mu']:<5g} {w['loop_width']:.4f} mm  ({w['status']}, {w['steps']} steps each way)")
    for p in res["push"]:
        say(f"push   mu {p['mu']:<5g} peak {p['peak_force']:.4f} N, largest force gap down/back "
            f"{p['force_gap']:.4f} N  ({p['status']}, {p['newton_iterations']} its, {p['time']:.1f} s)")
    say(f"wrote {a.out}/cable_friction.json, cable_friction_cycle.csv, cable_friction_push.csv, cable_friction.png, "
        f"cable_friction_push.png, cable_friction_width.png in {time.perf_counter() - t0:.1f} s")
    return 0 if res["converged"] else 2


if __name__ == "__main__":
    raise SystemExit(main())
