"""
A run in time
=============

A design with a ``[dynamics]`` section runs in time: every step of size dt
is one minimisation of the incremental potential (the energy plus the
inertia of the step) with the same Newton solver as a static solve. A
session takes the design as a dict of the TOML's keys, so the demo finger
gets its dynamics here in Python: the flexor's contraction follows a
schedule (0 to 8 mm in 50 ms, then held), BDF2 steps of 10 ms, and a little
mass damping so that the finger settles within the 0.6 s of the run.

:meth:`skelfem.Session.run_in_time` returns a Result whose ``report.trajectory`` has
one row per accepted step (``trajectory.csv`` of ``skelfem simulate``).
"""
from pathlib import Path
import tomllib

import matplotlib.pyplot as plt
import numpy as np

from skelfem import Session

# the repository's root, where the bundled designs are (sphinx-gallery runs an example
# from its own folder and without __file__)
ROOT = Path(__file__).resolve().parent.parent if "__file__" in globals() else Path.cwd().parent
with open(ROOT / "geometry" / "finger.toml", "rb") as f:
    design = tomllib.load(f)

design["mesh"]["size"] = 4.0
flexor = next(c for c in design["cables"] if c["name"] == "flexor")
flexor["schedule"] = [[0.0, 0.0], [0.05, 8.0]]          # [time s, contraction mm], held after the end
design["dynamics"] = {"dt": 0.01, "duration": 0.6, "integrator": "bdf2", "damping": {"mass": 20.0}}

with Session(design) as s:
    run = s.run_in_time()
    static = s.solve()        # the static equilibrium at the held contraction (8 mm), from rest

rows = run.report.trajectory
t = np.array([row["time"] for row in rows])
x = np.array([row["tip_x"] for row in rows])
y = np.array([row["tip_y"] for row in rows])
kinetic = np.array([row["kinetic_energy"] for row in rows])
end, rest = np.array(run.markers["tip"]["position"]), np.array(static.markers["tip"]["position"])
print(f"{run.dynamics['steps']} steps, {run.dynamics['cuts']} cut, {run.dynamics['newton_iterations']} Newton "
      f"iterations; time reached {run.dynamics['time_reached']} s")
print("tip at the end", end.round(3), "mm; static equilibrium", rest.round(3), "mm; apart",
      f"{np.linalg.norm(end - rest):.3f} mm")

# %%
# The tip against time
# --------------------

fig, (ax, bx) = plt.subplots(1, 2, figsize=(9, 4))
ax.plot(t, x, label="tip x")
ax.plot(t, y, label="tip y")
ax.axhline(rest[0], ls="--", color="tab:blue", lw=0.8)
ax.axhline(rest[1], ls="--", color="tab:orange", lw=0.8)
ax.set_xlabel("time [s]")
ax.set_ylabel("[mm]")
ax.set_title("dashed: the static equilibrium")
ax.legend(fontsize=8)
bx.semilogy(t[1:], kinetic[1:])
bx.set_xlabel("time [s]")
bx.set_ylabel("kinetic energy [N mm]")
fig.tight_layout()
plt.show()

# %%
# Checks: with mass damping the motion settles onto the static equilibrium of
# the same mesh (within 0.5 mm after 0.6 s; 0.13 mm when this was written),
# and that equilibrium is the first example's (the same design, mesh and 8 mm).
# Once the schedule has ended the tendon's rest length is exactly its path's
# length less 8 mm, and its tension k (l - L) at every step, the last included;
# the kinetic energy has fallen to a thousandth of its peak.
assert run.converged
assert np.linalg.norm(end - rest) < 0.5, (end, rest)
assert np.allclose(rest, [-35.516, 82.526], atol=0.05), rest
path = np.array(flexor["path"], float)
L0 = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
c = run.cables["flexor"]
assert np.isclose(c["rest_length"], L0 - 8.0, rtol=1e-12), (c["rest_length"], L0)
assert np.isclose(c["tension"], flexor["stiffness"] * (c["length"] - c["rest_length"]), rtol=1e-9), c
assert np.isclose(rows[-1]["flexor_tension"], c["tension"], rtol=1e-12)
assert kinetic[-1] < 1e-3 * kinetic.max(), (kinetic[-1], kinetic.max())
