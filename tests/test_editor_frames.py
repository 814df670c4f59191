"""The editor's frames while a handle is dragged: a frame budget, and a certificate on every frame.

The engine alone (no server, no browser), on geometry/finger.toml. A frame budget far
below one Newton step (``frame_budget=1e-6`` s) makes every draft outrun the solver:
each stops after one Newton step and is shown as a "preview". The certificate's
residual is checked against the model's residual read here, its tolerance against the
one a fresh batch solve of the same design (``Session(design).solve()``, what
``skelfem simulate`` runs) is held to, and the release's state against that batch
solve's, node by node.
"""
import copy
import tomllib

import numpy as np
import pytest
from conftest import GEOMETRY

from skelfem.editor.engine import Engine
from skelfem.fem.certificate import certificate
from skelfem.session import Session

RELEASE_RTOL = 1e-8        # the released state against a fresh batch solve, relative to its largest displacement


@pytest.fixture(scope="module")
def design():
    return tomllib.loads((GEOMETRY / "finger.toml").read_text())


def _residual(eng) -> float:
    """|R| at the engine's state, from the model (not from the certificate's code)."""
    model = eng.session.model
    x = model.u.vector.copy()
    b = x.duplicate()
    model.residual(x, b)
    out = b.norm()
    for v in (x, b):
        v.destroy()
    return float(out)


def _batch(d):
    """(dof coordinates, u, the tolerance its Newton stopped at) of a fresh batch solve of design dict d."""
    s = Session(copy.deepcopy(d))
    try:
        assert s.solve().converged
        tol = max(s.solver.atol, s.solver.rtol * s.solver.reference_residual)
        return s.model.V.tabulate_dof_coordinates()[:, :2].copy(), s.model.u.x.array.copy(), tol
    finally:
        s.close()


def _same_state(eng, batch) -> float:
    """max |u - u_batch| / max |u_batch| on the same mesh (the nodes are checked to be the same)."""
    X, u, _ = batch
    model = eng.session.model
    assert np.allclose(model.V.tabulate_dof_coordinates()[:, :2], X, rtol=0, atol=1e-12)
    return float(np.abs(model.u.x.array - u).max() / np.abs(u).max())


def _check(eng, answer) -> dict:
    """The certificate of answer holds: its residual is the model's, "converged" only at or below tolerance."""
    c = answer["certificate"]
    r = _residual(eng)
    assert c["residual"] == pytest.approx(r, rel=1e-6, abs=1e-14)
    # the tolerance the engine keeps between frames of one design is the one computed afresh
    assert c["tolerance"] == pytest.approx(certificate(eng.session.solver, eng.session.design.solver.steps)[1],
                                           rel=1e-12)
    assert c["ratio"] == pytest.approx(c["residual"] / c["tolerance"], rel=1e-12)
    if c["state"] == "converged":
        assert answer["converged"] and not answer["editor"]["draft"] and r <= c["tolerance"]
    else:
        assert c["state"] == "preview" and c["why"]
    return c


@pytest.mark.slow
def test_a_drag_that_outruns_the_solver_is_preview_until_converged_and_the_release_is_the_batch_solve(design):
    eng = Engine(copy.deepcopy(design), "finger.toml", frame_budget=1e-6)
    try:
        first = _check(eng, eng.first)
        assert first["state"] == "converged"
        d = copy.deepcopy(design)
        states = []
        for _ in range(6):                                  # a bone vertex dragged 3 mm in 6 frames
            d["bones"][-1]["outline"][0][0] -= 0.5
            a = eng.solve(d, draft=True)
            assert a["mesh"] is not None and a["editor"]["draft"]
            states.append((_check(eng, a), a["status"]))
        # the solver was outrun: frames stopped at their budget with the residual above tolerance, all "preview"
        outrun = [c for c, status in states if status == "frame_budget" and c["ratio"] > 1]
        assert outrun and all(c["state"] == "preview" for c, _ in states)
        released = eng.solve(d)                             # let go: a new mesh, solved to the end
        c = _check(eng, released)
        assert c["state"] == "converged" and released["editor"]["how"] == "edit (re-meshed)"
        batch = _batch(d)
        assert c["tolerance"] <= batch[2] * (1 + 1e-12)     # the certificate's tolerance is never looser
        assert _same_state(eng, batch) < RELEASE_RTOL
    finally:
        eng.close()


