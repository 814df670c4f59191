"""The three-finger hand holds objects of several shapes by friction: close, weigh until lost, against mu_min.

    python studies/hand_grasp.py [--shapes square hexagon octagon triangle] [--mu 0.3 0.6 0.9]
                                 [--density 310 620 ... 2480] [--contraction 4] [--centre 0] [--size 2]
                                 [--headroom 1] [--quick] [--out studies/output/hand_grasp]
                                 [--figures studies/figures]

geometry/hand.toml: a palm with three skeleton fingers hanging down (the
paper's Fig. 10 in 2D). The outer fingers curl inward onto the object's
sides, the shorter centre finger is the stop the squeezed object is pushed
up against: the closed hand holds it at three contacts. Each shape replaces
the design's object outline (``objects.box.outline``, a --set override):
a square (the design's box), a regular hexagon (corners towards the outer
fingers, flat top), a regular octagon (flat sides on the axes) and an
equilateral triangle (apex down), all as wide as the box and with their top
where the box's is, so the hand closes the same way on each.

For each shape and friction coefficient mu (``contact.friction``) one
Session closes the hand (outer flexors contracted, centre flexor at
``centre``, gravity off), then switches gravity on and makes the object
heavier step by step (``materials.box_pla.density``, ascending; each a warm
re-solve from the last equilibrium, its friction history kept) until it is
lost (a solve that ends "no equilibrium: object box is not held" or does not
converge); heavier ones are not tried (``skipped``).

Two friction limits are recorded for every weighing, both from the closed
grip (gravity off): ``mu_min`` = W / (sum of the normal forces of all three
contacts, the contact pair's ``normal_magnitude``), as studies/grasp.py
computes it for the gripper, and ``mu_min_pads`` = W / (N_left + N_right), the
outer fingers' share alone: the centre finger presses the object down, so
its friction cannot carry the weight. The margins are mu / mu_min. The split
of the normal force over the fingers is read from the contact forces on the
object's nodes, each given to the finger of the nearest body node (the finger
whose bones' centre lies nearest that node's rest x). What happens to each shape is read from the object's read-out:
its position and rotation closed and held (``moved``: since the closed grip);
a failed solve has no read-out, so a lost object's last pose is its heaviest held one.

ipctk's collision-free step search has been seen to allocate memory without
bound in a failing weighing of this hand (23 GB before the kernel stopped
the process; it starts from a node 5e-6 mm from an edge of the object), so
every solve runs under an address-space limit (``headroom_gb`` more than the
process holds when the solve starts) and one that hits it is recorded as failed
(counted as lost; the heavier ones are skipped). Outcomes poised at a
threshold depend on the Python hash seed (see docs/guide/objects.md); the
JSON records it.

run(**params) returns the numbers; main(argv) also writes hand_grasp.json
into out, hand_grasp.png (each shape held at the largest mu, heaviest held
weight, with its contact forces) and hand_grasp_margin.png (held and lost
against mu / mu_min, a marker per shape) into figures.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "hand.toml"
OUT = ROOT / "studies" / "output" / "hand_grasp"
FIGURES = ROOT / "studies" / "figures"
G = [0.0, -9.81]
OBJECT = "box"
DENSITY_KEY = "materials.box_pla.density"
OUTER = ("left", "right")               # the fingers whose friction carries the weight
CENTRE = "centre"
SHAPES = ("square", "hexagon", "octagon", "triangle")
MARKERS = {"square": "s", "hexagon": "h", "octagon": "8", "triangle": "v"}
QUICK = {"mus": (0.8,), "densities": (310.0, 2170.0, 3720.0)}


# -- shapes ---------------------------------------------------------------------------------------------
def shape_outline(kind: str, box: np.ndarray) -> list:
    """The outline of a shape as wide as the design's box (its horizontal extent), centred on it, its top
    where the box's top is; counter-clockwise, mm."""
    box = np.asarray(box, float)
    width = float(np.ptp(box[:, 0]))
    cx, top = float(box[:, 0].min()) + width / 2, float(box[:, 1].max())
    h = width / 2
    if kind == "square":
        pts = [(-h, -width), (h, -width), (h, 0.0), (-h, 0.0)]
    elif kind == "hexagon":                        # corners left and right, flat top and bottom
        a = np.radians(np.arange(0, 360, 60))
        pts = list(zip(h * np.cos(a), h * np.sin(a) - h * math.sin(math.pi / 3)))
    elif kind == "octagon":                        # flat sides on the axes, flat-to-flat = width
        r = h / math.cos(math.pi / 8)
        a = np.radians(22.5 + np.arange(0, 360, 45))
        pts = list(zip(r * np.cos(a), r * np.sin(a) - h))
    elif kind == "triangle":                       # equilateral, apex down, flat top
        pts = [(0.0, -width * math.sqrt(3) / 2), (h, 0.0), (-h, 0.0)]
    else:
        raise ValueError(f"unknown shape {kind!r}; known: {', '.join(SHAPES)}")
    return [[round(cx + float(x), 4), round(top + float(y), 4)] for x, y in pts]


