"""--tol on any observable: NAME=TOL targets, checked before meshing, met against a finer reference."""
import json

import numpy as np
import pytest

from skelfem.accuracy.targets import Targets, check
from skelfem.design.parse import parse_design
from skelfem.session import Session

from _designs import simulate_refused_before_meshing, strip, toml_text


def _buried(size=2.0, degree=1):
    d = strip(size=size, degree=degree, contraction=3.0, k=5.0, E=0.2, nu=0.45)
    d["cables"][0]["path"] = [[8.0, 0.0], [8.0, 40.0]]
    return d


@pytest.mark.parametrize("name, ok", [
    ("markers.tip", True), ("markers.tip.x", True), ("markers.tip.y", True), ("markers.tip.z", False),
    ("markers.nope", False), ("cables.flexor.tension", True), ("cables.flexor", False),
    ("cables.flexor.tension.x", False), ("pins.base.reaction", True), ("pins.base.reaction.y", True),
    ("pins.base.force", False), ("tips.x", False), ("markers", False), ("contacts.body|body.normal_magnitude", False),
])
def test_names_are_checked_against_the_design(name, ok):
    design = parse_design(strip(), "strip")
    assert (check(design, name) is None) == ok, check(design, name)


def test_rows_are_scaled_by_their_tolerances_and_know_their_owner():
    class R:                       # a result's dict, as Result.to_dict gives it
        def to_dict(self):
            return {"markers": {"tip": {"position": [1.0, 2.0]}, "mid": {"position": [3.0, 4.0]}},
                    "cables": {"flexor": {"tension": 0.5}}, "pins": {"base": {"reaction": [0.1, -0.2]}}}
    t = Targets((("cables.flexor.tension", 0.05), ("markers.tip.y", 0.5), ("pins.base.reaction", 0.1)), 2)
    assert not t.bare and t.tol == 1.0 and t.spec() == {"cables.flexor.tension": 0.05, "markers.tip.y": 0.5,
                                                        "pins.base.reaction": 0.1}
    assert np.allclose(t.rows(R()), [[10.0, 0.0], [4.0, 0.0], [1.0, -2.0]])
    assert t.owner(2, n_markers=2) == ("pins.base.reaction", 0)
    bare = Targets.markers(0.5, 2)
    assert bare.bare and bare.tol == 0.5 and np.allclose(bare.rows(R()), [[1, 2], [3, 4]])
    assert bare.owner(1, n_markers=2) == (None, 1)
    assert t.per_target(0.2)["cables.flexor.tension"]["estimated_error"] == pytest.approx(0.01)


@pytest.mark.parametrize("args, match", [
    (("--tol", "cables.nope.tension=0.1"), "no cable named 'nope'"),
    (("--tol", "cables.flexor.tension=-1"), "must be a finite number > 0"),
    (("--tol", "cables.flexor.tension=nan"), "must be a finite number > 0"),
    (("--tol", "markers.tip.z=0.1"), "the component is one of x, y"),
    (("--tol", "0.5", "--tol", "0.2"), "given twice"),
    (("--tol", "cables.flexor.tension=0.1", "--tol", "cables.flexor.tension=0.2"), "given twice"),
    (("--tol", "cables.flexor.tension=abc"), "invalid float value"),
])
def test_bad_targets_are_refused_before_meshing(args, match, tmp_path, monkeypatch, capsys):
    line = simulate_refused_before_meshing(strip(), tmp_path, monkeypatch, capsys, *args, names_file=False)
    assert match in line


def _reference_tension() -> float:
    with Session(parse_design(_buried(size=0.25, degree=2), "strip")) as s:
        r = s.solve()
        assert r.converged
        return r.tension("flexor")


@pytest.mark.slow
@pytest.mark.parametrize("adaptive", [False, True])
def test_a_tension_tolerance_is_met_against_a_finer_reference(adaptive, tmp_path, capsys):
    """The tendon ending in silicone: --tol cables.flexor.tension=0.01 (about 1 % of 0.89 N), uniform and
    goal-oriented (the tension's adjoint weights the indicators): the answer is within 0.01 N of P2 at
    h = 0.25, and the reported estimate is met."""
    from skelfem.cli.main import main
    path = tmp_path / "buried.toml"
    path.write_text(toml_text(_buried()))
    out = tmp_path / "o"
    args = ["simulate", str(path), "--out", str(out), "-q", "--no-picture", "--tol", "cables.flexor.tension=0.01"]
    assert main(args + (["--adaptive"] if adaptive else [])) == 0
    res = json.loads((out / "result.json").read_text())
    acc = res["accuracy"]
    assert acc["met"] and acc["tol"] == {"cables.flexor.tension": 0.01} and acc["unit"] == "tolerances"
    assert acc["targets"]["cables.flexor.tension"]["estimated_error"] <= 0.01 / 2
    assert abs(res["cables"]["flexor"]["tension"] - _reference_tension()) <= 0.01
