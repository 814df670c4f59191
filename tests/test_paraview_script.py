"""docs/paraview/skelfem_view.py (a pvbatch script; ParaView is not a dependency, so it does not run
here): it compiles, and every field it colours, warps or thresholds by is in the solution.xdmf that
skelfem writes, 2D and 3D, with the fill values the script relies on."""
import py_compile
import re

import numpy as np
import pytest
from conftest import ROOT

SCRIPT = ROOT / "docs" / "paraview" / "skelfem_view.py"


def _fields() -> set:
    text = SCRIPT.read_text()
    return set(re.findall(r'["(\[]\s*"(?:CELLS|POINTS)",\s*"(\w+)"', text)) | \
        set(re.findall(r'_between\(\w+, "(\w+)"', text))


def test_the_scripts_compile_and_name_fields():
    for script in SCRIPT.parent.glob("*.py"):
        py_compile.compile(str(script), doraise=True)
    assert {p.name for p in SCRIPT.parent.glob("*.py")} == {"skelfem_view.py", "skelfem_series.py", "skelfem_parts.py"}
    assert _fields() == {"region", "cable", "displacement", "stretch", "tension"}


@pytest.mark.parametrize("design", ["finger.toml", "pillar3d.toml"])
def test_every_field_the_script_uses_is_in_solution_xdmf(design, tmp_path):
    import meshio

    from skelfem import Session
    from skelfem.io.xdmf import write_xdmf
    from conftest import GEOMETRY
    with Session(GEOMETRY / design) as s:
        assert s.solve().converged
        write_xdmf(tmp_path / "solution.xdmf", s.model)
    m = meshio.read(tmp_path / "solution.xdmf")
    present = set(m.point_data) | set(m.cell_data)
    assert _fields() <= present, _fields() - present
    kinds = [b.type for b in m.cells]
    body = kinds.index("triangle" if design == "finger.toml" else "tetra")
    lines = kinds.index("line")
    # the script's thresholds: region >= 1 is the body alone, cable >= 0 the cables alone
    assert np.all(m.cell_data["region"][body] >= 1) and np.all(m.cell_data["region"][lines] < 1)
    assert np.all(m.cell_data["cable"][lines] >= 0) and np.all(m.cell_data["cable"][body] < 0)
    assert m.point_data["displacement"].shape[1] == 3


def test_the_render_study_says_what_it_needs_without_paraview(monkeypatch, capsys):
    from _studies import load_study
    study = load_study("paraview_renders")
    monkeypatch.setattr(study.shutil, "which", lambda tool: None)
    assert study.main([]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: this study needs ParaView") and "apt install" in err[0]
