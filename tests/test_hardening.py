"""Adversarial inputs, run in process: each gets its exit status, one `error:` line and no stray files.

Every test runs in a fresh working folder three levels below tmp_path and
compares a listing of the whole tmp_path before and after, so a write
anywhere (outside the output folder, or at all for bad input) is caught.
MPI, signals and properties are in test_hardening_mpi/_signals/_props.py.
"""
from __future__ import annotations

import fcntl
import json
import os
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from _hardening import (DELETE, ROOT, assert_one_error, box3d, changed, listing, strip2d, toml_dumps)
from skelfem.cli.main import main


class Sandbox:
    def __init__(self, root: Path, work: Path, capsys):
        self.root, self.work, self.capsys = root, work, capsys

    def write(self, name: str, content) -> Path:
        path = self.work / name
        if isinstance(content, dict):
            content = toml_dumps(content)
        if isinstance(content, str):
            path.write_text(content)
        else:
            path.write_bytes(content)
        return path

    def run(self, *args) -> tuple[int, str, str]:
        self.capsys.readouterr()
        code = main([str(a) for a in args])
        out, err = self.capsys.readouterr()
        return code, out, err

    def refused(self, *args, code: int = 1, match: str | None = None) -> str:
        """The command fails with `code`, one error line (containing match), nothing written anywhere."""
        before = listing(self.root)
        got, out, err = self.run(*args)
        assert got == code, (got, out, err)
        line = assert_one_error(err, match)
        assert listing(self.root) == before, "files were written"
        return line

    def ok(self, *args, out: Path, code: int = 0) -> dict:
        """The command succeeds and writes only inside `out`."""
        before = set(listing(self.root))
        got, stdout, err = self.run(*args)
        assert got == code, (got, stdout, err)
        new = set(listing(self.root)) - before
        inside = str(Path(out).resolve().relative_to(self.root))
        stray = [p for p in new if not (p == inside or p.startswith(inside + "/")
                                        or inside.startswith(p + "/"))]
        assert not stray, stray
        assert not [p for p in listing(out) if p.startswith(".")], "hidden files left in the output"
        return {"stdout": stdout, "stderr": err}


@pytest.fixture
def sandbox(tmp_path, monkeypatch, capsys):
    work = tmp_path / "a" / "b" / "work"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    return Sandbox(tmp_path, work, capsys)


S2 = strip2d()
S3 = box3d()

