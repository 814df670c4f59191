"""STEP files whose shapes a reader takes as they are (skelfem/fabricate/micrometres.py): a STEP file cannot hold
an edge's tolerance, a reader gives every edge 1e-7 mm, so no edge may lie further than that off its faces.
The bundled designs' parts are checked in test_fabricate.py (step_tolerance in fabrication.json)."""
import numpy as np
import pytest

from skelfem.fabricate.micrometres import (READER_TOLERANCE, UM_PER_MM, MicrometreOCC, in_millimetres,
                                           largest_tolerance)

# a round bone 12 mm thick with three channels through it at odd angles: the booleans' spline edges
CHANNELS = [((-3.0, 1.0, -30.0), (0.6, 0.3, 0.74)), ((2.0, -2.0, -50.0), (-0.2, 0.9, 0.39)),
            ((0.5, 0.5, -70.0), (0.8, -0.5, 0.33))]


def channelled_bone(occ) -> list:
    bone = occ.addCylinder(0, 0, -8, 0, 0, -80, 6)
    tools = []
    for (x, d), r in zip(CHANNELS, (0.6, 1.0, 1.4)):
        d = np.array(d) / np.linalg.norm(d)
        a = np.array(x) - 20 * d
        tools.append((3, occ.addCylinder(*a, *(40 * d), r)))
    out, _ = occ.cut([(3, bone)], tools)
    occ.synchronize()
    return out


def test_a_part_built_in_micrometres_has_no_edge_further_off_its_faces_than_a_reader_assumes(tmp_path):
    """Built in millimetres, OpenCASCADE leaves a channel's edge 1.2e-7 mm off its faces (more than a STEP
    reader's 1e-7: FreeCAD's BOP check finds it); built in micrometres and scaled back exactly, the same part
    keeps every edge within 1e-7 and has the same volume."""
    import gmsh  # noqa: F401 - imported on the main thread (it sets a signal handler)
    from skelfem.design.occ import gmsh_model
    with gmsh_model("step-mm") as model:
        out = channelled_bone(model.occ)
        mm_volume = model.occ.getMass(3, out[0][1])
        assert largest_tolerance(gmsh, tmp_path / "mm.brep") > READER_TOLERANCE     # what the fix is for
    with gmsh_model("step-um") as model:
        out = channelled_bone(MicrometreOCC(model.occ))
        assert model.occ.getMass(3, out[0][1]) == pytest.approx(mm_volume * UM_PER_MM ** 3, rel=1e-4)
        volumes = in_millimetres(gmsh, tmp_path / "scratch.brep")
        assert len(volumes) == 1 and not (tmp_path / "scratch.brep").exists()
        assert model.occ.getMass(3, volumes[0]) == pytest.approx(mm_volume, rel=1e-4)
        assert largest_tolerance(gmsh, tmp_path / "um.brep") <= READER_TOLERANCE
    assert not list(tmp_path.iterdir())                 # the scratch files are gone


@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (0.3, -0.4, 0.5)])
def test_a_balls_poles_lie_on_the_axis_asked_for(axis):
    """A mould's parting plane through a ball's centre must not pass through its poles: the ball is turned so
    that its poles (the ends of its seam) lie on pole_axis, centre and radius unchanged."""
    import gmsh  # noqa: F401
    from skelfem.design.occ import gmsh_model
    centre, r = np.array([3.0, -2.0, 5.0]), 4.0
    a = np.array(axis) / np.linalg.norm(axis)
    with gmsh_model("poles") as model:
        occ = MicrometreOCC(model.occ, axis)
        tag = occ.addSphere(*centre, r)
        occ.synchronize()
        poles = np.array([model.getValue(0, t, []) for _, t in model.getBoundary([(3, tag)], recursive=True)])
        box = np.reshape(occ.getBoundingBox(3, tag), (2, 3))
    poles = poles / UM_PER_MM
    assert len(poles) == 2
    assert sorted(np.round((poles - centre) @ a, 9)) == pytest.approx([-r, r], abs=1e-6)
    assert box.mean(axis=0) == pytest.approx(centre, abs=1e-3)


def test_a_part_whose_step_tolerance_is_too_large_is_built_again_with_its_poles_on_z(monkeypatch, tmp_path):
    """files.build: each part with its balls' poles on the parting plane's normal first, again with them on z
    only when its largest tolerance exceeds a reader's (a vent drilled next to a pole); no STEP file, no retry."""
    from types import SimpleNamespace

    from skelfem.fabricate import files
    from skelfem.fabricate.build import Part
    n = np.array([1.0, 0.0, 0.0])
    plan = SimpleNamespace(design=SimpleNamespace(bones=[SimpleNamespace(name="b")]), frame=SimpleNamespace(n=n))
    made = []

    def fake(kind, loose_side):
        def make(plan, what, folder, pole_axis):
            name = what if isinstance(what, str) else what.name
            made.append((name, tuple(pole_axis)))
            loose = name == loose_side and tuple(pole_axis) != (0.0, 0.0, 1.0)
            return Part(name, kind, None, 1.0, step_tolerance=None if folder is None else 4e-6 if loose else 1e-9)
        return make
    monkeypatch.setattr(files, "build_bone", fake("bone", None))
    monkeypatch.setattr(files, "build_half", fake("mould", "top"))
    parts = files.build(plan, tmp_path)
    assert [p.step_tolerance for p in parts] == [1e-9, 1e-9, 1e-9]
    assert made == [("b", (1.0, 0.0, 0.0)), ("bottom", (1.0, 0.0, 0.0)), ("top", (1.0, 0.0, 0.0)),
                    ("top", (0.0, 0.0, 1.0))]
    made.clear()
    files.build(plan, None)
    assert [axis for _, axis in made] == [(1.0, 0.0, 0.0)] * 3
