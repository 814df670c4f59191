"""Conformance of every registered energy term, and the two newest ingredients against references.

Each term of a design that exercises it is checked on its own: its gradient
and its Hessian (sparse part + rank-one parts) against central differences
of its energy, and the matrix pattern covering its Hessian. UFL terms are
checked through their compiled energy, gradient and Hessian forms.
"""

import numpy as np
import pytest
import scipy.sparse as sp
import ufl
from dolfinx import fem

from skelfem import Session
from skelfem.terms import BUILDERS
from skelfem.terms.friction import GroundFriction
from skelfem.terms.facets import closest_on_facets
from skelfem.terms.object_friction import ObjectFriction

from _designs import strip

FIXED_SEED = 7


def _designs():
    """One small design per ingredient (each term of BUILDERS appears in at least one)."""
    base = strip(length=30.0, width=8.0, size=2.0, contraction=2.0, k=2.0)
    base["materials"]["soft"]["density"] = 1100.0
    base["materials"]["hard"]["density"] = 1200.0
    full = dict(base)
    full.update({
        "bones": [{"name": "b1", "outline": [[2, 8], [6, 8], [6, 20], [2, 20]], "material": "hard"}],
        "loads": [{"name": "tip", "at": [4.0, 29.0], "force": [0.3, -0.2]}],
        "grounds": [{"name": "wall", "point": [-1.0, 0.0], "normal": [1.0, 0.0], "stiffness": 5.0}],
        "gravity": {"acceleration": [3.0, -9.81]},
        "tractions": [{"name": "pad", "region": [[-1, 29.9], [9, 31]], "traction": [0.01, -0.02]}],
    })
    spring = dict(base, pins=[{"name": "base", "region": [[-1, -1], [9, 1e-6]], "kind": "spring",
                               "stiffness": 3.0, "move": [0.2, 0.1]}])
    contact = dict(base, contact={"self": True, "dhat": 0.3},
                   body={"outline": [[0, 0], [8, 0], [8, 30], [0, 30], [0, 16], [5, 15.5], [0, 15]],
                         "material": "soft"})
    contact["cables"] = [dict(base["cables"][0], path=[[7, 0], [7, 30]])]
    dynamic = dict(base, dynamics={"dt": 0.01, "duration": 0.1, "integrator": "bdf2",
                                   "damping": {"mass": 5.0, "stiffness": 0.01}})
    rigid = dict(full, bones=[dict(full["bones"][0], rigid=True)])
    friction = dict(base, grounds=[{"name": "wall", "point": [0.0, 0.0], "normal": [1.0, 0.0], "stiffness": 5.0,
                                    "friction": 0.4, "friction_static": 0.6}])
    objects = dict(base, objects=[{"name": "box", "outline": [[8.25, 10], [12, 10], [12, 20], [8.25, 20]],
                                   "material": "hard"}], contact={"dhat": 0.2, "friction": 0.4},
                   gravity={"acceleration": [1.0, -9.81]})
    bodies = dict(base, contact={"dhat": 0.2, "friction": 0.4, "self": True}, body=None,
                  bodies=[dict(base["body"], name="left"),
                          {"name": "right", "outline": [[8.25, 0], [14, 0], [14, 30], [8.25, 30]], "material": "hard"}],
                  pins=[dict(base["pins"][0], region=[[-1, -1], [15, 1e-6]])])
    del bodies["body"]
    elastic = dict(objects, objects=[dict(objects["objects"][0], rigid=False, material="soft")])
    objects3d = {"format": 1, "name": "objects3d", "dim": 3, "mesh": {"size": 2.5, "degree": 1},
                 "materials": {"soft": {"E": 1.0, "nu": 0.3, "density": 1100.0},
                               "hard": {"E": 1000.0, "nu": 0.3, "density": 1200.0}},
                 "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [8, 12, 8]}}], "material": "soft"},
                 "pins": [{"name": "base", "region": [[-1, -1, -1], [9, 1e-6, 9]], "kind": "fixed"}],
                 "objects": [{"name": "box", "solids": [{"box": {"min": [8.25, 2, 1], "max": [12, 10, 7]}}],
                              "material": "hard"}],
                 "contact": {"dhat": 0.2, "friction": 0.4}, "gravity": {"acceleration": [1.0, -9.81, 0.5]}}
    contact3d = {"format": 1, "name": "contact3d", "dim": 3, "mesh": {"size": 2.0, "degree": 1},
                 "materials": {"soft": {"E": 1.0, "nu": 0.3}},
                 "body": {"solids": [{"extrude": {"outline": contact["body"]["outline"], "z": [0, 4]}}],
                          "material": "soft"},
                 "pins": [{"name": "base", "region": [[-1, -1, -1], [9, 1e-6, 5]], "kind": "fixed"}],
                 "cables": [dict(base["cables"][0], path=[[7, 0, 2], [7, 30, 2]])],
                 "contact": {"self": True, "dhat": 0.2}}    # the notch's tip: 0.23 mm between triangles at rest
    return {"contact3d": contact3d, "objects3d": objects3d, "elastic_object": elastic, "full": full, "spring": spring, "contact": contact, "dynamic": dynamic, "rigid": rigid,
            "friction": friction, "objects": objects, "bodies": bodies}