# -- design files: (id, design dict or raw text/bytes, text the error line must contain) ---------------
BAD_FILES = [
    ("empty file", "", "format: missing"),
    ("binary garbage", bytes(range(256)) * 4, "not a text (UTF-8) file"),
    ("latin-1 text", "name = 'caf\xe9'".encode("latin-1"), "not a text (UTF-8) file"),
    ("malformed toml", "format = 1\n[mesh\nsize = 2\n", "malformed TOML"),
    ("deeply nested arrays", "x = " + "[" * 5000 + "]" * 5000 + "\n", "strip.toml"),
    ("huge integer", toml_dumps(S2).replace("[10, 60]", "[10, " + "9" * 400 + "]", 1), "must be finite"),
    ("a table where a value goes", toml_dumps(S2).replace('thickness = 10.0', 'thickness = { a = 1 }'),
     "thickness: must be a number"),
    ("array of tables for materials", toml_dumps(S2) + "\n[[materials.extra]]\nE = 1\n", "materials.extra"),
    ("missing format", changed(S2, (("format",), DELETE)), "format: missing"),
    ("future format", changed(S2, (("format",), 2)), "format: unsupported"),
    ("name ../../x", changed(S2, (("name",), "../../x")), "name: the design name"),
    ("name /abs/path", changed(S2, (("name",), "/abs/path")), "must not contain '/'"),
    ("name ..", changed(S2, (("name",), "..")), "is not a folder name"),
    ("name .", changed(S2, (("name",), ".")), "is not a folder name"),
    ("name hidden", changed(S2, (("name",), ".hidden")), "must not start with '.'"),
    ("name with newline", changed(S2, (("name",), "a\nb")), "must not contain '\\n'"),
    ("name with NUL", changed(S2, (("name",), "a\x00b")), "must not contain"),
    ("name with backslash", changed(S2, (("name",), "a\\b")), "must not contain"),
    ("name too long", changed(S2, (("name",), "x" * 300)), "longer than 100 bytes"),
    ("name empty", changed(S2, (("name",), "")), "non-empty"),
    ("name blank edge", changed(S2, (("name",), " x")), "white space"),
    ("cable name with newline", changed(S2, (("cables", 0, "name"), "fl\nexor")), "cables."),
    ("marker name ../x", changed(S2, (("markers",), {"../x": [5, 60]})), "markers"),
    ("E = nan", changed(S2, (("materials", "soft", "E"), float("nan"))), "materials.soft.E: must be a finite number"),
    ("thickness = inf", changed(S2, (("thickness",), float("inf"))), "thickness: must be a finite number"),
    ("mesh.size = -inf", changed(S2, (("mesh", "size"), float("-inf"))), "mesh.size"),
    ("nan in outline", changed(S2, (("body", "outline", 2), [10, float("nan")])), "body.outline: must be finite"),
    ("inf in marker", changed(S2, (("markers", "tip"), [float("inf"), 0])), "markers.tip: must be finite"),
    ("nan force", changed(S2, (("loads",), [{"name": "f", "at": [5, 30], "force": [float("nan"), 0]}])),
     "loads.f.force: must be finite"),
    ("nan ground normal", changed(S2, (("grounds",), [{"name": "g", "point": [0, -1], "normal": [float("nan"), 1],
                                                       "stiffness": 1}])), "grounds.g.normal"),
    ("zero ground normal", changed(S2, (("grounds",), [{"name": "g", "point": [0, -1], "normal": [0, 0],
                                                        "stiffness": 1}])), "grounds.g.normal: must be a non-zero"),
    ("ground cutting the body at rest", changed(S2, (("grounds",), [{"name": "g", "point": [0, 30], "normal": [0, 1],
                                                                     "stiffness": 1}])),
     "grounds.g.point: the plane cuts the body at rest"),
    ("ground cutting 1 um", changed(S2, (("grounds",), [{"name": "g", "point": [0, 59.999], "normal": [0, -1],
                                                         "stiffness": 1}])), "the plane cuts the body"),
    ("bowtie outline", changed(S2, (("body", "outline"), [[0, 0], [10, 60], [10, 0], [0, 60]])), "not simple"),
    ("spike outline", changed(S2, (("body", "outline"), [[0, 0], [10, 0], [10, 60], [10, 30], [0, 60]])),
     "not simple"),
    ("outline touching itself", changed(S2, (("body", "outline"), [[0, 0], [10, 0], [5, 30], [10, 60], [0, 60],
                                                                     [5, 30]])), "not simple"),
    ("repeated point", changed(S2, (("body", "outline"), [[0, 0], [10, 0], [10, 0], [10, 60], [0, 60]])),
     "repeated consecutive points"),
    ("two-point outline", changed(S2, (("body", "outline"), [[0, 0], [10, 0]])), "at least 3 points"),
    ("collinear outline", changed(S2, (("body", "outline"), [[0, 0], [5, 0], [10, 0]])), "zero area"),
    ("hole touching outline", changed(S2, (("body", "holes"), [[[0, 26], [4, 26], [4, 29], [0, 29]]])),
     "holes[0]: a hole must lie strictly inside"),
    ("hole outside", changed(S2, (("body", "holes"), [[[20, 26], [24, 26], [24, 29]]])), "holes[0]: a hole must lie"),
    ("holes overlapping", changed(S2, (("body", "holes"), [[[7, 26], [9, 26], [9, 29], [7, 29]],
                                                          [[8, 27], [9.5, 27], [9.5, 28]]])),
     "holes[1]: overlaps holes[0]"),
    ("hole inside hole", changed(S2, (("body", "holes"), [[[6.5, 26], [9.5, 26], [9.5, 29.5], [6.5, 29.5]],
                                                         [[7, 27], [8, 27], [8, 28]]])), "overlaps holes[0]"),
    ("bone outside", changed(S2, (("bones", 0, "outline"), [[2, 5], [12, 5], [12, 25], [2, 25]])),
     "bones.b1.outline: a bone must lie strictly inside"),
    ("bone on the boundary", changed(S2, (("bones", 0, "outline"), [[0, 5], [6, 5], [6, 25], [0, 25]])),
     "bones.b1.outline: a bone must lie strictly inside"),
    ("bones overlapping", changed(S2, (("bones", 1, "outline"), [[2, 20], [6, 20], [6, 55], [2, 55]])),
     "bones.b2.outline: overlaps or touches bone 'b1'"),
    ("bones touching at a corner", changed(S2, (("bones", 1, "outline"), [[6, 25], [8, 25], [8, 55], [6, 55]])),
     "overlaps or touches bone 'b1'"),
    ("bone inside bone", changed(S2, (("bones", 1, "outline"), [[3, 6], [5, 6], [5, 8]])), "overlaps or touches"),
    ("bone in a hole", changed(S2, (("body", "holes"), [[[1, 2], [7, 2], [7, 27], [1, 27]]])),
     "bones.b1.outline: overlaps body.holes[0]"),
    ("hole in a bone", changed(S2, (("body", "holes"), [[[3, 10], [4, 10], [4, 11]]])), "overlaps body.holes[0]"),
    ("cable leaving between vertices", changed(S2, (("cables", 0, "path"), [[8, 0], [8, 30], [14, 40], [8, 59]])),
     "cables.flexor.path: the cable leaves the body"),
    ("cable through a hole", changed(S2, (("body", "holes"), [[[7, 40], [9, 40], [9, 45], [7, 45]]])),
     "cables.flexor.path: the cable leaves the body"),
    ("marker outside", changed(S2, (("markers", "tip"), [50, 50])), "markers.tip: the marker lies outside"),
    ("load outside", changed(S2, (("loads",), [{"name": "f", "at": [-3, 2], "force": [1, 0]}])),
     "loads.f.at: the load point lies outside"),
    ("coordinates 1e9", changed(S2, (("body", "outline", 2), [10, 1e9])), "coordinates must lie within"),
    ("steps 1e9", changed(S2, (("solver",), {"steps": 10 ** 9})), "solver.steps: must be >= 1 and <= 10000"),
    ("max_iterations 1e12", changed(S2, (("solver",), {"max_iterations": 10 ** 12})), "solver.max_iterations"),
    ("mesh.size 1e-6", changed(S2, (("mesh", "size"), 1e-6)), "mesh.size: 1e-06 mm gives about"),
    ("mesh.size 0", changed(S2, (("mesh", "size"), 0.0)), "mesh.size: must be > 0"),
    ("mesh.degree 3", changed(S2, (("mesh", "degree"), 3)), "mesh.degree: must be 1 or 2"),
    ("nu 0.5", changed(S2, (("materials", "soft", "nu"), 0.5)), "materials.soft.nu"),
    ("unknown key", changed(S2, (("colour",), "red")), "colour: unknown key"),
    ("list for a table", changed(S2, (("mesh",), [1, 2])), "mesh: must be a table"),
    ("string for a number", changed(S2, (("mesh", "size"), "fine")), "mesh.size: must be a number"),
    ("ragged points", changed(S2, (("body", "outline"), [[0, 0], [10], [10, 60]])), "body.outline: must be"),
    ("no pins", changed(S2, (("pins",), [])), "pins: at least one"),
    ("contraction longer than the cable", changed(S2, (("cables", 0, "contraction"), 100.0)), "must be shorter"),
    ("3D overlapping bones", changed(S3, (("bones", 1, "solids"), [{"box": {"min": [3, 3, 15], "max": [7, 7, 36]}}])),
     "bones.b2.solids: overlaps bone 'b1'"),
    ("3D touching bones", changed(S3, (("bones", 1, "solids"), [{"box": {"min": [3, 3, 18], "max": [7, 7, 36]}}])),
     "bones.b2.solids: touches bone 'b1'"),
    ("3D bones touching along an edge", changed(S3, (("bones", 1, "solids"),
                                                      [{"box": {"min": [7, 7, 10], "max": [9, 9, 30]}}])),
     "touches bone 'b1'"),
    ("3D bone partly outside", changed(S3, (("bones", 0, "solids"), [{"cylinder": {"from": [5, 5, 4], "to": [5, 5, 18],
                                                                                   "radius": 8}}])),
     "bones.b1.solids: a bone must lie strictly inside the body"),
    ("3D bone touching the surface", changed(S3, (("bones", 0, "solids"), [{"box": {"min": [0, 3, 4],
                                                                                   "max": [7, 7, 18]}}])),
     "it touches the body's surface"),
    ("3D bone in a cavity", changed(S3, (("bones", 0, "solids"), [{"sphere": {"center": [50, 5, 5], "radius": 2}}])),
     "is outside"),
    ("3D disconnected unpinned part", changed(S3, (("body", "solids"), [{"box": {"min": [0, 0, 0], "max": [10, 10, 40]}},
                                                                       {"box": {"min": [30, 0, 0],
                                                                                "max": [40, 10, 10]}}])),
     "body.solids: the body falls apart into 2 pieces"),
    ("3D cable through empty space", changed(S3, (("cables", 0, "path"), [[8, 5, 0], [20, 5, 20], [8, 5, 40]])),
     "cables.flexor.path: the cable leaves the body"),
    ("3D marker outside", changed(S3, (("markers", "tip"), [5, 5, 41])), "markers.tip: the marker lies outside"),
    ("3D load outside", changed(S3, (("loads",), [{"name": "f", "at": [5, 5, 50], "force": [0, 0, 1]}])),
     "loads.f.at: the load point lies outside"),
    ("3D ground cutting", changed(S3, (("grounds",), [{"name": "g", "point": [0, 0, 20], "normal": [0, 0, -1],
                                                       "stiffness": 1}])), "the plane cuts the body"),
    ("3D ground under a sphere", changed(S3, (("body", "solids"), [{"box": {"min": [0, 0, 0], "max": [10, 10, 40]}},
                                                                  {"sphere": {"center": [5, 5, 40], "radius": 5}}]),
                                         (("grounds",), [{"name": "g", "point": [0, 0, 44], "normal": [0, 0, -1],
                                                          "stiffness": 1}])), "the plane cuts the body"),
    ("3D tiny sphere", changed(S3, (("body", "solids"), [{"sphere": {"center": [0, 0, 0], "radius": 1e-15}}])),
     "radius: must lie in"),
    ("3D non-simple extrude", changed(S3, (("body", "solids"), [{"extrude": {"outline": [[0, 0], [10, 10], [10, 0],
                                                                                        [0, 10]], "z": [0, 40]}}])),
     "not simple"),
    ("3D mesh.size 1e-3", changed(S3, (("mesh", "size"), 1e-3)), "unknowns at P1, more than this machine solves"),
    ("3D P2 at 0.1 mm", changed(S3, (("mesh", "size"), 0.1), (("mesh", "degree"), 2)), "mesh.size"),
    ("3D outline in 2D", changed(S3, (("dim",), 2)), "body.outline: missing"),
]


