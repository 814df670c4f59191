"""
A finger touching an object
===========================

The recipe of :doc:`/guide/first-object`: ``geometry/finger_block.toml``
puts the demo finger's skeleton and flexor beside a steel block on a floor.
Pulled 6 mm, the finger curls onto the block's corner and pushes it
sideways; the block stays where it is, held by its weight and the floor's
friction. Everything here is read from the :class:`~skelfem.Result`, whose
``to_dict()`` is result.json: ``objects``, ``contacts`` and ``grounds``.
"""
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from skelfem import Session

# the repository's root, where the bundled designs are (sphinx-gallery runs an example
# from its own folder and without __file__)
ROOT = Path(__file__).resolve().parent.parent if "__file__" in globals() else Path.cwd().parent
DESIGN = ROOT / "geometry" / "finger_block.toml"

with Session(DESIGN) as s:
    r = s.solve()
    design = s.design.raw

print(r)
block = r.to_dict()["objects"]["block"]
pairs = {tuple(c["between"]): c for c in r.to_dict()["contacts"]}
touch, stand = pairs[("body", "block")], pairs[("floor", "block")]
print(f"the finger presses the block with {touch['normal_magnitude']:.3f} N "
      f"(friction {np.linalg.norm(touch['friction_force']):.3f} N, sticking {touch['sticking']:.2f})")
print(f"the floor holds it with {-stand['normal_force'][1]:.3f} N up and "
      f"{abs(stand['friction_force'][0]):.3f} N of friction; its weight is {-block['weight'][1]:.3f} N")
print("the block moved", np.round(block["displacement"], 4), "mm")

# %%
# The finger, the block and the forces on it
# -------------------------------------------

fig, ax = plt.subplots(figsize=(5, 6))
if s.comm.size == 1:        # the deformed mesh is kept by serial sessions (under mpirun: solution.xdmf)
    r.plot(ax)
outline = np.array(design["objects"][0]["outline"]) + block["displacement"]
ax.fill(*np.vstack([outline, outline[:1]]).T, color="tab:blue", alpha=0.3, label="block")
ax.axhline(0.0, color="k", lw=1)
corner = np.array(r.markers["corner"]["position"])
on_block = -np.asarray(touch["normal_force"]) - np.asarray(touch["friction_force"])   # forces act on `between`[0]
ax.annotate("", corner + 10 * on_block, corner, arrowprops={"arrowstyle": "->", "color": "tab:red"})
ax.set_aspect("equal")
ax.set_xlabel("x [mm]")
ax.set_ylabel("y [mm]")
ax.set_title(f"flexor at {design['cables'][0]['contraction']:g} mm; force on the block ×10 mm/N", fontsize=9)
ax.legend(loc="upper left", fontsize=8)
fig.tight_layout()
plt.show()

# %%
# The numbers this example checks, each against the statics of a rigid block:
# it is held (the solve converged and it moved less than 0.05 mm); the forces
# on it balance its weight; the floor's friction stays inside its cone
# (mu = 0.8) while the finger's contact slides on it at mu = 0.4
# (``[contact.pairs]``), so its friction force is exactly 0.4 times the
# normal force.
assert r.converged, r.status
assert touch["normal_magnitude"] > 0.5, touch
assert np.linalg.norm(block["displacement"]) < 0.05, block
total = (-np.asarray(touch["normal_force"]) - np.asarray(touch["friction_force"])      # the finger on the block
         - np.asarray(stand["normal_force"]) - np.asarray(stand["friction_force"])     # the floor on the block
         + np.asarray(block["weight"]))
assert np.linalg.norm(total) < 0.01 * np.linalg.norm(block["weight"]), total
assert abs(stand["friction_force"][0]) < 0.8 * abs(stand["normal_force"][1])
assert touch["sticking"] == 0.0
assert np.isclose(np.linalg.norm(touch["friction_force"]), 0.4 * touch["normal_magnitude"], rtol=0.02)
