"""3D editing end to end in headless Chromium: a bone moved and turned with its handles, markers, cable
sketch points and pins dragged, undo, save and a fresh simulate of the saved file.

One editor on a copy of geometry/finger3d.toml at mesh.size 4.5 (about 3k DOFs) and one browser serve the
module; the tests run in order. Screenshots go to a temporary folder, or to $SKELFEM_FIGURES (the guide's
are made with ``SKELFEM_FIGURES=studies/figures``).
"""
import json
import math
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from conftest import GEOMETRY, MPI_ENV, ROOT

from skelfem.editor.browser import BrowserMissing, Page, chrome

pytestmark = pytest.mark.slow
SIZE = 4.5
CONVERGED = "S.answer && S.answer.certificate.state === 'converged' && !S.inflight && !S.queued"


@pytest.fixture(scope="module")
def figures(tmp_path_factory):
    out = os.environ.get("SKELFEM_FIGURES")
    return Path(out) if out else tmp_path_factory.mktemp("figures")


@pytest.fixture(scope="module")
def editor(tmp_path_factory):
    from skelfem.editor.server import Editor
    folder = tmp_path_factory.mktemp("edit3d")
    text = (GEOMETRY / "finger3d.toml").read_text().replace("size = 3.0", f"size = {SIZE}")
    assert f"size = {SIZE}" in text
    (folder / "finger3d.toml").write_text(text)
    ed = Editor(folder / "finger3d.toml", port=0).start()
    yield ed
    ed.stop()


@pytest.fixture(scope="module")
def page(editor):
    try:
        driver = chrome(1100, 760)
    except BrowserMissing as exc:
        pytest.fail(f"the browser tests need Debian's Chromium: {exc}", pytrace=False)
    try:
        yield Page(driver, editor.url)
    finally:
        driver.quit()


def _line(a, b, n=10):
    return [(a[0] + (b[0] - a[0]) * k / n, a[1] + (b[1] - a[1]) * k / n) for k in range(1, n + 1)]


def test_a_3d_design_opens_editable_with_handles(page):
    assert not page.js("S.readonly") and page.js("S.dim") == 3
    kinds = set(page.js("S.handles3d.map((h) => h.kind)"))
    assert {"bone-move", "bone-axis", "bone-turn", "point", "pin"} <= kinds
    assert page.js("document.querySelectorAll('#sliders input[type=range]').length") == 5
    assert page.js("S.answer.certificate.state") == "converged"
    assert page.js("document.getElementById('banner').hidden")          # no read-only note any more
    assert page.js("!!GL3.gl && !GL3.failed && GL3.groups.length >= 2")    # the surfaces drawn with WebGL
    assert not page.console_errors()


def test_a_bone_dragged_moves_and_the_release_is_converged(page, figures, picture):
    start = page.handle3d("bone-move", name="distal")
    page.drag(start, _line(start, (start[0] + 5, start[1] - 3)))       # about 1 mm: the bone has 2 mm to the sides
    page.wait(CONVERGED, 120)
    bone = page.js("S.design.bones[2]")
    assert np.linalg.norm(bone["move"]) > 0.3 and bone["rotate"]["angle"] == 0
    drafts = page.js("S.server.filter((s) => s.draft).map((s) => s.how)")
    assert drafts and all(h in ("edit (moved nodes)", "go on", "edit (re-meshed)") for h in drafts)
    assert "edit (moved nodes)" in drafts
    kinds = {e["kind"] for e in page.js("S.latency.rendered")}
    assert "bone-move" in kinds and "release" in kinds
    assert page.js("S.certificates.every((c) => c.state !== 'converged' || c.ratio <= 1)")
    picture(page.screenshot(figures / "editor_3d.png"), 900, 600)
    assert not page.console_errors()


def test_a_bone_turned_by_its_ring_and_along_an_arrow(page, figures, picture):
    centre = page.handle3d("bone-move", name="distal")
    ring = page.handle3d("bone-turn", name="distal", axis=2)
    r, a0 = math.hypot(ring[0] - centre[0], ring[1] - centre[1]), math.atan2(ring[1] - centre[1], ring[0] - centre[0])
    page.drag(ring, [(centre[0] + r * math.cos(a0 + 0.025 * k), centre[1] + r * math.sin(a0 + 0.025 * k))
                     for k in range(1, 11)])
    page.wait(CONVERGED, 120)
    rot = page.js("S.design.bones[2].rotate")
    assert 3.0 < abs(rot["angle"]) < 30.0 and abs(abs(rot["axis"][2]) - 1) < 1e-3
    before = page.js("S.design.bones[2].move")                       # the turn writes move too
    assert before is not None
    tip = page.handle3d("bone-axis", name="distal", axis=1)
    page.drag(tip, _line(tip, (tip[0], tip[1] - 8), 6))
    page.wait(CONVERGED, 120)
    after = page.js("S.design.bones[2].move")
    assert after[0] == before[0] and after[2] == before[2] and after[1] != before[1]   # along y only
    picture(page.screenshot(figures / "editor_3d_turn.png"), 900, 600)
    assert not page.console_errors()