@pytest.mark.parametrize("label, design, match", BAD_FILES, ids=[b[0] for b in BAD_FILES])
def test_bad_design_file(sandbox, label, design, match):
    path = sandbox.write("strip.toml", design)
    sandbox.refused("simulate", path, "-q", code=1, match=match)


def test_design_file_errors_without_quiet_are_still_one_line(sandbox):
    path = sandbox.write("strip.toml", changed(S2, (("mesh", "size"), 1e-6)))
    sandbox.refused("simulate", path, code=1, match="mesh.size")
    sandbox.refused("simulate", path, "-v", code=1, match="mesh.size")


@pytest.mark.parametrize("label, make, match", [
    ("missing file", lambda s: s.work / "nope.toml", "no such file"),
    ("a folder", lambda s: s.work, "is a folder"),
    ("a 65 MB file", lambda s: _sparse(s.work / "big.toml", 65 * 2 ** 20), "larger than 64 MB"),
    ("a fifo-less special file", lambda s: Path("/dev/null"), "format: missing"),
], ids=lambda x: x if isinstance(x, str) else "")
def test_unreadable_design_files(sandbox, label, make, match):
    before = listing(sandbox.root)
    path = make(sandbox)
    if path.parent == sandbox.work and path.exists() and path.is_file():
        before = listing(sandbox.root)
    sandbox.refused("simulate", path, "-q", code=1, match=match)
    assert listing(sandbox.root) == before


