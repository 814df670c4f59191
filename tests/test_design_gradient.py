"""Exact design gradients (skelfem.analysis.design_gradient): Taylor tests against full re-solves.

For every kind of design variable, J(p0 + h e) is solved anew on the mesh moved by the morph (the same
topology) for four halving steps h, and the remainder |J(p0 + h e) - J(p0) - h dJ/dp . e| must fall
at order >= 1.9 over the three halvings: it does only if the adjoint gradient is the derivative of
the discrete problem, every part of dR/dX, dR/dQ and dJ/dX included. The steps stay inside the
piece where the discrete energy is smooth (DesignGradient.smooth_step: no node crosses a cable's
sketch, no sketch vertex or anchor point crosses an edge).
"""
import numpy as np
import pytest

from skelfem.design.parse import load_design
from skelfem.mesh.geometry import mesh_design
from skelfem.mesh.morph import Morph, polygons

FINGER = "geometry/finger.toml"
# the flexor off the mesh's node rows at x = 3 (a sketch through nodes is a kink), a hole, tight Newton
OVERRIDES = ["cables.flexor.path=[[3.3, 0], [3.3, 78.3], [9, 84]]",
             "body.holes=[[[16, 20], [18.5, 20], [18.5, 26], [16, 26]]]",
             "solver.atol=1e-12", "solver.rtol=1e-14"]
KEYS = ["bones.proximal.outline[2].y", "bones.distal.offset.x", "bones.distal.offset.y", "bones.middle.angle",
        "body.holes[0][1].x", "body.outline[8].x", "body.outline[1].x", "cables.flexor.path[2].x", "materials.ecoflex.E",
        "materials.pla.E", "cables.lig1_dorsal.pretension", "cables.flexor.stiffness"]


@pytest.fixture(scope="module")
def finger_gradient():
    from skelfem.analysis.design_gradient import DesignGradient
    from skelfem.session import Session
    session = Session(FINGER, overrides=OVERRIDES)
    yield DesignGradient(session, KEYS)
    session.close()


def _first_step(dg, key, j) -> float:
    e = np.eye(len(dg.keys))[j]
    if key.endswith(".E"):
        material = key.split(".")[1]
        return 0.05 * float(dg.session.design.materials[material].E)
    if key.endswith(".stiffness"):
        return 0.05 * float(dg.session.design.cable(key.split(".")[1]).stiffness)
    return min(0.25, 0.5 * dg.smooth_step(e))


def assert_second_order(dg, key, objectives, values, grads, h0, halvings=3):
    """Each objective's first-order Taylor remainder |J(p + h e) - J(p) - h dJ/dp_key| falls at order
    >= 1.9 over `halvings` halvings of h from h0 (every step converged); the design is put back at p."""
    j = dg.keys.index(key)
    e = np.eye(len(dg.keys))[j]
    remainders = np.zeros((len(objectives), halvings + 1))
    for i, h in enumerate(h0 * 0.5 ** np.arange(halvings + 1)):
        assert dg.solve(h * e).converged, (key, h)
        for k, o in enumerate(objectives):
            remainders[k, i] = abs(o.value(dg.session.model) - values[k] - h * grads[k][j])
    dg.solve(np.zeros(len(dg.keys)))
    for k, o in enumerate(objectives):
        orders = np.log2(remainders[k, :-1] / remainders[k, 1:])
        assert np.all(orders >= 1.9), (key, type(o).__name__, grads[k][j], remainders[k], orders)


@pytest.mark.slow
@pytest.mark.parametrize("key", KEYS)
def test_taylor_remainder_falls_at_second_order(finger_gradient, key):
    from skelfem.analysis.design_gradient import MarkerTarget, Tension
    dg = finger_gradient
    j = dg.keys.index(key)
    objectives = [MarkerTarget("tip", (-20.0, 80.0)), Tension("flexor")]
    dg.solve(np.zeros(len(dg.keys)))
    values, grads = zip(*[dg.gradient(o) for o in objectives])
    assert_second_order(dg, key, objectives, values, grads, _first_step(dg, key, j))


