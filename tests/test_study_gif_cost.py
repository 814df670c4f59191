"""studies/gif_cost.py at small size: every output's time is read back, and the GIF is a minor share."""
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "studies"))

pytestmark = pytest.mark.slow


def test_gif_cost_tiny(tmp_path):
    import gif_cost
    r = gif_cost.run(repeats=1, overrides=["dynamics.duration=0.1", "mesh.size=4"], out=tmp_path)
    assert (tmp_path / "gif_cost.json").exists()
    assert r["write_gif"] > 0 and r["write_xdmf"] > 0 and r["solve"] > 0
    assert r["wall_with_gif"] > r["write_gif"]
    assert r["gif_share_of_wall"] < 0.5          # the study's own run measures the share at full size
