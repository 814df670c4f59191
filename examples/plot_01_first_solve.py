"""
A first simulation
==================

The demo finger (``geometry/finger.toml``): a 20 × 100 mm EcoFlex body with
three PLA bones, ligaments across both joints and one flexor tendon pulled
8 mm onto its spool. A :class:`skelfem.Session` meshes the design, compiles
its energy and finds the static equilibrium with Newton's method.

The mesh is coarsened to 4 mm here (``mesh.size=4``, the same override as
``skelfem simulate --set mesh.size=4``) so that the example runs in about a
second.
"""
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from skelfem import Session

# the repository's root, where the bundled designs are (sphinx-gallery runs an example
# from its own folder and without __file__)
ROOT = Path(__file__).resolve().parent.parent if "__file__" in globals() else Path.cwd().parent
DESIGN = ROOT / "geometry" / "finger.toml"

with Session(DESIGN, ["mesh.size=4"]) as s:
    r = s.solve()                      # a Result: r.to_dict() is exactly result.json
    design = s.design.raw              # the design as a dict (the TOML's keys)

print(r)
print(f"{r.dofs} DOFs, {r.cells} cells, smallest det F {r.min_jacobian:.3f}")
tip = np.array(r.markers["tip"]["position"])
print("tip at", tip.round(3), "mm; moved", np.round(r.markers["tip"]["displacement"], 3), "mm")
for name, c in r.cables.items():
    print(f"  {c['kind']:8s} {name:12s} tension {c['tension']:6.3f} N, length {c['length']:6.2f} mm")

# %%
# The design at rest and where the tip went
# -----------------------------------------
# The outlines come from the design dict; the tip's position from the result.
# Newton's residuals per iteration show its quadratic end.

fig, (ax, bx) = plt.subplots(1, 2, figsize=(9, 4.5), gridspec_kw={"width_ratios": [1.2, 1]})
body = np.array(design["body"]["outline"] + design["body"]["outline"][:1])
ax.plot(body[:, 0], body[:, 1], "k-", lw=1, label="body at rest")
for bone in design["bones"]:
    b = np.array(bone["outline"] + bone["outline"][:1])
    ax.fill(b[:, 0], b[:, 1], color="0.8", ec="0.4")
for cable in design["cables"]:
    p = np.array(cable["path"])
    ax.plot(p[:, 0], p[:, 1], "-" if cable["kind"] == "tendon" else ":",
            color="tab:blue" if cable["kind"] == "tendon" else "tab:orange")
ref = np.array(r.markers["tip"]["reference"])
ax.plot(*ref, "ko", ms=5)
ax.plot(*tip, "r*", ms=12, label="tip at equilibrium")
ax.annotate("", tip, ref, arrowprops={"arrowstyle": "->", "color": "r"})
ax.set_aspect("equal")
ax.set_xlabel("x [mm]")
ax.set_ylabel("y [mm]")
ax.legend(loc="lower left", fontsize=8)
ax.set_title("finger.toml, flexor at 8 mm")

res = np.concatenate(r.residual_history)
bx.semilogy(np.arange(1, len(res) + 1), res, "o-")
bx.set_xlabel("Newton iteration")
bx.set_ylabel("|R|")
bx.set_title(f"{r.newton_iterations} Newton iterations")
fig.tight_layout()
plt.show()

# %%
# The numbers this example checks: the tip of the 4 mm mesh (P1), as measured
# when the example was written; two exact ones, the tendon's tension
# k (l - L) with rest length L = L0 - u (L0 the length of its sketch, u the
# 8 mm contraction), and the pin's reaction: nothing but the body's own cables
# pulls on it, so the pin holds nothing.
assert r.converged
assert np.allclose(tip, [-35.516, 82.526], atol=0.05), tip
flexor = next(c for c in design["cables"] if c["name"] == "flexor")
L0 = np.linalg.norm(np.diff(np.array(flexor["path"], float), axis=0), axis=1).sum()
c = r.cables["flexor"]
assert np.isclose(c["rest_length"], L0 - flexor["contraction"], rtol=1e-12)
assert np.isclose(c["tension"], flexor["stiffness"] * (c["length"] - c["rest_length"]), rtol=1e-9)
assert np.linalg.norm(r.pins["base"]["reaction"]) < 1e-6 * c["tension"], r.pins
