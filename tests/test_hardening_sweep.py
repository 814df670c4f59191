"""Sweeps against adversarial sweep files: names stay inside --out, reuse only by hash, failures retried."""
from __future__ import annotations

import json
import os

import pytest

from _hardening import assert_one_error, listing, strip2d, toml_dumps
from skelfem.cli.main import main


@pytest.fixture
def work(tmp_path, monkeypatch):
    w = tmp_path / "a" / "b" / "work"
    w.mkdir(parents=True)
    (w / "strip.toml").write_text(toml_dumps(strip2d(size=5.0)))
    monkeypatch.chdir(w)
    return w


def _run(capsys, *args):
    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def _write(work, text, name="sweep.toml"):
    (work / name).write_text('design = "strip.toml"\n' + text)
    return work / name


@pytest.mark.parametrize("label, text, match", [
    ("case named ..", '[[cases]]\nname = ".."\n', "cases[0].name"),
    ("case named /abs", '[[cases]]\nname = "/abs"\n', "must not contain '/'"),
    ("case named a/b", '[[cases]]\nname = "a/b"\n', "must not contain '/'"),
    ("hidden case", '[[cases]]\nname = ".x"\n', "must not start with '.'"),
    ("case named summary.csv", '[[cases]]\nname = "summary.csv"\n', "like the summary files"),
    ("case name with newline", '[[cases]]\nname = "a\\nb"\n', "cases[0].name"),
    ("duplicate cases", '[[cases]]\nname = "x"\n[[cases]]\nname = "x"\n', "duplicate case name 'x'"),
    ("sweep name ../x", 'name = "../x"\n[[cases]]\nname = "a"\n', "name: the sweep name"),
    ("sweep name not a string", 'name = 3\n[[cases]]\nname = "a"\n', "name: must be a string"),
    ("a million combinations", "[parameters]\n" + "".join(f'"p{i}" = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n'
                                                          for i in range(6)), "more than 100000 combinations"),
    ("set key with =", '[[cases]]\nname = "a"\nset = { "mesh.size=2" = 3 }\n', "is not a design key"),
    ("a date value", '[[cases]]\nname = "a"\nset = { "mesh.size" = 1979-05-27 }\n', "unsupported value type"),
    ("set not a list", 'set = "mesh.size=2"\n[[cases]]\nname = "a"\n', "set: must be a list"),
    ("ranks_per_case 0", 'ranks_per_case = 0\n[[cases]]\nname = "a"\n', "ranks_per_case"),
    ("picture not a bool", 'picture = "yes"\n[[cases]]\nname = "a"\n', "picture: must be true or false"),
    ("design missing", '', "no cases"),
    ("design is a folder", None, "design"),
])
def test_bad_sweep_file(work, capsys, label, text, match):
    path = _write(work, text) if text is not None else (work / "s.toml")
    if text is None:
        path.write_text('design = "."\n[[cases]]\nname = "a"\n')
    before = listing(work.parents[2])
    code, _, err = _run(capsys, "sweep", path, "--out", work / "out")
    assert code == 1, err
    assert_one_error(err, match)
    assert listing(work.parents[2]) == before


def test_values_with_slashes_stay_inside_out(work, capsys):
    path = _write(work, '[parameters]\n"name" = ["../../escape", "/abs/x", "ok/../..", "fine"]\n'
                        '"mesh.size" = [6.0]\n')
    root = work.parents[2]
    before = set(listing(root))
    code, _, err = _run(capsys, "sweep", path, "--out", work / "out", "-q")
    assert code == 1 and "3 of 4 case(s) failed" in assert_one_error(err)      # the bad names are bad input
    new = set(listing(root)) - before
    assert all(p.startswith("a/b/work/out") for p in new), sorted(new)
    names = sorted(os.listdir(work / "out"))
    assert len(names) == 6 and "name=fine__mesh.size=6.0" in names
    assert not [n for n in names if n.startswith(".") or "/" in n]