def _sparse(path: Path, size: int) -> Path:
    with open(path, "wb") as f:
        f.truncate(size)
    return path


# -- --set overrides --------------------------------------------------------------------------------------
@pytest.mark.parametrize("assignment, match", [
    ("cables.nope.stiffness=1", "no entry named 'nope'"),
    ("mesh.size=nan", "mesh.size: must be a finite number"),
    ("mesh.size=inf", "mesh.size: must be a finite number"),
    ("mesh.size=1e-9", "mesh.size: 1e-09 mm gives about"),
    ("name=../x", "name: the design name"),
    ("name=/tmp/x", "must not contain '/'"),
    ("mesh.size", "expected KEY=VALUE"),
    ("mesh..size=1", "empty key"),
    ("markers.tip=[1e400, 0]", "markers.tip: must be finite"),
    ("markers.tip=" + "[" * 3000 + "]" * 3000, "markers.tip"),
    ("solver.steps=99999999999999999999999", "solver.steps"),
    ("materials.soft.E=-0.0", "materials.soft.E: must be > 0"),
])
def test_bad_override(sandbox, assignment, match):
    path = sandbox.write("strip.toml", S2)
    sandbox.refused("simulate", path, "-q", "--set", assignment, code=1, match=match)


# -- the command line ---------------------------------------------------------------------------------------
def _ik_args(s, *extra):
    design = s.write("strip.toml", S2)
    return ("ik", design, "--marker", "tip", "-q", *extra)


