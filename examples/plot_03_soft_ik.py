"""
Soft IK: tendon contractions that put the tip on a target
=========================================================

``geometry/finger4.toml`` has four tendons: two flexors and two extensors.
Soft IK asks for the contractions u ≥ 0 that move the tip marker to a target
y′, minimising ‖y(u) − y′‖². ``skelfem ik`` does this with the exact
derivatives dy/du of the equilibrium (one factorisation, one solve per
tendon). This example writes the same bounded Levenberg–Marquardt loop by
hand on a :class:`skelfem.Session`, with derivatives by forward differences:
every evaluation is a :meth:`~skelfem.Session.set` of the contractions and a
warm :meth:`~skelfem.Session.solve`.

The target is made by a forward solve of known contractions (distal flexor
6 mm, middle flexor 4 mm), so it is reachable. The IK need not find those
contractions: with four tendons for a 2D target many poses reach it, and
without a regulariser the loop takes the first it finds.
"""
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from skelfem import Session

# the repository's root, where the bundled designs are (sphinx-gallery runs an example
# from its own folder and without __file__)
ROOT = Path(__file__).resolve().parent.parent if "__file__" in globals() else Path.cwd().parent
DESIGN = ROOT / "geometry" / "finger4.toml"
TENDONS = ["flexor_distal", "flexor_middle", "extensor_distal", "extensor_middle"]
KEYS = [f"cables.{name}.contraction" for name in TENDONS]
U_MAX = 15.0                                    # mm, an upper bound for every tendon

with Session(DESIGN, ["mesh.size=4"]) as s:
    solves = 0

    def tip(u) -> np.ndarray:
        """The tip's equilibrium position for contractions u (one warm solve)."""
        global solves
        s.set(dict(zip(KEYS, map(float, u))))
        r = s.solve()
        assert r.converged, r.status
        solves += 1
        return np.array(r.markers["tip"]["position"])

    target = tip([6.0, 4.0, 0.0, 0.0])
    u, lam, h = np.zeros(4), 1e-2, 0.05
    y = tip(u)
    path, errors = [y], [np.linalg.norm(y - target)]
    while errors[-1] > 1e-3 and len(errors) < 30:
        J = np.column_stack([(tip(u + h * e) - y) / h for e in np.eye(4)])   # dy/du, forward differences
        while True:                                  # bounded Levenberg-Marquardt step
            step = np.linalg.solve(J.T @ J + lam * np.eye(4), J.T @ (target - y))
            u_new = np.clip(u + step, 0.0, U_MAX)
            y_new = tip(u_new)
            if np.linalg.norm(y_new - target) < errors[-1]:
                lam = max(lam / 4, 1e-6)
                break
            lam *= 4                                 # a worse pose is never accepted
        u, y = u_new, y_new
        path.append(y)
        errors.append(np.linalg.norm(y - target))

print("target", target.round(3), "mm")
for name, value in zip(TENDONS, u):
    print(f"  {name:16s} {value:6.3f} mm")
print(f"reached within {errors[-1]:.2e} mm after {len(errors) - 1} steps and {solves} forward solves")

# %%
# The tip's path over the IK steps, and the error per step
# --------------------------------------------------------

path = np.array(path)
fig, (ax, bx) = plt.subplots(1, 2, figsize=(9, 4))
ax.plot(path[:, 0], path[:, 1], "o-", label="tip after each IK step")
ax.plot(*target, "x", color="tab:red", ms=12, mew=3, label="target")
ax.set_aspect("equal")
ax.set_xlabel("x [mm]")
ax.set_ylabel("y [mm]")
ax.legend(fontsize=8)
bx.semilogy(errors, "o-")
bx.set_xlabel("IK step")
bx.set_ylabel("|y(u) − y′| [mm]")
fig.tight_layout()
plt.show()

# %%
# Checks: the target is reached to 0.001 mm (far inside ``skelfem ik``'s
# default tolerance of 1e-3 × the finger's length, 0.1 mm) and no tendon
# pushes.
assert errors[-1] < 1e-3, errors
assert (u >= 0).all()
