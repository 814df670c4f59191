"""The command line's summary says how deep a 2D design's slab is, and when that is the 1 mm default."""
import subprocess
from pathlib import Path

import pytest

from skelfem.cli.common import meshing_line
from skelfem.design import load_design, parse_design

from conftest import SKELFEM


ROOT = Path(__file__).resolve().parents[1]
STRIP = {"format": 1, "name": "strip", "dim": 2, "mesh": {"size": 4.0},
         "materials": {"silicone": {"E": 0.1, "nu": 0.45}},
         "body": {"outline": [[0, 0], [10, 0], [10, 40], [0, 40]], "material": "silicone"},
         "pins": [{"name": "base", "region": [[-1, -1], [11, 0.01]]}]}


def test_a_2d_design_without_thickness_is_said_to_be_a_1_mm_slab():
    line = meshing_line(parse_design(STRIP, "strip.toml"))
    assert line == "strip: meshing (size 4 mm, P1, a 1 mm slab: thickness not given, the default)"


def test_a_given_thickness_is_printed_as_given():
    assert meshing_line(load_design(ROOT / "geometry" / "finger.toml")).endswith(", a 20 mm slab)")
    assert "slab" not in meshing_line(load_design(ROOT / "geometry" / "finger3d.toml"))


@pytest.mark.slow
def test_the_cli_prints_it(tmp_path):
    design = tmp_path / "strip.toml"
    design.write_text('format = 1\nname = "strip"\n[materials]\ns = { E = 0.1, nu = 0.45 }\n'
                      '[body]\noutline = [[0, 0], [10, 0], [10, 40], [0, 40]]\nmaterial = "s"\n'
                      '[[pins]]\nname = "base"\nregion = [[-1, -1], [11, 0.01]]\n')
    out = subprocess.run([SKELFEM, "simulate", str(design), "--out", str(tmp_path / "out"), "--no-picture",
                          "--set", "mesh.size=5"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "a 1 mm slab: thickness not given, the default" in out.stdout + out.stderr
