"""[[bodies]] in 3D: several soft bodies of their own solids and materials, apart at rest, each held by its
own pins, touching each other through the IPC barrier with friction (geometry/two_fingers3d.toml)."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from skelfem.design.parse import load_design
from skelfem.design.spec import DesignError

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "two_fingers3d.toml"
RIGHT_OUTLINE = "[[34, 0], [54, 0], [54, 92], [53, 96], [50, 99], [44, 100], [38, 99], [35, 96], [34, 92]]"


def test_the_bundled_design_reads_two_bodies_with_their_bones():
    d = load_design(DESIGN)
    assert d.dim == 3 and [b.name for b in d.bodies] == ["left", "right"]
    assert [b.material for b in d.bodies] == ["ecoflex", "dragonskin"]
    assert len(d.bones) == 6 and all(b.solids for b in d.bodies)


BAD = {
    "overlapping bodies": (lambda t: t.replace("outline = [[34, 0], [54, 0]", "outline = [[18, 0], [54, 0]", 1),
                           "bodies.right.solids: overlaps body 'left'"),
    "touching bodies": (lambda t: t.replace(RIGHT_OUTLINE, RIGHT_OUTLINE.replace("[34, 0]", "[20, 0]")
                                            .replace("[34, 92]", "[20, 92]")),
                        "bodies.right.solids: touches body 'left'"),
    "a body no pin holds": (lambda t: t.replace('region = [[33, -1, -1], [55, 0.01, 21]]',
                                                'region = [[-1, -1, -1], [21, 0.02, 21]]'),
                            "bodies.right: nothing holds this body"),
    "a cable from one body to the other": (lambda t: t.replace("[37, 78, 10], [43, 84, 10]", "[37, 78, 10], [11, 84, 10]"),
                                           "cables.right_flexor.path: the cable leaves the body"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_3d_bodies_are_one_error_naming_the_key(case, tmp_path):
    change, message = BAD[case]
    text = DESIGN.read_text()
    bad = change(text)
    assert bad != text
    path = tmp_path / "bad.toml"
    path.write_text(bad)
    with pytest.raises(DesignError) as info:
        load_design(path)
    assert f"{path}: {message}" in str(info.value)


@pytest.mark.slow
def test_two_3d_fingers_press_on_each_other_each_in_equilibrium(tmp_path):
    """As bundled (5 mm, a 2 mm contraction each): the fingertips meet. Each finger's pin reaction balances
    the contact force (normal and friction) on it, to 1e-6 N; the bodies never interpenetrate."""
    out = tmp_path / "two"
    r = subprocess.run([sys.executable, "-m", "skelfem", "simulate", str(DESIGN), "--out", str(out), "-q",
                        "--no-picture"], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    d = json.loads((out / "result.json").read_text())
    assert d["converged"]
    (c,) = d["contacts"]
    assert c["between"] == ["left", "right"] and c["normal_magnitude"] > 0.05
    assert 0 < c["min_distance"] < 0.2                              # in the barrier's reach (dhat), never through
    on_left = np.asarray(c["normal_force"]) + np.asarray(c["friction_force"])
    assert np.allclose(np.asarray(d["pins"]["left_base"]["reaction"]), -on_left, atol=1e-6)
    assert np.allclose(np.asarray(d["pins"]["right_base"]["reaction"]), on_left, atol=1e-6)
    assert on_left[0] < 0                                           # the right finger pushes the left back
    left, right = d["markers"]["left_tip"]["displacement"], d["markers"]["right_tip"]["displacement"]
    assert left[0] > 1 and right[0] < -1                            # curled toward each other
