"""studies/fabrication_volumes.py on finger_soft.toml: the guide's fabrication tables carry the numbers the
run writes into its own fabrication.json (the mould cavity against the body, how each part lies)."""
import importlib.util
import sys
from pathlib import Path

import pytest

from _studies import load_study

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[1]


def studytables():
    spec = importlib.util.spec_from_file_location("studytables", ROOT / "docs" / "_ext" / "studytables.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("studytables", module)
    spec.loader.exec_module(module)
    return module


def test_the_guides_tables_are_the_runs_numbers(tmp_path, monkeypatch):
    r = load_study("fabrication_volumes").run(designs=("finger_soft",), out=tmp_path / "fabrication_volumes")
    (row,) = r["rows"]
    assert r["all_passed"] and row["bones"] == {}
    assert row["cavity_relative_error"] == pytest.approx(row["cavity_volume"] / row["body_volume"] - 1, rel=1e-9)
    assert 0 < row["cavity_relative_error"] < 0.05 and abs(row["closed_relative_error"]) < 1e-3
    assert set(row["parts"]) == {"mould_bottom", "mould_top"}
    assert all(p["bed_area"] > 0 for p in row["parts"].values())
    tables = studytables()
    monkeypatch.setattr(tables, "OUTPUT", tmp_path)
    volumes = tables.TABLES["fabrication_volumes"]({})
    (cells,) = volumes.rows
    assert f"({100 * row['cavity_relative_error']:+.2f} %)" in cells[3] and cells[1] == "(no bones)"
    poses = tables.TABLES["fabrication_poses"]({})
    assert [c[1] for c in poses.rows] == list(row["parts"])
