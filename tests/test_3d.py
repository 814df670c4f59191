"""3D designs: tetrahedral meshing with tagged bones, the same solver, XDMF and picture output."""
import json
from pathlib import Path

import numpy as np
import pytest

from skelfem.cli.main import main
from skelfem.design import load_design
from skelfem.mesh.geometry import mesh_design

GEOMETRY = Path(__file__).resolve().parents[1] / "geometry"


@pytest.mark.parametrize("name", ["finger3d", "arm3d"])
def test_3d_design_meshes_tetrahedra_with_named_bones(name):
    design = load_design(GEOMETRY / f"{name}.toml", ["mesh.size=8"])
    tm = mesh_design(design)
    assert tm.mesh.topology.cell_type.name == "tetrahedron"
    assert set(tm.tags) == {"body"} | {f"bone:{b.name}" for b in design.bones}
    for tag in tm.tags.values():
        assert len(tm.cell_tags.find(tag)) > 0


def _run(design, out, *sets):
    code = main(["simulate", str(GEOMETRY / design), "--out", str(out), "-q", *sum((["--set", s] for s in sets), [])])
    return code, json.loads((out / "result.json").read_text())


@pytest.mark.slow
def test_finger3d_bends_like_the_2d_finger(tmp_path):
    """Same outlines and contraction: the tip moves the same way, within the 2D/3D modelling gap."""
    code2, r2 = _run("finger.toml", tmp_path / "2d", "mesh.size=4")
    code3, r3 = _run("finger3d.toml", tmp_path / "3d", "mesh.size=5")
    assert code2 == code3 == 0
    d2 = np.array(r2["markers"]["tip"]["displacement"])
    d3 = np.array(r3["markers"]["tip"]["displacement"])
    assert d3.shape == (3,) and abs(d3[2]) < 0.05 * np.linalg.norm(d3)     # stays in its plane
    assert np.linalg.norm(d3[:2] - d2) < 0.15 * np.linalg.norm(d2)          # same bend within 15 %
    assert r3["min_jacobian"] > 0


def test_3d_outputs_open_in_meshio_with_fields_and_cables(tmp_path, picture):
    import meshio
    code, res = _run("arm3d.toml", tmp_path, "mesh.size=9")
    assert code == 0 and res["converged"]
    m = meshio.read(tmp_path / "solution.xdmf")
    assert {"tetra", "line"} <= {c.type for c in m.cells}
    assert m.point_data["displacement"].shape == (len(m.points), 3)
    tets = [i for i, c in enumerate(m.cells) if c.type == "tetra"][0]
    assert set(np.unique(m.cell_data["region"][tets])) == {1.0, 2.0, 3.0, 4.0, 5.0}
    lines = [i for i, c in enumerate(m.cells) if c.type == "line"][0]
    tension = m.cell_data["tension"][lines]
    assert np.isclose(tension.max(), max(c["tension"] for c in res["cables"].values()))
    picture(tmp_path / "deformed.png", 800, 800)
    # the biceps (front) pulls the forearm up: the wrist rises
    assert res["markers"]["wrist"]["displacement"][2] > 5.0


def test_soft_ik_works_unchanged_in_3d(tmp_path, picture):
    out = tmp_path / "ik"
    code = main(["ik", str(GEOMETRY / "arm3d.toml"), "--marker", "hand", "--target", "50", "90", "-120",
                 "--set", "mesh.size=9", "--out", str(out), "-q"])
    assert code == 0
    res = json.loads((out / "ik.json").read_text())
    assert res["reached"] and res["error"] < res["tol"] and res["forward_solves"] <= 15
    picture(out / "ik.png", 800, 800)