@pytest.mark.parametrize("kind, match, path", [
    ("point", {"path": ["markers", "tip"]}, ["markers", "tip"]),
    ("point", {"path": ["cables", 0, "path", 1]}, ["cables", 0, "path", 1]),
    ("pin", {"path": ["pins", 0, "region"]}, ["pins", 0, "region"]),
])
def test_markers_cable_points_and_pins_drag_in_the_view_plane(page, kind, match, path):
    before = page.js("arguments[0].reduce((o, k) => o[k], S.design)", path)
    start = page.handle3d(kind, **match)
    page.drag(start, _line(start, (start[0] - 4, start[1] + 3), 4))
    page.wait("S.answer && !S.inflight && !S.queued && S.inputs.length === 0", 120)
    after = page.js("arguments[0].reduce((o, k) => o[k], S.design)", path)
    assert after != before
    assert page.js("S.error") is None or page.js("S.error.key")         # moved, or an error at its key
    page.js("(undo(), true)")                            # back to the valid design for the next test
    page.wait(CONVERGED, 120)
    assert page.js("arguments[0].reduce((o, k) => o[k], S.design)", path) == before
    assert not page.console_errors()


def test_undo_restores_the_pose_and_save_writes_a_file_simulate_agrees_with(page, editor, tmp_path):
    # its own edit first: under xdist this test may have a fresh page of its own
    n = page.js("S.undo.length")
    before = page.js("S.design.bones[2].move")
    start = page.handle3d("bone-move", name="distal")
    page.drag(start, _line(start, (start[0] - 3, start[1] + 2), 5))
    page.wait(CONVERGED, 120)
    assert page.js("S.undo.length") == n + 1
    pose = page.js("S.design.bones[2]")
    assert pose["move"] != before and "rotate" in pose
    page.click("#save")
    page.wait("S.saved && S.saved.file === 'finger3d.toml'", 60)
    saved = editor.folder / "finger3d.toml"
    text = saved.read_text()
    assert text.startswith("# The 2D demo finger") and tomllib.loads(text)["bones"][2]["move"] == pose["move"]
    page.wait(CONVERGED, 120)
    out = tmp_path / "sim"
    r = subprocess.run([sys.executable, "-m", "skelfem", "simulate", str(saved), "--out", str(out), "--no-picture",
                        "-q"], cwd=ROOT, env={**MPI_ENV, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    result = json.loads((out / "result.json").read_text())
    assert result["cells"] == page.js("S.answer.cells")
    assert np.allclose(result["markers"]["tip"]["position"], page.js("S.answer.markers.tip.position"), atol=1e-4)
    page.js("(undo(), true)")                             # and undo goes back past the save
    page.wait(CONVERGED, 120)
    assert page.js("S.undo.length") == n and page.js("S.design.bones[2].move") == before
    assert not page.console_errors()


def test_an_object_dragged_whole_in_3d(tmp_path, figures, picture):
    """gripper3d's ball (at mesh.size 6) moved with its square: every primitive of its solids moves."""
    from skelfem.editor.server import Editor
    text = (GEOMETRY / "gripper3d.toml").read_text().replace("size = 2.5", "size = 6.0")
    assert "size = 6.0" in text
    (tmp_path / "gripper3d.toml").write_text(text)
    ed = Editor(tmp_path / "gripper3d.toml", port=0).start()
    driver = chrome(1100, 760)
    try:
        page = Page(driver, ed.url)
        before = page.js("S.design.objects[0].solids[0].sphere.center")
        start = page.handle3d("object", path=["objects", 0, "solids"])
        page.drag(start, _line(start, (start[0], start[1] - 4), 4))
        page.wait(CONVERGED, 120)
        after = page.js("S.design.objects[0].solids[0].sphere.center")
        assert after != before and np.linalg.norm(np.subtract(after, before)) < 3.0
        assert page.js("S.answer.converged") and page.js("S.error") is None
        picture(page.screenshot(figures / "editor_3d_object.png"), 900, 600)
        assert not page.console_errors()
    finally:
        driver.quit()
        ed.stop()
