"""Calibration of a cable's friction coefficient from a loading/unloading sequence (the hysteresis loop)."""
import numpy as np
import pytest

from skelfem import Session
from skelfem.analysis.caldata import DataError, prepare_data
from skelfem.analysis.calibrate import calibrate, synthesize
from skelfem.design import load_design

from conftest import GEOMETRY

DESIGN = GEOMETRY / "finger_friction.toml"
CHANGED = ["mesh.size=6.0", "materials.ecoflex.nu=0.42", "cables.flexor.stiffness=15"]   # not the bundled one
COLUMNS = ["markers.tip.x", "markers.tip.y", "cables.flexor.tension"]
NOISE = {"markers.*": 0.05, "cables.flexor.tension": 0.02}
LOOP = [2.0, 4.0, 6.0, 8.0, 6.0, 4.0, 2.0]           # contraction up, then down: one load path


@pytest.mark.slow
def test_friction_is_recovered_from_a_hysteresis_loop(monkeypatch):
    """model_error "ignore" only reports the model's error, which this test does not read: its estimate (a
    quarter of the fit's time) is skipped, its cells reported as not estimated; values and intervals are
    the same without it."""
    from skelfem.analysis.calerror import ModelError
    monkeypatch.setattr(ModelError, "estimate", lambda self, rows, theta, states=None: (
        np.full(self.data.values.shape, np.nan), np.full(self.data.values.shape, np.nan)))
    with Session(DESIGN, CHANGED + ["cables.flexor.friction=0.2"]) as s:
        data = synthesize(s, {"cables.flexor.contraction": np.array(LOOP)}, COLUMNS,
                          experiments=["a"] * 7, noise=NOISE, rng=np.random.default_rng(5))
    tension = np.array(data["cables.flexor.tension"])
    assert tension[2] > tension[4] + 0.2            # the loop: more tension loading than unloading at 6 mm
    with Session(DESIGN, CHANGED + ["cables.flexor.friction=0.1"]) as s:
        cal = calibrate(s, data, ["cables.flexor.friction"], sigma=NOISE, model_error="ignore")
    assert cal.converged and abs(cal.values[0] / 0.2 - 1) < 0.1, cal.values
    lo, hi = cal.ci95[0]
    assert 0 < lo <= 0.2 <= hi and cal.identified[0]


def test_a_frictionless_cable_cannot_be_fitted_from_zero():
    with pytest.raises(DataError, match=r"starts at 0, a cable without friction.*--set cables.flexor.friction=0.1"):
        prepare_data(load_design(GEOMETRY / "finger.toml"), "markers.tip.x\n1\n2\n", ["cables.flexor.friction"])
    data = prepare_data(load_design(DESIGN), "markers.tip.x\n1\n2\n", ["cables.flexor.friction"])
    assert data.parameters[0].log and data.parameters[0].initial == 0.3
