"""Findings of the adversarial pass (studies/adversarial.py), each with the test that failed before its fix,
and a handful of the pass's own probes run as the study runs them (subprocesses of `skelfem`).

Every test says what the code did before.
"""
from __future__ import annotations

import copy

import numpy as np
import pytest

from _studies import load_study
from skelfem.design.parse import parse_design
from skelfem.design.spec import DesignError

adversarial = load_study("adversarial")


def moved_object(x: float) -> dict:
    """The study's strip (a tendon anchored in silicone at both ends) with its PLA box x mm to the right."""
    d = adversarial.strip_with_object()
    d["objects"][0]["outline"] = [[x, 30], [x + 10, 30], [x + 10, 40], [x, 40]]
    return d


# == 1. "The body's size" counted the objects =============================================================
# Before: the default anchor radius (1 % of the body's diagonal), ground friction's slip length and
# breakaway distance (fractions of the body's size) and IK's tolerance scale were taken from the whole
# mesh, objects included: a box 10 m beside a 60 mm strip made the anchors 100 mm wide, they swallowed the
# tendon (one via point left) and `simulate` exited 3 (IndexError in the cable's read-out); nearer, moving
# the box changed the tendon's anchors and the ground's friction.
@pytest.mark.slow
def test_the_body_size_ignores_where_an_object_lies():
    from skelfem import Session
    from skelfem.analysis.control import body_extent
    from skelfem.terms.cable_route import default_anchor_radius
    answers = []
    for x in (12.0, 1e4):
        s = Session(moved_object(x))
        model = s.model
        ground = next(t for t in model.terms if getattr(t, "name", None) == "floor" and hasattr(t, "eps"))
        answers.append((default_anchor_radius(model.ctx), ground.eps, ground.dc, body_extent(model)))
        r = s.solve()
        assert r.converged
        tension = r.to_dict()["cables"]["flexor"]["tension"]
        answers[-1] += (tension,)
        s.close()
    near, far = answers
    assert near[0] == pytest.approx(0.01 * np.hypot(10, 60))          # the strip's own diagonal
    assert far[:4] == pytest.approx(near[:4], rel=1e-12)
    assert far[4] == pytest.approx(near[4], rel=1e-6)


# == 2. A piece too small for the mesh: an empty range for dhat ===========================================
# Before: `contact.dhat: must lie in [0.004, 1e-07] mm` (a 1 nm wide box at mesh.size 4) and `[1, 0.1]`
# (400 boxes of 1 mm at mesh.size 1000): a range no value fits, blaming dhat. Now the mesh size is named.
@pytest.mark.parametrize("size, width", [(4.0, 1e-6), (1000.0, 1.0)])
def test_no_dhat_fits_names_the_mesh_size(size, width):
    d = moved_object(12.0)
    d["mesh"]["size"] = size
    d["objects"][0]["outline"] = [[12, 30], [12 + width, 30], [12 + width, 40], [12, 40]]
    with pytest.raises(DesignError) as err:
        parse_design(d, "x.toml")
    message = str(err.value)
    assert message.startswith("x.toml: mesh.size: ") and "'box'" in message and "no contact.dhat fits" in message
    assert f"at most {100 * width:.3g} mm" in message


def test_a_coarse_mesh_that_fits_the_pieces_still_checks_dhat():
    d = copy.deepcopy(moved_object(12.0))
    d["mesh"]["size"] = 1000.0                  # 100 x the 10 mm box: dhat must be exactly 1
    d["contact"]["dhat"] = 1.0
    assert parse_design(d, "x.toml").contact.dhat == 1.0


# == the study itself, at a small size ====================================================================
FAST = ["object named slash", "contact.dhat 1e-300", "cable friction 10.0001", "CSV cell 1_000"]


def test_a_handful_of_probes_answer_as_the_contract_says(tmp_path):
    res = adversarial.run(only=["objects", "friction", "calibration"], names=set(FAST))
    assert res["probes"] == len(FAST)
    assert res["clean"] == len(FAST), [r for r in res["results"] if r["findings"]]
    assert all(r["answer"] == "bad_input" and r["error"].startswith("error: ") for r in res["results"])
    assert res["findings_by_class"] == {}


