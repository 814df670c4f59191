"""Calibration with the model's own error: estimated per cell, corrected and carried into the intervals
(inflate), removed by re-meshing (refine) or only reported (ignore); data from another, finer mesh."""
import csv
import json

import numpy as np
import pytest

from skelfem import Session
from skelfem.analysis.caldata import prepare_data
from skelfem.analysis.calibrate import calibrate, synthesize
from skelfem.analysis.calrows import Rows
from skelfem.cli.main import main

from conftest import GEOMETRY

THUMB = GEOMETRY / "thumb.toml"
CHANGED = ["materials.ecoflex.nu=0.40"]                 # not the bundled thumb
TRUE = {"materials.ecoflex.E": 0.065, "cables.flexor.stiffness": 11.0}
COLUMNS = ["markers.tip.x", "markers.tip.y", "cables.flexor.tension"]
SIGMA = {"markers.*": 0.1, "cables.flexor.tension": 0.05}


def thumb_data(size, degree, rows, seed=None):
    with Session(THUMB, CHANGED + [f"mesh.size={size}", f"mesh.degree={degree}"]) as s:
        s.set(TRUE)
        noise = SIGMA if seed is not None else None
        return synthesize(s, {"cables.flexor.contraction": np.linspace(1.0, 8.0, rows)}, COLUMNS, noise=noise,
                          rng=np.random.default_rng(seed))


def test_a_rows_estimate_is_the_sessions_at_its_conditions():
    """Rows set a row's conditions in place (Model.set_parameter): the estimate must solve the richer model
    with them, not with the design's values (it solved contraction 4 from a state at 6)."""
    with Session(THUMB, ["mesh.size=5.0", "cables.flexor.contraction=6.0"]) as s:
        s.solve()
        want = s.estimate()["errors"]
    with Session(THUMB, ["mesh.size=5.0"]) as s:
        data = prepare_data(s.design, {"cables.flexor.contraction": [6.0], "markers.tip.x": [0.0],
                                       "cables.flexor.tension": [1.0]}, ["materials.ecoflex.E"])
        with Rows(s, data) as rows:
            E, S = rows.errors([0.1])
    for j, c in enumerate(data.columns):
        assert E[0, j] == pytest.approx(want[c]["error"], rel=1e-5)
        assert S[0, j] == pytest.approx(want[c]["change"], rel=1e-5) and abs(S[0, j]) > 0


@pytest.mark.slow
def test_inflate_covers_the_truth_where_ignore_does_not():
    """Data of a finer P2 mesh, the fit on a coarse P1 one: ignoring the model's error puts the tendon's
    stiffness far off with a tight interval; inflate corrects it and its intervals hold the truth."""
    data = thumb_data(1.25, 2, 6, seed=3)
    true = np.array(list(TRUE.values()))
    with Session(THUMB, CHANGED + ["mesh.size=2.5"]) as s:
        out = {mode: calibrate(s, data, list(TRUE), sigma=SIGMA, model_error=mode) for mode in ("ignore", "inflate")}
    ignored, inflated = out["ignore"], out["inflate"]
    assert ignored.model_error["too_coarse"] and ignored.model_error["max_over_sigma"] > 3
    assert not np.all((ignored.ci95[:, 0] <= true) & (true <= ignored.ci95[:, 1]))
    assert np.all((inflated.ci95[:, 0] <= true) & (true <= inflated.ci95[:, 1])), inflated.ci95
    me = inflated.model_error
    assert me["mode"] == "inflate" and me["corrections"] >= 1 and all(v > 0 for v in me["std_share"].values())
    assert set(me["columns"]) == set(COLUMNS) and all(v["max_over_sigma_at_estimate"] > 0
                                                       for v in me["columns"].values())
    assert abs(inflated.values[0] / true[0] - 1) < abs(ignored.values[0] / true[0] - 1)      # E: less bias
    assert inflated.model_errors.shape == (6, 3) and np.all(inflated.model_errors > 0)


@pytest.mark.slow
def test_refine_halves_the_mesh_until_the_dof_cap(caplog):
    data = thumb_data(2.5, 2, 3)
    with Session(THUMB, CHANGED + ["mesh.size=5.0"]) as s:
        cap = 4 * s.dofs + 200                   # one halving fits, the next (16x) does not
        cal = calibrate(s, data, list(TRUE), sigma=SIGMA, model_error="refine", max_dofs=cap)
        assert s.design.mesh.size == 2.5          # the session keeps the finer mesh
    me = cal.model_error
    assert [m["size"] for m in me["meshes"]][:2] == [5.0, 2.5] and me["capped"]
    assert me["meshes"][1]["max_over_sigma"] < me["meshes"][0]["max_over_sigma"]
    assert "would pass" in me["how"] and str(cap) in me["how"]
    assert caplog.text.count("the error left is inflated") == 1          # said once, not at every check
    assert [m["at"] for m in me["meshes"]][-1] == "estimate"


@pytest.mark.slow
def test_the_cli_reports_the_model_error(tmp_path, capsys):
    data = thumb_data(2.5, 2, 3)
    path = tmp_path / "data.csv"
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["cables.flexor.contraction"] + COLUMNS)
        for i in range(3):
            w.writerow([data["cables.flexor.contraction"][i]] + [data[c][i] for c in COLUMNS])
    out = tmp_path / "cal"
    code = main(["calibrate", str(THUMB), "--set", "mesh.size=5.0", "--set", "materials.ecoflex.nu=0.4",
                 "--data", str(path), "--fit", "materials.ecoflex.E", "--sigma", "markers.*=0.1",
                 "--sigma", "cables.flexor.tension=0.05", "--out", str(out)])
    printed = capsys.readouterr()
    assert code in (0, 2), printed.err
    assert "model error (max e/sigma): markers.tip.x" in printed.out and "inflate:" in printed.out
    assert "WARNING" not in printed.err                       # the estimate's advice on tolerances stays quiet
    res = json.loads((out / "calibration.json").read_text())
    assert res["model_error"]["mode"] == "inflate" and set(res["model_error"]["columns"]) == set(COLUMNS)
    with (out / "fit.csv").open() as f:
        header = next(csv.reader(f))
    assert "markers.tip.x:model_error" in header and "cables.flexor.tension:model_error" in header


def test_a_failed_estimate_is_a_warning_not_a_crash(monkeypatch, caplog):
    """A richer solve that raises (a factorisation failing, say) leaves those cells without an estimate,
    taken as 0 and counted in the report; the calibration still answers."""
    import skelfem.estimate

    def broken(session):
        raise RuntimeError("MUMPS: not enough memory")
    with Session(THUMB, ["mesh.size=5.0"]) as s:
        data = synthesize(s, {"cables.flexor.contraction": [2.0, 4.0, 6.0]}, COLUMNS)
        monkeypatch.setattr(skelfem.estimate, "estimate", broken)
        cal = calibrate(s, data, ["materials.ecoflex.E"], sigma=SIGMA)
    assert cal.converged and cal.values[0] == pytest.approx(0.1, rel=1e-4)
    assert cal.model_error["not_estimated"] == 9 and np.all(np.isnan(cal.model_errors))
    assert "no model error estimate" in caplog.text
