"""studies/mpi_speed.py on a coarse design: serial and mpirun -n 2 runs, timed, agreeing."""
import pytest
from _studies import load_study

from conftest import GEOMETRY

pytestmark = [pytest.mark.mpi, pytest.mark.slow]


def test_mpi_speed_tiny(tmp_path, mpirun):
    study = load_study("mpi_speed")
    r = study.run(GEOMETRY / "finger4.toml", ["mesh.size=4"], ranks=2, repeats=1, out=tmp_path)
    for side in ("serial", "parallel"):
        assert r[side]["wall"] > r[side]["solve"] > 0.0 and r[side]["setup"] > 0.0
    assert r["wall_ratio"] == pytest.approx(r["parallel"]["wall"] / r["serial"]["wall"])
    assert r["energy_difference"] <= 1e-8 * max(1.0, abs(r["energy"]))
    assert len(r["newton_iterations"]) == 1                 # the same iterates on 1 and 2 ranks
