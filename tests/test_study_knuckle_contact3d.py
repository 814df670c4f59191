"""studies/knuckle_contact3d.py: the 3D knuckle finger closes without interpenetrating only with self-contact;
the exact Hessian of settled contacts and the growing pattern change the cost, not the answer."""
import json

import numpy as np
import pytest
from _studies import load_study
from conftest import ROOT


def test_the_mid_depth_section_is_the_extruded_outline():
    """The boundary triangles of the notched 3D strip cut at mid-depth: closed loops whose length is the 2D
    outline's perimeter, and no crossing edges nor area covered twice at rest."""
    from skelfem import Session
    from skelfem.terms.contact import SelfContact, crossing_edges, oriented_edges, overlap_area
    from test_contact_3d import notched
    study = load_study("knuckle_contact3d")
    d = notched(self_contact=False)
    outline = np.array(d["body"]["solids"][0]["extrude"]["outline"], float)
    with Session(d) as s:
        probe = SelfContact(s.model.V, 0.2, 1.0)
        rest, moved, segments = study.section(probe.X, probe.X, probe.facets, z0=2.0)
    assert np.array_equal(rest, moved) and np.all(np.bincount(segments.ravel()) == 2)    # closed loops
    perimeter = np.linalg.norm(np.roll(outline, -1, axis=0) - outline, axis=1).sum()
    assert np.linalg.norm(rest[segments[:, 1]] - rest[segments[:, 0]], axis=1).sum() == pytest.approx(perimeter)
    assert crossing_edges(rest, segments) == 0
    box = np.array([rest.min(axis=0), rest.max(axis=0)])
    assert overlap_area(rest, oriented_edges(rest, segments), box, 200) == 0.0


@pytest.mark.slow
def test_the_study_closes_the_knuckles_on_a_coarse_mesh(tmp_path, picture):
    study = load_study("knuckle_contact3d")
    # the pattern comparison (grown against full) on a 10 mm mesh of its own (984 DOFs, 220 boundary nodes: the
    # same 48 iterations and tip either way, 15 s against 28 s at 8 mm on a loaded host)
    res = study.run(size=8.0, contraction=22.0, full_size=10.0, out=tmp_path / "out", figures=tmp_path / "fig")
    on, off, projected, grown, full = (res[k] for k in ("on", "off", "projected", "grown", "full"))
    assert all(r["converged"] for r in res.values())
    assert on["min_distance"] > 0 and not on["intersects"] and 0 < on["final_distance"] < on["dhat"]
    assert on["meet_step"] is not None and on["section_crossing_edges"] == 0 and on["section_overlap_area"] == 0
    assert off["intersects"]
    # the same equilibrium whatever the Hessian of settled contacts and the pattern
    assert np.allclose(projected["tip"], on["tip"], atol=1e-3)
    assert full["pattern_pairs"] == full["boundary_nodes"] ** 2 > grown["pattern_pairs"]
    assert full["newton_iterations"] == grown["newton_iterations"] and np.allclose(full["tip"], grown["tip"], atol=1e-9)
    saved = json.loads((tmp_path / "out" / "knuckle_contact3d.json").read_text())
    assert saved["on"]["newton_iterations"] == on["newton_iterations"]
    picture(tmp_path / "fig" / "knuckles3d.png", 500, 500)
    picture(tmp_path / "fig" / "knuckles3d_section.png", 800, 800)


def test_the_committed_study_closes_the_knuckles_without_interpenetrating():
    """The study's committed output (the design's 3 mm mesh): with self-contact the notches close (within
    dhat from the step it names on), every accepted iterate apart, nothing intersecting, in fewer Newton
    iterations than with the Hessian projected throughout; without, the triangles intersect."""
    out = json.loads((ROOT / "studies" / "output" / "knuckle_contact3d" / "knuckle_contact3d.json").read_text())
    on, off, projected = out["on"], out["off"], out["projected"]
    assert on["size"] == 3.0 and on["contraction"] == 16.0 and on["converged"] and projected["converged"]
    assert on["min_distance"] > 0 and not on["intersects"] and 0 < on["final_distance"] < on["dhat"]
    assert on["meet_step"] is not None and all(s["min_distance"] < on["dhat"] for s in on["steps"][on["meet_step"] - 1:])
    assert off["converged"] and off["intersects"] and off["section_overlap_area"] > 0
    assert on["newton_iterations"] < projected["newton_iterations"]
    assert np.allclose(on["tip"], projected["tip"], atol=1e-3)
