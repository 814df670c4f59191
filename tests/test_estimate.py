"""--estimate: an error bar for every observable (skelfem.estimate), checked against finer references."""
import json

import numpy as np
import pytest

from skelfem.design.parse import parse_design
from skelfem.session import Session

from _designs import strip, toml_text


def _buried(size=2.0, degree=1):
    """A strip bent by a tendon that ends in silicone (a finite anchor), no bones."""
    d = strip(size=size, degree=degree, contraction=3.0, k=5.0, E=0.2, nu=0.45)
    d["cables"][0]["path"] = [[8.0, 0.0], [8.0, 40.0]]
    d["markers"]["mid"] = [5.0, 30.0]
    return d


def _solve(d, estimate=False):
    with Session(parse_design(d, "strip")) as s:
        r = s.solve(estimate=estimate)
        assert r.converged, r.status
        again = s.solve()                     # the estimate leaves the state as it was: nothing to re-solve
        assert again.newton_iterations == 0 and again.observables() == r.observables()
        return r


@pytest.mark.slow
def test_every_observable_has_an_error_bar_that_brackets_the_true_error():
    """P1 at h = 2 with a finite anchor: estimate / true error (against P2 at h = 0.5, whose own change from
    h = 1 is far smaller) within [0.5, 2] for the tip and the tension, [1/3, 3] for every measurable one."""
    r = _solve(_buried(), estimate=True)
    ref = _solve(_buried(size=0.5, degree=2)).observables()
    ref_coarse = _solve(_buried(size=1.0, degree=2)).observables()
    errors = r.errors
    assert set(errors) == set(r.observables())
    checked = 0
    for name, value in r.observables().items():
        e = errors[name]
        assert e["error"] == pytest.approx(e["discretisation"] + e["algebraic"])
        assert e["algebraic"] < 1e-3 * max(e["discretisation"], 1e-12) + 1e-9     # Newton converged far below
        true = abs(ref[name] - value)
        if name.startswith("pins") or true < 3 * abs(ref[name] - ref_coarse[name]):
            continue                                                            # round-off / not measurable
        checked += 1
        lo, hi = (0.5, 2.0) if name in ("markers.tip.x", "markers.tip.y", "cables.flexor.tension") else (1 / 3, 3)
        assert lo <= e["error"] / true <= hi, (name, e["error"], true)
        assert r.error(name) == e["error"]
    assert checked >= 4


def test_estimate_reports_its_cost_and_the_richer_degree():
    with Session(parse_design(strip(size=4.0, contraction=1.0), "strip")) as s:
        r = s.solve(estimate=True)
        est = r.estimate
        assert est["degree"] == 2 and est["status"] == "converged" and est["dofs"] > r.dofs
        assert set(est["seconds"]) == {"algebraic", "compile", "solve"} and est["algebraic_below_discretisation"]
        assert s.estimate()["errors"].keys() == r.errors.keys()       # the same, asked again
    with Session(parse_design(strip(size=4.0), "strip")) as s:
        r = s.solve()
        with pytest.raises(ValueError, match="no error estimate"):
            r.error("markers.tip.x")


def test_p2_is_estimated_with_p3_whose_interpolation_matches_dolfinx():
    """P2 -> P3: the cable's via points are interpolated with DOLFINx's own P3 basis (GLL-warped nodes,
    not equispaced ones): P3 at h = 4 lands within the P2 (h = 1) reference's reach, not 0.8 mm off."""
    from skelfem.estimate import observables_of, richer
    from skelfem.fem.model import Model
    from skelfem.fem.newton import NewtonSolver
    d = _buried(size=4.0, degree=2)
    with Session(parse_design(d, "strip")) as s:
        design = richer(s.design)
        model = Model(design, s.model.tm)
        solver = NewtonSolver(model, design.solver)
        try:
            model.to_rest()
            assert solver.solve(design.solver.steps).converged
            model.end_step()
            p3 = observables_of(model)
        finally:
            solver.destroy()
    ref = _solve(_buried(size=1.0, degree=2)).observables()
    p2 = _solve(d).observables()
    for name in ("markers.tip.x", "cables.flexor.tension"):
        assert abs(p3[name] - ref[name]) < 0.6 * abs(p2[name] - ref[name]) + 1e-3, name


def test_p3_interpolation_rows_reproduce_a_p3_function():
    from dolfinx import fem
    from skelfem.mesh.points import interpolation_matrix, locate_cells
    with Session(parse_design(strip(size=4.0), "strip")) as s:
        mesh = s.model.mesh
        V = fem.FunctionSpace(mesh, ("Lagrange", 3))
        f = fem.Function(V)
        f.interpolate(lambda x: x[0] ** 3 - 2 * x[0] * x[1] ** 2 + x[1] ** 3 / 7)
        rng = np.random.default_rng(0)
        X = np.c_[rng.uniform(0.1, 9.9, 40), rng.uniform(0.1, 59.9, 40)]
        S = interpolation_matrix(V, X, locate_cells(mesh, X))
        exact = X[:, 0] ** 3 - 2 * X[:, 0] * X[:, 1] ** 2 + X[:, 1] ** 3 / 7
        assert np.allclose(S @ f.x.array, exact, rtol=1e-9, atol=1e-7)


def test_ground_rule_of_the_richer_degree_is_positive_and_exact_for_linear_functions():
    from skelfem.terms.grounds import _interpolatory
    points, weights = _interpolatory(3)
    assert np.all(weights > 0) and weights.sum() == pytest.approx(0.5)
    assert weights @ points[:, 0] == pytest.approx(1 / 6) and weights @ points[:, 1] == pytest.approx(1 / 6)


