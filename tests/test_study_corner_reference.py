"""studies/corner_reference.py, tiny: a strip with two bones, graded at their eight corners."""
import json

import numpy as np
import pytest
from _designs import strip, toml_text
from _studies import load_study

pytestmark = pytest.mark.slow


def test_only_sharp_turns_of_a_bone_outline_are_corners():
    study = load_study("corner_reference")
    t = np.linspace(0.0, np.pi / 2, 10)                             # a filleted corner: 9 turns of 10 degrees
    fillet = np.column_stack([4.0 + np.cos(t), 4.0 + np.sin(t)])
    outline = np.vstack([[[0.0, 0.0], [5.0, 0.0]], fillet, [[0.0, 5.0]]])
    bone = type("B", (), {"outline": outline})()
    design = type("D", (), {"bones": [bone]})()
    found = study.corners(design)
    assert len(found) == 3 and not any(np.allclose(c, p) for c in found for p in fillet[1:-1])


def test_corner_reference_study_tiny(tmp_path):
    from skelfem import Session
    from skelfem.design import load_design
    study = load_study("corner_reference")
    path = tmp_path / "strip.toml"
    path.write_text(toml_text(strip(length=60.0, width=10.0, size=3.0, contraction=1.0, tendon_offset=2.0,
                                    bones=True)))
    with Session(load_design(path, ["mesh.degree=2", "mesh.size=3.0"])) as s:
        plain = s.dofs
    res = study.run(path, sizes=(3.0, 2.85), fraction=0.25, radius=1.0)
    rows = res["rows"]
    assert res["corners"] == 8 and [r["size"] for r in rows] == [3.0, 2.85]
    assert rows[0]["dofs"] > 1.5 * plain                              # graded at the corners
    x0, x1 = (np.array(r["markers"]["tip"]) for r in rows)
    assert res["scatter"] == pytest.approx(np.linalg.norm(x1 - x0)) and 0 < res["scatter"] < 0.1
    answer = tmp_path / "answer.json"
    answer.write_text(json.dumps({"markers": {"tip": {"position": (x0 + [0.05, 0.0]).tolist()}},
                                  "accuracy": {"estimated_error": 0.1}}))
    res = study.run(path, sizes=(3.0, 2.85), answers=[answer])
    (c,) = res["answers"]
    assert c["error"] == pytest.approx(0.05) and c["effectivity"] == pytest.approx(2.0)
    assert c["measurable"] == (0.05 > 2 * res["scatter"])
    assert study.main([f"--design={path}", "--sizes", "3", "--out", str(tmp_path / "o")]) == 0
    assert json.loads((tmp_path / "o" / "corner_reference.json").read_text())["scatter"] is None