def polygon_area(outline) -> float:
    p = np.asarray(outline, float)
    return 0.5 * abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(p[:, 1], np.roll(p[:, 0], -1))))


# -- read-outs ------------------------------------------------------------------------------------------
def _pair(d: dict) -> dict:
    pairs = [c for c in d.get("contacts") or [] if c["between"] == ["body", OBJECT]]
    return pairs[0] if pairs else {}


def _finger_centres(design) -> dict:
    """{finger: x of the centre of its bones at rest} (bones are named FINGER_PHALANX)."""
    xs: dict = {}
    for b in design.bones:
        xs.setdefault(b.name.split("_")[0], []).append(float(np.mean(np.asarray(b.outline)[:, 0])))
    return {f: float(np.mean(v)) for f, v in xs.items()}


def finger_forces(model) -> tuple[dict, dict]:
    """({finger: sum of the magnitudes of the barrier's nodal forces on the object from that finger} (N),
    {finger: where that force acts, the force-weighted mean of its contact nodes (mm)}).

    Each contact node of the object goes to the finger of the nearest body node (deformed positions),
    the finger being the one whose bones' centre is nearest that node's rest x. The sum over the
    fingers is the contact pair's normal_magnitude."""
    from scipy.spatial import cKDTree

    from skelfem.io.xdmf import snapshot
    snap = snapshot(model)
    centres = _finger_centres(model.design)
    forces, where = {f: 0.0 for f in centres}, {f: None for f in centres}
    obj = next((o for o in snap.objects if o.get("name") == OBJECT and "points" in o), None)
    if obj is None or not len(obj["points"]):
        return forces, where
    points = np.asarray(obj["points"])
    nodes = np.unique(snap.cells[np.isin(snap.regions, snap.body_tags)])
    _, k = cKDTree(snap.x[nodes] + snap.u[nodes]).query(points)
    rest_x = snap.x[nodes[k], 0]
    names = list(centres)
    which = np.argmin(np.abs(rest_x[:, None] - np.array([centres[f] for f in names])[None, :]), axis=1)
    mags = np.linalg.norm(np.asarray(obj["normal"]), axis=1)
    for i, f in enumerate(names):
        m = mags[which == i]
        forces[f] = float(m.sum())
        if forces[f] > 0:
            where[f] = [float(v) for v in (m[:, None] * points[which == i]).sum(axis=0) / m.sum()]
    return forces, where


def _pose(r: dict | None) -> dict | None:
    if not r:
        return None
    return {"position": [float(v) for v in r["position"]], "rotation": float(r["rotation"])}


def _relative(pose: dict | None, ref: dict | None) -> dict | None:
    """Motion since the closed grip: displacement (mm) and rotation (rad)."""
    if pose is None or ref is None:
        return None
    return {"displacement": [float(a - b) for a, b in zip(pose["position"], ref["position"])],
            "rotation": float(pose["rotation"] - ref["rotation"])}


