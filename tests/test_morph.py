"""Keeping the mesh across edits: moving its nodes with the outlines (drafts) or reusing it as it is."""
import copy
import tomllib

import numpy as np
import pytest

from skelfem import Session
from skelfem.design import parse_design
from skelfem.mesh.morph import Morph, laplacian, shape_ratio

from conftest import GEOMETRY

FINGER = GEOMETRY / "finger.toml"


def _raw(path=FINGER) -> dict:
    with open(path, "rb") as f:
        return tomllib.load(f)


def _moved(raw: dict, f) -> dict:
    """raw with f applied to every polygon vertex of the body, its holes and the bones."""
    d = copy.deepcopy(raw)
    d["body"]["outline"] = [f(np.asarray(p, float)).tolist() for p in d["body"]["outline"]]
    d["body"]["holes"] = [[f(np.asarray(p, float)).tolist() for p in h] for h in d["body"].get("holes", [])]
    for b in d.get("bones", []):
        b["outline"] = [f(np.asarray(p, float)).tolist() for p in b["outline"]]
    return d


def test_laplacian_rows_sum_to_zero_and_is_symmetric():
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.2]])
    cells = np.array([[0, 1, 2], [1, 3, 2]])
    K = laplacian(x, cells).toarray()
    assert np.allclose(K.sum(axis=1), 0.0) and np.allclose(K, K.T)
    assert np.all(np.linalg.eigvalsh(K)[1:] > 0)            # only constants in the kernel
    area, q = shape_ratio(np.array([[0, 0], [1, 0], [0.5, np.sqrt(3) / 2]]), np.array([[0, 1, 2]]))
    assert area[0] > 0 and q[0] == pytest.approx(1.0)


def test_an_affine_move_of_every_polygon_moves_every_node_affinely():
    """Harmonic extension reproduces linear fields exactly: all nodes follow an affine map."""
    shapes = {k: v for k, v in _raw().items() if k in ("format", "name", "dim", "thickness", "mesh",
                                                      "materials", "body", "bones", "pins")}
    with Session(shapes) as s:
        m = Morph(s.model.tm, s.design)
        A, c = np.array([[1.02, 0.01], [-0.015, 0.99]]), np.array([0.3, -0.2])
        moved = parse_design(_moved(shapes, lambda p: A @ p + c), "moved.toml")
        x = m.moved(moved)
        assert x is not None
        assert np.allclose(x, m.X0 @ A.T + c, atol=1e-9)
        assert len(m.bound) > 0 and len(m.free) > 0


def test_a_dragged_bone_vertex_moves_nodes_and_agrees_with_a_fresh_mesh():
    raw = _raw()
    d = copy.deepcopy(raw)
    d["bones"][0]["outline"][0][0] += 0.5
    with Session(raw) as s:
        s.solve()
        cells = s.model.mesh.topology.index_map(2).size_local
        assert s.edit(d, morph=True) == "moved nodes"
        assert s.model.mesh.topology.index_map(2).size_local == cells           # no new mesh
        r = s.solve()
        assert r.converged and r.newton_iterations <= 4
        tip = np.asarray(r.markers["tip"]["position"])
        assert s.edit(d) == "re-meshed"                                          # the release re-meshes
        fresh = s.solve()
    rest = np.asarray(fresh.markers["tip"]["reference"])
    motion = np.linalg.norm(np.asarray(fresh.markers["tip"]["position"]) - rest)
    # a moved mesh differs from a new one by the discretisation error only
    assert np.linalg.norm(tip - fresh.markers["tip"]["position"]) < 0.02 * motion


def test_a_poor_moved_mesh_is_re_meshed_instead():
    raw = _raw()
    d = copy.deepcopy(raw)
    bone = np.asarray(d["bones"][0]["outline"], float)
    centre = bone.mean(axis=0)
    d["bones"][0]["outline"] = (centre + 0.5 * (bone - centre)).tolist()     # the bone shrinks to half
    with Session(raw) as s:
        s.solve()
        assert s.edit(d, morph=True) == "re-meshed"
        assert s.solve().converged