@pytest.mark.parametrize("label, args, match", [
    ("no arguments", lambda s: (), "the following arguments are required"),
    ("unknown command", lambda s: ("frobnicate",), "invalid choice"),
    ("unknown option", lambda s: ("simulate", s.write("strip.toml", S2), "--colour", "red"), "unrecognized"),
    ("missing design", lambda s: ("simulate",), "required: design"),
    ("--tol not a number", lambda s: ("simulate", s.write("strip.toml", S2), "--tol", "abc"), "invalid float"),
    ("--tol nan", lambda s: ("simulate", s.write("strip.toml", S2), "--tol", "nan"), "--tol: must be a finite"),
    ("--tol -1", lambda s: ("simulate", s.write("strip.toml", S2), "--tol", "-1"), "--tol: must be a finite"),
    ("--tol inf", lambda s: ("simulate", s.write("strip.toml", S2), "--tol", "inf"), "--tol: must be a finite"),
    ("ik --target nan", lambda s: _ik_args(s, "--target", "nan", "0"), "--target: coordinates must be finite"),
    ("ik --target inf", lambda s: _ik_args(s, "--target", "inf", "0"), "--target: coordinates must be finite"),
    ("ik --target one number", lambda s: _ik_args(s, "--target", "1"), "--target"),
    ("ik --target 1e300", lambda s: _ik_args(s, "--target", "1e300", "0"), "within"),
    ("ik --reg nan", lambda s: _ik_args(s, "--target", "5", "50", "--reg", "nan"), "--reg nan: must be a finite"),
    ("ik --reg -1", lambda s: _ik_args(s, "--target", "5", "50", "--reg", "-1"), "--reg -1: must be"),
    ("ik --reg inf", lambda s: _ik_args(s, "--target", "5", "50", "--reg", "inf"), "--reg inf"),
    ("ik --tol nan", lambda s: _ik_args(s, "--target", "5", "50", "--tol", "nan"), "--tol nan"),
    ("ik --max-contraction inf", lambda s: _ik_args(s, "--target", "5", "50", "--max-contraction", "flexor=inf"),
     "--max-contraction flexor=inf"),
    ("ik --max-contraction nan", lambda s: _ik_args(s, "--target", "5", "50", "--max-contraction", "flexor=nan"),
     "--max-contraction flexor=nan"),
    ("ik --max-contraction no tendon", lambda s: _ik_args(s, "--target", "5", "50", "--max-contraction", "nope=3"),
     "'nope' is not a tendon"),
    ("ik --max-contraction no value", lambda s: _ik_args(s, "--target", "5", "50", "--max-contraction", "flexor"),
     "--max-contraction flexor"),
    ("ik --max-solves 0", lambda s: _ik_args(s, "--target", "5", "50", "--max-solves", "0"), "--max-solves 0"),
    ("ik --max-solves 1e9", lambda s: _ik_args(s, "--target", "5", "50", "--max-solves", "1000000000"),
     "--max-solves 1000000000"),
    ("ik unknown marker", lambda s: ("ik", s.write("strip.toml", S2), "--marker", "nose", "--target", "1", "2"),
     "marker 'nose' not in design"),
    ("ik without tendons", lambda s: ("ik", s.write("strip.toml", changed(S2, (("cables",), []))), "--marker", "tip",
                                      "--target", "5", "50"), "needs at least one tendon"),
    ("ik with a ligament only", lambda s: ("ik", s.write("strip.toml", changed(
        S2, (("cables", 0), {"name": "lig", "kind": "ligament", "path": [[8, 0], [8, 60]], "stiffness": 1.0}))),
        "--marker", "tip", "--target", "5", "50"), "needs at least one tendon"),
    ("track --line nan", lambda s: ("track", s.write("strip.toml", S2), "--marker", "tip", "--line", "nan", "0", "1",
                                    "1", "--steps", "3"), "--line: coordinates must be finite"),
    ("track --steps 1e9", lambda s: ("track", s.write("strip.toml", S2), "--marker", "tip", "--line", "0", "0", "1",
                                     "1", "--steps", "1000000000"), "--steps N with 2 <= N"),
    ("track --steps 1", lambda s: ("track", s.write("strip.toml", S2), "--marker", "tip", "--line", "0", "0", "1",
                                   "1", "--steps", "1"), "--steps N"),
    ("track --line 3 numbers", lambda s: ("track", s.write("strip.toml", S2), "--marker", "tip", "--line", "0", "0",
                                          "1", "--steps", "3"), "--line"),
    ("track --csv binary", lambda s: ("track", s.write("strip.toml", S2), "--marker", "tip", "--csv",
                                      s.write("t.csv", bytes(range(256)))), "not a text (UTF-8) file"),
    ("track --csv with inf", lambda s: ("track", s.write("strip.toml", S2), "--marker", "tip", "--csv",
                                        s.write("t.csv", "x,y\n1,2\ninf,3\n")), "line 3: expected 2 finite numbers"),
    ("track --csv empty", lambda s: ("track", s.write("strip.toml", S2), "--marker", "tip", "--csv",
                                     s.write("t.csv", "")), "no targets"),
    ("track --csv and --steps", lambda s: ("track", s.write("strip.toml", S2), "--marker", "tip", "--csv",
                                           s.write("t.csv", "1,2\n"), "--steps", "3"), "--steps goes with --line"),
    ("track --csv missing", lambda s: ("track", s.write("strip.toml", S2), "--marker", "tip", "--csv",
                                       s.work / "none.csv"), "cannot read"),
    ("sweep file missing", lambda s: ("sweep", s.work / "none.toml"), "no such file"),
    ("bench --sizes -1", lambda s: ("bench", s.write("strip.toml", S2), "--sizes", "-1"), "--sizes"),
], ids=lambda x: x if isinstance(x, str) else "")
def test_bad_command_line(sandbox, label, args, match):
    a = args(sandbox)
    before = listing(sandbox.root)
    got, out, err = sandbox.run(*a)
    assert got == 1, (got, out, err)
    assert_one_error(err, match)
    assert listing(sandbox.root) == before


