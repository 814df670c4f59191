"""Keeping the mesh across edits: moving its nodes with the outlines (drafts) or reusing it as it is."""
import copy
import tomllib

import numpy as np
import pytest

from skelfem import Session
from skelfem.design import parse_design
from skelfem.morph import Morph, laplacian, shape_ratio

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
    import skelfem.model
    raw = _raw()
    d = copy.deepcopy(raw)
    d["bones"][0]["outline"][0][0] += 0.5
    with Session(raw) as s:
        before = s.solve()
        x0 = s.model.mesh.geometry.x.copy()

        def fail(*a, **k):
            raise RuntimeError("boom")
        monkeypatch.setattr(skelfem.model.Model, "__init__", fail)
        with pytest.raises(RuntimeError):
            s.edit(d, morph=True)
        monkeypatch.undo()
        assert np.array_equal(s.model.mesh.geometry.x, x0) and s.design.raw == raw
        again = s.solve()
        assert again.converged and again.newton_iterations <= 1
        assert np.allclose(again.markers["tip"]["position"], before.markers["tip"]["position"], atol=1e-8)