@pytest.mark.slow
def test_a_slider_frame_goes_on_from_its_state_to_the_batch_solve(design):
    eng = Engine(copy.deepcopy(design), "finger.toml", frame_budget=1e-6)
    try:
        d = copy.deepcopy(design)
        d["cables"][0]["contraction"] = float(d["cables"][0].get("contraction", 0.0)) + 3.0
        a = eng.solve(d, draft=True)
        seen = [(_check(eng, a), a)]
        assert a["editor"]["how"] == "set" and a["status"] == "frame_budget" and a["mesh"] is not None
        while seen[-1][1]["status"] == "frame_budget" and len(seen) < 30:   # the page asks again
            a = eng.solve(d, draft=True)
            assert a["editor"]["how"] == "go on"
            seen.append((_check(eng, a), a))
        last, answer = seen[-1]
        assert answer["converged"] and last["state"] == "converged" and len(seen) >= 2
        assert [c["state"] for c, _ in seen[:-1]] == ["preview"] * (len(seen) - 1)
        # a new Newton step each time: the residual falls frame by frame
        ratios = [c["ratio"] for c, _ in seen]
        assert ratios[-1] < ratios[0]
        assert eng.solve(d)["editor"]["how"] == "unchanged"          # the release: nothing left to solve
        assert _same_state(eng, _batch(d)) < RELEASE_RTOL
    finally:
        eng.close()


def test_without_a_budget_every_draft_is_solved_to_the_end(design):
    eng = Engine(copy.deepcopy(design), "finger.toml", frame_budget=None)
    try:
        d = copy.deepcopy(design)
        d["cables"][0]["contraction"] = float(d["cables"][0].get("contraction", 0.0)) + 1.0
        a = eng.solve(d, draft=True)
        c = _check(eng, a)
        assert a["converged"] and c["state"] == "converged" and c["ratio"] <= 1      # the mesh's own nodes
        d["bones"][-1]["outline"][0][0] -= 0.3
        a = eng.solve(d, draft=True)
        c = _check(eng, a)
        assert a["converged"] and c["ratio"] <= 1 and c["state"] == "preview"       # moved nodes: a preview
        assert "moved mesh" in c["why"]
    finally:
        eng.close()


def test_the_solver_thread_runs_openblas_on_one_thread():
    import ctypes

    from skelfem.editor.worker import Worker, loaded_libraries
    libs = [ctypes.CDLL(p) for p in loaded_libraries("blas")]
    libs = [lib for lib in libs if hasattr(lib, "openblas_get_num_threads")]
    if not libs:
        pytest.skip("no OpenBLAS in this process")
    for lib in libs:
        lib.openblas_set_num_threads(2)                 # as a two-core host starts it
    w = Worker(engine=None)
    try:
        counts = w.submit("t", lambda e: [lib.openblas_get_num_threads() for lib in libs]).result(30)
    finally:
        w.close()
    assert counts == [1] * len(libs)


@pytest.mark.slow
def test_frames_of_one_design_stop_being_budgeted_past_the_solvers_iteration_limit(design):
    eng = Engine(copy.deepcopy(design), "finger.toml", frame_budget=1e-6)
    try:
        eng.session.solver.max_iterations = 2            # a Newton that needs more steps than its limit
        d = copy.deepcopy(design)
        d["cables"][0]["contraction"] = float(d["cables"][0].get("contraction", 0.0)) + 3.0
        answers = [eng.solve(d, draft=True) for _ in range(4)]
        statuses = [a["status"] for a in answers]
        # the predictor's frame (no Newton step: the predictor spent the time) and two one-step frames reach
        # the limit; the fourth is solved to the end (whatever it ends with), and the page, which asks again
        # only after a frame_budget answer, stops asking
        assert [a["newton_iterations"] for a in answers[:3]] == [0, 1, 1]
        assert statuses[:3] == ["frame_budget"] * 3 and statuses[3] != "frame_budget"
    finally:
        eng.close()


@pytest.mark.parametrize("dim", [2, 3])
def test_the_cell_maps_are_inverted_without_lapack_as_lapack_does(dim):
    from skelfem.io.xdmf import small_inverses
    rng = np.random.default_rng(dim)
    A = rng.normal(size=(500, dim, dim)) + 3 * np.eye(dim)
    assert np.allclose(small_inverses(A), np.linalg.inv(A), rtol=1e-12, atol=1e-12)
    flat = np.zeros((1, dim, dim))                           # a degenerate cell: no error, no finite inverse
    assert not np.isfinite(small_inverses(flat)).all()


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(p, q) for p, q in zip(a, b))
    if isinstance(a, np.ndarray):
        return np.array_equal(a, b)
    return a == b