def test_names_that_collide_once_made_safe_stay_distinct(work, capsys):
    path = _write(work, '[parameters]\n"name" = ["x y", "x_y"]\n"mesh.size" = [6.0]\n')
    code, _, err = _run(capsys, "sweep", path, "--out", work / "out", "-q")
    assert code == 0, err
    cases = [n for n in os.listdir(work / "out") if not n.startswith("summary")]
    assert len(cases) == 2 and "name=x_y__mesh.size=6.0" in cases


def test_overrides_are_carried_at_full_precision(work, capsys):
    path = _write(work, '[parameters]\n"cables.flexor.contraction" = [1.23456789]\n"mesh.size" = [6.0]\n')
    code, _, err = _run(capsys, "sweep", path, "--out", work / "out", "-q")
    assert code == 0, err
    (case,) = [n for n in os.listdir(work / "out") if not n.startswith("summary")]
    res = json.loads((work / "out" / case / "result.json").read_text())
    assert "cables.flexor.contraction=1.23456789" in res["sweep"]["overrides"]
    assert res["cables"]["flexor"]["contraction"] == 1.23456789
    assert "1.23456789" in case


def test_every_case_failing_to_converge_exits_2(work, capsys):
    path = _write(work, 'set = ["solver.max_iterations=1", "cables.flexor.stiffness=50", "mesh.size=6"]\n'
                        '[parameters]\n"cables.flexor.contraction" = [20.0, 25.0]\n')
    code, out, err = _run(capsys, "sweep", path, "--out", work / "out", "-q")
    assert code == 2
    assert_one_error(err, "2 of 2 case(s) failed")


def test_a_case_is_rerun_when_the_design_file_changes(work, capsys):
    path = _write(work, '[parameters]\n"cables.flexor.contraction" = [1.0, 2.0]\n"mesh.size" = [6.0]\n')
    out = work / "out"
    assert _run(capsys, "sweep", path, "--out", out)[0] == 0
    code, text, _ = _run(capsys, "sweep", path, "--out", out)
    assert code == 0 and "2 already done, 0 to run" in text
    design = work / "strip.toml"
    design.write_text(design.read_text().replace("E = 1.0", "E = 2.0", 1))         # same overrides, new design
    code, text, _ = _run(capsys, "sweep", path, "--out", out)
    assert code == 0 and "0 already done, 2 to run" in text


def test_failed_cases_are_retried(work, capsys):
    path = _write(work, '[parameters]\n"cables.flexor.contraction" = [1.0]\n"mesh.size" = [6.0]\n'
                        '[[cases]]\nname = "flaky"\nset = { "mesh.size" = 6.0 }\n')
    out = work / "out"
    (out / "flaky").mkdir(parents=True)
    (out / "flaky" / "result.json").write_text(json.dumps({"converged": False, "status": "max_iterations",
                                                           "sweep": {"overrides": []}}))
    code, text, err = _run(capsys, "sweep", path, "--out", out)
    assert code == 0, err
    assert "0 already done, 2 to run" in text
    assert json.loads((out / "flaky" / "result.json").read_text())["converged"] is True


def test_a_case_folder_holding_foreign_files_refuses_the_sweep(work, capsys):
    path = _write(work, '[[cases]]\nname = "mine"\nset = { "mesh.size" = 6.0 }\n'
                        '[[cases]]\nname = "good"\nset = { "mesh.size" = 6.0 }\n')
    out = work / "out"
    (out / "mine").mkdir(parents=True)
    (out / "mine" / "notes.txt").write_text("keep me")
    before = listing(work.parents[2])
    code, _, err = _run(capsys, "sweep", path, "--out", out, "-q")
    assert code == 1 and "holds 'mine/notes.txt'" in assert_one_error(err)
    assert listing(work.parents[2]) == before


def test_sweep_into_a_foreign_folder_is_refused(work, capsys):
    path = _write(work, '[[cases]]\nname = "a"\n')
    (work / "mine").mkdir()
    (work / "mine" / "notes.txt").write_text("x")
    before = listing(work.parents[2])
    code, _, err = _run(capsys, "sweep", path, "--out", work / "mine")
    assert code == 1 and "notes.txt" in assert_one_error(err)
    assert listing(work.parents[2]) == before
