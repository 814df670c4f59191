"""Property tests (hypothesis): random designs solve or are refused cleanly; garbage never crashes.

- random valid-looking 2D designs (star-shaped outlines, bones shrunk
  around inner points, a pin at the base) either solve (exit 0 or 2) or
  are refused with exit 1 and one error line, never an internal error;
- random byte strings as design files are always bad input (exit 1, one
  line, no traceback);
- random mutations of a valid design (any leaf replaced by an adversarial
  value) give a Design or a one-line DesignError, nothing else.
"""
from __future__ import annotations

import copy
import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from _hardening import assert_one_error, listing, strip2d, toml_dumps
from skelfem.cli.main import main
from skelfem.design import Design, DesignError, parse_design

SETTINGS = dict(deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)


def _star(center, radii, angles):
    a = np.sort(np.asarray(angles))
    return np.c_[center[0] + np.asarray(radii) * np.cos(a), center[1] + np.asarray(radii) * np.sin(a)]


@st.composite
def designs(draw):
    n = draw(st.integers(5, 14))          # angular steps below 2/3 pi: the centre stays well inside
    steps = np.asarray(draw(st.lists(st.floats(0.5, 1.0), min_size=n, max_size=n)))
    angles = np.cumsum(steps) / steps.sum() * 2 * math.pi
    radii = draw(st.lists(st.floats(5.0, 30.0), min_size=n, max_size=n))
    outline = _star((0.0, 0.0), radii, angles)
    bones = []
    for k in range(draw(st.integers(0, 2))):
        m = draw(st.integers(3, 6))
        ba = draw(st.lists(st.floats(0.0, 2 * math.pi, allow_nan=False), min_size=m, max_size=m, unique=True))
        br = draw(st.lists(st.floats(0.3, 1.2), min_size=m, max_size=m))
        c = draw(st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)))
        bones.append({"name": f"b{k}", "outline": _star(c, br, ba).tolist(), "material": "hard"})
    lo = outline[:, 1].min()
    d = {
        "format": 1, "name": "random", "dim": 2, "thickness": 5.0,
        "mesh": {"size": draw(st.sampled_from([4.0, 6.0])), "degree": draw(st.sampled_from([1, 1, 2]))},
        "materials": {"soft": {"E": draw(st.floats(0.05, 5.0)), "nu": draw(st.floats(0.0, 0.49))},
                      "hard": {"E": 100.0, "nu": 0.35}},
        "body": {"outline": outline.tolist(), "material": "soft"},
        "pins": [{"name": "base", "region": [[-40.0, lo - 1.0], [40.0, lo + 8.0]]}],
        "markers": {"c": [0.0, 0.0]},
        "loads": [{"name": "f", "at": [0.0, 0.0], "force": [draw(st.floats(-1.0, 1.0)), draw(st.floats(-1.0, 1.0))]}],
    }
    if bones:
        d["bones"] = bones
    return d


@settings(max_examples=12, **SETTINGS)
@given(designs())
def test_random_2d_designs_solve_or_are_refused_cleanly(tmp_path_factory, d):
    work = tmp_path_factory.mktemp("prop")
    path = work / "random.toml"
    path.write_text(toml_dumps(d))
    out = work / "out"
    import io
    import contextlib
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["simulate", str(path), "--out", str(out), "-q", "--no-picture"])
    assert code in (0, 1, 2), err.getvalue()
    if code == 1:
        assert_one_error(err.getvalue())
        assert not out.exists()
    else:
        assert (out / "result.json").exists()
        assert [p for p in listing(work) if not p.startswith("out") and p != "random.toml"] == []


@settings(max_examples=60, **SETTINGS)
@given(st.binary(max_size=300))
def test_random_bytes_as_design_files_are_bad_input(tmp_path_factory, data):
    work = tmp_path_factory.mktemp("bytes")
    path = work / "junk.toml"
    path.write_bytes(data)
    import io
    import contextlib
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["simulate", str(path), "--out", str(work / "out"), "-q"])
    assert code == 1, err.getvalue()
    assert_one_error(err.getvalue(), "junk.toml")
    assert sorted(listing(work)) == ["junk.toml"]


ADVERSARIAL = st.sampled_from([
    float("nan"), float("inf"), -float("inf"), 0, -1, 1e300, -1e-300, 10 ** 30, "", "../x", "/abs", "a\nb",
    [], {}, [[]], [[0, 0]], True, [1, 2, 3], {"a": 1}, "energy", 2, 0.5, [[0, 0], [1, 0], [0, 1]],
])


def _leaves(d, path=()):
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(d, list) and d and isinstance(d[0], (dict, list)):
        for i, v in enumerate(d):
            yield from _leaves(v, path + (i,))
    yield path


BASE = strip2d()
PATHS = sorted(set(_leaves(BASE)) - {()}, key=str)


@settings(max_examples=300, **SETTINGS)
@given(st.lists(st.tuples(st.sampled_from(PATHS), ADVERSARIAL), min_size=1, max_size=3))
def test_mutated_designs_validate_or_fail_in_one_line(changes):
    d = copy.deepcopy(BASE)
    for path, value in changes:
        node = d
        try:
            for p in path[:-1]:
                node = node[p]
            node[path[-1]] = copy.deepcopy(value)
        except (KeyError, IndexError, TypeError):
            continue
    try:
        design = parse_design(d, "mutant.toml")
    except DesignError as exc:
        message = str(exc)
        assert message.startswith("mutant.toml: ") and "\n" not in message.replace("\\n", "")
        return
    assert isinstance(design, Design)