def test_the_study_counts_findings_by_class():
    records = [{"group": "objects", "answer": "ok", "findings": [], "after_signal": None},
               {"group": "objects", "answer": "exit 3", "findings": [{"class": "exit3", "what": ""}]},
               {"group": "editor", "answer": "HTTP 500", "findings": [{"class": "http500", "what": ""},
                                                                       {"class": "dead", "what": ""}]}]
    s = adversarial.summarise(records)
    assert s["clean"] == 1 and s["findings_by_class"] == {"exit3": 1, "http500": 1, "dead": 1}
    assert s["groups"]["objects"] == {"probes": 2, "clean": 1, "answers": {"ok": 1, "exit 3": 1}}


@pytest.mark.slow
def test_an_exit_3_is_a_finding(tmp_path):
    """The runner itself: a probe that crashes is reported as exit3, never as clean."""
    probe = adversarial.Probe("crash", "objects", ("ok",), ["simulate", "{design}", "--out", "{out}", "-q"],
                              b"format = 1\n")
    rec = adversarial.run_command(probe, tmp_path / "p")
    assert rec["answer"] == "bad_input" and rec["findings"][0]["class"] == "wrong_class"
    probe = adversarial.Probe("signal", "signals", ("interrupted", "ok"),
                              ["simulate", "{design}", "--out", "{out}", "-q", "--no-picture"],
                              adversarial.load("gripper.toml", **{"mesh.size": 1.0}), interrupt_after=3.0)
    rec = adversarial.run_command(probe, tmp_path / "q")
    assert rec["findings"] == [] and rec["answer"] in ("interrupted", "ok")


# == 3. Dragging a rigid object in a draft: "new nonzero" (HTTP 500) ===========================================
# Before: the editor's draft of gripper.toml with its box moved 1 mm (or one of its vertices dragged) answered
# 500 "internal error: Error: error code 63 ... New nonzero at (534,624) caused a malloc": the edit kept the
# Newton matrix because its check left a rigid body's nodes out, the border's host nodes too, so the new
# nodes near the moved box had no room in it.
@pytest.mark.slow
def test_a_rigid_object_moved_in_a_draft_solves_on_the_kept_mesh():
    from skelfem import Session
    g = adversarial.load("gripper.toml", **{"mesh.size": 6.0})
    s = Session(g)
    assert s.solve().converged
    for dx in (1.0, 2.0, 0.5):
        moved = adversarial.variant(g, {("objects", 0, "outline"): [[x + dx, y] for x, y in
                                                                    g["objects"][0]["outline"]]})
        assert s.edit(moved, morph=True) == "moved nodes"
        assert s.solve().converged
    s.close()