def test_help_exits_0(sandbox):
    code, out, err = sandbox.run("simulate", "--help")
    assert code == 0 and "usage" in out and not err


# -- output folders --------------------------------------------------------------------------------------
@pytest.mark.parametrize("label, out, match", [
    ("an existing file", lambda s: s.write("taken", "x"), "exists and is not a folder"),
    ("below an existing file", lambda s: s.write("taken", "x") / "sub", "exists and is not a folder"),
    ("the working folder", lambda s: Path("."), "is the working folder or one of its parents"),
    ("the parent folder", lambda s: Path(".."), "is the working folder or one of its parents"),
    ("the root", lambda s: Path("/"), "is the working folder or one of its parents"),
    ("a 300-byte name", lambda s: Path("x" * 300), "is too long for a folder"),
    ("a 5000-byte path", lambda s: Path("/".join(["y" * 100] * 50)), "path too long"),
    ("a folder of someone else's files", lambda s: _folder_with(s.work / "mine", "notes.txt"),
     "holds 'notes.txt', which skelfem did not write"),
    ("a folder with a sub-folder", lambda s: _folder_with(s.work / "mine", "data/x.csv"), "holds 'data'"),
    ("under /proc", lambda s: Path("/proc/skelfem-test/out"), "/proc/skelfem-test/out"),
    ("an empty name", lambda s: Path(""), "is the working folder"),
], ids=lambda x: x if isinstance(x, str) else "")
def test_unusable_output_folder(sandbox, label, out, match):
    design = sandbox.write("strip.toml", S2)
    target = out(sandbox)
    sandbox.refused("simulate", design, "-q", "--out", target, code=1, match=match)


def _folder_with(folder: Path, *names) -> Path:
    for name in names:
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text("mine")
    return folder


def test_default_output_for_a_bad_name_is_refused_before_anything(sandbox):
    design = sandbox.write("strip.toml", S2)
    sandbox.refused("simulate", design, "-q", "--set", "name=../../escape", code=1, match="name")
    assert not (sandbox.root / "escape").exists() and not (sandbox.work / "results").exists()


def test_output_locked_by_another_run_is_refused(sandbox):
    design = sandbox.write("strip.toml", S2)
    out = sandbox.work / "res"
    lock = sandbox.work / ".res.lock"
    fd = os.open(lock, os.O_RDWR | os.O_CREAT)
    os.write(fd, b"4242")
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        line = sandbox.refused("simulate", design, "-q", "--out", out, code=1,
                               match="another skelfem run (pid 4242) is writing this folder")
        assert "res" in line
    finally:
        os.close(fd)
        lock.unlink()
    sandbox.ok("simulate", design, "-q", "--no-picture", "--out", out, out=out)


def test_stale_staging_and_temporaries_are_cleaned(sandbox):
    design = sandbox.write("strip.toml", S2)
    out = sandbox.work / "res"
    _folder_with(sandbox.work / ".res.tmp-999999-deadbeef", "result.json")          # a killed run's staging
    _folder_with(sandbox.work / ".res.old-999999-deadbeef", "result.json")
    _folder_with(out, "result.json", ".result-abc123.json", "solution.xdmf")            # old result + temp file
    (sandbox.work / ".res.lock").write_text("999999")                                  # a dead run's lock file
    code, _, err = sandbox.run("simulate", design, "-q", "--no-picture", "--out", out)
    assert code == 0, err
    assert sorted(os.listdir(sandbox.work)) == ["res", "strip.toml"]
    assert sorted(os.listdir(out)) == ["result.json", "solution.xdmf"]
    assert json.loads((out / "result.json").read_text())["converged"] is True


def test_failed_solve_replaces_the_old_result_whole(sandbox):
    design = sandbox.write("strip.toml", S2)
    out = sandbox.work / "res"
    sandbox.ok("simulate", design, "-q", "--out", out, out=out)
    assert sorted(os.listdir(out)) == ["deformed.png", "result.json", "solution.xdmf"]
    got, _, err = sandbox.run("simulate", design, "-q", "--out", out, "--set", "solver.max_iterations=1",
                              "--set", "cables.flexor.contraction=20", "--set", "cables.flexor.stiffness=50")
    assert got == 2 and "solve failed" in assert_one_error(err)
    assert sorted(os.listdir(out)) == ["result.json"]          # no equilibrium of the old run beside it
    assert json.loads((out / "result.json").read_text())["converged"] is False


