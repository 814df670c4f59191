"""skelfem bench: the table, bench.json's fields, positive times, quadratic Newton, bad input."""
import json
from pathlib import Path

import numpy as np
import pytest

from skelfem.bench import convergence_orders
from skelfem.cli import main

FINGER = Path(__file__).resolve().parents[1] / "geometry" / "finger.toml"


@pytest.fixture(scope="module")
def bench_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    status = main(["bench", str(FINGER), "--sizes", "6", "4", "--repeats", "1", "--out", str(out), "-q"])
    return status, out


def test_bench_writes_json_with_positive_times(bench_run):
    status, out = bench_run
    assert status == 0
    assert not list(out.glob(".*"))                      # atomic: no temporary left behind
    result = json.loads((out / "bench.json").read_text())
    assert [r["size"] for r in result["rows"]] == [6.0, 4.0]
    small, big = result["rows"]
    assert 0 < small["dofs"] < big["dofs"]
    for r in result["rows"]:
        assert r["converged"] and r["status"] == "converged"
        for key in ("assembly_time", "refactorization_time", "iteration_time_median", "iteration_time_mean",
                    "solve_time", "floor_time"):
            assert np.isfinite(r[key]) and r[key] > 0, key
        assert r["newton_iterations"] > 0
        assert r["ratio"] == pytest.approx(r["iteration_time_median"] / r["floor_time"])
        # an iteration contains an assembly and a factorisation: it cannot be far below their sum
        assert r["ratio"] > 0.3
        assert r["nnz"] > r["fe_pattern"]["nnz"] > 0       # the cables add entries to the pattern
        assert r["breakdown"]["factorization"] > 0 and r["breakdown"]["jacobian"] > 0
        assert r["breakdown"]["calls_per_iteration"]["jacobian"] == pytest.approx(1.0)
        lr = r["low_rank_prototype"]
        assert lr["available"] and lr["nnz"] < r["nnz"]
        assert lr["direction_difference"] < 1e-6           # Woodbury gives the same Newton direction
    assert not result["floor"]["checked"]                  # too small for the 20k-DOF floor


def test_bench_newton_step_is_quadratic_and_ends_at_round_off(bench_run):
    _, out = bench_run
    row = json.loads((out / "bench.json").read_text())["rows"][-1]
    assert row["newton_order"]["slope"] == pytest.approx(2.0, abs=0.2)
    assert row["last_residuals"][-1] <= max(1e-8, 10 * row["residual_floor"])


def test_convergence_orders_of_model_sequences():
    quadratic = [1e-1, 1e-2, 1e-4, 1e-8]
    linear = [1e-1, 1e-2, 1e-3, 1e-4]
    assert convergence_orders(quadratic) == pytest.approx([2.0, 2.0])
    assert convergence_orders(linear) == pytest.approx([1.0, 1.0])
    assert convergence_orders(quadratic + [1e-20], noise=1e-12) == pytest.approx([2.0, 2.0])


@pytest.mark.parametrize("args", [["--sizes", "4", "-1"], ["--repeats", "0"], ["--set", "mesh.degree=3"]])
def test_bench_bad_input_is_one_error_line(tmp_path, capsys, args):
    status = main(["bench", str(FINGER), "--out", str(tmp_path / "o"), *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 1
    assert len(err) == 1 and err[0].startswith("error:")
    assert not (tmp_path / "o").exists()
