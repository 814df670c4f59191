"""Observables are named once: the output guide's table, the names a solve produces, calibration's columns."""
import re
from pathlib import Path

import pytest

from skelfem import Session
from skelfem.analysis.caldata import measurement_columns
from skelfem.observables import PATTERNS, observables

from test_objects import _base, _box

GUIDE = Path(__file__).resolve().parents[1] / "docs" / "guide" / "output.md"


def _regex(pattern: str) -> re.Pattern:
    """markers.M.x|y|z -> markers\\.[^.]+\\.(x|y|z); contacts.A|B.... -> contacts\\.[^.|]+\\|[^.|]+\\...."""
    parts = pattern.split(".")
    out = [re.escape(parts[0])]
    for p in parts[1:]:
        if p == "A|B":
            out.append(r"[^.|]+\|[^.|]+")
        elif len(p) == 1 and p.isupper():
            out.append(r"[^.|]+")
        elif "|" in p:
            out.append("(" + p + ")")
        else:
            out.append(re.escape(p))
    return re.compile(r"\.".join(out) + "$")


def test_the_output_guide_lists_exactly_the_observables_the_code_names():
    text = GUIDE.read_text()
    section = text[text.index("### Observables"):text.index("## Exit status")]
    table = re.findall(r"^\| `([^`]+)` \|", section, flags=re.M)
    assert [t.replace("\\|", "|") for t in table] == list(PATTERNS)


def test_a_solve_names_every_observable_by_the_guide_and_calibration_reads_the_same_names():
    d = _base([_box(2, 10.3, 8, 13.3)], contact={"dhat": 0.2, "friction": 0.5},
              markers={"m": [5.0, 5.0]})
    d["cables"] = [{"name": "t", "kind": "tendon", "path": [[8, 0], [8, 9]], "stiffness": 1.0, "contraction": 0.2}]
    d["grounds"] = [{"name": "wall", "point": [10.5, 0], "normal": [-1, 0], "stiffness": 10.0, "friction": 0.3}]
    with Session(d) as s:
        r = s.solve()
        assert r.converged, r.status
        names = r.observables()
        design = s.design
    regexes = [_regex(p) for p in PATTERNS]
    assert names and all(any(x.match(n) for x in regexes) for n in names), names
    sections = {n.split(".")[0] for n in names}
    assert sections == {"markers", "cables", "pins", "grounds", "objects", "contacts"}
    assert "contacts.body|box.normal_magnitude" in names and "objects.box.rotation" in names
    assert set(measurement_columns(design)) <= set(names)          # calibration's columns are observables
    assert r.observable("markers.m.y") == pytest.approx(r.marker("m")[1])
    assert r.observable("cables.t.tension") == r.tension("t")
    with pytest.raises(KeyError, match="markers.m.x"):
        r.observable("markers.nope.x")


def test_observables_skip_what_is_not_a_number():
    data = {"markers": {"a": {"position": [1.0, float("nan")]}}, "cables": {"c": {"tension": None}},
            "contacts": [{"between": ["x"], "normal_magnitude": 1.0}]}
    assert observables(data) == {"markers.a.x": 1.0}
