"""3D editing: a bone's pose in the design format, the mesh that follows it while it is dragged, and the
release that equals a fresh batch solve.

geometry/finger3d.toml at mesh.size 6 (about 1.5k DOFs: cheap); the editor's engine alone (no server, no
browser: tests/test_editor_browser.py drives the page).
"""
import copy
import tomllib

import numpy as np
import pytest
from conftest import GEOMETRY

from skelfem.design.parse import parse_design
from skelfem.design.pose import affine, relative, rotation
from skelfem.design.spec import DesignError

RELEASE_RTOL = 1e-8        # the released state against a fresh batch solve, relative to its largest displacement
SIZE = 6.0


@pytest.fixture(scope="module")
def design():
    d = tomllib.loads((GEOMETRY / "finger3d.toml").read_text())
    d["mesh"]["size"] = SIZE
    return d


def posed(design, move, angle=0.0, axis=(0, 0, 1), centre=(10.0, 82.0, 10.0), bone=2):
    d = copy.deepcopy(design)
    d["bones"][bone]["move"] = [float(v) for v in move]
    d["bones"][bone]["rotate"] = {"angle": float(angle), "axis": [float(v) for v in axis],
                                  "centre": [float(v) for v in centre]}
    return d


# -- the format --------------------------------------------------------------------------------------------
def test_rotation_is_rodrigues_and_the_relative_pose_composes():
    R = rotation([0, 0, 1], 90.0)
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0])
    a = {"angle": 30.0, "axis": np.array([1.0, 2.0, 2.0]) / 3, "centre": np.array([1.0, 2.0, 3.0]),
         "move": np.array([0.5, -1.0, 2.0])}
    b = {"angle": -12.0, "axis": np.array([0.0, 1.0, 0.0]), "centre": np.array([4.0, 0.0, 1.0]),
         "move": np.array([0.0, 0.3, 0.0])}
    X = np.random.default_rng(0).normal(size=(5, 3))
    Ra, ba = affine(a)
    Rb, bb = affine(b)
    R, t = relative(a, b)
    assert np.allclose((X @ Ra.T + ba) @ R.T + t, X @ Rb.T + bb, atol=1e-12)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.allclose(Ra @ ((X[0] - a["centre"])) + a["centre"] + a["move"], X[0] @ Ra.T + ba)


def test_a_posed_bone_is_placed_and_checked_as_placed(design):
    d = parse_design(posed(design, [0.4, 0.2, 0.1], 4.0), "f.toml")
    pose = d.bones[2].pose
    assert pose["angle"] == 4.0 and np.allclose(pose["move"], [0.4, 0.2, 0.1])
    assert all(next(iter(p.values()))["pose"] is pose for p in d.bones[2].solids)
    assert parse_design(copy.deepcopy(design), "f.toml").bones[2].pose is None
    with pytest.raises(DesignError, match=r"bones.distal.solids: a bone must lie strictly inside the body"):
        parse_design(posed(design, [0.0, 8.0, 0.0]), "f.toml")


@pytest.mark.parametrize("rotate, match", [
    ({"angle": 5.0, "axis": [0, 0, 0], "centre": [10, 82, 10]}, r"bones.distal.rotate.axis: must not be zero"),
    ({"angle": 400.0, "axis": [0, 0, 1], "centre": [10, 82, 10]}, r"bones.distal.rotate.angle: must lie within"),
    ({"angle": 5.0, "axis": [0, 0, 1]}, r"bones.distal.rotate.centre: missing"),
    ({"angle": 5.0, "axis": [0, 0, 1], "centre": [10, 82, 10], "about": 1}, r"bones.distal.rotate.about: unknown"),
])
def test_a_bad_rotate_is_one_error_naming_its_key(design, rotate, match):
    d = copy.deepcopy(design)
    d["bones"][2]["rotate"] = rotate
    with pytest.raises(DesignError, match=match):
        parse_design(d, "f.toml")


