"""Command lines and names that are not valid UTF-8: paths still work, names are refused in one line."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from skelfem.design import load_design

ROOT = Path(__file__).resolve().parents[1]
SKELFEM = os.fsencode(str(Path(sys.executable).parent / "skelfem"))
FINGER = os.fsencode(str(ROOT / "geometry" / "finger.toml"))
ENV = {**os.environ, "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1", "MPLBACKEND": "Agg"}


def run(*args: bytes, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([SKELFEM, *args], capture_output=True, env=ENV, cwd=cwd, timeout=300)


def one_error(res) -> str:
    lines = res.stderr.decode("utf-8", "replace").strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


@pytest.mark.slow
def test_an_output_folder_whose_name_is_not_utf8_works(tmp_path):
    out = os.fsencode(str(tmp_path)) + b"/res\xff"
    res = run(b"simulate", FINGER, b"--out", out, b"--set", b"mesh.size=6", b"--no-picture", b"-q")
    assert res.returncode == 0, res.stderr
    assert os.path.exists(out + b"/result.json")


@pytest.mark.parametrize("args, key", [
    ((b"--set", b"name=\xff"), "name"),
    ((b"--set", b"cables.flexor.contraction=\xff"), "cables.flexor.contraction"),
    ((b"--set", b"mesh.size=\xfe2"), "mesh.size"),
])
def test_a_value_that_is_not_utf8_is_bad_input(tmp_path, args, key):
    res = run(b"simulate", FINGER, b"--out", os.fsencode(str(tmp_path / "o")), *args, b"-q")
    assert res.returncode == 1 and key in one_error(res)
    assert not (tmp_path / "o").exists()


def test_a_design_path_that_is_not_utf8_is_reported_not_crashed(tmp_path):
    res = run(b"simulate", os.fsencode(str(tmp_path)) + b"/\xff.toml", b"-q")
    assert res.returncode == 1 and "no such file" in one_error(res)


def test_a_lone_surrogate_design_name_is_refused_before_meshing(tmp_path):
    from skelfem.design import DesignError, load_design
    with pytest.raises(DesignError, match="name: .*valid UTF-8"):
        load_design(ROOT / "geometry" / "finger.toml", ["name=\udcff"])
    with pytest.raises(DesignError, match="valid UTF-8"):
        load_design(ROOT / "geometry" / "finger.toml", ["markers.tip=[0, 0]", "name=a\ud800b"])


@pytest.mark.parametrize("command", ["track", "optimize"])
def test_an_endless_target_file_is_refused_quickly(tmp_path, command):
    """/dev/zero as --csv: refused once over the size limit (it used to grow memory without end)."""
    import time
    design = tmp_path / "finger.toml"             # optimize plans motions in time: a [dynamics] section
    design.write_text((ROOT / "geometry" / "finger.toml").read_text() + "\n[dynamics]\ndt = 0.01\nduration = 0.1\n")
    t0 = time.perf_counter()
    res = run(command.encode(), os.fsencode(str(design)), b"--marker", b"tip", b"--csv", b"/dev/zero",
              b"--out", os.fsencode(str(tmp_path / "o")), b"-q")
    assert res.returncode == 1 and "larger than 16 MB" in one_error(res)
    assert time.perf_counter() - t0 < 30                 # process start and imports included
    assert not (tmp_path / "o").exists()


def test_read_bounded_reads_no_more_than_its_limit(tmp_path):
    from skelfem.io.files import InputTooLarge, read_bounded
    p = tmp_path / "t.csv"
    p.write_text("1,2\n" * 1000)
    assert read_bounded(p, 4000, "target file").count("\n") == 1000
    with pytest.raises(InputTooLarge, match="not a target file"):
        read_bounded(p, 3999, "target file")
    with pytest.raises(InputTooLarge):
        read_bounded("/dev/zero", 2 ** 20, "target file")


def test_optimize_with_stiffness_damping_is_bad_input_before_meshing(tmp_path, monkeypatch):
    """It used to mesh, run and exit 3 (an internal error) from inside the adjoint."""
    import skelfem.mesh.geometry as geometry
    from skelfem.cli.main import main
    design = tmp_path / "finger.toml"
    design.write_text((ROOT / "geometry" / "finger.toml").read_text()
                      + "\n[dynamics]\ndt = 0.01\nduration = 0.1\ndamping = { stiffness = 0.01 }\n")
    monkeypatch.setattr(geometry, "mesh_design", lambda *a, **k: pytest.fail("meshed"))
    assert main(["optimize", str(design), "--marker", "tip", "--target", "0", "80",
                 "--out", str(tmp_path / "o"), "-q"]) == 1
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("content", [
    lambda key: {"key": key, "results": [{"target": [1, 2]}]},                 # an entry missing its fields
    lambda key: {"key": key, "results": [{"target": "x"}] * 3, "poses": [0]},  # a pose file that is not there
    lambda key: {"key": key, "results": 7},                                     # not a list
    lambda key: [key],                                                           # not an object
])
def test_a_malformed_track_progress_file_starts_over(tmp_path, content):
    """A resume from a broken progress.json used to exit 3; now the track starts from the first target."""
    import json
    from types import SimpleNamespace

    from skelfem.cli.control import TrackProgress
    design = load_design(ROOT / "geometry" / "finger.toml")
    args = SimpleNamespace(marker="tip", max_contraction=[], reg=0.0, tol=None, max_solves=10)
    targets = np.array([[0.0, 80.0], [1.0, 80.0]])
    fresh = TrackProgress(tmp_path / "out", design, args, targets)
    fresh.folder.mkdir()
    (fresh.folder / "progress.json").write_text(json.dumps(content(fresh.key)))
    again = TrackProgress(tmp_path / "out", design, args, targets)
    assert again.entries == [] and again.results() == [] and not again.folder.exists()
