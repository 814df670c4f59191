"""Adversarial inputs, third round: the design layer bounds contact.dhat, dt and friction coefficients by
the design's own scales, counts every piece in the mesh budget, checks many objects in near-linear time,
holds object names to the one name rule and refuses, before any meshing, what later hung or misreported.

Every test says what the code did before it (each failed then).
"""
from __future__ import annotations

import copy
import time

import pytest

from _hardening import assert_one_error, strip2d, box3d
from skelfem.cli.main import main
from skelfem.design import resources
from skelfem.design.parse import parse_design
from skelfem.design.spec import DesignError


def with_object(d: dict | None = None, outline=((10.5, 30), (20, 30), (20, 70), (10.5, 70)), **entry) -> dict:
    """strip2d (or d) with a rigid PLA wall beside the strip, and densities for gravity and dynamics."""
    d = copy.deepcopy(d or strip2d())
    d["materials"]["pla"] = {"E": 1000.0, "nu": 0.35, "density": 1200.0}
    d["objects"] = [{"name": "wall", "outline": [list(p) for p in outline], "material": "pla", **entry}]
    return d


def refused(d: dict, key: str | None, match: str = "") -> str:
    """parse_design refuses d with one message naming key (if given) and holding match."""
    with pytest.raises(DesignError) as err:
        parse_design(d, "x.toml")
    message = str(err.value)
    assert message.startswith(f"x.toml: {key}: " if key else "x.toml: "), message
    assert match in message, message
    assert "\n" not in message
    return message


def run_cli(capsys, *args) -> tuple[int, str]:
    capsys.readouterr()
    code = main([str(a) for a in args])
    return code, capsys.readouterr().err


def refused_before_meshing(tmp_path, capsys, monkeypatch, d: dict, key: str) -> None:
    """`skelfem simulate` exits 1 with one error line naming key, meshes nothing and writes nothing."""
    import skelfem.mesh.geometry as geometry
    from _hardening import toml_dumps

    def no_meshing(*a, **k):
        raise AssertionError("meshing started for a design that should have been refused")
    monkeypatch.setattr(geometry, "_build_model", no_meshing)   # after the mesh budget, before Gmsh
    path = tmp_path / "design.toml"
    path.write_text(toml_dumps(d))
    out = tmp_path / "out"
    t0 = time.perf_counter()
    code, err = run_cli(capsys, "simulate", path, "--out", out, "-q", "--no-picture")
    assert code == 1, err
    assert_one_error(err, f"{key}:")
    assert time.perf_counter() - t0 < 20
    assert not out.exists()


# == 1. contact.dhat bounded by the mesh size and the pieces' size ======================================
# Before: only dhat > 0; dhat = 1e-300 mm on touching pieces never ended (collision detection), 1e-6 mm
# took 136 s for 274 DOFs (4 s at 4e-4 mm).
@pytest.mark.parametrize("dhat", [1e-300, 1e-6, 3e-3])
def test_a_vanishing_dhat_is_refused(dhat):
    refused({**with_object(), "contact": {"dhat": dhat}}, "contact.dhat", "0.001 x mesh.size")


def test_a_dhat_wider_than_a_tenth_of_a_piece_is_refused():
    # the wall is 9.5 mm wide, the strip 10 mm: at most 0.95 mm
    refused({**with_object(), "contact": {"dhat": 1.0}}, "contact.dhat", "0.95")
    assert parse_design({**with_object(), "contact": {"dhat": 0.95}}).contact.dhat == 0.95


def test_the_dhat_bounds_follow_the_mesh_size():
    d = {**with_object(), "contact": {"dhat": 0.01}}
    assert parse_design(d).contact.dhat == 0.01                      # h = 4 mm: from 0.004 mm
    refused({**d, "mesh": {"size": 20.0}}, "contact.dhat", "[0.02,")


def test_the_default_dhat_is_not_bounded_where_nothing_touches():
    d = strip2d(size=500.0)                        # one body, no contact: the default 0.3 mm is unused
    assert parse_design(d).contact.dhat == 0.3


def test_a_vanishing_dhat_is_refused_by_simulate_before_meshing(tmp_path, capsys, monkeypatch):
    refused_before_meshing(tmp_path, capsys, monkeypatch, {**with_object(), "contact": {"dhat": 1e-300}},
                           "contact.dhat")