@pytest.mark.slow
def test_gradient_needs_the_cables_part(finger_gradient, monkeypatch):
    """Leaving out the cables' part of z^T dR/dX changes the gradient by far more than the Taylor test
    resolves: the part the test holds is not negligible."""
    from skelfem.analysis.design_gradient import MarkerTarget
    from skelfem.analysis.shape import ShapeDerivative
    dg = finger_gradient
    dg.solve(np.zeros(len(dg.keys)))
    objective = MarkerTarget("tip", (-20.0, 80.0))
    _, full = dg.gradient(objective)
    monkeypatch.setattr(ShapeDerivative, "trace_cables", lambda self: setattr(self, "cables", {}))
    _, without = dg.gradient(objective)
    j = dg.keys.index("bones.distal.offset.x")
    assert abs(full[j] - without[j]) > 1e-2 * abs(full[j])


def test_morph_pull_back_is_the_transpose_of_the_move():
    """g . displacement(moves) == pull_back(g) . moves for random g and moves: the adjoint of the morph that
    carries dJ/dX to the polygon vertices whatever the number of design variables."""
    from mpi4py import MPI
    design = load_design(FINGER)
    morph = Morph(mesh_design(design, MPI.COMM_SELF), design)
    rng = np.random.default_rng(0)
    moves = [rng.standard_normal(p.shape) for p in polygons(design)]
    g = rng.standard_normal(morph.X0.shape)
    lhs = float(np.sum(g * morph.displacement(moves)))
    rhs = sum(float(np.sum(a * b)) for a, b in zip(morph.pull_back(g), moves))
    assert abs(lhs - rhs) <= 1e-10 * abs(lhs)
    # and displacement is what moved() applies
    moved = [p + 0.01 * m for p, m in zip(polygons(design), moves)]
    assert morph.moved(design) is not None
    assert np.allclose(morph.X0 + morph.displacement([a - b for a, b in zip(moved, polygons(design))]),
                       morph.X0 + 0.01 * morph.displacement(moves))


@pytest.mark.parametrize("key, message", [
    ("bones.nope.angle", "no bone 'nope'"),
    ("bones.distal.offset.z", "bones.B.offset.x"),
    ("body.outline[99].x", "out of range"),
    ("cables.flexor.contraction", "not a design variable"),
    ("materials.steel.E", "no material 'steel'"),
    ("cables.flexor.pretension", "a tendon has no pretension"),
    ("cables.nope.stiffness", "no cable 'nope'"),
])
def test_unknown_variables_are_named(key, message):
    from skelfem.analysis.handles import DesignHandles
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace(".", r"\.")):
        DesignHandles(load_design(FINGER), [key])


def test_handles_move_the_design_exactly():
    """points(p) is the design the handles describe: a bone's pose carries the sketch vertices inside it,
    and velocities() is points()'s derivative (central differences, linear handles exact)."""
    from skelfem.analysis.handles import DesignHandles
    design = load_design(FINGER)
    keys = ["bones.distal.angle", "bones.distal.offset.y", "cables.flexor.path[2].x", "body.outline[1].y"]
    h = DesignHandles(design, keys)
    p = np.array([10.0, 1.0, 0.5, -2.0])
    polys, paths, _ = h.split(h.points(p))
    raw = h.raw(p)
    assert np.allclose(raw["cables"][0]["path"], paths["flexor"])
    assert np.allclose(paths["flexor"][2], np.asarray(raw["cables"][0]["path"][2]))
    c = h.centre[2]
    rot = np.radians(10.0)
    R = np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]])
    expected = c + R @ (np.array([9.5, 84.0]) - c) + [0.0, 1.0]     # the flexor's end rides on the distal bone
    assert np.allclose(paths["flexor"][2], expected)
    V = h.velocities(p)
    for j in range(len(keys)):
        e = np.eye(len(keys))[j] * 1e-6
        fd = (h.points(p + e) - h.points(p - e)) / 2e-6
        assert np.allclose(fd, V[:, :, j], atol=1e-6)


def test_designs_the_gradient_does_not_cover_are_refused():
    from skelfem.analysis.design_gradient import DesignGradient
    from skelfem.session import Session
    with Session("geometry/finger_friction.toml") as session:
        with pytest.raises(ValueError, match="friction"):
            DesignGradient(session, ["bones.distal.angle"])


def test_a_variable_named_twice_is_refused():
    from skelfem.analysis.handles import DesignHandles
    with pytest.raises(ValueError, match=r"bones\.distal\.angle: named twice"):
        DesignHandles(load_design(FINGER), ["bones.distal.angle", "body.outline[1].x", "bones.distal.angle"])


