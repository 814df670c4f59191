"""Command lines and names that are not valid UTF-8: paths still work, names are refused in one line."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

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