# == 2. every piece counts in the mesh budget; one coordinate rule for every section ===================
# Before: the estimate counted the body only: an object 400 x 200 m at h = 4 mm went on to meshing
# (billions of triangles); object coordinates beyond +-1e7 mm were accepted.
def test_a_huge_object_is_refused_by_the_mesh_budget(tmp_path, capsys, monkeypatch):
    d = with_object(outline=((20, 0), (400_020, 0), (400_020, 200_000), (20, 200_000)), rigid=True)
    est = resources.estimate(parse_design(d))
    assert est["cells"] > 1e10                  # 2.4 x 8e10 mm^2 / 16 mm^2
    refused_before_meshing(tmp_path, capsys, monkeypatch, d, "mesh.size")


def test_the_estimate_counts_objects_in_3d():
    d = box3d()
    d["materials"]["pla"] = {"E": 1000.0, "nu": 0.35}
    base = resources.estimate(parse_design(d))["cells"]
    d["objects"] = [{"name": "ball", "solids": [{"box": {"min": [20, 0, 0], "max": [60, 40, 40]}}],
                     "material": "pla"}]
    grown = resources.estimate(parse_design(d))["cells"]
    assert grown - base == pytest.approx(6.0 * 40 ** 3 / 4 ** 3 + 4.0 * 8)


@pytest.mark.parametrize("section, change, key", [
    ("objects", lambda d: d["objects"][0].update(outline=[[2e7, 0], [2e7 + 10, 0], [2e7, 10]]), "objects.wall.outline"),
    ("pins", lambda d: d["pins"][0].update(region=[[-2e7, -1], [11, 1e-6]]), "pins.base.region"),
    ("tractions", lambda d: d.update(tractions=[{"name": "pad", "region": [[-1, 59], [1e8, 61]],
                                                  "traction": [0, -0.01]}]), "tractions.pad.region"),
    ("holes", lambda d: d["body"].update(holes=[[[3, 27], [4, 27], [4, 2e7]]]), "body.holes[0]"),
])
def test_one_coordinate_rule_for_every_section(section, change, key):
    d = with_object()
    change(d)
    refused(d, key, "coordinates must lie within +-1e+07 mm")