@pytest.mark.slow
@pytest.mark.parametrize("key", ["bones.distal.offset.x", "cables.flexor.path[2].x", "body.outline[8].x"])
def test_taylor_remainder_at_p2(key):
    """The same at P2, where a cable is cut into four pieces per cell (points between the cuts)."""
    from skelfem.analysis.design_gradient import DesignGradient, MarkerTarget
    from skelfem.session import Session
    with Session(FINGER, overrides=OVERRIDES + ["mesh.degree=2", "mesh.size=3"]) as session:
        dg = DesignGradient(session, [key])
        dg.solve()
        objective = MarkerTarget("tip", (-20.0, 80.0))
        J0, g = dg.gradient(objective)
        h0 = min(0.25, 0.5 * dg.smooth_step([1.0]))
        remainders = []
        for h in h0 * 0.5 ** np.arange(4):
            dg.solve(np.array([h]))
            remainders.append(abs(objective.value(session.model) - J0 - h * g[0]))
    orders = np.log2(np.array(remainders[:-1]) / np.array(remainders[1:]))
    assert np.all(orders >= 1.9), (key, remainders, orders)


def test_a_gradient_needs_a_solved_design_and_a_real_marker():
    from skelfem.analysis.design_gradient import DesignGradient, MarkerTarget
    from skelfem.session import Session
    with Session(FINGER) as session:
        dg = DesignGradient(session, ["bones.distal.angle"])
        with pytest.raises(ValueError, match="not solved"):
            dg.gradient(MarkerTarget("tip", (0.0, 0.0)))
        dg.solve()
        with pytest.raises(ValueError, match="markers.nail: no such marker"):
            dg.gradient(MarkerTarget("nail", (0.0, 0.0)))


# -- through a ground's sticking friction ----------------------------------------------------------------------
def _block_on_floor():
    """A soft block (20 x 8 mm, a vertex in the middle of its base and a peak of 0.5 mm on top) with a stiff
    bone, resting on a floor with friction (mu 1) under gravity tilted 5 degrees: every contact node sticks
    (the tangential load is 0.09 of the normal one); a weak spring pin."""
    import math
    g, th = 9.81, math.radians(5.0)
    return {"format": 1, "name": "block", "dim": 2, "thickness": 10.0, "mesh": {"size": 1.0, "degree": 1},
            "materials": {"m": {"E": 0.1, "nu": 0.45, "density": 1e5},
                          "pla": {"E": 3000.0, "nu": 0.35, "density": 1240.0}},
            "body": {"outline": [[0, 0], [10, 0], [20, 0], [20, 8], [10, 8.5], [0, 8]], "material": "m"},
            "bones": [{"name": "core", "outline": [[6, 3], [14, 3], [14, 5.5], [6, 5.5]], "material": "pla"}],
            "grounds": [{"name": "floor", "point": [0, 0], "normal": [0, 1], "stiffness": 100.0, "friction": 1.0}],
            "gravity": {"acceleration": [-g * math.sin(th), -g * math.cos(th)]},
            "pins": [{"name": "pull", "region": [[19.9, -1], [21, 9]], "kind": "spring", "stiffness": 1e-4 / 80}],
            "markers": {"c": [10, 8]}, "solver": {"steps": 2, "atol": 1e-12, "rtol": 1e-14}}


# the base's middle vertex moves its contact nodes along the floor (their anchors with them: from rest), the
# peak's height the body's bounding box (friction's slip length eps, a fraction of its diagonal)
FRICTION_KEYS = ["bones.core.outline[2].x", "bones.core.offset.y", "bones.core.angle", "materials.m.E",
                 "body.outline[1].x", "body.outline[4].y"]


@pytest.fixture(scope="module")
def block_gradient():
    from skelfem.analysis.design_gradient import DesignGradient
    from skelfem.session import Session
    session = Session(_block_on_floor())
    yield DesignGradient(session, FRICTION_KEYS)
    session.close()


def _sticks(result) -> bool:
    return result.converged and result.to_dict()["grounds"]["floor"]["sticking"] == 1.0