def _perturbed_state(model, scale):
    rng = np.random.default_rng(FIXED_SEED)
    u = scale * rng.standard_normal(model.n_local)
    u[model.fixed] = 0.0
    model.u.x.array[:] = u
    model.u.vector.ghostUpdate()
    return u


def _term_energy(model, term, u, form):
    model.u.x.array[:] = u
    return term.energy(u) + (fem.assemble_scalar(form) if form is not None else 0.0)


def _term_derivatives(model, term):
    """Compiled UFL energy/gradient/Hessian forms of one term (None if it has no UFL part)."""
    e = term.ufl_energy(model.ctx)
    if e is None:
        return None, None, None
    v, du = ufl.TestFunction(model.V), ufl.TrialFunction(model.V)
    g = ufl.derivative(e, model.u, v)
    return fem.form(e), fem.form(g), fem.form(ufl.derivative(g, model.u, du))


def _dense_hessian(model, term, u, hform):
    n = model.n_local
    H = np.zeros((n, n))
    for dofs, block in term.hessian(u):
        block = block.tocoo() if hasattr(block, "tocoo") else sp.coo_matrix(np.asarray(block))
        np.add.at(H, (np.asarray(dofs)[block.row], np.asarray(dofs)[block.col]), block.data)   # repeated DOFs add up
    for c, dofs, g in term.low_rank(u):
        H[np.ix_(dofs, dofs)] += c * np.outer(g, g)
    if hform is not None:
        model.u.x.array[:] = u
        A = fem.petsc.assemble_matrix(hform)
        A.assemble()
        H += A.convert("dense").getDenseArray()
    return H


def _gradient(model, term, u, gform):
    g = np.zeros(model.n_local)
    out = term.gradient(u)
    if out is not None:
        np.add.at(g, out[0], out[1])
    if gform is not None:
        model.u.x.array[:] = u
        g += fem.petsc.assemble_vector(gform).array
    return g


@pytest.mark.parametrize("name", ["full", "spring", "contact", "dynamic", "rigid", "friction", "objects", "bodies",
                                  "elastic_object", "objects3d", "contact3d"])
