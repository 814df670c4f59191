"""studies/dynamics.py run tiny: the quasi-static plan against the plan through the dynamics."""
import numpy as np
import pytest

from _studies import load_study


@pytest.mark.slow
def test_flick_study_runs_tiny(tmp_path):
    study = load_study("dynamics")
    res = study.run(T=0.01, dt=0.005, size=5.0, knots=2, max_evaluations=3)
    assert res["dynamic_plan"]["forward_runs"] <= 3 and len(res["quasi_static_plan"]["path"]) == 3
    assert np.isfinite(res["quasi_static_plan"]["error_at_T"]) and np.isfinite(res["dynamic_plan"]["error_at_T"])
    study.plot(res, tmp_path / "flick.png")
    assert (tmp_path / "flick.png").stat().st_size > 10_000
