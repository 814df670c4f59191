"""studies/adaptive.py run tiny on the thumb: rows for every method, the --tol runs, outputs and figure."""
import json

import numpy as np
import pytest
from _studies import load_study

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    study = load_study("adaptive")
    out = tmp_path_factory.mktemp("adaptive")
    return study, study.run(("thumb",), ref_size=1.0, rounds=2, levels=3, degrees=(1, 2), out=out, tols=(0.5,)), out


def test_every_method_and_degree_has_its_meshes_and_errors(tiny):
    _, res, _ = tiny
    rows = res["rows"]
    for method, degree, meshes in (("uniform", 1, 4), ("uniform", 2, 3), ("adaptive", 1, 6), ("adaptive", 2, 6)):
        mine = [r for r in rows if (r["method"], r["degree"]) == (method, degree)]
        assert len(mine) == meshes, (method, degree, len(mine))
        times = [r["time"] for r in mine]
        assert all(b > a for a, b in zip(times, times[1:]))            # time spent only grows
        assert all(np.isfinite(r["error"]) and r["error"] >= 0 for r in mine)
    uni = [r for r in rows if (r["method"], r["degree"]) == ("uniform", 2)]
    assert uni[-1]["error"] < 1e-6                       # the reference is the ladder's P2 mesh at h = 1
    ada = [r for r in rows if (r["method"], r["degree"]) == ("adaptive", 2)]
    ladder = [r for r in res["tol_runs"] if r["method"] == "uniform"][0]
    assert ladder["meshes"] == 4 and len(ladder["ladder_dofs"]) == 3     # three meshes and the twin
    assert ada[2]["dofs"] == ladder["ladder_dofs"][-1]                   # round 1 is the --tol ladder (graded
    assert ada[0]["dofs"] == uni[0]["dofs"]                              # at the thumb's anchor, as uni is)
    assert uni[0]["min_size"] < uni[0]["max_size"]                       # the ladder's zones grade uni too
    assert ada[-1]["min_size"] < ada[-1]["max_size"]                  # round 2 is graded


def test_the_summary_counts_answers_and_not_what_the_reference_cannot_measure(tiny):
    study, res, _ = tiny
    answers = [r for r in res["rows"] if study.answer(r)]
    assert {r["mesh"] for r in answers if r["method"] == "adaptive"} == {3, 6}
    assert min(r["mesh"] for r in answers if r["method"] == "uniform") == 3
    refs = {"thumb": {"scatter": 0.2}}
    s = study.summary(res["rows"], refs)["thumb uniform P2"]["reach"]
    assert s["0.1"] == s["0.05"] == "not measurable" and isinstance(s["0.5"], (dict, type(None)))


def test_tol_runs_report_met_honestly(tiny):
    _, res, _ = tiny
    runs = res["tol_runs"]
    assert {r["method"] for r in runs} == {"uniform", "adaptive"}
    for r in runs:
        assert not r["met"] or 2.0 * r["estimate"] <= r["tol"]


def test_outputs_written(tiny, picture):
    study, res, out = tiny
    data = json.loads((out / "adaptive.json").read_text())
    assert len(data["rows"]) == len(res["rows"]) and "summary" in data
    assert (out / "thumb" / "reference.json").exists()
    ref = res["references"]["thumb"]
    assert ref["graded"] and 0.0 < ref["scatter"] < 0.5                  # the twin is another mesh
    picture(out / "adaptive.png", 400, 600)
    again = study.reference("thumb", 1.0, out, reuse=True)           # read back, not solved
    assert again["tip"] == res["references"]["thumb"]["tip"]