def test_every_term_gradient_and_hessian_match_central_differences(name):
    import dolfinx.fem.petsc  # noqa: F401
    design = _designs()[name]
    s = Session(design)
    model = s.model
    model.set_factor(0.7)
    seen = set()
    u0 = _perturbed_state(model, 0.02 if name not in ("contact", "objects", "objects3d", "contact3d") else 1e-3)
    if name in ("objects", "elastic_object", "objects3d"):          # the box 0.12 mm from the strip: in the barrier's reach
        box = model.term("objects", "box")
        u0[box.dofs[:, 0]] = -0.13
        model.u.x.array[:] = u0
        contact = model.term("contacts", "pieces")
        assert contact.min_distance(u0) < 0.2 and not contact.intersects(u0)
    if name == "bodies":                              # the right body 0.12 mm from the left one
        x = model.V.tabulate_dof_coordinates()[:, 0]
        u0.reshape(-1, 2)[:, 0] -= 0.13 * (x > 8.1) * ~model.fixed.reshape(-1, 2)[:, 0]
        model.u.x.array[:] = u0
        contact = model.term("contacts", "pieces")
        assert contact.min_distance(u0) < 0.2 and not contact.intersects(u0)
    if name in ("contact", "contact3d"):              # close the notch so that contacts are active
        y = model.V.tabulate_dof_coordinates()[:, 1]
        uy = -0.45 * np.clip(y - 15.0, 0.0, 2.0)
        u0.reshape(-1, model.bs)[:, 1] += uy
        model.u.x.array[:] = u0
        contact = model.term("contact")
        assert contact.min_distance(u0) < contact.dhat and not contact.intersects(u0)
        assert len(contact.collisions(contact.positions(u0))) >= 3
    rng = np.random.default_rng(1)
    for term in model.terms:
        seen.add(type(term).__name__)
        if hasattr(term, "project"):
            term.project = False                      # the exact barrier Hessian (Newton uses its PSD projection)
        if hasattr(term, "prepare"):                  # inertia: a BDF2 step from a moving state
            term.start(0.3 * u0, v0=np.roll(u0, 3))
            term.prepare(0.01)
            model.u.x.array[:] = 0.6 * u0
            term.end_step(model)
            term.prepare(0.005)
        if isinstance(term, GroundFriction) and term.active:   # pressed into the wall, half the nodes sticking
            u0 = u0.copy()
            u0.reshape(-1, 2)[:, 0] -= 0.05 * ~model.fixed.reshape(-1, 2)[:, 0]
            model.u.x.array[:] = u0
            term.update_lag(model)
            assert np.count_nonzero(term.N) >= 4
            s_now = term.positions(u0) @ term.T
            term.anchor = s_now + 0.5 * term.eps * np.where(np.arange(len(s_now)) % 2 == 0, 1.0, 3.0)[:, None]
            term.trial[::3] = True                    # some kinetic nodes too
        if isinstance(term, ObjectFriction):          # anchored, half the nodes sticking, some kinetic
            term.set_factor(model.factor)
            term.update_lag(model)
            on = np.flatnonzero(term.facet >= 0)
            assert len(on) >= 3 and np.count_nonzero(term.N[on]) >= 3
            y = term.c.positions(u0)
            shift = np.where(np.arange(len(on)) % 2 == 0, 0.5, 1.5) * term.eps     # anchors moved along T
            P = term._anchor_points(y, on) + shift[:, None] * term.T[on][:, :, 0]
            term.b[on] = closest_on_facets(P, y, term.facets[term.facet[on]])
            term.trial[on[::3]] = True
        eform, gform, hform = _term_derivatives(model, term)
        if eform is None and term.gradient(u0) is None:
            continue                                  # a read-out only term (markers)
        g = _gradient(model, term, u0, gform)
        H = _dense_hessian(model, term, u0, hform)
        free = ~model.fixed
        for _ in range(2):
            p = rng.standard_normal(model.n_local) * free
            h = 1e-6 * max(np.abs(u0).max(), 1.0)
            if isinstance(term, ObjectFriction):      # 3D slip curves over the slip length eps: steps well below it
                h = min(h, 1e-3 * term.eps)
            ep = _term_energy(model, term, u0 + h * p, eform)
            em = _term_energy(model, term, u0 - h * p, eform)
            fd = (ep - em) / (2 * h)
            assert fd == pytest.approx(g @ p, rel=1e-5, abs=1e-9 * max(1.0, abs(fd))), type(term).__name__
            gp = _gradient(model, term, u0 + h * p, gform)
            gm = _gradient(model, term, u0 - h * p, gform)
            Hp = (gp - gm) / (2 * h)
            err = np.linalg.norm((Hp - H @ p)[free])
            roundoff = 1e-14 * np.linalg.norm(g[free]) * np.linalg.norm(p) / h     # of the gradient's own size
            assert err <= 1e-5 * max(np.linalg.norm(Hp[free]), 1e-12) + roundoff, (type(term).__name__, err)
        # the Newton matrix's pattern covers the term's sparse Hessian
        A = s.solver.A
        for dofs, block in term.hessian(u0):
            block = block.toarray() if hasattr(block, "toarray") else np.asarray(block)
            rows, cols = np.nonzero(block)
            keep = free[dofs[rows]] & free[dofs[cols]]
            for r, c in zip(dofs[rows[keep]], dofs[cols[keep]]):
                A.getValue(int(r), int(c))           # raises if the entry is not in the pattern
    s.close()
    if name == "full":
        assert {"Elasticity", "Pin", "CableTerm", "PointLoad", "Ground", "Markers", "Gravity", "Traction"} <= seen
    if name in ("contact", "contact3d"):
        assert "SelfContact" in seen
    if name == "dynamic":
        assert "Inertia" in seen
    if name == "rigid":
        assert "RigidBone" in seen
    if name == "friction":
        assert "GroundFriction" in seen
    if name == "objects":
        assert {"RigidObject", "PieceContact", "ObjectFriction"} <= seen
    if name == "bodies":
        assert {"PieceContact", "ObjectFriction", "SelfContact"} <= seen
    if name == "elastic_object":
        assert {"ElasticObject", "PieceContact", "ObjectFriction", "Elasticity"} <= seen