def _vm_size() -> int | None:
    """This process's virtual memory size (bytes; Linux), or None."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


@contextlib.contextmanager
def memory_cap(headroom_gb: float | None):
    """Inside the block, at most headroom_gb GiB more address space than the process has now (a soft
    limit, restored after; nothing on systems without it, or if an existing limit is lower)."""
    try:
        import resource
    except ImportError:
        resource = None
    now = _vm_size()
    if resource is None or not headroom_gb or now is None:
        yield
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = now + int(headroom_gb * (1 << 30))
    if (soft != resource.RLIM_INFINITY and soft <= cap) or (hard != resource.RLIM_INFINITY and hard < cap):
        yield
        return
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


# -- the sweep ------------------------------------------------------------------------------------------
def grasp(shape: str, outline: list, mu: float, densities, contraction: float = 4.0, centre: float = 0.0,
          size: float | None = None, panel=None, say=print, headroom_gb: float | None = 1.0) -> dict:
    """One shape at one mu: close, then weigh each density in turn until the object is lost.
    panel: an axes to draw the heaviest object held into (with its contact forces)."""
    from skelfem import Session
    overrides = [f"contact.friction={mu}", f"objects.{OBJECT}.outline={json.dumps(outline)}"]
    overrides += [f"mesh.size={size}"] if size else []
    out = {"shape": shape, "mu": float(mu), "weighings": []}
    t0 = time.perf_counter()
    with Session(DESIGN, overrides) as s:
        out["dofs"] = s.dofs
        flexors = {f"cables.{f}_flexor.contraction": contraction for f in OUTER}
        flexors[f"cables.{CENTRE}_flexor.contraction"] = centre
        s.set(flexors)
        t1 = time.perf_counter()
        try:
            with memory_cap(headroom_gb):
                r = s.solve()
        except MemoryError as exc:                # see the module doc
            out["close"] = {"converged": False, "status": f"failed: out of memory ({exc})",
                            "time": time.perf_counter() - t1}
            say(f"{shape:9s} mu {mu:<4g} closing failed: out of memory", flush=True)
            return out
        d = r.to_dict()
        fingers, at = finger_forces(s.model) if r.converged else ({}, {})
        closed = _pose(d.get("objects", {}).get(OBJECT))
        N = float(_pair(d).get("normal_magnitude", 0.0))
        N_pads = sum(fingers.get(f, 0.0) for f in OUTER)
        out["close"] = {"converged": r.converged, "status": r.status, "newton_iterations": r.newton_iterations,
                        "time": time.perf_counter() - t1, "build_time": t1 - t0, "normal_magnitude": N,
                        "fingers": fingers, "contact_at": at, "normal_pads": N_pads,
                        "fingers_touching": sum(v > 0 for v in fingers.values()), "object": closed,
                        "moved": {"displacement": d["objects"][OBJECT]["displacement"],
                                  "rotation": d["objects"][OBJECT]["rotation"]} if closed else None}
        c = out["close"]
        say(f"{shape:9s} mu {mu:<4g} closed: {r.status}, {r.newton_iterations} its, {c['time']:.1f} s, sum N = "
            f"{N:.3f} N (" + ", ".join(f"{f} {v:.3f}" for f, v in fingers.items()) + ")", flush=True)
        if not r.converged:
            return out
        if panel is not None:
            _draw(panel, s, f"{shape}: closed, gravity off (mu = {mu:g})")
        term = s.model.term("objects", OBJECT)
        lost = False
        for rho in densities:
            entry = {"density": float(rho)}
            out["weighings"].append(entry)
            if lost:
                entry["status"] = "skipped"
                continue
            s.set({"gravity.acceleration": G, DENSITY_KEY: float(rho)})
            t1 = time.perf_counter()
            W = float(np.linalg.norm(term.weight()))
            try:
                with memory_cap(headroom_gb):
                    r = s.solve()
            except MemoryError as exc:            # ipctk's step search ran away (see the module doc)
                entry.update(status=f"failed: out of memory in the collision-free step search ({exc})",
                             held=False, newton_iterations=None, converged=False)
                r = d = None
            if r is not None:
                d = r.to_dict()
                entry.update(status=r.status, held=bool(r.converged), converged=bool(r.converged),
                             newton_iterations=r.newton_iterations)
            entry.update(weight=W, time=time.perf_counter() - t1, mu_min=W / N if N > 0 else math.inf,
                         mu_min_pads=W / N_pads if N_pads > 0 else math.inf)
            entry["margin"] = mu / entry["mu_min"]
            entry["margin_pads"] = mu / entry["mu_min_pads"]
            if entry["held"]:
                pose = _pose(d.get("objects", {}).get(OBJECT))
                forces, at = finger_forces(s.model)
                entry.update(normal_magnitude=float(_pair(d).get("normal_magnitude", 0.0)), fingers=forces,
                             contact_at=at, object=pose, moved=_relative(pose, closed),
                             friction_force=_pair(d).get("friction_force"), sticking=_pair(d).get("sticking"))
                if panel is not None:
                    _draw(panel, s, f"{shape}: W = {W:.3g} N held (mu = {mu:g}, margin {entry['margin']:.2f}, "
                                    f"pads {entry['margin_pads']:.2f})")
            moved = (f"; moved ({entry['moved']['displacement'][0]:+.2f}, "
                     f"{entry['moved']['displacement'][1]:+.2f}) mm, "
                     f"turned {entry['moved']['rotation']:+.4f} rad") if entry["held"] else ""
            say(f"{shape:9s} mu {mu:<4g} density {rho:6g}: W = {W:.3f} N, mu_min {entry['mu_min']:.3f} "
                f"(pads {entry['mu_min_pads']:.3f}): {'held' if entry['held'] else 'LOST'} "
                f"[{entry['status']}], {entry['newton_iterations']} its, {entry['time']:.1f} s{moved}", flush=True)
            if not entry["held"]:
                lost = True
                if r is None:                       # the session's state is unknown after the error
                    break
    done = {w["density"] for w in out["weighings"]}
    out["weighings"] += [{"density": float(rho), "status": "skipped"} for rho in densities if float(rho) not in done]
    return out


def _draw(ax, session, title: str) -> None:
    from skelfem.viz.plots import plot_deformed
    ax.clear()
    plot_deformed(None, session.model, title, ax=ax)
    legend = ax.get_legend()
    if legend is not None:
        legend.remove()
    ax.title.set_fontsize(8)


def run(shapes=SHAPES, mus=(0.3, 0.6, 0.9), densities=(310.0, 620.0, 930.0, 1240.0, 1550.0, 1860.0, 2170.0, 2480.0),
        contraction: float = 4.0, centre: float = 0.0, size: float | None = None, out: Path | None = None,
        figures: Path | None = None, headroom_gb: float | None = 1.0, say=print) -> dict:
    """The sweep; writes hand_grasp.json into out and the two figures into figures if given."""
    from skelfem.design import load_design
    from skelfem.io.files import atomic_write, write_json
    if not shapes:
        raise ValueError("no shapes given")
    for s in shapes:
        if s not in SHAPES:
            raise ValueError(f"unknown shape {s!r}; known: {', '.join(SHAPES)}")
    mus, densities = sorted(float(m) for m in mus), sorted(float(r) for r in densities)
    if not mus or not densities or min(mus) < 0 or min(densities) <= 0:
        raise ValueError("give at least one mu >= 0 and one density > 0")
    design = load_design(DESIGN)
    box = next(o.outline for o in design.objects if o.name == OBJECT)
    outlines = {s: shape_outline(s, box) for s in shapes}
    fig = axes = None
    if figures is not None:
        from matplotlib.figure import Figure
        cols = min(2, len(shapes))
        rows = -(-len(shapes) // cols)
        fig = Figure(figsize=(4.6 * cols, 5.4 * rows), dpi=110)
        axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
        for ax in axes[len(shapes):]:
            ax.set_visible(False)
    results = []
    t0 = time.perf_counter()
    for i, shape in enumerate(shapes):
        for mu in mus:
            panel = axes[i] if axes is not None and mu == mus[-1] else None
            results.append(grasp(shape, outlines[shape], mu, densities, contraction, centre, size, panel, say,
                                 headroom_gb))
    tried = [(res, w) for res in results for w in res["weighings"] if "held" in w]
    summary = {
        "design": str(DESIGN.relative_to(ROOT)), "object": OBJECT,
        "params": {"shapes": list(shapes), "mus": mus, "densities": densities, "contraction": contraction,
                   "centre": centre, "size": size if size else design.mesh.size, "gravity": G,
                   "thickness": design.thickness, "dhat": design.contact.dhat,
                   "python_hash_seed": os.environ.get("PYTHONHASHSEED", "random")},
        "shapes": {s: {"outline": outlines[s], "area": polygon_area(outlines[s])} for s in shapes},
        "results": results,
        "weighings": len(tried),
        "agree_with_mu_min": int(sum(w["held"] == (res["mu"] > w["mu_min"]) for res, w in tried)),
        "agree_with_mu_min_pads": int(sum(w["held"] == (res["mu"] > w["mu_min_pads"]) for res, w in tried)),
        "time": time.perf_counter() - t0,
    }
    if out is not None:
        write_json(Path(out) / "hand_grasp.json", summary)
    if figures is not None:
        figures = Path(figures)
        handles, labels = [], []
        for ax in axes[:len(shapes)]:
            for h, lab in zip(*ax.get_legend_handles_labels()):
                lab = lab.replace(f" on {OBJECT}", "")
                if "force" in lab and lab not in labels:
                    handles.append(h)
                    labels.append(lab)
        if handles:
            fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8, frameon=False)
        fig.tight_layout(rect=(0, 0.03, 1, 1))
        atomic_write(figures / "hand_grasp.png", lambda tmp: fig.savefig(tmp, format="png"))
        plot_margin(figures / "hand_grasp_margin.png", results, list(shapes))
    return summary


def plot_margin(path: Path, results: list, shapes: list) -> None:
    """Every weighing: held (filled) or lost (hollow) against mu / mu_min, one row per shape, a marker per
    shape, a colour per mu; left the three contacts' mu_min, right the outer fingers' alone."""
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    from skelfem.io.files import atomic_write
    fig = Figure(figsize=(9.0, 1.6 + 0.75 * len(shapes)), dpi=120)
    axes = fig.subplots(1, 2, sharey=True)
    mus = sorted({res["mu"] for res in results})
    colour = {mu: colormaps["viridis"](0.15 + 0.7 * k / max(1, len(mus) - 1)) for k, mu in enumerate(mus)}
    for ax, key, title in ((axes[0], "margin", "mu_min = W / sum N (three contacts, as the gripper)"),
                           (axes[1], "margin_pads", "mu_min = W / (N_left + N_right) (outer fingers)")):
        xs = []
        for res in results:
            row = shapes.index(res["shape"])
            dy = 0.25 * (mus.index(res["mu"]) - (len(mus) - 1) / 2) / max(1, len(mus) - 1) * 2
            for w in res["weighings"]:
                if "held" not in w or not math.isfinite(w[key]) or w[key] <= 0:
                    continue
                xs.append(w[key])
                ax.plot(w[key], row + dy, MARKERS.get(res["shape"], "o"), ms=7, mec=colour[res["mu"]],
                        mfc=colour[res["mu"]] if w["held"] else "none", mew=1.4)
        ax.axvline(1.0, color="k", ls="--", lw=1)
        ax.set_xscale("log")
        if xs:
            ax.set_xlim(min(min(xs), 1.0) / 1.3, max(max(xs), 1.0) * 1.3)
        ax.set_xlabel("holding margin mu / mu_min")
        ax.set_title(title, fontsize=9)
        ax.grid(True, axis="x", which="both", alpha=0.3)
    axes[0].set_yticks(range(len(shapes)))
    axes[0].set_yticklabels(shapes)
    axes[0].set_ylim(len(shapes) - 0.5, -0.5)
    for mu in mus:
        axes[1].plot([], [], "o", color=colour[mu], label=f"mu = {mu:g}")
    axes[1].plot([], [], "o", color="0.4", label="held (filled)")
    axes[1].plot([], [], "o", mec="0.4", mfc="none", label="lost (hollow)")
    fig.legend(*axes[1].get_legend_handles_labels(), loc="lower center", ncol=len(mus) + 2, fontsize=8,
               frameon=False)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--shapes", nargs="+", choices=SHAPES, default=list(SHAPES))
    p.add_argument("--mu", type=float, nargs="+", default=[0.3, 0.6, 0.9])
    p.add_argument("--density", type=float, nargs="+",
                   default=[310.0, 620.0, 930.0, 1240.0, 1550.0, 1860.0, 2170.0, 2480.0])
    p.add_argument("--contraction", type=float, default=4.0, help="outer flexors, mm")
    p.add_argument("--centre", type=float, default=0.0, help="centre flexor, mm")
    p.add_argument("--size", type=float, default=None)
    p.add_argument("--headroom", type=float, default=1.0,
                   help="address space a solve may add, GiB (0: no limit); see the module doc")
    p.add_argument("--quick", action="store_true", help=f"a small sweep: {QUICK}")
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--figures", type=Path, default=FIGURES)
    a = p.parse_args(argv)
    mus, densities = (QUICK["mus"], QUICK["densities"]) if a.quick else (a.mu, a.density)
    s = run(a.shapes, mus, densities, a.contraction, a.centre, a.size, a.out, a.figures, a.headroom or None)
    print(f"{s['agree_with_mu_min']} of {s['weighings']} weighings agree with mu_min = W / sum N, "
          f"{s['agree_with_mu_min_pads']} with W / (N_left + N_right); {s['time']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
