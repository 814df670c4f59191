"""skelfem calibrate: a fit from CSV to calibrated design, and bad input refused before meshing."""
import json
import tomllib

import pytest

from skelfem.cli.main import main

from conftest import GEOMETRY

FINGER = GEOMETRY / "finger.toml"
HEADER = "cables.flexor.contraction,markers.tip.x,markers.tip.y,cables.flexor.tension\n"
ROWS = ("2.0,-1.9933223151859956,97.65964934214473,1.472393274892454\n"
        "4.0,-13.862069783258399,94.43972635675517,3.054206648346849\n"
        "6.0,-25.16956577563269,89.35530109028294,4.727845989792172\n"
        "8.0,-35.51594940410135,82.52645450860332,6.479869387406723\n")     # finger.toml at mesh.size 4


@pytest.mark.slow
def test_calibrate_writes_every_file(tmp_path, capsys, monkeypatch):
    """With --model-error ignore the model's error is only reported, and this test reads none of it: its
    estimate (a richer solve of every row, twice) is skipped, its cells reported as not estimated."""
    import numpy as np

    from skelfem.analysis.calerror import ModelError

    def not_estimated(self, rows, theta, states=None):
        assert self.mode == "ignore"
        return np.full(self.data.values.shape, np.nan), np.full(self.data.values.shape, np.nan)
    monkeypatch.setattr(ModelError, "estimate", not_estimated)
    data = tmp_path / "data.csv"
    data.write_text(HEADER + ROWS)
    out = tmp_path / "cal"
    code = main(["calibrate", str(FINGER), "--set", "mesh.size=4.0", "--set", "materials.ecoflex.E=0.2",
                 "--data", str(data), "--fit", "materials.ecoflex.E", "--fit", "cables.flexor.stiffness",
                 "--sigma", "markers.*=0.1", "--sigma", "cables.flexor.tension=0.01", "--holdout", "0.25",
                 "--model-error", "ignore", "--out", str(out), "-q"])     # the data are this mesh's own
    assert code == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["calibrated.toml", "calibration.json", "fit.csv", "fit.png",
                                                     "parameters.png", "residuals.png"]
    res = json.loads((out / "calibration.json").read_text())
    e = res["parameters"]["materials.ecoflex.E"]
    assert res["converged"] and e["initial"] == 0.2 and e["value"] == pytest.approx(0.1, rel=1e-6)
    assert e["ci95"][0] <= e["value"] <= e["ci95"][1] and res["holdout"]["rows"] == 1
    text = (out / "calibrated.toml").read_text()
    assert "# A cable-driven finger" in text and "size = 2.0" in text      # comments kept, mesh not
    cal = tomllib.loads(text)
    assert cal["materials"]["ecoflex"]["E"] == pytest.approx(0.1, rel=1e-6)


BAD = [
    (HEADER.replace("markers.tip.y", "markers.nail.y") + ROWS, [], "'markers.nail.y' names no marker"),
    (HEADER + ROWS.replace("97.65964934214473", "ninety"), [], "'ninety' is not a number"),
    (HEADER + ROWS.splitlines()[0] + "\n", ["--fit", "cables.lig1_dorsal.stiffness", "--fit", "materials.pla.E",
                                           "--fit", "materials.ecoflex.nu"], "fewer than the 5 parameters"),
    (HEADER + ROWS, ["--fit", "mesh.size"], "'mesh.size' is not a live parameter"),
    (HEADER + ROWS, ["--bounds", "materials.ecoflex.E=0.5,1"], "excludes the start 0.1"),
    (HEADER + ROWS, ["--holdout", "1.5"], "--holdout 1.5"),
    (HEADER + ROWS, ["--bounds", "cables.flexor.stiffness=-100,100"], "needs a lower bound > 0"),
    (HEADER + ROWS, ["--fit", "materials.ecoflex.nu", "--bounds", "materials.ecoflex.nu=-0.5,0.6"],
     "0.6 is not a valid value (materials.ecoflex.nu: must lie in (-1, 0.5)"),
    (HEADER + ROWS, ["--sigma", "markers.*=1e-200"], "must lie within 1e-09 and 1e+09 times that"),
    (HEADER + ROWS.replace("97.65964934214473", "97_659"), [], "'97_659' is not a number"),
    (HEADER + ROWS, ["--starts", "0"], "--starts 0"),
    (HEADER + ROWS, ["--max-dofs", "0"], "--max-dofs 0"),
    (HEADER + ROWS, ["--model-error", "maybe"], "--model-error"),
]