# -- the mesh that follows ---------------------------------------------------------------------------------
def test_the_laplacian_of_an_affine_field_vanishes_inside():
    from skelfem.mesh.morph3d import laplacian, outer_nodes
    g = np.linspace(0.0, 1.0, 4)
    X = np.array([[x, y, z] for x in g for y in g for z in g])
    idx = np.arange(64).reshape(4, 4, 4)
    cells = []
    for i in range(3):
        for j in range(3):
            for k in range(3):
                c = [idx[i + a, j + b, k + e] for a in (0, 1) for b in (0, 1) for e in (0, 1)]
                for t in ((0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)):
                    cells.append([c[m] for m in t])
    cells = np.array(cells)
    K = laplacian(X, cells)
    inner = np.setdiff1d(np.arange(64), outer_nodes(cells))
    assert len(inner) == 8 and len(outer_nodes(cells)) == 56
    f = X @ [0.3, -1.2, 2.0] + 0.7
    assert np.abs(K @ f)[inner].max() < 1e-12
    assert np.abs(K.sum(axis=1)).max() < 1e-12


@pytest.fixture(scope="module")
def engine(design):
    from skelfem.editor.engine import Engine
    eng = Engine(copy.deepcopy(design), "finger3d.toml", frame_budget=1e-6)
    yield eng
    eng.close()


def test_a_dragged_bone_moves_the_nodes_rigidly_and_frames_are_previews(engine, design):
    first = engine.first
    assert first["converged"] and first["certificate"]["state"] == "converged"
    X0 = engine.session.model.mesh.geometry.x.copy()
    for k in range(1, 4):
        a = engine.solve(posed(design, [0.1 * k, 0.05 * k, 0.0], 0.8 * k), draft=True)
        assert a["editor"]["how"] == "edit (moved nodes)" and a["mesh"] is not None
        assert a["certificate"]["state"] == "preview" and a["certificate"]["why"]
        assert not a["converged"]
    x = engine.session.model.mesh.geometry.x
    assert x.shape == X0.shape and np.abs(x - X0).max() > 0.05
    # the distal bone's nodes moved rigidly by the relative pose
    d = engine.session.design
    morph = engine.session._morph
    nodes = morph.bone_nodes["distal"]
    R, t = relative(None, d.bones[2].pose)
    assert np.allclose(x[nodes], X0[nodes] @ R.T + t, atol=1e-10)
    assert np.allclose(x[morph.bone_nodes["proximal"]], X0[morph.bone_nodes["proximal"]], atol=0)


def test_the_release_equals_a_fresh_batch_solve(engine, design):
    from skelfem.session import Session
    d = posed(design, [0.3, 0.15, 0.0], 2.4)
    a = engine.solve(copy.deepcopy(d), draft=True)
    assert a["certificate"]["state"] == "preview"
    done = engine.solve(copy.deepcopy(d))
    assert done["converged"] and done["editor"]["how"] == "edit (re-meshed)"
    c = done["certificate"]
    assert c["state"] == "converged" and c["residual"] <= c["tolerance"]
    s = Session(parse_design(copy.deepcopy(d), "finger3d.toml"))
    try:
        assert s.solve().converged
        model = engine.session.model
        assert np.array_equal(model.V.tabulate_dof_coordinates(), s.model.V.tabulate_dof_coordinates())
        u = s.model.u.x.array
        assert np.abs(model.u.x.array - u).max() / np.abs(u).max() < RELEASE_RTOL
    finally:
        s.close()


def test_a_marker_or_cable_edit_keeps_the_3d_mesh(engine, design):
    d = posed(design, [0.3, 0.15, 0.0], 2.4)
    engine.solve(copy.deepcopy(d))
    d["markers"]["tip"] = [10.0, 98.0, 10.0]
    a = engine.solve(copy.deepcopy(d))
    assert a["converged"] and a["editor"]["how"] == "edit (same mesh)"
    assert a["mesh"]["markers"]["tip"] is not None