@pytest.mark.parametrize("key", FRICTION_KEYS)
def test_taylor_remainder_through_sticking_friction(block_gradient, key):
    """J(p + h e) solved anew from rest on the moved mesh, every contact node sticking at every h: the
    remainder falls at order >= 1.9 over three halvings for a bone vertex, the bone's pose, E and the body's
    vertices (one under the contact). The friction's lagged normal forces follow the state in the adjoint
    (J^T = H + C^T), and its shape derivative (the normal forces' boundary weights and gaps, the slip length's
    bounding box) is in z^T dR/dX."""
    from skelfem.analysis.design_gradient import MarkerTarget
    dg = block_gradient
    j = dg.keys.index(key)
    objective = MarkerTarget("c", (9.0, 7.0))
    assert _sticks(dg.solve(np.zeros(len(dg.keys))))
    J0, grad = dg.gradient(objective)
    e = np.eye(len(dg.keys))[j]
    h0 = 0.002 if key.endswith(".E") else 0.1
    remainders = []
    for h in h0 * 0.5 ** np.arange(4):
        assert _sticks(dg.solve(h * e)), h
        remainders.append(abs(objective.value(dg.session.model) - J0 - h * grad[j]))
    dg.solve(np.zeros(len(dg.keys)))
    orders = np.log2(np.array(remainders[:-1]) / np.array(remainders[1:]))
    assert np.all(orders >= 1.9), (key, grad[j], remainders, orders)


def test_the_adjoint_through_friction_solves_with_the_transpose(block_gradient):
    """c . J^-T b == b . J^-1 c with J = H + C (C: the lagged normal forces' coupling, not symmetric), and C
    is not negligible here: H^-1 alone misses it."""
    from skelfem.analysis.sensitivity import Linearization
    dg = block_gradient
    dg.solve(np.zeros(len(dg.keys)))
    model = dg.session.model
    lin = Linearization(model, dg.session.solver)
    try:
        n = len(model.u.vector.array_r)
        rng = np.random.default_rng(4)
        b, c = rng.standard_normal(n), rng.standard_normal(n)
        b[model.fixed[:n]] = c[model.fixed[:n]] = 0.0
        vb, vc = model.u.vector.duplicate(), model.u.vector.duplicate()
        vb.array_w[:], vc.array_w[:] = b, c
        zb, xc = lin.solve_transposed(vb), lin.solve(vc)
        lhs, rhs = float(c @ zb.array_r), float(b @ xc.array_r)
        assert abs(lhs - rhs) <= 1e-8 * abs(lhs), (lhs, rhs)
        plain = float(c @ lin.h_solve_many(b[:, None])[:, 0])
        assert abs(plain - lhs) > 1e-6 * abs(lhs), (plain, lhs)
        for v in (vb, vc, zb, xc):
            v.destroy()
    finally:
        lin.destroy()


def test_the_friction_shape_derivative_is_not_negligible(block_gradient, monkeypatch):
    """Leaving out the friction's z^T dR/dX changes the gradient of the contact vertex's move by 0.7 %: at the
    Taylor test's smallest step that is 40 % of its remainder (3.7e-9 of 8.9e-9), enough to break its order.
    (For the peak's height, which moves the slip length eps, the part is 2e-6 of the gradient: the adjoint
    barely moves the stuck nodes.)"""
    from skelfem.analysis.design_gradient import MarkerTarget
    from skelfem.analysis.shape import ShapeDerivative
    dg = block_gradient
    dg.solve(np.zeros(len(dg.keys)))
    objective = MarkerTarget("c", (9.0, 7.0))
    _, full = dg.gradient(objective)
    monkeypatch.setattr(ShapeDerivative, "_friction_adjoint", lambda self, z: 0.0)
    _, without = dg.gradient(objective)
    j = dg.keys.index("body.outline[1].x")
    assert abs(full[j] - without[j]) > 5e-3 * abs(full[j]), (full[j], without[j])


# -- 3D: bone poses ------------------------------------------------------------------------------------------
BLOCK3D = {"format": 1, "name": "block3d", "dim": 3, "mesh": {"size": 2.5, "degree": 1},
           "materials": {"ecoflex": {"E": 0.1, "nu": 0.45, "density": 1070.0},
                         "pla": {"E": 3000.0, "nu": 0.35, "density": 1240.0}},
           "body": {"solids": [{"extrude": {"outline": [[0, 0], [12, 0], [12, 40], [0, 40]], "z": [0, 12]}}],
                    "material": "ecoflex"},
           "bones": [{"name": "bone", "solids": [{"extrude": {"outline": [[3, 20], [9, 20], [9, 32], [3, 32]],
                                                             "z": [3, 9]}}], "material": "pla"}],
           # a straight tendon from the base into the bone: cut by the silicone's facets (moved by the harmonic
           # extension) and the bone's (moved rigidly); its end rides on the bone's pose
           "cables": [{"name": "flexor", "kind": "tendon", "path": [[5.1, 0, 6.1], [5.1, 26.3, 6.1]],
                       "stiffness": 20.0, "contraction": 2.0}],
           "pins": [{"name": "base", "region": [[-1, -1, -1], [13, 0.01, 13]], "kind": "fixed"}],
           "markers": {"tip": [6, 40, 6]}, "solver": {"atol": 1e-12, "rtol": 1e-14}}
