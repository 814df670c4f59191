"""Figures for the README: the demo finger, three skeletons side by side, Newton's residuals, the 3D arm,
and the fabrication parts of the demo finger (exploded view).

    python studies/readme_figures.py [--out studies/figures] [--size 2.0]

run(**params) returns the numbers shown in the figures; main(argv) writes the PNGs.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from skelfem.io.files import say

ROOT = Path(__file__).resolve().parents[1]
CONDITIONS = {"finger": "bones + ligaments", "finger_bones": "bones only", "finger_soft": "no bones"}


def solve(name: str, overrides=()):
    """Session of geometry/<name>.toml, solved; returns (session, result)."""
    from skelfem import Session

    session = Session(ROOT / "geometry" / f"{name}.toml", overrides)
    return session, session.solve()


def run(size: float = 2.0, contraction: float = 8.0, out: Path | None = None, arm: bool = False,
        fabrication: bool = False) -> dict:
    """Solve the three finger conditions (and arm3d.toml if arm, and build finger.toml's fabrication
    parts if fabrication); if out is given, write the figures there."""
    overrides = [f"mesh.size={size}", f"cables.flexor.contraction={contraction}"]
    results, models = {}, {}
    for name in CONDITIONS:
        session, result = solve(name, overrides)
        session.close()
        if not result.converged:
            raise RuntimeError(f"{name}: {result.status}")
        results[name] = {"tip": result.markers["tip"]["position"], "newton_iterations": result.newton_iterations,
                         "residual_history": result.residual_history,
                         "tension": result.cables["flexor"]["tension"]}
        models[name] = session.model
    if out is not None:
        _figures(Path(out), models, results, contraction)
    if arm:
        results["arm3d"] = _arm(out)
    if fabrication:
        results["fabrication"] = _fabrication(out)
    return results


def _fabrication(out: Path | None) -> dict:
    """finger.toml's bones and mould (skelfem.fabricate); the exploded view as fabrication.png, the casting
    sequence as casting.png and the single-process print (body and bones) as fabrication_3mf.png."""
    from skelfem import fabricate
    from skelfem.fabricate.multimaterial import build_print
    from skelfem.fabricate.picture import picture as draw
    from skelfem.fabricate.sequence import casting_sequence
    from skelfem.design import load_design

    plan = fabricate.plan(load_design(ROOT / "geometry" / "finger.toml"))
    parts = fabricate.build(plan)
    printed, _, _ = build_print(plan)
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        draw(Path(out) / "fabrication.png", parts, plan,
                          "finger.toml: bones and the two-part mould, exploded along the mould's normal")
        casting_sequence(Path(out) / "casting.png", parts, plan)
        draw(Path(out) / "fabrication_3mf.png", printed, plan,
             "finger.toml as one print: the body (translucent) and its bones, channels open")
    return {p.name: p.cad_volume for p in parts}


def _arm(out: Path | None) -> dict:
    from skelfem.viz.plots import plot_deformed_3d
    from skelfem.jobs.run import picture_title

    session, result = solve("arm3d")
    session.close()
    if not result.converged:
        raise RuntimeError(f"arm3d: {result.status}")
    if out is not None:
        plot_deformed_3d(Path(out) / "arm3d.png", session.model, picture_title(session.design))
    return {"hand": result.markers["hand"]["position"], "newton_iterations": result.newton_iterations}


def _figures(out: Path, models: dict, results: dict, contraction: float) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skelfem.io.files import atomic_write
    from skelfem.viz.plots import plot_deformed

    out.mkdir(parents=True, exist_ok=True)
    plot_deformed(out / "finger.png", models["finger"], f"finger.toml: flexor contracted {contraction:g} mm")

    fig, axes = plt.subplots(1, 3, figsize=(12, 5.2), dpi=110, sharey=True)
    for ax, (name, label) in zip(axes, CONDITIONS.items()):
        plot_deformed(None, models[name], f"{label}\ntip at ({results[name]['tip'][0]:.1f}, "
                      f"{results[name]['tip'][1]:.1f}) mm, T = {results[name]['tension']:.2f} N", ax=ax)
        ax.legend().remove() if ax.get_legend() else None
    fig.suptitle(f"Same tendon contraction ({contraction:g} mm), three skeletons", fontsize=11)
    fig.tight_layout()
    atomic_write(out / "skeletons.png", lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=110)
    offset = 0
    for k, hist in enumerate(results["finger"]["residual_history"]):
        its = np.arange(offset, offset + len(hist))
        ax.semilogy(its, hist, "o-", ms=3, label=f"load step {k + 1}")
        offset += len(hist)
    ax.set_xlabel("Newton iteration (cumulative)")
    ax.set_ylabel("|grad Pi| [N]")
    ax.set_title("finger.toml: residual per Newton iteration", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_write(out / "newton.png", lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "figures")
    p.add_argument("--size", type=float, default=2.0)
    p.add_argument("--contraction", type=float, default=8.0)
    p.add_argument("--no-arm", action="store_true", help="skip the 3D arm picture")
    p.add_argument("--no-fabrication", action="store_true", help="skip the fabrication picture")
    a = p.parse_args(argv)
    res = run(a.size, a.contraction, a.out, arm=not a.no_arm, fabrication=not a.no_fabrication)
    arm = res.pop("arm3d", None)
    fab = res.pop("fabrication", None)
    if fab:
        say("fabrication   " + ", ".join(f"{name} {volume:.0f} mm^3" for name, volume in fab.items()))
    if arm:
        say(f"arm3d         hand at ({', '.join(f'{v:.2f}' for v in arm['hand'])}) mm, "
              f"{arm['newton_iterations']} Newton iterations")
    for name, r in res.items():
        say(f"{name:13s} tip ({r['tip'][0]:7.2f}, {r['tip'][1]:7.2f}) mm  tension {r['tension']:.3f} N  "
              f"{r['newton_iterations']} Newton iterations")
    say(f"figures in {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
