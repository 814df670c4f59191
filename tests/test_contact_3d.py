"""Self-contact in 3D: a notched strip curled by a tendon closes its notch; FD checks of the barrier on the
boundary triangles (P1, P2), the notch closing without interpenetration only with the barrier, the
per-node contact fields against result.json's total, and what the design layer accepts and refuses."""
import meshio
import numpy as np
import pytest

from _designs import simulate_refused_before_meshing, variant
from _taylor import hessian_error
from skelfem import Session
from skelfem.design import DesignError, parse_design
from skelfem.io.xdmf import write_xdmf
from skelfem.terms.contact import SelfContact

DHAT = 0.2


def notched(self_contact=True, size=1.5, degree=1, contraction=6.0, bottom=1.0, depth=4.0, dhat=DHAT):
    """A 6 x 30 mm strip, `depth` mm deep, with a wedge notch 2 mm deep on its x = 0 side (3 mm open,
    `bottom` mm at the bottom) and a tendon beside the notch bottom: pulled 6 mm it closes the notch."""
    b = bottom / 2
    outline = [[0, 0], [6, 0], [6, 30], [0, 30], [0, 16.5], [2, 15 + b], [2, 15 - b], [0, 13.5]]
    return {"format": 1, "name": "notched3d", "dim": 3, "mesh": {"size": size, "degree": degree},
            "materials": {"soft": {"E": 0.1, "nu": 0.45}},
            "body": {"solids": [{"extrude": {"outline": outline, "z": [0, depth]}}], "material": "soft"},
            "cables": [{"name": "flexor", "kind": "tendon", "path": [[2.5, 0, depth / 2], [2.5, 28, depth / 2]],
                        "stiffness": 20.0, "contraction": contraction}],
            "pins": [{"name": "base", "region": [[-1, -1, -1], [7, 0.01, depth + 1]], "kind": "fixed"}],
            "markers": {"tip": [3, 30, depth / 2]},
            "contact": {"self": self_contact, "dhat": dhat}, "solver": {"steps": 2}}


def _solved(session):
    r = session.solve()
    assert r.converged, r.status
    return r