@pytest.mark.slow
def test_the_certificate_leaves_a_frictional_state_and_its_history_as_they_were():
    s = Session(str(GEOMETRY / "gripper.toml"))            # an object held by friction
    try:
        assert s.solve().converged and s.model.path_dependent
        u, history, factor = s.model.u.x.array.copy(), copy.deepcopy(s.model.history()), s.model.factor
        residual, tol = certificate(s.solver, s.design.solver.steps)
        assert 0 <= residual <= tol
        assert np.array_equal(s.model.u.x.array, u) and s.model.factor == factor
        assert _same(s.model.history(), history)          # friction's anchors, slips and trial states
    finally:
        s.close()


@pytest.mark.slow
def test_the_page_asks_again_after_a_frame_out_of_time_until_converged(tmp_path):
    """In Chromium: every slider frame outruns the solver (a budget of 1 us); the page asks again for the
    same design (answers "go on" still out of time), shows "preview" meanwhile and "converged" at the end."""
    import shutil

    from skelfem.editor.browser import BrowserMissing, Page, chrome
    from skelfem.editor.server import Editor
    shutil.copy(GEOMETRY / "finger.toml", tmp_path / "finger.toml")
    ed = Editor(tmp_path / "finger.toml", port=0).start()
    driver = None
    try:
        try:
            driver = chrome()
        except BrowserMissing as exc:
            pytest.fail(f"this test needs Debian's Chromium: {exc}", pytrace=False)
        page = Page(driver, ed.url)
        ed.engine.frame_budget = 1e-6
        css = "#sliders input[data-cable=flexor]"
        x, y = page.center(css)
        width = page.js("document.querySelector(arguments[0]).getBoundingClientRect().width", css)
        page.drag((x, y), [(x - k * 0.03 * width, y) for k in range(1, 5)], hold=True)     # held: drafts only
        page.idle()
        server = page.js("S.server")
        assert any(e["how"] == "go on" and e["status"] == "frame_budget" for e in server)   # asked again
        assert server[-1]["status"] == "converged"                  # ... until converged, still held
        certs = page.js("S.certificates")
        assert "preview" in [c["state"] for c in certs] and certs[-1]["state"] == "converged"
        assert all(c["ratio"] <= 1 for c in certs if c["state"] == "converged")
        assert page.js("document.getElementById('certificate').dataset.state") == "converged"
        assert not page.console_errors()
    finally:
        if driver is not None:
            driver.quit()
        ed.stop()


@pytest.mark.slow
def test_the_pages_release_is_framed_and_goes_on_to_the_batch_solve(design):
    """The page's release (framed=True): the new mesh, then Newton within the frame budget, asked again until
    converged; preview until then, and the state is then a fresh batch solve's within 1e-8."""
    eng = Engine(copy.deepcopy(design), "finger.toml", frame_budget=1e-6)
    try:
        d = copy.deepcopy(design)
        for _ in range(3):
            d["bones"][-1]["outline"][0][0] -= 0.5
            eng.solve(d, draft=True)
        a = eng.solve(d, framed=True)
        # the new mesh took the frame's time: the first frame is the state carried over onto it
        assert a["editor"]["how"] == "edit (re-meshed)" and a["status"] == "frame_budget"
        assert a["newton_iterations"] == 0 and a["mesh"] is not None
        seen = [_check(eng, a)]
        while a["status"] == "frame_budget" and len(seen) < 40:       # the page asks again
            a = eng.solve(d, framed=True)
            assert a["editor"]["how"] == "go on"
            seen.append(_check(eng, a))
        assert a["converged"] and seen[-1]["state"] == "converged" and len(seen) >= 2
        assert all(c["state"] == "preview" for c in seen[:-1])
        assert _same_state(eng, _batch(d)) < RELEASE_RTOL
    finally:
        eng.close()


