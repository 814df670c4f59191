"""Self-contact: boundary polygon, FD checks of the IPC barrier's derivatives, step bound, knuckles."""

import dataclasses

import numpy as np
import scipy.sparse as sp
import pytest
from dolfinx import fem
from dolfinx import mesh as dmesh

from _designs import simulate_refused_before_meshing, strip, variant
from _studies import load_study
from _taylor import hessian_error, taylor_rates
from skelfem import Session
from skelfem.design import DesignError, SolverSpec, parse_design
from skelfem.terms.contact import SelfContact, boundary_facets, crossing_edges, oriented_edges, overlap_area

SLOT = [[2.0, 2.6], [8.0, 2.6], [8.0, 3.4], [2.0, 3.4]]      # a 0.8 mm slot in a 10 x 6 block


def _slot_design(degree=1, self_contact=True, dhat=0.3, size=1.0):
    return {
        "format": 1, "name": "slot", "dim": 2, "thickness": 4.0, "mesh": {"size": size, "degree": degree},
        "materials": {"soft": {"E": 1.0, "nu": 0.3}},
        "body": {"outline": [[0, 0], [10, 0], [10, 6], [0, 6]], "holes": [SLOT], "material": "soft"},
        "pins": [{"name": "base", "region": [[-1, -1], [11, 1e-6]], "kind": "fixed"}],
        "contact": {"self": self_contact, "dhat": dhat},
    }


def _model(d):
    return Session(d).model


def _contact(model):
    return model.term("contact")


def _squeeze(V, closing=0.75, noise=0.0, seed=0):
    """u_y = -closing (y - 3) above y = 2 (zero at the pinned base): the slot faces come 0.8 (1 - closing) apart."""
    X = V.tabulate_dof_coordinates()[:, :2]
    u = np.zeros((len(X), 2))
    u[:, 1] = -closing * (X[:, 1] - 3.0) * np.clip(X[:, 1] / 2.0, 0.0, 1.0)
    u[:, 0] = 0.02 * np.sin(X[:, 1])
    u += noise * np.random.default_rng(seed).normal(size=u.shape)
    return u.ravel()


@pytest.mark.parametrize("degree", [1, 2])
def test_boundary_facets_is_closed_loops_through_all_boundary_nodes(degree):
    sc = _model(_slot_design(degree, self_contact=False))
    nodes, edges = boundary_facets(sc.V)
    X = sc.V.tabulate_dof_coordinates()[nodes, :2]
    assert np.all(np.bincount(edges.ravel(), minlength=len(nodes)) == 2)     # every node on two edges
    length = np.linalg.norm(X[edges[:, 1]] - X[edges[:, 0]], axis=1).sum()
    assert length == pytest.approx(2 * (10 + 6) + 2 * (6 + 0.8))              # outline + slot
    on_outline = (np.isclose(X[:, 0], 0) | np.isclose(X[:, 0], 10) | np.isclose(X[:, 1], 0) | np.isclose(X[:, 1], 6))
    on_slot = ((np.isclose(X[:, 1], 2.6) | np.isclose(X[:, 1], 3.4)) & (X[:, 0] > 2 - 1e-9) & (X[:, 0] < 8 + 1e-9)
               | (np.isclose(X[:, 0], 2) | np.isclose(X[:, 0], 8)) & (X[:, 1] > 2.6 - 1e-9) & (X[:, 1] < 3.4 + 1e-9))
    assert np.all(on_outline | on_slot)
    all_boundary = fem.locate_dofs_topological(sc.V, 1, dmesh.exterior_facet_indices(sc.mesh.topology))
    assert set(nodes) == set(all_boundary)                                    # P2: midpoints included