# == 3. many objects are checked in near-linear time =====================================================
# Before: every object was tested exactly against every earlier one: 400 objects took 110 s.
def _grid_of_objects(n: int, overlap: tuple[int, int] | None = None) -> dict:
    d = {**with_object(), "contact": {"dhat": 0.1}}
    k = int(n ** 0.5) + 1
    d["objects"] = [{"name": f"o{i}", "outline": [[20 + 3 * (i % k) + x, 3 * (i // k) + y]
                                                  for x, y in ((0, 0), (2, 0), (2, 2), (0, 2))], "material": "pla"}
                    for i in range(n)]
    if overlap is not None:
        a, b = overlap
        d["objects"][b]["outline"] = [[x + 0.5, y + 0.5] for x, y in d["objects"][a]["outline"]]
    return d


def test_a_thousand_objects_are_checked_in_seconds():
    d = _grid_of_objects(1000)
    t0 = time.perf_counter()
    assert len(parse_design(d).objects) == 1000
    assert time.perf_counter() - t0 < 15          # about 1 s here; minutes before


@pytest.mark.parametrize("overlap", [(300, 700), (5, 6)])
def test_an_overlap_among_many_objects_is_still_found(overlap):
    a, b = overlap
    refused(_grid_of_objects(800, overlap), f"objects.o{b}.outline", f"overlaps object 'o{a}' at rest")


@pytest.mark.parametrize("outline, message", [
    (((12, 0), (40, 0), (40, 80), (12, 80)), None),                     # apart: fine
    (((10, 30), (20, 30), (20, 70), (10, 70)), "overlaps the body"),     # touching the strip's side
    (((-5, -5), (30, -5), (30, 80), (-5, 80)), "overlaps the body"),     # around the strip
    (((3, 27), (4, 27), (4, 28)), "overlaps the body"),                  # inside it
])
def test_objects_against_the_body(outline, message):
    d = {**with_object(outline=outline), "contact": {"dhat": 0.1}}
    if message is None:
        assert parse_design(d).objects[0].name == "wall"
    else:
        refused(d, "objects.wall.outline", message)


def test_an_object_inside_another_is_refused():
    d = with_object()
    d["objects"].append({"name": "inner", "outline": [[12, 40], [14, 40], [14, 42]], "material": "pla"})
    refused(d, "objects.inner.outline", "overlaps object 'wall'")


# == 4. object names follow the name rule; names that share result.json's contact keys are distinct ======
# Before: object names skipped the rule ('a/b', control characters, 5000 bytes, a lone surrogate passed)
# and an object named "body" gave a contact between ["body", "body"].
@pytest.mark.parametrize("name, key, match", [
    ("a/b", "objects.a/b.name", "must not contain '/'"),
    ("x\x01", "objects.x\\x01.name", "must not contain"),
    ("y" * 5000, "objects.0.name", "longer than 100 bytes"),
    ("\ud800", None, "valid UTF-8"),                     # the key names the entry by its index or its name
    ("body", "objects.body.name", "the body's name"),
    ("a|b", "objects.a|b.name", "'|'"),
], ids=["slash", "control", "long", "surrogate", "body", "bar"])
def test_object_names_follow_the_name_rule(name, key, match):
    d = with_object()
    d["objects"][0]["name"] = name
    refused(d, key, match)


def test_a_ground_and_an_object_need_distinct_names():
    d = with_object()
    d["grounds"] = [{"name": "wall", "point": [0, -1], "normal": [0, 1], "stiffness": 1.0}]
    refused(d, "grounds.wall.name", "the name of objects.wall")


def test_bodies_and_objects_need_distinct_names():
    d = with_object()
    outline = d.pop("body")["outline"]
    d["bodies"] = [{"name": "wall", "outline": outline, "material": "soft"}]
    d["bones"] = []
    refused(d, "objects.wall.name", "the name of bodies.wall")


# == 5. [contact.pairs]: one entry per pair, no unknown keys ==========================================
# Before: "soft:pla" and "pla:soft" were both accepted (the last won); a misspelt key in a pair's table was
# ignored.
def test_the_same_pair_twice_is_refused():
    d = {**with_object(), "contact": {"pairs": {"soft:pla": 0.3, "pla:soft": 0.5}}}
    refused(d, 'contact.pairs."pla:soft"', 'the same pair as "soft:pla"')


def test_an_unknown_key_in_a_pair_table_is_refused():
    d = {**with_object(), "contact": {"pairs": {"soft:pla": {"friction": 0.3, "frction_static": 0.5}}}}
    refused(d, 'contact.pairs."soft:pla".frction_static', "unknown key")


# == 6. a fixed pin over a rigid object: refused before meshing, naming the real key ==================
# Before: refused after meshing as "bones.wall.rigid" (no such key).
def test_a_fixed_pin_over_a_rigid_object_is_refused_before_meshing(tmp_path, capsys, monkeypatch):
    d = with_object()
    d["pins"].append({"name": "hold", "region": [[19, 29], [21, 71]], "kind": "fixed"})
    refused(d, "objects.wall.rigid", "pins.hold.region")
    refused_before_meshing(tmp_path, capsys, monkeypatch, d, "objects.wall.rigid")


@pytest.mark.parametrize("pin, rigid", [
    ({"region": [[19, 29], [21, 71]], "kind": "spring", "stiffness": 100.0}, True),   # a spring may hold it
    ({"region": [[19, 29], [21, 71]], "kind": "fixed"}, False),                       # so may a fixed pin an elastic one
    ({"region": [[20, 70], [21, 71]], "kind": "fixed"}, True),                          # a corner only: no boundary held
    ({"region": [[30, 29], [31, 71]], "kind": "fixed"}, True),                        # beside it
])
def test_pins_that_may_meet_an_object(pin, rigid):
    d = with_object(rigid=rigid)
    d["pins"].append({"name": "hold", **pin})
    assert len(parse_design(d).pins) == 2


# == 7. [dynamics] dt bounded below ====================================================================
# Before: dt = duration = 1e-300 s exited 3 (ZeroDivisionError in 1 / dt^2).
def _dynamic(dt: float, duration: float) -> dict:
    d = strip2d()
    for m in d["materials"].values():
        m["density"] = 1000.0
    d["dynamics"] = {"dt": dt, "duration": duration}
    return d


@pytest.mark.parametrize("dt", [1e-300, 1e-160, 1e-13])
def test_a_vanishing_time_step_is_refused(dt):
    # the stiffest material (E 1000 MPa, 1000 kg/m^3) crosses a 4 mm element in 4e-6 s: dt >= 4e-12 s
    refused(_dynamic(dt, dt), "dynamics.dt", "4e-12 s")


def test_a_vanishing_time_step_is_refused_by_simulate(tmp_path, capsys, monkeypatch):
    refused_before_meshing(tmp_path, capsys, monkeypatch, _dynamic(1e-300, 1e-300), "dynamics.dt")


def test_a_small_time_step_above_the_bound_is_accepted():
    assert parse_design(_dynamic(1e-11, 1e-9)).dynamics.steps == 100


# == 8. friction coefficients bounded above ============================================================
# Before: no upper bound; a ground's friction_force read 3.19 N at mu 1e8 and 4.34 N at 1e10 against the
# pin's 3.23 N (relative error 3e-9 up to mu 100, 1.7e-5 at 1e6).
@pytest.mark.parametrize("where, key", [
    ("contact", "contact.friction"), ("static", "contact.friction_static"), ("ground", "grounds.g.friction"),
    ("pair", 'contact.pairs."soft:pla"'), ("pair table", 'contact.pairs."soft:pla".friction'),
])
def test_a_huge_friction_coefficient_is_refused(where, key):
    d = with_object()
    mu = 1e8
    if where == "contact":
        d["contact"] = {"friction": mu}
    elif where == "static":
        d["contact"] = {"friction": 0.5, "friction_static": mu}
    elif where == "ground":
        d["grounds"] = [{"name": "g", "point": [0, -1], "normal": [0, 1], "stiffness": 1.0, "friction": mu}]
    elif where == "pair":
        d["contact"] = {"pairs": {"soft:pla": mu}}
    else:
        d["contact"] = {"pairs": {"soft:pla": {"friction": mu}}}
    refused(d, key, "[0, 100]")


def test_friction_up_to_the_bound_is_accepted():
    d = {**with_object(), "contact": {"friction": 100.0}}
    assert parse_design(d).friction.default.kinetic == 100.0


# == 9. a ground that cuts an object at rest ===========================================================
# Before: accepted without a word (only the bodies were checked).
def test_a_ground_cutting_an_object_is_refused():
    d = with_object(outline=((20, -5), (30, -5), (30, 5), (20, 5)))
    d["grounds"] = [{"name": "g", "point": [0, 0], "normal": [0, 1], "stiffness": 1.0}]
    refused(d, "grounds.g.point", "cuts object 'wall'")
    d["objects"][0]["outline"] = [[20, 0], [30, 0], [30, 5], [20, 5]]                # resting on it: fine
    assert len(parse_design(d).grounds) == 1


# == 10. a tendon schedule without [dynamics] ==========================================================
# Before: accepted and ignored.
def test_a_schedule_without_dynamics_is_refused():
    d = strip2d()
    d["cables"][0]["schedule"] = [[0.0, 0.0], [1.0, 1.0]]
    refused(d, "cables.flexor.schedule", "[dynamics]")
    d = _dynamic(0.01, 1.0)
    d["cables"][0]["schedule"] = [[0.0, 0.0], [1.0, 1.0]]
    assert parse_design(d).cables[0].schedule is not None


def test_in_3d_a_fixed_pin_over_a_rigid_object_and_a_ground_cutting_one_are_refused():
    d = box3d()
    d["materials"]["pla"] = {"E": 1000.0, "nu": 0.35}
    d["objects"] = [{"name": "cube", "solids": [{"box": {"min": [20, 0, 0], "max": [30, 10, 10]}}], "material": "pla"}]
    assert len(parse_design(d).objects) == 1
    held = copy.deepcopy(d)
    held["pins"].append({"name": "hold", "region": [[19, -1, 9], [31, 11, 11]], "kind": "fixed"})
    refused(held, "objects.cube.rigid", "pins.hold.region")
    cut = copy.deepcopy(d)
    # the side x <= 25: the body (x <= 10) lies on it, half the cube does not
    cut["grounds"] = [{"name": "g", "point": [25, 0, 0], "normal": [-1, 0, 0], "stiffness": 1.0}]
    refused(cut, "grounds.g.point", "cuts object 'cube'")