@pytest.mark.parametrize("text, extra, message", BAD,
                         ids=["unknown column", "non-numeric", "too few rows", "not live", "bounds", "holdout",
                              "negative stiffness bound", "nu bound", "tiny sigma", "underscore", "starts",
                              "max dofs", "model error mode"])
def test_bad_input_one_line_nothing_written_no_meshing(tmp_path, capsys, monkeypatch, text, extra, message):
    import skelfem.jobs.run as run

    def no_meshing(*a, **k):
        raise AssertionError("meshed")
    monkeypatch.setattr(run, "open_session", no_meshing)
    data = tmp_path / "data.csv"
    data.write_text(text)
    out = tmp_path / "never"
    code = main(["calibrate", str(FINGER), "--data", str(data), "--fit", "materials.ecoflex.E",
                 "--fit", "cables.flexor.stiffness", *extra, "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and err[0].startswith("error:") and message in err[0], err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["data.csv"]


def test_csv_over_the_size_limit(tmp_path, capsys, monkeypatch):
    import skelfem.analysis.caldata as caldata
    monkeypatch.setattr(caldata, "MAX_BYTES", 200)
    data = tmp_path / "data.csv"
    data.write_text(HEADER + ROWS * 3)
    assert main(["calibrate", str(FINGER), "--data", str(data), "--fit", "materials.ecoflex.E",
                 "--out", str(tmp_path / "never"), "-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "over the limit of 200" in err[0]
    assert not (tmp_path / "never").exists()


def test_interrupted_calibration_writes_nothing(tmp_path, capsys, monkeypatch):
    import skelfem.analysis.calibrate as calibrate

    def interrupted(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(calibrate, "calibrate", interrupted)
    data = tmp_path / "data.csv"
    data.write_text(HEADER + ROWS)
    code = main(["calibrate", str(FINGER), "--set", "mesh.size=4.0", "--data", str(data),
                 "--fit", "materials.ecoflex.E", "--out", str(tmp_path / "cal"), "-q"])
    assert code == 130 and "interrupted" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv"]          # no folder, lock or staging


def test_progress_line(capsys):
    from skelfem.cli.calibrate import _progress
    show = _progress(True)
    show(2, 3, 8)
    show(2, 8, 8)
    err = capsys.readouterr().err
    assert "iteration  2" in err and "row 3/8" in err and err.endswith("\r")


def test_a_row_that_does_not_converge_exits_2_and_writes_nothing(tmp_path, capsys):
    data = tmp_path / "data.csv"
    data.write_text(HEADER + ROWS)
    code = main(["calibrate", str(FINGER), "--set", "mesh.size=4.0", "--set", "solver.max_iterations=1",
                 "--data", str(data), "--fit", "materials.ecoflex.E", "--out", str(tmp_path / "cal"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "row 1: the equilibrium did not converge" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv"]


def test_a_fit_that_does_not_converge_exits_2_with_a_partial_result(tmp_path, capsys):
    data = tmp_path / "data.csv"
    data.write_text(HEADER + ROWS)
    out = tmp_path / "cal"
    out.mkdir()
    (out / "calibrated.toml").write_text("# an earlier run's\n")           # replaced, not left beside it
    code = main(["calibrate", str(FINGER), "--set", "mesh.size=4.0", "--set", "materials.ecoflex.E=0.3",
                 "--data", str(data), "--fit", "materials.ecoflex.E", "--max-iterations", "1",
                 "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "did not converge (max_iterations)" in err[0], err
    assert sorted(p.name for p in out.iterdir()) == ["calibration.json", "fit.csv", "fit.png", "parameters.png",
                                                     "partial.toml", "residuals.png"]
    res = json.loads((out / "calibration.json").read_text())
    assert res["converged"] is False and res["iterations"] == 1
    assert res["cost_history"][-1] < res["cost_history"][0]                  # its best state, not the start
    partial = tomllib.loads((out / "partial.toml").read_text())
    assert partial["materials"]["ecoflex"]["E"] == pytest.approx(res["parameters"]["materials.ecoflex.E"]["value"])


def test_a_failed_sensitivity_solve_exits_2_and_writes_nothing(tmp_path, capsys, monkeypatch):
    from skelfem.analysis.sensitivity import Linearization

    def stalled(self, B):
        raise RuntimeError("sensitivity through friction: GMRES did not converge (|r| 0.1)")
    monkeypatch.setattr(Linearization, "solve_many", stalled)
    data = tmp_path / "data.csv"
    data.write_text(HEADER + ROWS)
    code = main(["calibrate", str(FINGER), "--set", "mesh.size=4.0", "--data", str(data),
                 "--fit", "materials.ecoflex.E", "--out", str(tmp_path / "cal"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "sensitivity solve failed" in err[0] and "GMRES" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv"]