@pytest.mark.slow
def test_cli_estimate_writes_errors_and_prints_bars(tmp_path, capsys):
    from skelfem.cli.main import main
    path = tmp_path / "strip.toml"
    path.write_text(toml_text(strip(size=4.0, contraction=1.0)))
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--estimate", "--out", str(out), "--no-picture"]) == 0
    res = json.loads((out / "result.json").read_text())
    assert res["errors"]["markers.tip.x"]["error"] > 0 and res["estimate"]["degree"] == 2
    printed = capsys.readouterr().out
    assert "+-" in printed and "--estimate: P2" in printed


def test_cli_estimate_refuses_a_run_in_time_before_meshing(tmp_path, monkeypatch, capsys):
    from _designs import simulate_refused_before_meshing
    d = strip(size=4.0)
    d["materials"]["soft"]["density"] = 1000.0
    d["materials"]["hard"]["density"] = 1000.0
    d["dynamics"] = {"dt": 0.01, "duration": 0.05}
    line = simulate_refused_before_meshing(d, tmp_path, monkeypatch, capsys, "--estimate")
    assert "--estimate" in line and "run in time" in line


def _block3d(linear="auto"):
    """A coarse 3D block (12 x 30 x 12 mm, h = 6) with a bone where its tendon ends: a few hundred DOFs."""
    return {"format": 1, "name": "block3d", "dim": 3, "mesh": {"size": 6.0, "degree": 1},
            "materials": {"soft": {"E": 0.2, "nu": 0.45}, "hard": {"E": 2000.0, "nu": 0.35}},
            "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [12, 30, 12]}}], "material": "soft"},
            "bones": [{"name": "b", "solids": [{"box": {"min": [2, 18, 3], "max": [8, 27, 9]}}], "material": "hard"}],
            "cables": [{"name": "flexor", "kind": "tendon", "path": [[6, 0, 6], [6, 24, 6]],
                        "stiffness": 5.0, "contraction": 1.0}],
            "pins": [{"name": "base", "region": [[-1, -1, -1], [13, 1e-6, 13]], "kind": "fixed"}],
            "markers": {"tip": [6, 30, 6]}, "solver": {"linear": linear}}


@pytest.mark.slow
def test_3d_richer_solve_is_iterative_and_matches_the_factorised_one(monkeypatch):
    """In 3D the richer (P2) solve runs CG with two-level p-multigrid above RICH_ITERATIVE_DOFS (here: always;
    skelfem.estimate.richer_linear); its error bars are those of the factorised richer solve to 2 % (each
    stops at 1e-3 of its first residual)."""
    from skelfem import estimate
    assert estimate.richer_linear(parse_design(_block3d(), "b"), 1000) == "auto"      # MUMPS at this size
    assert estimate.richer_linear(parse_design(_block3d(), "b"), 10 ** 6) == "iterative"
    monkeypatch.setattr(estimate, "RICH_ITERATIVE_DOFS", 0)
    bars = {}
    for linear in ("auto", "direct"):
        with Session(parse_design(_block3d(linear), "block3d")) as s:
            r = s.solve(estimate=True)
            assert r.converged and r.estimate["status"] == "converged"
            bars[linear] = r.errors, r.estimate
    (iterative, est), (direct, est_direct) = bars["auto"], bars["direct"]
    assert est["krylov_iterations"] > 0 and est_direct["krylov_iterations"] is None
    for name in ("markers.tip.x", "markers.tip.y", "markers.tip.z", "cables.flexor.tension"):
        assert iterative[name]["error"] == pytest.approx(direct[name]["error"], rel=0.02), name
        assert direct[name]["error"] > 1e-4


def test_slip_sensitive_bars_are_named_when_friction_is_anchored():
    """Ground friction keeps per-node anchors that the richer degree cannot take over: the estimate says so and
    names the read-outs its bars leave a different slip history out of (the ground's forces)."""
    import math
    d = {"format": 1, "name": "block", "dim": 2, "thickness": 10.0, "mesh": {"size": 2.5, "degree": 1},
         "materials": {"m": {"E": 100.0, "nu": 0.3, "density": 1e4}},
         "body": {"outline": [[0, 0], [20, 0], [20, 5], [0, 5]], "material": "m"},
         "pins": [{"name": "pull", "region": [[19.9, -1], [21, 6]], "kind": "spring", "stiffness": 2e-6}],
         "grounds": [{"name": "floor", "point": [0, 0], "normal": [0, 1], "stiffness": 100.0, "friction": 0.5}],
         "gravity": {"acceleration": [-9.81 * math.sin(0.2), -9.81 * math.cos(0.2)]},
         "markers": {"c": [10, 2.5]}, "solver": {"steps": 2}}
    with Session(parse_design(d, "block")) as s:
        r = s.solve(estimate=True)
        assert r.converged and r.estimate["status"] == "converged"
        assert r.estimate["slip_history"] == "anchored"
        assert "grounds.floor.friction_force.x" in r.estimate["not_covered"]
        assert not any(k.startswith("markers") for k in r.estimate["not_covered"])
    with Session(parse_design(strip(size=4.0, contraction=1.0), "strip")) as s:
        est = s.solve(estimate=True).estimate
        assert est["slip_history"] == "carried" and "not_covered" not in est
