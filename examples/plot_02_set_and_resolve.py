"""
Changing a parameter and solving again
======================================

:meth:`skelfem.Session.set` takes the ``--set`` keys of the command line.
A key that an ingredient exposes as a live parameter (contractions,
pretensions, stiffnesses, loads, pin moves, E and ν, ...) changes in place:
no re-meshing, no recompilation, no new matrix, and the next
:meth:`~skelfem.Session.solve` starts from the last equilibrium with a
first-order predictor. Here the flexor of the demo finger is pulled from 0 to
14 mm in 1 mm steps.
"""
from pathlib import Path
import time

import matplotlib.pyplot as plt
import numpy as np

from skelfem import Session

# the repository's root, where the bundled designs are (sphinx-gallery runs an example
# from its own folder and without __file__)
ROOT = Path(__file__).resolve().parent.parent if "__file__" in globals() else Path.cwd().parent
DESIGN = ROOT / "geometry" / "finger.toml"

contractions = np.arange(0.0, 14.5, 1.0)
tips, tensions, iterations, seconds = [], [], [], []
with Session(DESIGN, ["mesh.size=4", "cables.flexor.contraction=0"]) as s:
    print("live parameters:", ", ".join(sorted(s.model.parameters())))
    for u in contractions:
        t0 = time.perf_counter()
        s.set({"cables.flexor.contraction": float(u)})
        r = s.solve()
        seconds.append(time.perf_counter() - t0)
        assert r.converged, r.status
        tips.append(r.markers["tip"]["position"])
        tensions.append(r.cables["flexor"]["tension"])
        iterations.append(r.newton_iterations)

    # a softer skeleton: E of the bones' material is a live parameter too
    s.set({"materials.pla.E": 1.0})
    soft = s.solve()

tips = np.array(tips)
for u, p, t, n, dt in zip(contractions, tips, tensions, iterations, seconds):
    print(f"u = {u:4.1f} mm: tip ({p[0]:7.2f}, {p[1]:6.2f}) mm, tension {t:6.3f} N, "
          f"{n:2d} Newton iterations, {1e3 * dt:5.1f} ms")
print("bones of E = 1 MPa instead of 3000: tip at", np.round(soft.markers["tip"]["position"], 2))

# %%
# The tip's path and the tendon's tension
# ---------------------------------------

fig, (ax, bx) = plt.subplots(1, 2, figsize=(9, 4))
ax.plot(tips[:, 0], tips[:, 1], "o-", ms=4, label="PLA bones (3000 MPa)")
ax.plot(*soft.markers["tip"]["position"], "s", color="tab:red", label="bones of 1 MPa, u = 14 mm")
for u, p in zip(contractions[::2], tips[::2]):
    ax.annotate(f"{u:g}", p, textcoords="offset points", xytext=(4, 4), fontsize=7)
ax.set_aspect("equal")
ax.set_xlabel("tip x [mm]")
ax.set_ylabel("tip y [mm]")
ax.legend(fontsize=8)
ax.set_title("tip path (labels: contraction in mm)")
bx.plot(contractions, tensions, "o-", label="tension [N]")
bx.bar(contractions, iterations, width=0.4, alpha=0.4, color="tab:gray", label="Newton iterations")
bx.set_xlabel("flexor contraction [mm]")
bx.legend(fontsize=8)
fig.tight_layout()
plt.show()

# %%
# Checks: warm re-solves after a 1 mm change take a few Newton iterations;
# without friction the path leaves no trace, so the tip at 8 mm reached in
# 1 mm steps is the tip of one solve from rest at 8 mm (the first example's,
# the same mesh) to the solver's tolerance; and the tip at 14 mm sits where it
# was measured when the example was written.
assert max(iterations[1:]) <= 8, iterations
with Session(DESIGN, ["mesh.size=4", "cables.flexor.contraction=8"]) as cold:
    at8 = cold.solve().markers["tip"]["position"]
assert np.allclose(tips[list(contractions).index(8.0)], at8, atol=1e-6), (tips[8], at8)
assert np.allclose(tips[-1], [-57.549, 54.054], atol=0.05), tips[-1]