KEYS_3D = ["bones.bone.offset.x", "bones.bone.offset.y", "bones.bone.offset.z", "bones.bone.angle.z",
           "materials.ecoflex.E"]


@pytest.fixture(scope="module")
def block3d_gradient():
    from skelfem.analysis.design_gradient import DesignGradient
    from skelfem.session import Session
    session = Session(BLOCK3D)
    yield DesignGradient(session, KEYS_3D)
    session.close()


@pytest.mark.parametrize("key", KEYS_3D)
def test_taylor_remainder_in_3d_for_bone_poses(block3d_gradient, key):
    """A 3D block (about 2000 DOFs) whose bone is translated or turned: the mesh follows by skelfem.mesh.morph3d
    (the bone's nodes rigidly, the silicone's by the harmonic extension, the same tetrahedra), UFL's
    CoordinateDerivative gives dPi/dX in 3D, the tendon's cuts with the tetrahedra's facets are differentiated
    through their 3 x 3 systems. The remainder falls at order >= 1.9 over three halvings, for the tip's
    target and the tendon's tension."""
    from skelfem.analysis.design_gradient import MarkerTarget, Tension
    dg = block3d_gradient
    objectives = [MarkerTarget("tip", (0.0, 30.0, 6.0)), Tension("flexor")]
    dg.solve(np.zeros(len(dg.keys)))
    values, grads = zip(*[dg.gradient(o) for o in objectives])
    assert_second_order(dg, key, objectives, values, grads, 0.005 if key.endswith(".E") else 0.05)


def test_3d_pose_handles_and_the_morphs_transpose(block3d_gradient):
    """velocities() is points()'s derivative (a turn moves the bone's nodes and the tendon's end in it), and
    Morph3D.pull_back is the transpose of the harmonic extension that moves the other nodes."""
    dg = block3d_gradient
    h = dg.handles
    p = np.array([0.3, -0.2, 0.1, 7.0, 0.0])
    V = h.velocities(p)
    for j in range(len(p)):
        step = np.eye(len(p))[j] * 1e-6
        assert np.allclose((h.points(p + step) - h.points(p - step)) / 2e-6, V[:, :, j], atol=1e-6)
    assert ("path", "flexor", 1) in h.index and ("path", "flexor", 0) not in h.index
    morph = dg.morph
    rng = np.random.default_rng(5)
    moves = np.zeros_like(morph.X0)
    moves[morph.bound] = rng.standard_normal((len(morph.bound), 3))
    inner = -(morph.K_IB @ moves[morph.bound])
    from scipy.sparse.linalg import spsolve
    from skelfem.mesh.morph3d import laplacian
    K = laplacian(morph.X0, morph.cells).tocsc()
    moves[morph.free] = np.column_stack([spsolve(K[morph.free][:, morph.free], inner[:, a]) for a in range(3)])
    g = rng.standard_normal(morph.X0.shape)
    assert np.sum(g * moves) == pytest.approx(np.sum(morph.pull_back(g) * moves), rel=1e-9)


def test_3d_variables_that_do_not_exist_are_named():
    from skelfem.analysis.handles import PoseHandles3D
    from skelfem.design.parse import parse_design
    from skelfem.mesh.geometry import mesh_design
    from mpi4py import MPI
    design = parse_design(BLOCK3D)
    tm = mesh_design(design, MPI.COMM_SELF)
    for keys, message in ((["bones.nope.offset.x"], "no bone 'nope'"), (["bones.bone.outline[0].x"], "not a 3D design"),
                          (["bones.bone.angle.x", "bones.bone.angle.z"], "one turning axis per bone")):
        with pytest.raises(ValueError, match=message):
            PoseHandles3D(design, keys, tm)