def test_ik_beside_simulate_keeps_both_results(sandbox):
    design = sandbox.write("strip.toml", S2)
    out = sandbox.work / "res"
    sandbox.ok("simulate", design, "-q", "--no-picture", "--out", out, out=out)
    stamp = (out / "result.json").stat().st_ino
    sandbox.ok("ik", design, "--marker", "tip", "--target", "4", "59", "-q", "--out", out, out=out)
    assert sorted(os.listdir(out)) == ["ik.json", "ik.png", "result.json", "solution.xdmf"]
    assert (out / "result.json").stat().st_ino == stamp          # carried over untouched (hard link)
    ik = json.loads((out / "ik.json").read_text())
    assert set(ik["contractions"]) == {"flexor"}


def test_collinear_vertices_on_a_straight_edge_are_accepted_and_solve(sandbox):
    d = changed(S2, (("body", "outline"), [[0, 0], [5, 0], [10, 0], [10, 20], [10, 40], [10, 60], [0, 60],
                                           [0, 30]]))
    design = sandbox.write("strip.toml", d)
    out = sandbox.work / "res"
    sandbox.ok("simulate", design, "-q", "--no-picture", "--out", out, out=out)
    assert json.loads((out / "result.json").read_text())["converged"] is True


def test_disconnected_3d_body_with_a_pin_each_is_accepted():
    from skelfem.design import parse_design
    d = changed(S3, (("body", "solids"), [{"box": {"min": [0, 0, 0], "max": [10, 10, 40]}},
                                          {"box": {"min": [30, 0, 0], "max": [40, 10, 10]}}]))
    d["pins"].append({"name": "second", "region": [[29, -1, -1], [41, 11, 1e-6]]})
    design = parse_design(d, "two.toml")
    assert design.measure == pytest.approx(4000 + 1000)


def test_3d_overlapping_bones_are_refused_by_the_session_api_too():
    from skelfem.design import DesignError, parse_design
    d = changed(S3, (("bones", 1, "solids"), [{"box": {"min": [3, 3, 15], "max": [7, 7, 36]}}]))
    with pytest.raises(DesignError, match="overlaps bone 'b1'"):
        parse_design(d, "x.toml")


def test_force_lets_a_large_estimate_through_to_meshing():
    from skelfem.design import resources
    from skelfem.design import DesignError, parse_design
    design = parse_design(changed(S2, (("mesh", "size"), 0.003)), "x.toml")
    est = resources.estimate(design)
    assert 4e6 < est["cells"] < 2e8
    with pytest.raises(DesignError, match="--force"):
        resources.check(design)
    assert resources.check(design, force=True) == est


@pytest.mark.parametrize("design, size", [("finger.toml", 1.0), ("finger3d.toml", 3.0), ("arm3d.toml", 4.0)])
def test_mesh_estimate_is_close_to_gmsh(design, size):
    """The estimate behind the limit is within a factor 1.5 of what Gmsh makes."""
    from skelfem.design import resources
    from skelfem.design import load_design
    from skelfem.mesh.geometry import mesh_design
    d = load_design(ROOT / "geometry" / design, [f"mesh.size={size}"])
    tm = mesh_design(d)
    cells = tm.mesh.topology.index_map(tm.mesh.topology.dim).size_global
    assert 0.67 < resources.estimate(d)["cells"] / cells < 1.5


# -- polygons at scale -------------------------------------------------------------------------------------
def _wavy(n: int) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = 50 + 5 * np.sin(37 * a)
    return np.c_[60 + r * np.cos(a), 60 + r * np.sin(a)]


def test_20000_vertex_outline_validates_in_seconds_with_little_memory():
    from skelfem.design import parse_design
    d = changed(S2, (("body", "outline"), _wavy(20000).tolist()),
                (("bones",), [{"name": "b", "outline": _wavy(2000)[:, :] * 0.3 + 42, "material": "hard"}]),
                (("cables", 0, "path"), [[60, 20], [60, 100]]), (("markers", "tip"), [60, 60]),
                (("pins", 0, "region"), [[0, 0], [120, 20]]))
    d["bones"][0]["outline"] = d["bones"][0]["outline"].tolist()
    tracemalloc.start()
    t0 = time.perf_counter()
    design = parse_design(d, "wavy.toml")
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(f"\n20,000-vertex outline + 2,000-vertex bone: {seconds:.2f} s, peak {peak / 1e6:.1f} MB")
    assert len(design.body.outline) == 20000
    assert seconds < 5.0 and peak < 200e6


