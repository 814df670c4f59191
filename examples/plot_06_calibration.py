"""
Calibrating against measurements
================================

``geometry/finger_calibration.csv`` holds eight measured states of the demo
finger: the flexor contracted by 1 to 8 mm, the tip's position and the
flexor's tension in each. :func:`skelfem.calibrate` fits the silicone's E and
the tendon's stiffness to them (bounded Levenberg–Marquardt on exact
sensitivities of every row's equilibrium) and reports intervals, correlations
and what the data cannot separate; ``skelfem calibrate`` does the same from the
command line and writes a calibrated design.

The mesh is coarsened to 4 mm so that the example runs in a few seconds; the
data were measured on a finer model, so the coarse mesh is off by several
sigmas: the fit estimates that error in every cell, corrects itself by it and
widens the intervals by the correction (``model_error``, the default
``"inflate"``; see the guide's page on calibration).
"""
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from skelfem import Session, calibrate
from skelfem.viz.calplots import draw_fit

ROOT = Path(__file__).resolve().parent.parent if "__file__" in globals() else Path.cwd().parent
DESIGN = ROOT / "geometry" / "finger.toml"
DATA = ROOT / "geometry" / "finger_calibration.csv"

with Session(DESIGN, ["mesh.size=4"]) as s:
    cal = calibrate(s, DATA, fit=["materials.ecoflex.E", "cables.flexor.stiffness"],
                    sigma={"markers.*": 0.05, "cables.flexor.tension": 0.02})

for key, value, start, (lo, hi) in zip(cal.keys, cal.values, cal.initial, cal.ci95):
    print(f"{key:26s} {value:.5g} (start {start:g}), 95 % interval [{lo:.5g}, {hi:.5g}]")
print(f"correlation {cal.correlation[0, 1]:+.3f}; {cal.iterations} iterations, {cal.solves} solves; "
      f"unidentifiable: {cal.unidentifiable or 'none'}")
print("RMS misfit per column:", {c: round(v, 4) for c, v in cal.rms.items()})
print("model error / sigma per column:", {c: round(v["max_over_sigma_at_estimate"], 2)
                                           for c, v in cal.model_error["columns"].items()},
      f"({cal.model_error['corrections']} corrections)")

# %%
# The model against the data
# --------------------------
# One panel per measured column, row by row (error bars: the sigmas given).

fig = plt.figure(figsize=(10, 3.2))
draw_fit(fig, cal)
fig.tight_layout()

assert cal.converged and 0.09 < cal.values[0] < 0.14 and np.all(np.isfinite(cal.std))
