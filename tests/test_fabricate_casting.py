"""Pour, vents, air under bones and undercuts (skelfem.fabricate.casting), against geometry worked out by hand:
3D bodies with two high points and with an overhang, and the bundled finger."""
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
BASE = """format = 1
name = "{name}"
dim = 3
[mesh]
size = 3.0
[materials]
ecoflex = {{ E = 0.1, nu = 0.45 }}
pla = {{ E = 3000.0, nu = 0.35 }}
[body]
solids = [{solids}]
material = "ecoflex"
[[bones]]
name = "bar"
solids = [{{ box = {{ min = {bone_min}, max = {bone_max} }} }}]
material = "pla"
[[pins]]
name = "base"
region = [[-1, -1, -1], [0.01, 21, 19]]
"""


def box(lo, hi) -> str:
    return f"{{ box = {{ min = {list(lo)}, max = {list(hi)} }} }}"


def planned(tmp_path, name, solids, bone):
    from skelfem import fabricate
    from skelfem.design.parse import load_design
    path = tmp_path / f"{name}.toml"
    path.write_text(BASE.format(name=name, solids=", ".join(box(*s) for s in solids),
                                bone_min=list(bone[0]), bone_max=list(bone[1])))
    return fabricate.plan(load_design(path))


def test_each_high_point_of_the_cavity_is_vented(tmp_path):
    """A 60 x 20 base 8 high with towers 14 and 12 high at its ends (normal z, parted at z = 7): air rises
    to both tower tops; the pour takes the higher (the flat top nearest the middle of the highest), a vent
    the other. The base between them is not a high point: its roof rises to the towers on either side."""
    plan = planned(tmp_path, "towers", [((0, 0, 0), (60, 20, 8)), ((0, 0, 7), (12, 20, 14)), ((48, 0, 7), (60, 20, 12))],
                   ((20, 6, 2), (40, 14, 6)))
    flow = plan.flow
    heights = sorted(round(h["height"], 6) for h in flow["high_points"])
    assert heights == [12.0, 14.0]
    by = {round(h["height"]): h for h in flow["high_points"]}
    assert by[14]["vented_by"] == "pour" and by[12]["vented_by"] == "vent"
    assert 0 <= flow["pour"]["site"][0] <= 12 and flow["pour"]["clear_of_bones"]
    assert any(48 <= v[0] <= 60 for v in flow["vents"])                 # the lower tower has its vent
    assert len(flow["vents"]) == 2                                       # the default two, the tower's among them
    assert flow["undercut"] == {"bottom": 0.0, "top": 0.0}
    assert flow["air_under_bones"]["bar"] == pytest.approx(20 * 8)       # its bottom face looks down


def test_an_overhang_is_an_undercut_of_the_top_half(tmp_path):
    """A mushroom on a base: a 30 x 20 cap (z 14 to 18) on a 10 x 10 stem over a 40 x 20 base (z 0 to 10),
    parted at z = 9. The top half's material under the cap is locked in: the cap's underside (600 - 100),
    the base's top under it (600 - 100) and the stem's sides (40 x 4): 1160 mm^2; the bottom half none."""
    plan = planned(tmp_path, "mushroom", [((0, 0, 0), (40, 20, 10)), ((15, 5, 9), (25, 15, 15)), ((5, 0, 14), (35, 20, 18))],
                   ((12, 6, 2), (28, 14, 6)))
    under = plan.flow["undercut"]
    assert under["bottom"] == 0.0
    assert under["top"] == pytest.approx(1160, rel=0.1)     # whole triangles counted by their centroids
    assert any("the top half has" in n and "undercut" in n for n in plan.notes)


def test_the_fingers_pour_hole_misses_every_bone(tmp_path):
    """finger.toml (2D, parted at the slab's mid-plane): the pour hole's disc lies clear of every bone's
    outline, so the silicone falls to the bottom of the cavity; air clings under each bone's bottom face,
    its outline's area."""
    from skelfem import fabricate
    from skelfem.design.parse import load_design
    design = load_design(ROOT / "geometry" / "finger.toml")
    plan = fabricate.plan(design)
    (pour,) = [t for t in plan.mould_tools if t.kind == "pour"]
    centre, r = pour.points[0][:2], pour.radius
    for bone in design.bones:
        poly = np.asarray(bone.outline, float)
        a, b = poly, np.roll(poly, -1, axis=0)
        t = np.clip(np.einsum("ij,ij->i", centre - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0, 1)
        d = np.linalg.norm(centre - (a + t[:, None] * (b - a)), axis=1).min()
        x, y = poly.T
        inside = np.sum(((y > centre[1]) != (np.roll(y, -1) > centre[1]))
                        & (centre[0] < x + (centre[1] - y) * (np.roll(x, -1) - x) / (np.roll(y, -1) - y + 1e-300))) % 2
        assert not inside and d >= r, (bone.name, d, r)
        area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
        assert plan.flow["air_under_bones"][bone.name] == pytest.approx(area, rel=1e-6)
    assert plan.flow["pour"]["clear_of_bones"]
    assert [h["vented_by"] for h in plan.flow["high_points"]] == ["pour"]      # a flat top: one high plateau
    assert plan.flow["undercut"] == {"bottom": 0.0, "top": 0.0}