def test_every_builder_is_exercised():
    names = {b.__module__.rsplit(".", 1)[1] for b in BUILDERS}
    assert names == {"elasticity", "pins", "cables", "loads", "grounds", "contact", "markers", "gravity",
                     "tractions", "inertia", "rigid", "friction", "objects"}


def test_woodbury_direction_equals_the_full_hessian_direction():
    """Newton's direction with the rank-one parts out of the matrix equals the one with them in it."""
    import dolfinx.fem.petsc  # noqa: F401
    s = Session(_designs()["full"])
    model, solver = s.model, s.solver
    model.set_factor(1.0)
    _perturbed_state(model, 0.05)
    x = model.u.vector.copy()
    model.apply_bcs(x)
    b, p = x.duplicate(), x.duplicate()
    model.residual(x, b)
    solver.jacobian(x)
    assert len(solver.lin.c) >= 1                   # a taut cable takes part
    solver.lin.solve(b, p)
    K = solver.A.copy().convert("dense").getDenseArray().copy()
    for c, g in model.low_rank(x):
        K += c * np.outer(g.array_r, g.array_r)
    p_full = np.linalg.solve(K, b.array_r)
    assert np.linalg.norm(p.array_r - p_full) <= 1e-10 * np.linalg.norm(p_full)
    # no dense block: the Newton matrix has (almost) the finite-element pattern's size
    fe = dolfinx.fem.petsc.assemble_matrix(model.jacobian_form, bcs=model.bcs)
    fe.assemble()
    assert solver.A.getInfo()["nz_used"] <= 1.05 * fe.getInfo()["nz_used"]
    s.close()


# -- gravity: a cantilever sagging under its own weight ------------------------------------------
def test_gravity_sag_matches_beam_theory():
    """Plane-strain cantilever L x h: tip deflection q L^4 / (8 E' I) (Euler-Bernoulli; shear < 0.3 %)."""
    L, h, t, E, nu, rho, g = 100.0, 5.0, 10.0, 50.0, 0.3, 1000.0, 9.81
    d = {"format": 1, "name": "sag", "dim": 2, "thickness": t, "mesh": {"size": 1.25, "degree": 2},
         "materials": {"m": {"E": E, "nu": nu, "density": rho}},
         "body": {"outline": [[0, 0], [L, 0], [L, h], [0, h]], "material": "m"},
         "pins": [{"name": "wall", "region": [[-1, -1], [1e-6, h + 1]]}],
         "gravity": {"acceleration": [0.0, -g]}, "markers": {"tip": [L, h / 2]}}
    with Session(d) as s:
        r = s.solve()
    assert r.converged
    q = 1e-9 * rho * g * h * t                        # N/mm
    delta = q * L ** 4 / (8 * E / (1 - nu ** 2) * t * h ** 3 / 12)
    assert delta / L < 0.02                           # small deflection: beam theory applies
    sag = -r.markers["tip"]["displacement"][1]
    assert sag == pytest.approx(delta, rel=0.03)
    assert r.gravity["weight"] == pytest.approx([0.0, -q * L], rel=1e-9, abs=1e-15)
    assert r.pins["wall"]["reaction"][1] == pytest.approx(q * L, rel=1e-6)