def test_20000_vertex_self_touching_outline_is_refused():
    from skelfem.design import DesignError, parse_design
    poly = _wavy(20000)
    poly[10000] = poly[5000]          # one vertex moved onto another far along the outline
    with pytest.raises(DesignError, match="not simple"):
        parse_design(changed(S2, (("body", "outline"), poly.tolist())), "wavy.toml")


def test_many_bones_validate_quickly():
    from skelfem.design import parse_design
    bones = [{"name": f"b{i}_{j}", "material": "hard",
              "outline": [[1 + 2 * i, 1 + 2 * j], [2 + 2 * i, 1 + 2 * j], [2 + 2 * i, 2 + 2 * j], [1 + 2 * i, 2 + 2 * j]]}
             for i in range(40) for j in range(40)]
    d = changed(S2, (("body", "outline"), [[0, 0], [82, 0], [82, 82], [0, 82]]), (("bones",), bones),
                (("cables", 0, "path"), [[0.5, 0], [0.5, 82]]), (("pins", 0, "region"), [[-1, -1], [83, 0]]))
    t0 = time.perf_counter()
    parse_design(d, "grid.toml")
    assert time.perf_counter() - t0 < 10.0


# -- strict JSON ----------------------------------------------------------------------------------------
def test_json_is_strict(tmp_path):
    from skelfem.io.files import write_json
    write_json(tmp_path / "r.json", {"a": float("inf"), "b": [float("nan"), np.float64(-np.inf), 1.5],
                                     "c": np.arange(3), "d": {"e": np.float32(2.0)}})
    text = (tmp_path / "r.json").read_text()
    assert "Infinity" not in text and "NaN" not in text
    assert json.loads(text) == {"a": None, "b": [None, None, 1.5], "c": [0, 1, 2], "d": {"e": 2.0}}
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".")]


# -- internal errors and interrupts, injected ---------------------------------------------------------
def test_a_linear_solve_that_fails_outside_newton_is_exit_2_not_an_internal_error(sandbox, monkeypatch):
    """E.g. a sensitivity's Krylov solve that failed on a mesh beyond MUMPS's memory model."""
    import numpy as np
    import skelfem.cli.main as cli

    def stalled(args):
        raise np.linalg.LinAlgError("the Krylov solve failed, and MUMPS cannot take over")
    monkeypatch.setattr(cli, "simulate", stalled)
    design = sandbox.write("strip.toml", S2)
    line = sandbox.refused("simulate", design, "-q", code=2, match="linear solve failed: the Krylov solve failed")
    assert "internal error" not in line


def test_internal_error_is_exit_3_with_and_without_v(sandbox, monkeypatch):
    import skelfem.cli.main as cli

    def broken(args):
        raise RuntimeError("boom")
    monkeypatch.setattr(cli, "simulate", broken)
    design = sandbox.write("strip.toml", S2)
    line = sandbox.refused("simulate", design, "-q", code=3, match="internal error: RuntimeError: boom")
    assert "run with -v" in line
    before = listing(sandbox.root)
    code, _, err = sandbox.run("simulate", design, "-v")
    assert code == 3 and "Traceback" in err and err.strip().splitlines()[-1].startswith("error: internal error")
    assert listing(sandbox.root) == before


@pytest.mark.parametrize("signum, code", [(2, 130), (15, 143)])
def test_interrupt_while_writing_keeps_the_old_result(sandbox, monkeypatch, signum, code):
    import skelfem.io.files as output
    from skelfem.runtime.interrupts import Interrupted
    design = sandbox.write("strip.toml", S2)
    out = sandbox.work / "res"
    sandbox.ok("simulate", design, "-q", "--out", out, out=out)
    old = (out / "result.json").read_text()
    real = output.write_json

    def interrupted(path, data):
        if ".tmp-" in str(path):
            raise Interrupted(signum)
        real(path, data)
    monkeypatch.setattr(output, "write_json", interrupted)
    before = listing(sandbox.root)
    got, _, err = sandbox.run("simulate", design, "-q", "--out", out, "--set", "cables.flexor.contraction=2")
    assert got == code and assert_one_error(err) == "error: interrupted"
    assert listing(sandbox.root) == before                   # staging and lock gone, old files untouched
    assert (out / "result.json").read_text() == old


def test_error_lines_are_one_line_whatever_the_message(sandbox, monkeypatch):
    import skelfem.cli.main as cli

    def multiline(args):
        raise cli.InputError("first\nsecond\r\x1b[31mred")
    monkeypatch.setattr(cli, "simulate", multiline)
    line = sandbox.refused("simulate", sandbox.write("strip.toml", S2), code=1)
    assert line == "error: first\\nsecond\\r\\x1b[31mred"