def test_an_edit_that_keeps_the_outlines_keeps_the_mesh_and_gives_the_fresh_answer():
    raw = _raw()
    d = copy.deepcopy(raw)
    d["markers"]["tip"][0] -= 1.0
    d["cables"][0]["path"][-1][1] -= 2.0
    with Session(raw) as s:
        s.solve()
        x0 = s.model.mesh.geometry.x.copy()
        assert s.edit(d) == "same mesh"
        assert np.array_equal(s.model.mesh.geometry.x, x0)
        kept = s.solve()
    with Session(d) as fresh:
        new = fresh.solve()
    assert kept.converged and kept.dofs == new.dofs
    assert np.allclose(kept.markers["tip"]["position"], new.markers["tip"]["position"], atol=1e-6)
    a, b = kept.cables[raw["cables"][0]["name"]], new.cables[raw["cables"][0]["name"]]
    assert a["tension"] == pytest.approx(b["tension"], rel=1e-6)


def test_a_failed_rebuild_on_moved_nodes_leaves_the_session_as_it_was(monkeypatch):
    import skelfem.fem.model
    import skelfem.terms.cables
    raw = _raw()
    d = copy.deepcopy(raw)
    d["bones"][0]["outline"][0][0] += 0.5
    with Session(raw) as s:
        before = s.solve()
        x0 = s.model.mesh.geometry.x.copy()

        def fail(*a, **k):
            raise RuntimeError("boom")
        monkeypatch.setattr(skelfem.fem.model.Model, "__init__", fail)       # a model built anew fails, ...
        monkeypatch.setattr(skelfem.terms.cables.CableTerm, "__init__", fail)   # ... and so does following
        with pytest.raises(RuntimeError):
            s.edit(d, morph=True)
        monkeypatch.undo()
        assert np.array_equal(s.model.mesh.geometry.x, x0) and s.design.raw == raw
        again = s.solve()
        assert again.converged and again.newton_iterations <= 1
        assert np.allclose(again.markers["tip"]["position"], before.markers["tip"]["position"], atol=1e-8)


def _rich(raw: dict) -> dict:
    """finger.toml with every kind of ingredient: spring pin, point load, ground, gravity, traction,
    a rigid bone and a tendon bend anchored in silicone."""
    d = copy.deepcopy(raw)
    d["pins"].append({"name": "side", "region": [[19.99, 10], [21, 20]], "kind": "spring", "stiffness": 5.0})
    d["loads"] = [{"name": "push", "at": [10, 99], "force": [0.3, -0.2]}]
    d["grounds"] = [{"name": "floor", "point": [-6, 0], "normal": [1, 0], "stiffness": 5.0}]
    d["gravity"] = {"acceleration": [0.0, -9.81]}
    d["tractions"] = [{"name": "pad", "region": [[-1, 50], [0.01, 60]], "traction": [0.002, 0.0]}]
    d["bones"][1]["rigid"] = True
    return d


def _drag(raw: dict, bone: int, by) -> dict:
    d = copy.deepcopy(raw)
    d["bones"][bone]["outline"][0] = (np.asarray(d["bones"][bone]["outline"][0], float) + by).tolist()
    return d


def _same_answers(a, b, atol=1e-6):
    assert a.converged and b.converged and a.dofs == b.dofs
    for name, m in a.markers.items():
        assert np.allclose(m["position"], b.markers[name]["position"], atol=atol), name
    for name, c in a.cables.items():
        assert c["tension"] == pytest.approx(b.cables[name]["tension"], rel=1e-6, abs=1e-9), name
    for name, p in a.pins.items():
        assert np.allclose(p["reaction"], b.pins[name]["reaction"], rtol=1e-5, atol=1e-7), name


