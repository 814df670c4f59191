"""Every bundled example runs, as a user runs it, at a small size: each design in geometry/ through
`skelfem simulate` (a run in time for a design with [dynamics]) on a coarser mesh, and the bundled
calibration data through `skelfem calibrate` as the calibration guide shows it."""
import json
import subprocess
import sys
import tomllib

import pytest
from conftest import GEOMETRY, MPI_ENV, ROOT

DESIGNS = sorted(p.name for p in GEOMETRY.glob("*.toml"))
COARSE = {2: 3.0, 3: 8.0}            # mesh size, mm, by dimension
# designs another test runs as bundled, with more checks (not run twice)
RUN_ELSEWHERE = {"two_fingers3d.toml": "tests/test_bodies_3d.py"}


def _run(args, cwd):
    return subprocess.run([sys.executable, "-m", "skelfem", *args], cwd=cwd, capture_output=True, text=True,
                          env={**MPI_ENV, "PYTHONPATH": str(ROOT)}, timeout=600)


def test_every_design_in_geometry_is_listed_here():
    assert len(DESIGNS) >= 15 and "flick.toml" in DESIGNS and "gripper.toml" in DESIGNS


@pytest.mark.slow
@pytest.mark.parametrize("name", DESIGNS)
def test_a_bundled_design_runs_at_a_small_size(name, tmp_path):
    if name in RUN_ELSEWHERE:
        assert (ROOT / RUN_ELSEWHERE[name]).read_text().count(name.removesuffix(".toml")) > 0
        return
    data = tomllib.loads((GEOMETRY / name).read_text())
    dim = data.get("dim", 2)
    args = ["simulate", str(GEOMETRY / name), "--out", str(tmp_path / "out"), "-q",
            "--set", f"mesh.size={max(COARSE[dim], data['mesh']['size'])}"]
    if "dynamics" in data:
        args += ["--set", f"dynamics.duration={5 * data['dynamics']['dt']}"]
    p = _run(args, tmp_path)
    assert p.returncode == 0, p.stderr[-2000:]
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["converged"] is True
    if "dynamics" in data:
        assert result["dynamics"]["steps"] >= 5 and (tmp_path / "out" / "trajectory.csv").exists()


@pytest.mark.slow
def test_the_bundled_calibration_data_calibrates(tmp_path):
    p = _run(["calibrate", str(GEOMETRY / "finger.toml"), "--data", str(GEOMETRY / "finger_calibration.csv"),
              "--fit", "materials.ecoflex.E", "--set", "mesh.size=4", "--sigma", "markers.*=0.05",
              "--sigma", "cables.flexor.tension=0.02", "--out", str(tmp_path / "cal"), "-q"], tmp_path)
    assert p.returncode == 0, p.stderr[-2000:]
    out = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    E = out["parameters"]["materials.ecoflex.E"]
    E = E["value"] if isinstance(E, dict) else E
    assert 0.05 < E < 0.2                                    # the data were made with E = 0.1 MPa (finer mesh)
