"""`skelfem simulate` end to end: files, exit codes, one-line errors."""
import json
from pathlib import Path

import numpy as np
import pytest

from _designs import strip
from _designs import toml_text as _toml
from skelfem.cli.main import main

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def strip_file(tmp_path):
    path = tmp_path / "strip.toml"
    path.write_text(_toml(strip(size=3.0, contraction=0.5)))
    return path


def test_simulate_writes_contract_result_xdmf_and_picture(strip_file, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["simulate", str(strip_file), "--out", str(out), "-q"]) == 0
    res = json.loads((out / "result.json").read_text())
    for key in ("format", "design", "converged", "status", "newton_iterations", "load_steps", "energy",
                "dofs", "cells", "degree", "min_jacobian", "markers", "cables", "pins", "grounds", "timings"):
        assert key in res
    assert res["converged"] and res["status"] == "converged" and res["min_jacobian"] > 0
    tip = res["markers"]["tip"]
    assert np.allclose(np.add(tip["reference"], tip["displacement"]), tip["position"])
    cable = res["cables"]["flexor"]
    assert cable["tension"] == pytest.approx(max(0.0, cable["length"] - cable["rest_length"]) * 1.0)
    assert set(res["timings"]) >= {"mesh", "compile", "solve", "total"}
    assert (out / "deformed.png").stat().st_size > 10_000
    import meshio
    m = meshio.read(out / "solution.xdmf")
    assert m.point_data["displacement"].shape == (len(m.points), 3)
    assert {"triangle", "line"} <= {c.type for c in m.cells}
    assert "region" in m.cell_data and "tension" in m.cell_data
    line_block = [i for i, c in enumerate(m.cells) if c.type == "line"][0]
    assert np.allclose(m.cell_data["tension"][line_block], cable["tension"])
    assert not list(out.glob(".*")), "temporary files left behind"


def test_set_overrides_change_the_run(strip_file, tmp_path):
    out = tmp_path / "o"
    assert main(["simulate", str(strip_file), "--out", str(out), "-q", "--no-picture",
                 "--set", "cables.flexor.contraction=0", "--set", "mesh.degree=2"]) == 0
    res = json.loads((out / "result.json").read_text())
    assert res["degree"] == 2
    assert np.allclose(res["markers"]["tip"]["displacement"], 0.0)


def test_bad_design_is_one_error_line_and_no_output(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    d = strip()
    d["body"]["material"] = "unobtainium"
    bad.write_text(_toml(d))
    out = tmp_path / "never"
    assert main(["simulate", str(bad), "--out", str(out), "-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "bad.toml" in err[0]
    assert not out.exists()


def test_missing_file_is_an_error(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "nope.toml"), "-q"]) == 1
    assert capsys.readouterr().err.startswith("error:")


def test_unconverged_solve_exits_2_and_says_why(strip_file, tmp_path, capsys):
    out = tmp_path / "fail"
    code = main(["simulate", str(strip_file), "--out", str(out), "-q",
                 "--set", "solver.max_iterations=1", "--set", "cables.flexor.contraction=5",
                 "--set", "cables.flexor.stiffness=50"])
    assert code == 2
    res = json.loads((out / "result.json").read_text())
    assert res["converged"] is False and res["status"] == "max_iterations"
    assert res["markers"] is None
    assert not (out / "solution.xdmf").exists()
    assert "error:" in capsys.readouterr().err