# == 4. Calibration conditions the design refuses ==========================================================
# Before: a CSV condition cell the design file would refuse (cables.flexor.contraction = 1e9, longer than the
# cable) was meshed and solved, and `calibrate` ended after 15 s with exit 2 blaming the equilibrium; --set
# with the same value is refused before meshing. Every row's conditions now go through the design's rules.
def test_a_condition_the_design_refuses_is_bad_input_before_meshing(tmp_path, capsys, monkeypatch):
    import skelfem.jobs.run as run
    from skelfem.cli.main import main

    def no_meshing(*a, **k):
        raise AssertionError("meshed")
    monkeypatch.setattr(run, "open_session", no_meshing)
    data = tmp_path / "data.csv"
    data.write_text(adversarial.CAL_HEADER + adversarial.CAL_ROWS.replace("6.0,", "1e9,"))
    out = tmp_path / "never"
    code = main(["calibrate", str(adversarial.GEOMETRY / "finger.toml"), "--data", str(data),
                 "--fit", "materials.ecoflex.E", "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1, err
    assert "row 3: its conditions make a design" in err[0] and "cables.flexor.contraction: must be shorter" in err[0]
    assert not out.exists()


def test_vector_conditions_are_checked_by_component():
    from skelfem.analysis.caldata import DataError, prepare_data
    from skelfem.design.parse import load_design
    design = load_design(adversarial.GEOMETRY / "finger.toml")
    good = {"pins.base.move.x": [0.0, 0.5], "markers.tip.x": [1.0, 2.0]}
    assert prepare_data(design, good, ["materials.ecoflex.E"]).conditions["pins.base.move.x"].tolist() == [0.0, 0.5]
    with pytest.raises(DataError, match="row 2: its conditions make a design"):
        prepare_data(design, {"pins.base.move.x": [0.0, 1e300], "markers.tip.x": [1.0, 2.0]},
                     ["materials.ecoflex.E"])


# == 5. A pin's move beyond the coordinate rule ==============================================================
# Before: `pins.base.move = [1e300, 0]` was accepted (a vector with no bound) and the solve failed with
# "inverted_elements" (exit 2); every other length in a design obeys the coordinate rule (+-1e7 mm).
@pytest.mark.parametrize("move", [[1e300, 0.0], [0.0, -2e7]])
def test_a_pin_move_obeys_the_coordinate_rule(move):
    d = adversarial.load("finger.toml")
    d["pins"][0]["move"] = move
    with pytest.raises(DesignError, match=r"^x.toml: pins.base.move: coordinates must lie within \+-1e\+07 mm"):
        parse_design(d, "x.toml")
    d["pins"][0]["move"] = [5.0, -1.0]
    assert parse_design(d, "x.toml").pins[0].move.tolist() == [5.0, -1.0]


# == 6. Young's moduli without a range ======================================================================
# Before: E only had to be > 0. two_fingers.toml with materials.ecoflex.E = 1e-300 (beside 20 N/mm tendons)
# made Newton steps of ~1e300 mm; the contact's collision detection on such a step ran for minutes and the
# command did not stop within 2 s of SIGINT (the pass's only hang). E = 1e300 "converged". Now E lies in
# [1e-6, 1e7] MPa (1 Pa to 10 TPa); 1e-6 solves two_fingers.
@pytest.mark.parametrize("E", [1e-300, 1e-7, 2e7, 1e300])
def test_a_modulus_outside_one_pascal_to_ten_terapascal_is_refused(E):
    d = adversarial.load("two_fingers.toml")
    d["materials"]["ecoflex"]["E"] = E
    with pytest.raises(DesignError, match=r"^x.toml: materials.ecoflex.E: must lie in \[1e-06, 1e\+07\] MPa"):
        parse_design(d, "x.toml")


def test_calibration_bounds_beyond_the_modulus_range_are_refused():
    from skelfem.analysis.caldata import DataError, prepare_data
    from skelfem.design.parse import load_design
    design = load_design(adversarial.GEOMETRY / "finger.toml")
    data = {"cables.flexor.contraction": [2.0, 4.0], "markers.tip.x": [-2.0, -13.9]}
    with pytest.raises(DataError, match="1e-300 is not a valid value"):
        prepare_data(design, data, ["materials.ecoflex.E"], bounds={"materials.ecoflex.E": (1e-300, 1.0)})


# == 7. Interrupts that leave with os._exit left Open MPI's session folder in TMPDIR =======================
# Before: SIGINT while the command imported its modules (after MPI_Init), or while Gmsh meshed in its
# thread, ended it with os._exit, without MPI_Finalize, and `TMPDIR/ompi.HOST.UID/jf.N` stayed (the pass's
# "SIGINT while validating 3000 objects" and "SIGINT while solving the gripper" on a loaded host).
def _interrupted_leaves_no_session_folder(tmp_path, args: list, delays) -> None:
    import os
    import signal
    import subprocess
    import time
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    left = []
    for delay in delays:
        proc = subprocess.Popen([adversarial.SKELFEM, *args, "--out", str(tmp_path / "out"), "-q"], cwd=tmp_path,
                                stderr=subprocess.PIPE, env={**adversarial.ENV, "TMPDIR": str(tmp)})
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 130 and err.decode().strip().splitlines() == ["error: interrupted"], err
        time.sleep(3)                         # Open MPI's daemon removes its own folder a moment later
        left += [str(p.relative_to(tmp)) for p in tmp.rglob("*")]
        for p in sorted(tmp.rglob("*"), reverse=True):
            p.rmdir() if p.is_dir() else os.unlink(p)
    assert left == []


@pytest.mark.slow
def test_an_interrupt_during_start_up_leaves_no_mpi_session_folder(tmp_path):
    _interrupted_leaves_no_session_folder(tmp_path, ["simulate", str(adversarial.GEOMETRY / "finger.toml")],
                                          (0.4, 0.7))


@pytest.mark.slow
def test_an_interrupt_inside_gmsh_leaves_no_mpi_session_folder(tmp_path):
    _interrupted_leaves_no_session_folder(tmp_path, ["simulate", str(adversarial.GEOMETRY / "finger3d.toml"),
                                                     "--set", "mesh.size=0.6", "--force"], (8.0,))


# == the kept run and its tables ============================================================================
def _kept():
    import json
    return json.loads(adversarial.OUT.read_text())


def test_the_kept_pass_meets_the_floor():
    """At least 150 probes over every group; no exit 3, no 500, no traceback, no write outside the output
    folder, no editor that stopped answering (the hang and the slow input it found are in the guide)."""
    kept = _kept()
    assert kept["probes"] >= 150 and set(kept["groups"]) == set(adversarial.GROUPS)
    assert not set(kept["findings_by_class"]) & {"exit3", "exit", "http500", "traceback", "write_outside", "dead",
                                                 "dropped", "error_lines", "wrong_class", "wrong_reason"}
    assert kept["clean"] == sum(not r["findings"] for r in kept["results"])


def test_the_guide_tables_come_from_the_kept_run():
    import importlib.util
    import sys
    path = adversarial.ROOT / "docs" / "_ext" / "studytables.py"
    spec = importlib.util.spec_from_file_location("studytables", path)
    tables = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("studytables", tables)
    spec.loader.exec_module(tables)
    kept = _kept()
    summary = tables.TABLES["adversarial"]({})
    assert summary.rows[-1][:3] == ["**all**", f"**{kept['probes']}**", f"**{kept['clean']}**"]
    assert sum(int(r[1]) for r in summary.rows[:-1]) == kept["probes"]
    assert all(sum(int(c) for c in r[3:]) == int(r[1]) for r in summary.rows[:-1])
    found = tables.TABLES["adversarial_findings"]({})
    assert len(found.rows) == kept["probes"] - kept["clean"]


# == 8. Many rigid objects: the border's K T as a sparse-dense product in PETSc ==============================
# Before: every Jacobian formed K T with PETSc's sparse x dense product (T dense: DOFs x 3 columns per rigid
# body): 400 boxes of 1 mm at mesh.size 100 (4,040 DOFs, 1,200 columns) took 9.7 s in that one C call (13.9 s a
# Jacobian), so SIGINT waited for it (more than 2 s on a loaded host). Serial runs multiply by T's few
# entries per column instead (2.4 s a Jacobian, its longest C call 0.3 s).
def test_the_rigid_border_is_formed_without_a_dense_product(monkeypatch):
    from petsc4py import PETSc

    from skelfem import Session
    d = adversarial.strip_with_object()
    d["objects"] = [{"name": f"o{i}", "outline": [[20 + 3 * i, 0], [21 + 3 * i, 0], [21 + 3 * i, 1], [20 + 3 * i, 1]],
                     "material": "pla"} for i in range(12)]
    d["contact"]["dhat"] = 0.1
    import skelfem.fem.assembly as assembly
    s = Session(d)
    model = s.model
    A = model.create_matrix()
    x = model.u.vector.copy()

    class NoDenseMat(PETSc.Mat):
        def createDense(self, *a, **k):
            raise AssertionError("K T formed as a PETSc sparse x dense product")

    class Guarded:                           # PETSc, but a dense matrix may not be made
        Mat = NoDenseMat

        def __getattr__(self, name):
            return getattr(PETSc, name)
    monkeypatch.setattr(assembly, "PETSc", Guarded())
    model.assemble_jacobian(x, A)
    border = model.border
    assert border.E.shape == (model.n_owned, 36) and border.C.shape == (36, 36)
    assert np.allclose(border.C, border.C.T) and np.all(np.isfinite(border.E))
    s.close()


# == 9. Gravity without a bound ===============================================================================
# Before: `--set gravity.acceleration=[0,-1e300]` on gripper.toml printed numpy's "RuntimeWarning: overflow
# encountered in multiply" on stderr above its error line and ended in a diverged solve (exit 2). The
# acceleration is at most 1e5 m/s^2 (about 10,000 g), refused before meshing.
@pytest.mark.parametrize("g", [[0.0, -1e300], [3e5, 0.0]])
def test_gravity_beyond_ten_thousand_g_is_refused(g):
    d = adversarial.load("gripper.toml")
    d["gravity"]["acceleration"] = g
    with pytest.raises(DesignError, match=r"^x.toml: gravity.acceleration: must be at most 100000 m/s\^2"):
        parse_design(d, "x.toml")
    d["gravity"]["acceleration"] = [0.0, -9.81 * 1000]
    assert parse_design(d, "x.toml").gravity[1] == pytest.approx(-9810.0)