def test_a_frame_leaves_out_the_mesh_the_client_holds_and_the_fields_it_does_not_draw(design):
    eng = Engine(copy.deepcopy(design), "finger.toml", frame_budget=None)
    try:
        whole = eng.first["mesh"]
        key = whole["topology"]
        assert {"cells", "regions", "x", "y", "fields", "region_names"} <= whole.keys()
        d = copy.deepcopy(design)
        d["cables"][0]["contraction"] = float(d["cables"][0].get("contraction", 0.0)) + 0.5
        a = eng.solve(d, draft=True, have=key, fields=False)["mesh"]
        assert a["topology"] == key and "cells" not in a and "x" not in a and "fields" not in a
        assert len(a["y"]) == len(whole["y"]) and a["cables"] and a["markers"]
        d["bones"][-1]["outline"][0][0] -= 0.3                     # moved nodes: the same cells
        a = eng.solve(d, draft=True, have=key, fields=False)["mesh"]
        assert a["topology"] == key and "cells" not in a
        b = eng.solve(d, have=key, fields=False)["mesh"]          # the release: a new mesh, sent whole
        assert b["topology"] != key and len(b["cells"]) > 0 and "fields" not in b
        c = eng.solve(d, have=b["topology"], fields=True)         # unchanged, but the fields asked for now
        assert c["editor"]["how"] == "unchanged" and "fields" in c["mesh"] and "cells" not in c["mesh"]
        assert "cells" in eng.solve(d)["mesh"]                    # a client holding nothing gets it whole
    finally:
        eng.close()


def test_the_solver_thread_collects_the_garbage_between_requests_not_in_them():
    import gc
    import time

    from skelfem.editor.worker import IDLE, Worker
    w = Worker(engine=None)
    try:
        assert w.submit("t", lambda e: gc.get_freeze_count()).result(30) > 0     # frozen when it started
        assert w.tidied == 0                                    # nothing tidied at once
        t_end = time.monotonic() + IDLE + 30.0                  # a full collection takes long on a busy host
        while not (w.tidied and not w.tidying) and time.monotonic() < t_end:
            time.sleep(0.05)
        assert w.tidied == 1 and not w.tidying                  # once after a quiet spell, not again
        time.sleep(3 * IDLE)
        assert w.tidied == 1
        assert w.submit("t", lambda e: 42).result(30) == 42
    finally:
        w.close()
    assert gc.get_freeze_count() == 0                           # the worker unfreezes all when it ends


def test_a_2d_draft_keeps_the_cables_and_markers_in_their_cells_and_an_exact_edit_builds_them_anew(design):
    """A draft on moved nodes (a bone vertex dragged) is a preview: the cables and markers keep the cells
    their points were found in (terms.base.moved_nodes_only), half of a frame's time not spent; the same
    move as an edit that is not a preview (a design gradient's moved mesh) builds them anew."""
    eng = Engine(copy.deepcopy(design), "finger.toml", frame_budget=None)

    def kept() -> list:
        return [t for t in eng.session.model.terms if t.section in ("cables", "markers")]
    try:
        before = kept()
        assert len(before) == 6                                   # five cables, the markers
        d = copy.deepcopy(design)
        d["bones"][-1]["outline"][0][0] -= 0.3
        a = eng.solve(d, draft=True)
        assert a["editor"]["how"] == "edit (moved nodes)" and a["certificate"]["state"] == "preview"
        assert all(p is q for p, q in zip(kept(), before))
        d["bones"][-1]["outline"][0][0] -= 0.3
        assert eng.session.edit(copy.deepcopy(d), morph=True) == "moved nodes"    # not a preview
        assert not any(p is q for p, q in zip(kept(), before))
    finally:
        eng.close()


def test_the_tolerance_kept_between_frames_follows_every_change_of_the_design(design):
    """The certificate's tolerance (|R| at rest) is computed once per design and kept for its frames; a live
    change, a cable sketched anew on the same mesh (the model follows in place) and moved nodes each get
    their own, the one a fresh computation gives."""
    eng = Engine(copy.deepcopy(design), "finger.toml", frame_budget=1e-6)
    try:
        d = copy.deepcopy(design)
        tolerances = [_check(eng, eng.first)["tolerance"]]
        d["cables"][0]["contraction"] = float(d["cables"][0].get("contraction", 0.0)) + 2.0
        for _ in range(3):                            # a live change, then its frames go on
            tolerances.append(_check(eng, eng.solve(d, draft=True))["tolerance"])
        d["cables"][0]["path"] = [[x + 0.5, y] for x, y in d["cables"][0]["path"]]
        a = eng.solve(d)                              # the same mesh, the cable built anew
        assert a["editor"]["how"] == "edit (same mesh)"
        tolerances.append(_check(eng, a)["tolerance"])
        d["bones"][-1]["outline"][0][0] -= 0.5
        tolerances.append(_check(eng, eng.solve(d, draft=True))["tolerance"])      # moved nodes
        assert len(set(tolerances)) >= 3            # each change above moves the residual at rest
    finally:
        eng.close()
