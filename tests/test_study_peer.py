"""studies/peer_comparison.py: skelfem and scikit-fem solve the same tendon strip to the same answer."""
import json

import pytest
from _studies import load_study

pytest.importorskip("skfem")


def _load():
    return load_study("peer_comparison")


@pytest.mark.slow
@pytest.mark.parametrize("degree", [1, 2])
def test_same_mesh_same_answer(tmp_path, degree, picture):
    study = _load()
    res = study.run(sizes=(6.0, 4.0), degree=degree, out=tmp_path, progress=None)
    for case in res["summary"]["cases"]:
        assert case["both_converged"]
        assert case["tip_difference"] < 1e-7                     # mm, on a ~3.5 mm tip motion
        assert case["tension_skelfem"] == pytest.approx(case["tension_scikit_fem"], rel=1e-8)
        assert case["time_skelfem"] > 0 and case["time_scikit_fem"] > 0
    assert json.loads((tmp_path / "summary.json").read_text())["degree"] == degree
    picture(tmp_path / "peer_comparison.png", 1000, 420)


def test_peer_tendon_derivatives_match_finite_differences():
    import numpy as np
    from skfem import Basis, ElementTriP1, ElementVector, MeshTri

    study = _load()
    mesh = MeshTri.init_tensor(np.linspace(0, 10, 6), np.linspace(0, 20, 9))
    basis = Basis(mesh, ElementVector(ElementTriP1()))
    X = study._via_points(mesh.p.T, mesh.facets, np.array([[3.0, 0.0], [3.0, 15.0], [7.0, 19.0]]))
    assert len(X) > 8
    cable = study.PeerTendon(basis, X, k=2.0, contraction=1.0)
    rng = np.random.default_rng(1)
    u, d = 0.05 * rng.normal(size=basis.N), rng.normal(size=basis.N)
    assert cable.tension(u) > 0
    h = 1e-6
    fd_e = (cable.energy(u + h * d) - cable.energy(u - h * d)) / (2 * h)
    fd_g = (cable.gradient(u + h * d) - cable.gradient(u - h * d)) / (2 * h)
    assert fd_e == pytest.approx(cable.gradient(u) @ d, rel=1e-6)
    assert np.allclose(fd_g, cable.hessian(u) @ d, rtol=1e-5, atol=1e-8)