# -- tractions ------------------------------------------------------------------------------------
def _cook(eps: float, size: float = 1.0):
    """Cook's membrane (mm): E = 70 MPa, nu = 1/3, plane strain, shear traction eps x 6.25 MPa on the right edge."""
    return {"format": 1, "name": "cook", "dim": 2, "thickness": 1.0, "mesh": {"size": size, "degree": 2},
            "materials": {"m": {"E": 70.0, "nu": 1 / 3}},
            "body": {"outline": [[0, 0], [48, 44], [48, 60], [0, 44]], "material": "m"},
            "pins": [{"name": "left", "region": [[-1, -1], [1e-6, 45]]}],
            "tractions": [{"name": "shear", "region": [[48 - 1e-6, 43], [49, 61]],
                           "traction": [0.0, eps * 6.25]}],
            "markers": {"C": [48, 60]}}


def test_traction_cooks_membrane_matches_published_value():
    """Small-load limit of the hyperelastic model against the cofea benchmark's 32.27 mm (fine quadratic FEM)."""
    eps = 1e-4
    with Session(_cook(eps)) as s:
        r = s.solve()
    assert r.converged
    uy = r.markers["C"]["displacement"][1] / eps
    assert uy == pytest.approx(32.27, rel=0.01)
    assert r.tractions["shear"]["force"][1] == pytest.approx(eps * 6.25 * 16.0, rel=1e-9)


def test_traction_uniaxial_stretch_is_exact():
    """nu = 0: a dead traction tau on a clamped strip gives the homogeneous stretch mu (l - 1/l) = tau."""
    E, tau, L = 2.0, 1.5, 20.0
    mu = E / 2
    d = {"format": 1, "name": "bar", "dim": 2, "thickness": 2.0, "mesh": {"size": 2.0, "degree": 1},
         "materials": {"m": {"E": E, "nu": 0.0}},
         "body": {"outline": [[0, 0], [L, 0], [L, 4], [0, 4]], "material": "m"},
         "pins": [{"name": "left", "region": [[-1, -1], [1e-6, 5]]}],
         "tractions": [{"name": "pull", "region": [[L - 1e-6, -1], [L + 1, 5]], "traction": [tau, 0.0]}],
         "markers": {"end": [L, 2.0]}, "solver": {"steps": 2}}
    with Session(d) as s:
        r = s.solve()
    stretch = (tau / mu + np.sqrt((tau / mu) ** 2 + 4)) / 2
    assert r.converged
    assert r.markers["end"]["displacement"] == pytest.approx([(stretch - 1) * L, 0.0], abs=1e-8 * L)


# -- live parameters and the session ----------------------------------------------------------------
def test_session_set_changes_gravity_and_traction_live():
    with Session(_cook(1e-4, size=4.0)) as s:
        r1 = s.solve()
        s.set({"tractions.shear.traction": [0.0, 2e-4 * 6.25]})
        mesh = s.model.mesh
        r2 = s.solve()
        assert s.model.mesh is mesh                  # no re-mesh
    assert r2.markers["C"]["displacement"][1] == pytest.approx(2 * r1.markers["C"]["displacement"][1], rel=1e-3)


@pytest.mark.parametrize("degree", [1, 2])
def test_the_elastic_energy_is_integrated_with_degree_2p_and_exactly_for_p1(degree):
    """Quadrature of degree 2p (FFCx's estimate asks for far more points), one point (degree 1) for P1 on
    straight cells, whose F is constant per cell: its energy is the same as with FFCx's own degree; P2's
    differs by a quadrature error only."""
    from skelfem.terms.elasticity import deformation_gradient, psi
    with Session(strip(length=30.0, width=8.0, size=2.0, degree=degree, contraction=2.0, k=2.0)) as s:
        s.solve()
        el = s.model.term("materials")
        integrals = el.ufl_energy(s.model.ctx).integrals()
        assert {i.metadata().get("quadrature_degree") for i in integrals} == {1 if degree == 1 else 2 * degree}
        t = s.model.ctx.thickness
        own = fem.assemble_scalar(fem.form(t * psi(deformation_gradient(s.model.u), el.mu, el.lam) * el.dx))
        ffcx = fem.assemble_scalar(fem.form(t * psi(deformation_gradient(s.model.u), el.mu, el.lam) * ufl.dx))
        assert own > 0.0
        if degree == 1:
            assert own == pytest.approx(ffcx, rel=1e-12)
        else:
            assert own == pytest.approx(ffcx, rel=1e-3) and own != ffcx
