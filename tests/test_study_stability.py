"""studies/stability.py on a hard case: the energy line search converges where plain Newton fails."""
import json

import numpy as np
from _studies import load_study


def _load():
    return load_study("stability")


def test_energy_converges_where_plain_newton_fails(tmp_path, picture):
    study = _load()
    res = study.run(ratios=(1e6,), contractions=(8.0,), strategies=("none", "energy"), stepping=(1,),
                    size=5.0, out=tmp_path, progress=None)
    by = {r["strategy"]: r for r in res["cases"]}
    assert by["energy"]["converged"] and by["energy"]["min_jacobian"] > 0
    assert by["energy"]["newton_iterations"] < 30
    assert not by["none"]["converged"] and by["none"]["status"] != "converged"
    assert "tip_x" not in by["none"]                   # a failed solve is never reported as an equilibrium
    s = res["summary"]
    assert s["picked"] == "energy" and s["picked_is_default"]
    assert s["strategies"]["energy"]["successes"] == 1 and s["strategies"]["none"]["successes"] == 0
    assert s["energy_converges_over_all_ratios_at_demo_contraction"] == {"1": True}
    picture(tmp_path / "stability.png", 500, 150)
    assert json.loads((tmp_path / "summary.json").read_text())["picked"] == "energy"
    assert len((tmp_path / "cases.csv").read_text().splitlines()) == 3
    assert not list(tmp_path.glob(".*"))


def test_strategies_that_converge_agree_on_the_equilibrium():
    study = _load()
    # plain Newton ("none") is fragile by design; at 6 mm it converges, so both are compared
    res = study.run(ratios=(1.0,), contractions=(6.0,), strategies=("none", "energy"), stepping=(1,),
                    size=5.0, progress=None)
    ok = [r for r in res["cases"] if r["converged"]]
    assert len(ok) == 2
    assert all(r["same_equilibrium"] and r["tip_deviation"] < 1e-4 for r in ok)
    assert np.isfinite(res["summary"]["strategies"]["none"]["median_iterations"])


def test_slender_case_curved_beats_monotone_energy():
    study = _load()
    rows = study.run_slender(("elastica PL²/EI=3",), ("energy", "curved"), progress=None)
    by = {r["strategy"]: r for r in rows}
    assert by["curved"]["converged"] and by["energy"]["converged"]
    assert by["curved"]["newton_iterations"] <= 25 < by["energy"]["newton_iterations"]
    assert np.hypot(by["curved"]["tip_x"] - by["energy"]["tip_x"], by["curved"]["tip_y"] - by["energy"]["tip_y"]) < 1e-3
    s = study.summarise_slender(rows)
    assert s["curved"]["successes"] == 1 and s["curved"]["iterations"]["elastica PL²/EI=3"] <= 25