@pytest.mark.parametrize("degree", [1, 2])
def test_barrier_gradient_and_hessian_match_central_differences(degree):
    sc = _model(_slot_design(degree, self_contact=False))
    term = SelfContact(sc.V, dhat=0.3, stiffness=1.0, thickness=4.0, project=False)
    u = _squeeze(sc.V, noise=0.01)
    assert 0.0 < term.min_distance(u) < 0.3 and len(term.collisions(term.positions(u))) >= 6
    dofs, g = term.gradient(u)
    (hdofs, H), = term.hessian(u)
    H = H.toarray()                                     # a sparse block over the boundary DOFs
    touched = np.flatnonzero(np.abs(H).sum(axis=0))
    hdofs, H = hdofs[touched], H[np.ix_(touched, touched)]
    h = 1e-7
    active = np.flatnonzero(g)
    assert set(dofs[active]) <= set(hdofs)

    def e_dir(k):
        e = np.zeros_like(u)
        e[k] = h
        return e
    g_fd = np.array([(term.energy(u + e_dir(k)) - term.energy(u - e_dir(k))) / (2 * h) for k in dofs[active]])
    assert np.linalg.norm(g_fd - g[active]) <= 1e-6 * np.linalg.norm(g)
    full = np.zeros((len(u), len(u)))
    full[np.ix_(hdofs, hdofs)] = H
    for k in hdofs[:: max(1, len(hdofs) // 12)]:                      # a dozen Hessian columns
        col = np.zeros_like(u)
        col[dofs] = (term.gradient(u + e_dir(k))[1] - term.gradient(u - e_dir(k))[1]) / (2 * h)
        assert np.linalg.norm(col - full[:, k]) <= 1e-5 * np.linalg.norm(full[:, k]) + 1e-9 * np.abs(H).max()
    # Newton's Hessian: ipctk's per-collision projection is positive semi-definite
    term.project = True
    (_, Hp), = term.hessian(u)
    Hp = Hp.toarray()
    assert np.linalg.eigvalsh(Hp).min() >= -1e-9 * np.abs(Hp).max()
    assert np.linalg.eigvalsh(H).min() < -1e-6 * np.abs(H).max()         # the exact one is not


def test_model_with_contact_has_consistent_energy_gradient_and_jacobian():
    """Taylor remainders of Pi and grad Pi with the barrier active (exact Hessian), pins respected."""
    sc = _model(_slot_design(1))
    _contact(sc).project = False
    x = sc.u.vector.copy()
    x.array[:] = _squeeze(sc.V, noise=0.005)
    sc.apply_bcs(x)
    assert sc.admissible(x) and _contact(sc).energy(x.array) > 0
    rng = np.random.default_rng(1)
    d = x.duplicate()
    d.array[:] = rng.normal(size=d.array.shape) * 1e-2
    d.array[sc.fixed] = 0.0
    for rates in taylor_rates(sc, x, d, [1e-1, 5e-2, 2.5e-2, 1.25e-2]):
        assert np.all(rates > 1.8), rates
    assert hessian_error(sc, x, d, h=1e-4) < 1e-7


def test_the_pattern_grows_with_the_contacts_and_contact_costs_nothing_when_off():
    on = _model(_slot_design(1, dhat=0.05, size=0.25))              # at rest the slot's faces are out of reach
    off = _model(_slot_design(1, self_contact=False, size=0.25))
    assert not off.terms_in("contact") and not any(isinstance(t, SelfContact) for t in off.terms)
    assert not off.bounds_steps and off.max_step(np.zeros(off.n_local), np.ones(off.n_local)) == 1.0
    contact = _contact(on)
    nb = len(contact.nodes)
    A_on, A_off = on.create_matrix(), off.create_matrix()
    assert len(contact.pairs()) < 0.25 * nb * nb                    # not the dense boundary x boundary block
    # as the slot closes, contacts form: the matrix is made anew where they need new pairs, and holds the
    # same K as a matrix over every boundary pair
    x = on.u.vector.copy()
    grew = 0
    for closing in (0.5, 0.95, 0.97):                               # gaps 0.4, 0.04, 0.024 mm
        x.array[:] = _squeeze(on.V, closing)
        on.apply_bcs(x)
        A = on.assemble_jacobian(x, A_on)
        grew += A is not A_on
        A_on = A
        on.jacobian(x, A_on)                                       # held now: new entries would raise
        pairs, contact._pairs = contact._pairs, np.arange(nb * nb, dtype=np.int64)
        A_full = on.create_matrix()
        contact._pairs = pairs
        on.jacobian(x, A_full)
        K, K_full = (sp.csr_matrix(M.getValuesCSR()[::-1], shape=M.getSize()) for M in (A_on, A_full))
        assert abs(K - K_full).max() <= 1e-12 * abs(K_full).max()
        assert A_on.getInfo()["nz_used"] < 0.5 * A_full.getInfo()["nz_used"]
    assert grew >= 1
    assert A_off.getInfo()["nz_used"] < A_on.getInfo()["nz_used"]


def test_step_bound_stops_the_faces_before_they_cross():
    sc = _model(_slot_design(1))
    contact = _contact(sc)
    u0 = _squeeze(sc.V, closing=0.5)
    p = _squeeze(sc.V, closing=1.4) - u0              # the full step takes the faces through each other
    assert crossing_edges(contact.positions(u0 + p), contact.edges) > 0
    alpha = sc.max_step(u0, p)
    assert 0.0 < alpha < 1.0
    # the faces meet at closing 0.5 + 0.9 s = 1; the step stops `approach` of the way there
    toi = alpha / contact.approach
    assert toi == pytest.approx(0.5 / 0.9, abs=0.01) and toi <= 0.5 / 0.9
    for s in np.linspace(0.0, alpha, 6):
        assert not contact.intersects(u0 + s * p)
    assert contact.min_distance(u0 + alpha * p) == pytest.approx(0.8 * (1 - 0.5 - 0.9 * alpha), rel=0.05)


def test_collision_detection_is_bounded_and_stays_conservative_when_it_stops_early():
    """Each CCD query runs at most CCD_MAX_ITERATIONS refinements (Tight Inclusion's default of 1e7 let one
    grazing query run for over an hour); one stopped early returns a time no later than the first contact."""
    import ipctk
    from skelfem.terms.contact import CCD_MAX_ITERATIONS
    sc = _model(_slot_design(1))
    assert _contact(sc).ccd.max_iterations == CCD_MAX_ITERATIONS <= 10**6
    tri = [np.array(v, float) for v in ([0, 0, 0], [1, 0, 0], [0, 1, 0])]
    p0, p1 = np.array([0.2, 0.3, 1.0]), np.array([0.25, 0.3, -1.0])        # crosses the face at t = 0.5
    times = []
    for iterations in (10**7, CCD_MAX_ITERATIONS, 3):
        hit, toi = ipctk.TightInclusionCCD(tolerance=1e-9, max_iterations=iterations).point_triangle_ccd(
            p0, *tri, p1, *tri, min_distance=0.0, tmax=1.0)
        assert hit
        times.append(toi)
    assert times[0] == pytest.approx(0.5, abs=1e-3)
    assert 0.0 <= times[2] <= times[1] <= times[0] + 1e-12


def test_designs_contact_cannot_honour_are_refused():
    """dhat against the mesh's rest distances; the line search when the design is read, and the term
    still refuses a Design whose line search was changed after reading."""
    with pytest.raises(DesignError, match="contact.dhat"):
        _model(_slot_design(1, dhat=0.9))                    # the slot is 0.8 mm wide at rest
    with pytest.raises(DesignError, match=r"^<design>: solver\.line_search: 'residual' cannot bound steps"):
        parse_design(variant(_slot_design(1), **{"solver.line_search": "residual"}))
    d = dataclasses.replace(parse_design(_slot_design(1)), solver=SolverSpec(line_search="residual"))
    with pytest.raises(DesignError, match=r"^<design>: contact\.self: .*solver\.line_search"):
        Session(d)


@pytest.mark.parametrize("line_search", ["residual", "none", "trust_region"])
def test_simulate_refuses_line_searches_that_cannot_bound_contact_steps(line_search, tmp_path, monkeypatch, capsys):
    """One error line naming the key and self-contact, exit 1, before meshing and before the output folder."""
    d = variant(_slot_design(1), **{"solver.line_search": line_search})
    line = simulate_refused_before_meshing(d, tmp_path, monkeypatch, capsys)
    assert line.startswith(f"solver.line_search: '{line_search}' ") and "for self-contact (contact.self = true)" in line


def test_line_searches_on_the_energy_keep_contact_designs_valid():
    for line_search in ("auto", "energy", "curved"):
        d = parse_design(variant(_slot_design(1), **{"solver.line_search": line_search}))
        assert d.solver.line_search == line_search and d.contact.self_contact
    assert not parse_design(variant(_slot_design(1, self_contact=False), **{"solver.line_search": "residual"})
                            ).contact.self_contact


def test_a_line_search_refused_for_rigid_bones_and_self_contact_names_both():
    d = strip(bones=True)
    for b in d["bones"]:
        b["rigid"] = True
    d = variant(d, **{"contact.self": True, "solver.line_search": "none"})
    with pytest.raises(DesignError, match=r"^<design>: solver\.line_search: 'none' cannot keep rigid bones rigid "
                                          r"\(rigid: b1, b2\) nor bound steps to collision-free ones for "
                                          r"self-contact \(contact\.self = true\); use \"energy\" or \"curved\"$"):
        parse_design(d)


def test_overlap_measures_count_a_body_passing_through_itself():
    sc = _model(_slot_design(1, self_contact=False))
    term = SelfContact(sc.V, dhat=0.3, stiffness=1.0)
    ccw = oriented_edges(term.X, term.edges)
    box = np.array([[0.0, 0.0], [10.0, 6.0]])
    assert overlap_area(term.X, ccw, box) == 0.0
    y = term.X.copy()
    top = np.isclose(y[:, 1], 3.4) & (y[:, 0] > 2 - 1e-9) & (y[:, 0] < 8 + 1e-9)
    y[top, 1] -= 1.2                        # the slot's whole upper face 0.4 mm past the lower one
    assert overlap_area(y, ccw, box, n=400) == pytest.approx(6.0 * 0.4, rel=0.05)
    assert crossing_edges(y, term.edges) == 0     # a hole turned inside out crosses no edge: area sees it
    y = term.X.copy()
    inner = top & (y[:, 0] > 2.5) & (y[:, 0] < 7.5)
    y[inner, 1] -= 1.2                      # only the face's interior: its end edges cut the lower face
    assert crossing_edges(y, term.edges) >= 2
    assert 0.4 * 4.0 < overlap_area(y, ccw, box, n=400) < 0.4 * 6.0


def _study():
    return load_study("knuckle_contact")


@pytest.mark.slow
def test_knuckles_close_without_interpenetrating_only_with_self_contact(tmp_path, picture):
    res = _study().run(size=2.0, contraction=16.0, out=tmp_path)
    on, off = res["on"], res["off"]
    assert on["converged"] and off["converged"]
    # contact on: every accepted iterate is intersection-free, the faces come within dhat (they touch)
    assert on["min_distance"] > 0.0 and on["crossing_edges"] == 0 and not on["intersects"]
    assert on["overlap_area"] == 0.0 and 0.0 < on["final_distance"] < 0.3
    assert all(d > 0 for _, d in on["history"])
    # contact off: the same contraction pushes the notch faces through each other
    assert off["crossing_edges"] > 0 and off["intersects"] and off["overlap_area"] > 0.5
    assert (tmp_path / "knuckle_contact.csv").stat().st_size > 1_000
    rows = (tmp_path / "knuckle_contact.csv").read_text().splitlines()
    assert rows[0] == "self_contact,iterate,load_factor,min_distance_mm"
    assert len(rows) == 1 + len(on["history"]) + len(off["history"])
    picture(tmp_path / "knuckles.png", 1000, 1000)
    picture(tmp_path / "knuckle_distance.png", 600, 350)
    assert not list(tmp_path.glob(".*"))


def test_settled_contacts_take_the_exact_hessian_and_a_new_load_step_projects_again():
    """settle=True: the first Hessian over a set of collisions is projected (PSD), the next over the same
    set is the exact one, and set_factor (a new load step) or a change of the set projects again."""
    sc = _model(_slot_design(1, self_contact=False))
    u = _squeeze(sc.V, noise=0.01)
    exact = SelfContact(sc.V, dhat=0.3, stiffness=1.0, thickness=4.0, project=False).hessian(u)[0][1].toarray()
    term = SelfContact(sc.V, dhat=0.3, stiffness=1.0, thickness=4.0, settle=True)
    first, second = (term.hessian(u)[0][1].toarray() for _ in range(2))
    assert np.linalg.eigvalsh(first).min() >= -1e-9 * np.abs(first).max()
    assert np.abs(second - exact).max() == 0.0 and np.abs(first - exact).max() > 1e-6 * np.abs(exact).max()
    term.set_factor(1.0)
    assert np.abs(term.hessian(u)[0][1].toarray() - first).max() == 0.0
    term.hessian(_squeeze(sc.V, closing=0.7, noise=0.01))                 # other collisions
    assert np.abs(term.hessian(u)[0][1].toarray() - first).max() == 0.0


def test_the_knuckles_close_in_few_newton_iterations_per_load_step():
    """Once the notch faces touch, the exact Hessian of the settled contacts converges fast: each of
    finger_knuckles.toml's four load steps in at most 15 Newton iterations (the projected Hessian's
    linear tail took 50 in the third), to the same closed shape."""
    from conftest import GEOMETRY
    with Session(GEOMETRY / "finger_knuckles.toml") as s:
        r = s.solve()
        assert r.converged, r.status
        steps = [len(h) - 1 for h in r.report.residual_history]
        assert len(steps) == 4 and max(steps) <= 15, steps
        entry = r.to_dict()["contact"]["self"]
        assert 0.0 < entry["min_distance"] < 0.3 and entry["normal_magnitude"] > 1.0