def test_a_preview_keeps_cables_and_markers_and_an_exact_edit_builds_them_anew(design):
    """The editor's 3D drafts (preview=True) keep the cables' and markers' points in their cells on the moved
    nodes; any other edit on moved nodes (a design gradient's) builds them anew, exact."""
    from skelfem.session import Session
    from skelfem.terms.base import PREVIEW, bone_poses_only

    class Ctx:
        class design:
            dim = 3
    assert bone_poses_only(Ctx, {PREVIEW, "bones.distal.move", "bones.distal.rotate.angle"})
    assert not bone_poses_only(Ctx, {"bones.distal.move"})                     # not a preview
    assert not bone_poses_only(Ctx, {PREVIEW, "bones.distal.move", "cables.flexor.path"})
    assert not bone_poses_only(Ctx, {PREVIEW})
    s = Session(parse_design(copy.deepcopy(design), "finger3d.toml"))
    try:
        assert s.solve().converged
        cable, markers = s.model.terms_in("cables")[0], s.model.terms_in("markers")[0]
        assert s.edit(parse_design(posed(design, [0.1, 0.0, 0.0], 1.0), "f.toml"), morph=True,
                      preview=True) == "moved nodes"
        assert s.model.terms_in("cables")[0] is cable and s.model.terms_in("markers")[0] is markers
        assert s.edit(parse_design(posed(design, [0.2, 0.0, 0.0], 1.5), "f.toml"), morph=True) == "moved nodes"
        assert s.model.terms_in("cables")[0] is not cable and s.model.terms_in("markers")[0] is not markers
        assert s.solve().converged
    finally:
        s.close()


def test_a_pose_draft_skips_the_solids_check_and_a_bone_out_of_the_body_is_still_refused(design, monkeypatch):
    """A draft that only moves or turns bones is checked by the moved mesh (every tetrahedron keeps its
    orientation), not by OpenCASCADE; the release checks exactly; a bone dragged out of the body turns the
    tetrahedra over, and the draft is then checked exactly and refused at its key, the last answer kept."""
    from skelfem.design import solids
    from skelfem.editor.engine import EditError, Engine
    calls = []
    check = solids.check
    monkeypatch.setattr(solids, "check", lambda *a, **k: calls.append(1) or check(*a, **k))
    eng = Engine(copy.deepcopy(design), "finger3d.toml", frame_budget=1e-6)
    try:
        n = len(calls)
        for k in range(1, 3):
            a = eng.solve(posed(design, [0.1 * k, 0.0, 0.0], 0.5 * k), draft=True)
            assert a["editor"]["how"] == "edit (moved nodes)"
        assert len(calls) == n                                     # no OpenCASCADE check while dragged
        done = eng.solve(posed(design, [0.2, 0.0, 0.0], 1.0))
        assert done["converged"] and done["editor"]["how"] == "edit (re-meshed)" and len(calls) == n + 1
        with pytest.raises(EditError) as err:
            eng.solve(posed(design, [0.0, 8.0, 0.0]), draft=True)
        assert err.value.key == "bones.distal.solids" and "strictly inside the body" in err.value.message
        assert len(calls) == n + 2 and eng.session.design.bones[2].pose["move"][0] == 0.2
        with pytest.raises(EditError):                             # asked again: still refused
            eng.solve(posed(design, [0.0, 8.0, 0.0]), draft=True)
    finally:
        eng.close()


def test_a_new_pose_whose_step_would_outlast_the_frame_is_the_moved_state(design, monkeypatch):
    """Where a modified Newton step takes longer than frames3d.STEP_SECONDS (0 here: every step), a new pose's
    frame takes no step (the moved state, a preview); the same design asked again (the hand at rest) does."""
    from skelfem.editor import frames3d
    from skelfem.editor.engine import Engine
    monkeypatch.setattr(frames3d, "STEP_SECONDS", 0.0)
    eng = Engine(copy.deepcopy(design), "finger3d.toml", frame_budget=1e-6)
    try:
        a = eng.solve(posed(design, [0.1, 0.0, 0.0], 0.5), draft=True)       # the steps' time not known yet
        assert a["frame"]["steps"] >= 1 and eng.frames3d.step_seconds > 0
        b = eng.solve(posed(design, [0.2, 0.0, 0.0], 1.0), draft=True)
        assert b["editor"]["how"] == "edit (moved nodes)" and b["frame"]["steps"] == 0
        assert "moved state" in b["frame"]["kind"] and b["certificate"]["state"] == "preview"
        c = eng.solve(posed(design, [0.2, 0.0, 0.0], 1.0), draft=True)
        assert c["editor"]["how"] == "go on" and c["newton_iterations"] >= 1
        assert c["certificate"]["residual"] < b["certificate"]["residual"]
    finally:
        eng.close()
