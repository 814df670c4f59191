"""studies/sweep_speedup.py on two coarse cases: the same sweep serially, under mpirun and as two processes."""
import json

import pytest
from _studies import load_study

pytestmark = [pytest.mark.mpi, pytest.mark.slow]


def test_sweep_speedup_tiny(tmp_path, mpirun):
    study = load_study("sweep_speedup")
    r = study.run(cases=2, ranks=2, size=4.0, out=tmp_path)
    assert r["cases"] == 2 and r["ranks"] == 2
    for key in ("serial_s", "parallel_s", "independent_s"):
        assert r[key] > 0.5, key                       # each is a real run: interpreter, mesh and solves
    assert r["ratio"] == pytest.approx(r["parallel_s"] / r["serial_s"])
    assert r["machine_ratio"] == pytest.approx(r["independent_s"] / r["serial_s"])
    assert 0.2 < r["ratio"] < 5.0 and 0.2 < r["machine_ratio"] < 5.0
    for run in ("serial", "parallel"):                 # every case of both sweeps converged and was written
        results = sorted((tmp_path / run).rglob("result.json"))
        assert len(results) == 2, run
        assert all(json.loads(p.read_text())["converged"] for p in results)
