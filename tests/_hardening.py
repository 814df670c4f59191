"""Helpers of the adversarial suite (tests/test_hardening*.py): a sandbox, TOML text, designs."""
from __future__ import annotations

import copy
import os
import sys
from pathlib import Path

from _designs import toml_text  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SKELFEM = str(Path(sys.executable).parent / "skelfem")
ENV = {**os.environ, "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
       "OMPI_MCA_rmaps_base_oversubscribe": "1", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
       "MPLBACKEND": "Agg"}


def toml_dumps(d: dict) -> str:
    """TOML text of a design dict (the tests' one writer, tomlkit)."""
    return toml_text(d)


def strip2d(size=4.0, bones=True, contraction=1.0) -> dict:
    """A small 2D strip (10 x 60 mm) with two bones, a tendon, a pinned base and a tip marker."""
    d = {
        "format": 1, "name": "strip", "dim": 2, "thickness": 10.0,
        "mesh": {"size": size, "degree": 1},
        "materials": {"soft": {"E": 1.0, "nu": 0.3}, "hard": {"E": 1000.0, "nu": 0.35}},
        "body": {"outline": [[0, 0], [10, 0], [10, 60], [0, 60]], "material": "soft"},
        "cables": [{"name": "flexor", "kind": "tendon", "path": [[8, 0], [8, 60]], "stiffness": 1.0,
                    "contraction": contraction}],
        "pins": [{"name": "base", "region": [[-1, -1], [11, 1e-6]], "kind": "fixed"}],
        "markers": {"tip": [5, 60]},
    }
    if bones:
        d["bones"] = [{"name": "b1", "outline": [[2, 5], [6, 5], [6, 25], [2, 25]], "material": "hard"},
                      {"name": "b2", "outline": [[2, 30], [6, 30], [6, 55], [2, 55]], "material": "hard"}]
    return d


def box3d(size=4.0) -> dict:
    """A small 3D block (10 x 10 x 40 mm) with two box bones, a tendon, a pinned base and a tip marker."""
    return {
        "format": 1, "name": "block", "dim": 3,
        "mesh": {"size": size, "degree": 1},
        "materials": {"soft": {"E": 1.0, "nu": 0.3}, "hard": {"E": 1000.0, "nu": 0.35}},
        "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [10, 10, 40]}}], "material": "soft"},
        "bones": [{"name": "b1", "solids": [{"box": {"min": [3, 3, 4], "max": [7, 7, 18]}}], "material": "hard"},
                  {"name": "b2", "solids": [{"box": {"min": [3, 3, 22], "max": [7, 7, 36]}}], "material": "hard"}],
        "cables": [{"name": "flexor", "kind": "tendon", "path": [[8, 5, 0], [8, 5, 40]], "stiffness": 1.0,
                    "contraction": 1.0}],
        "pins": [{"name": "base", "region": [[-1, -1, -1], [11, 11, 1e-6]], "kind": "fixed"}],
        "markers": {"tip": [5, 5, 40]},
    }


def changed(d: dict, *changes) -> dict:
    """Deep copy of d with (path tuple, value) changes; value DELETE removes the key."""
    d = copy.deepcopy(d)
    for path, value in changes:
        node = d
        for p in path[:-1]:
            node = node[p]
        if value is DELETE:
            del node[path[-1]]
        else:
            node[path[-1]] = value
    return d


DELETE = object()


def listing(root: Path) -> list[str]:
    """Every file and folder under root (hidden ones included), relative, sorted."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root):
        rel = Path(dirpath).relative_to(root)
        out += [str(rel / n) for n in dirnames + filenames]
    return sorted(out)


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("error:")]


def assert_one_error(stderr: str, match: str | None = None) -> str:
    """stderr holds exactly one error: line (and no traceback); returns it."""
    assert "Traceback" not in stderr, stderr
    lines = error_lines(stderr)
    assert len(lines) == 1, stderr
    if match is not None:
        assert match in lines[0], lines[0]
    return lines[0]