@pytest.mark.parametrize("rich", [False, True], ids=["finger", "every-ingredient"])
def test_a_draft_follows_in_place_and_equals_a_model_built_anew_on_the_same_nodes(rich, monkeypatch):
    """Model.refresh keeps the compiled forms, the matrix and the solver, and gives the answer a model built
    anew on the moved nodes gives, over a drag (pattern growth included) and a live change within it."""
    import skelfem.fem.model
    raw = _rich(_raw()) if rich else _raw()
    steps = [_drag(raw, 2, [0.1 * k, 0.05 * k]) for k in range(1, 6)]
    steps.append(_drag(raw, 0, [-0.3, 0.2]))                        # a bone, then another
    lifted = copy.deepcopy(steps[-1])
    lifted["body"]["outline"][1][1] = 0.05                          # the base's nodes leave the pin's box
    lifted["cables"][0]["path"][0][1] = 0.05                        # (the tendon's start stays inside)
    steps.append(lifted)
    live = copy.deepcopy(steps[-1])
    live["cables"][0]["contraction"] = 6.5                           # live changes in the same edit: of a
    live["materials"]["ecoflex"]["E"] = 0.12                         # term built anew and of a kept one
    steps.append(live)
    with Session(raw) as s:
        s.solve()
        model, form = s.model, s.model.jacobian_form
        followed = []
        for d in steps:
            assert s.edit(d, morph=True) == "moved nodes"
            followed.append(s.solve())
            if rich and d is lifted:        # the base pin's facets changed and the pins include a spring
                assert s.model is not model                                # pin (a UFL energy): built anew
                model, form = s.model, s.model.jacobian_form
            assert s.model is model and s.model.jacobian_form is form       # nothing rebuilt or recompiled
            assert s.model._within_pattern([b for t in s.model.terms for b in t.pattern()])   # every block in K
        assert s.model.term("cables", raw["cables"][0]["name"]).cable.contraction == 6.5
    monkeypatch.setattr(skelfem.fem.model.Model, "refresh", lambda self, design, changed: None)
    with Session(raw) as s:
        s.solve()
        for d, kept in zip(steps, followed):
            model = s.model
            assert s.edit(d, morph=True) == "moved nodes"
            assert s.model is not model                                    # built anew on the same nodes
            _same_answers(kept, s.solve())


def test_a_draft_that_changes_a_compiled_ingredient_builds_the_model_anew():
    """A ground's normal is in the compiled energy (not a live parameter): the model cannot follow."""
    raw = _rich(_raw())
    d = _drag(raw, 2, [0.3, 0.0])
    d["grounds"][0]["normal"] = [1.0, 0.1]
    with Session(raw) as s:
        s.solve()
        model = s.model
        assert s.edit(d, morph=True) == "moved nodes"
        assert s.model is not model
        moved = s.solve()
        x = s.model.mesh.geometry.x.copy()
    with Session(raw) as fresh:                                         # the same nodes, a new model
        fresh.solve()
        fresh.edit(d, morph=True)
        assert np.array_equal(fresh.model.mesh.geometry.x, x)
        _same_answers(moved, fresh.solve())


def test_a_drag_back_and_forth_grows_the_matrix_pattern_once_and_then_keeps_it(monkeypatch):
    """A via point moving into another cell needs new entries: the new matrix keeps the old ones too
    (the union of the patterns so far), so moving among places seen before makes no further matrices."""
    import skelfem.fem.newton
    made = []
    new_matrix = skelfem.fem.newton.NewtonSolver.new_matrix
    monkeypatch.setattr(skelfem.fem.newton.NewtonSolver, "new_matrix", lambda self: (made.append(1), new_matrix(self)))
    raw = _raw()
    places = [_drag(raw, 2, [0.3 * k, 0.15 * k]) for k in (1, -1, 2)]
    with Session(raw) as s:
        s.solve()
        for d in places * 4:
            assert s.edit(d, morph=True) == "moved nodes" and s.solve().converged
            assert s.model._within_pattern([b for t in s.model.terms for b in t.pattern()])
    assert 1 <= len(made) <= 3