@pytest.mark.parametrize("degree, size", [(1, 1.5), (2, 4.0)])
def test_3d_barrier_gradient_and_hessian_match_central_differences(degree, size):
    """At the curled strip's equilibrium (the notch's faces within dhat: vertex-face and edge-edge
    collisions), a little perturbed: the gradient against central differences of the energy, a dozen
    Hessian columns against central differences of the gradient; the projected Hessian is PSD."""
    with Session(notched(size=size, degree=degree)) as s:
        _solved(s)
        V = s.model.V
        u = s.model.u.x.array + 0.003 * np.random.default_rng(0).normal(size=s.model.u.x.array.shape)
        term = SelfContact(V, dhat=DHAT, stiffness=0.1, project=False)
        c = term.collisions(term.positions(u))
        assert 0.0 < term.min_distance(u) < DHAT and len(c.fv_collisions) > 0 and len(c.ee_collisions) > 0
        dofs, g = term.gradient(u)
        (hdofs, H), = term.hessian(u)
        H = H.toarray()
        h = 1e-7
        active = np.flatnonzero(g)
        active = active[:: max(1, len(active) // 48)]                  # four dozen entries, spread

        def shifted(k, s):
            e = u.copy()
            e[k] += s
            return e
        g_fd = np.array([(term.energy(shifted(k, h)) - term.energy(shifted(k, -h))) / (2 * h) for k in dofs[active]])
        assert np.linalg.norm(g_fd - g[active]) <= 1e-6 * np.linalg.norm(g[active])
        touched = np.flatnonzero(np.abs(H).sum(axis=0))
        for j in touched[:: max(1, len(touched) // 12)]:
            col = (term.gradient(shifted(hdofs[j], h))[1] - term.gradient(shifted(hdofs[j], -h))[1]) / (2 * h)
            assert np.linalg.norm(col - H[:, j]) <= 1e-5 * np.linalg.norm(H[:, j]) + 1e-9 * np.abs(H).max()
        term.project = True
        (_, Hp), = term.hessian(u)
        Hp = Hp.toarray()[np.ix_(touched, touched)]
        assert np.linalg.eigvalsh(Hp).min() >= -1e-9 * np.abs(Hp).max()
        assert np.linalg.eigvalsh(H[np.ix_(touched, touched)]).min() < -1e-6 * np.abs(H).max()   # the exact is not


def test_the_model_s_gradient_and_jacobian_agree_with_the_3d_barrier_active():
    """Central differences of the model's residual against its Jacobian (elasticity, tendon, the exact
    barrier Hessian) at the curled strip's equilibrium, perturbed."""
    with Session(notched()) as s:
        _solved(s)
        model = s.model
        model.term("contact").project = False
        x = model.u.vector.copy()
        rng = np.random.default_rng(1)
        x.array[:] += 0.003 * rng.normal(size=x.array.shape)
        model.apply_bcs(x)
        assert model.admissible(x) and model.term("contact").energy(x.array) > 0
        d = x.duplicate()
        d.array[:] = rng.normal(size=d.array.shape) * 1e-2
        d.array[model.fixed] = 0.0
        assert hessian_error(model, x, d, h=1e-5) < 1e-6


def test_the_notch_closes_without_interpenetrating_only_with_self_contact(tmp_path):
    """Contact on: every accepted Newton iterate keeps the boundary apart (ipctk's minimum distance > 0),
    the faces end within dhat, nothing intersects; solution.xdmf's contact_normal_force sums to zero (the
    body pushes itself) and half its magnitudes to result.json's normal_magnitude. Contact off: the same
    pull passes the faces through each other (ipctk finds intersecting triangles)."""
    with Session(notched()) as s:
        contact = s.model.term("contact")
        history = []
        s.solver.snes.setMonitor(lambda snes, it, fnorm: history.append(
            contact.min_distance(snes.getSolution().array_r)))
        r = _solved(s)
        u = s.model.u.x.array
        write_xdmf(tmp_path / "s.xdmf", s.model)
        assert len(history) >= r.report.newton_iterations and min(history) > 0.0
        assert not contact.intersects(u)
    entry = r.to_dict()["contact"]["self"]
    assert 0.0 < entry["min_distance"] < DHAT and entry["normal_magnitude"] > 0.01
    m = meshio.read(tmp_path / "s.xdmf")
    f = m.point_data["contact_normal_force"][:, :3]
    assert np.count_nonzero(np.linalg.norm(f, axis=1)) > 4
    assert np.linalg.norm(f.sum(axis=0)) <= 1e-9 * entry["normal_magnitude"]
    assert 0.5 * np.linalg.norm(f, axis=1).sum() == pytest.approx(entry["normal_magnitude"], rel=1e-6)
    assert np.array_equal(m.point_data["contact_force"][:, :3], f)
    with Session(notched(self_contact=False)) as s:
        _solved(s)
        probe = SelfContact(s.model.V, DHAT, 1.0)
        assert probe.intersects(s.model.u.x.array)


def test_a_notch_pressed_hard_converges_once_its_contacts_settle():
    """Pulled 8 mm the notch's faces press hard: with the barrier's Hessian projected at every iteration
    the linear tail took over 50 iterations in each step (752 in all, every step cut, no equilibrium);
    with the exact Hessian of settled contacts, two load steps in under 30 iterations each."""
    with Session(notched(contraction=8.0)) as s:
        r = _solved(s)
        steps = [len(h) - 1 for h in r.report.residual_history]
        assert len(steps) == 2 and max(steps) < 30, steps
        assert 0.0 < r.to_dict()["contact"]["self"]["min_distance"] < DHAT
        assert not s.model.term("contact").intersects(s.model.u.x.array)


def test_2d_self_contact_writes_its_per_node_forces_too(tmp_path):
    """The same strip in 2D (plane strain, 4 mm thick): contact_normal_force in solution.xdmf, half its
    magnitudes summing to result.json's normal_magnitude."""
    d = notched(size=1.0)
    d.update(dim=2, thickness=4.0)
    d["body"] = {"outline": d["body"]["solids"][0]["extrude"]["outline"], "material": "soft"}
    d["cables"][0]["path"] = [p[:2] for p in d["cables"][0]["path"]]
    d["pins"][0]["region"] = [[-1, -1], [7, 0.01]]
    d["markers"] = {"tip": [3, 30]}
    with Session(d) as s:
        r = _solved(s)
        write_xdmf(tmp_path / "s.xdmf", s.model)
    entry = r.to_dict()["contact"]["self"]
    f = meshio.read(tmp_path / "s.xdmf").point_data["contact_normal_force"][:, :2]
    assert 0.0 < entry["min_distance"] < DHAT and entry["normal_magnitude"] > 0.01
    assert 0.5 * np.linalg.norm(f, axis=1).sum() == pytest.approx(entry["normal_magnitude"], rel=1e-6)


def test_3d_self_contact_is_read_and_what_it_cannot_honour_is_refused(tmp_path, monkeypatch, capsys):
    """contact.self = true reads in 3D; a line search that cannot bound steps is one error line before
    meshing; a dhat not below the notch's rest width is refused when the term is built."""
    from conftest import GEOMETRY

    from skelfem.design import load_design
    assert load_design(GEOMETRY / "pillar3d.toml", ["contact.self=true"]).contact.self_contact
    assert parse_design(notched()).contact.self_contact
    with pytest.raises(DesignError, match=r"^<design>: contact\.dhat: 0\.5 mm is not below the smallest rest "
                                          r"distance between boundary parts \(0\.\d+ mm\)"):
        Session(notched(bottom=0.4, depth=8.0, dhat=0.5))
    line = simulate_refused_before_meshing(variant(notched(), **{"solver.line_search": "residual"}),
                                           tmp_path, monkeypatch, capsys)
    assert line.startswith("solver.line_search: 'residual' ") and "for self-contact (contact.self = true)" in line
