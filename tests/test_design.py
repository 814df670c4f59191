"""Design validation: every bad input of the contract is one DesignError naming file and key."""
import copy

import numpy as np
import pytest

from _designs import strip
from skelfem.design import DesignError, load_design, parse_design
from skelfem.design.polygons import contains, is_simple, sample_polyline


def _with_bones():
    return strip(bones=True)


def _set(d, path, value):
    *head, last = path
    node = d
    for p in head:
        node = node[p]
    if value is _DELETE:
        del node[last]
    else:
        node[last] = value
    return d


_DELETE = object()

# (label, design factory, [(path, value)], text the message must contain)
BAD = [
    ("missing format", strip, [(("format",), _DELETE)], "format: missing"),
    ("future format", strip, [(("format",), 2)], "format: unsupported"),
    ("unknown top key", strip, [(("colour",), "red")], "colour: unknown key"),
    ("unknown nested key", strip, [(("cables", 0, "stifness"), 3.0)], "cables.flexor.stifness: unknown key"),
    ("missing material key", strip, [(("body", "material"), _DELETE)], "body.material: missing"),
    ("wrong type", strip, [(("mesh", "size"), "fine")], "mesh.size: must be a number"),
    ("bool is no number", strip, [(("thickness",), True)], "thickness: must be a number"),
    ("bad dim", strip, [(("dim",), 4)], "dim: must be 2 or 3"),
    ("bad degree", strip, [(("mesh", "degree"), 3)], "mesh.degree: must be 1 or 2"),
    ("point with 3 coords", strip, [(("markers", "tip"), [1, 2, 3])], "markers.tip: must be 2 numbers"),
    ("self-intersecting outline", strip, [(("body", "outline"), [[0, 0], [10, 60], [10, 0], [0, 60]])],
     "body.outline: polygon is not simple"),
    ("degenerate outline", strip, [(("body", "outline"), [[0, 0], [5, 0], [10, 0]])], "body.outline: polygon has zero area"),
    ("two-point outline", strip, [(("body", "outline"), [[0, 0], [5, 0]])], "body.outline: a polygon needs"),
    ("repeated vertex", strip, [(("body", "outline"), [[0, 0], [10, 0], [10, 0], [10, 60], [0, 60]])],
     "body.outline: repeated"),
    ("bone outside body", _with_bones, [(("bones", 0, "outline"), [[2, 5], [12, 5], [12, 25], [2, 25]])],
     "bones.b1.outline: a bone must lie strictly inside"),
    ("bone on boundary", _with_bones, [(("bones", 0, "outline"), [[0, 5], [8, 5], [8, 25], [0, 25]])],
     "bones.b1.outline: a bone must lie strictly inside"),
    ("overlapping bones", _with_bones, [(("bones", 1, "outline"), [[2, 20], [8, 20], [8, 55], [2, 55]])],
     "bones.b2.outline: overlaps or touches bone 'b1'"),
    ("bone in a hole", _with_bones, [(("body", "holes"), [[[3, 10], [7, 10], [7, 12], [3, 12]]])],
     "bones.b1.outline: overlaps body.holes[0]"),
    ("hole crossing the outline", strip, [(("body", "holes"), [[[-1, 10], [3, 10], [3, 12], [-1, 12]]])],
     "body.holes[0]: a hole must lie strictly inside"),
    ("cable leaving the body", strip, [(("cables", 0, "path"), [[8, 0], [8, 30], [14, 40], [8, 59]])],
     "cables.flexor.path: the cable leaves the body"),
    ("cable through a hole", strip, [(("body", "holes"), [[[6, 20], [9, 20], [9, 25], [6, 25]]])],
     "cables.flexor.path: the cable leaves the body"),
    ("cable with one point", strip, [(("cables", 0, "path"), [[8, 0]])], "cables.flexor.path: a cable path needs"),
    ("bad cable kind", strip, [(("cables", 0, "kind"), "muscle")], "cables.flexor.kind: must be"),
    ("unknown material", strip, [(("body", "material"), "unobtainium")], "body.material: unknown material 'unobtainium'"),
    ("unknown bone material", _with_bones, [(("bones", 1, "material"), "steel")], "bones.b2.material: unknown material"),
    ("zero E", strip, [(("materials", "soft", "E"), 0.0)], "materials.soft.E: must be > 0"),
    ("negative E", strip, [(("materials", "soft", "E"), -1.0)], "materials.soft.E: must be > 0"),
    ("nu = 0.5", strip, [(("materials", "soft", "nu"), 0.5)], "materials.soft.nu: must lie in (-1, 0.5)"),
    ("nu = -1", strip, [(("materials", "soft", "nu"), -1.0)], "materials.soft.nu: must lie in (-1, 0.5)"),
    ("zero cable stiffness", strip, [(("cables", 0, "stiffness"), 0.0)], "cables.flexor.stiffness: must be > 0"),
    ("negative spring pin", strip, [(("pins", 0, "kind"), "spring"), (("pins", 0, "stiffness"), -2.0)],
     "pins.base.stiffness: must be > 0"),
    ("spring pin without stiffness", strip, [(("pins", 0, "kind"), "spring")], "pins.base.stiffness: missing"),
    ("no pins", strip, [(("pins",), _DELETE)], "pins: missing"),
    ("empty pins", strip, [(("pins",), [])], "pins: at least one"),
    ("inverted pin box", strip, [(("pins", 0, "region"), [[5, 5], [0, 0]])], "pins.base.region: must be [min, max]"),
    ("ligament contracted", strip, [(("cables", 0, "kind"), "ligament")],
     "cables.flexor.contraction: ligaments are passive"),
    ("contraction longer than cable", strip, [(("cables", 0, "contraction"), 100.0)],
     "cables.flexor.contraction: must be shorter"),
    ("duplicate names", strip, [(("cables",), [strip()["cables"][0]] * 2)], "duplicate name 'flexor'"),
    ("dotted name", strip, [(("cables", 0, "name"), "a.b")], "must be a non-empty name without '.'"),
    ("marker outside", strip, [(("markers", "tip"), [50, 50])], "markers.tip: the marker lies outside"),
    ("load outside", strip, [(("loads",), [{"name": "f", "at": [-3, 2], "force": [1, 0]}])],
     "loads.f.at: the load point lies outside"),
    ("zero ground normal", strip, [(("grounds",), [{"name": "g", "point": [0, 0], "normal": [0, 0], "stiffness": 1}])],
     "grounds.g.normal: must be a non-zero"),
    ("zero ground stiffness", strip, [(("grounds",), [{"name": "g", "point": [0, 0], "normal": [0, 1], "stiffness": 0}])],
     "grounds.g.stiffness: must be > 0"),
    ("bad line search", strip, [(("solver",), {"line_search": "magic"})], "solver.line_search: must be one of"),
    ("zero steps", strip, [(("solver",), {"steps": 0})], "solver.steps: must be >= 1"),
    ("bad contact flag", strip, [(("contact",), {"self": "yes"})], "contact.self: must be true or false"),
    ("thickness in 3D", strip, [(("dim",), 3)], "thickness: is for dim = 2 only"),
]


@pytest.mark.parametrize("label, factory, changes, expected", BAD, ids=[b[0] for b in BAD])
def test_bad_design_is_one_error_naming_file_and_key(label, factory, changes, expected):
    d = factory()
    for path, value in changes:
        _set(d, path, value)
    with pytest.raises(DesignError) as info:
        parse_design(d, "robot.toml")
    message = str(info.value)
    assert message.startswith("robot.toml: "), message
    assert expected in message, message
    assert "\n" not in message


def test_good_design_parses_with_defaults():
    d = parse_design(strip(bones=True), "robot.toml")
    assert d.dim == 2 and d.mesh.degree == 1 and d.solver.steps == 1 and d.solver.line_search == "auto"
    assert [b.name for b in d.bones] == ["b1", "b2"]
    assert d.cables[0].kind == "tendon" and d.cables[0].contraction == 0.1
    assert np.allclose(d.pins[0].move, 0.0) and d.pins[0].kind == "fixed"
    assert not d.contact.self_contact
    assert d.name == "strip"


def test_overrides_address_entries_by_name():
    d = strip(bones=True)
    design = parse_design(d, "r.toml", ["cables.flexor.contraction=0.7", "materials.hard.E=500",
                                        "mesh.size=1", "pins.base.kind=spring", "pins.base.stiffness=20",
                                        "markers.tip=[4, 50]", "solver.steps=3"])
    assert design.cables[0].contraction == 0.7
    assert design.materials["hard"].E == 500.0
    assert design.mesh.size == 1.0
    assert design.pins[0].kind == "spring" and design.pins[0].stiffness == 20.0
    assert np.allclose(design.markers["tip"], [4, 50])
    assert design.solver.steps == 3
    assert d["cables"][0]["contraction"] == 0.1          # the caller's dict is untouched


@pytest.mark.parametrize("assignment, expected", [
    ("cables.nope.stiffness=1", "no entry named 'nope' in cables (have: flexor)"),
    ("bones.b1.material=hard", "the design has no 'bones' section"),
    ("mesh.size", "expected KEY=VALUE"),
    ("mesh..size=1", "empty key"),
    ("cables.stiffness=1", "address an entry of cables by name"),
    ("mesh.size.x=1", "mesh.size is a value, not a table"),
    ("mesh.sise=1", "mesh.sise: unknown key"),
    ("mesh.size=-1", "mesh.size: must be > 0"),
])
def test_bad_override_is_one_error(assignment, expected):
    with pytest.raises(DesignError) as info:
        parse_design(strip(), "r.toml", [assignment])
    assert expected in str(info.value) and str(info.value).startswith("r.toml: ")


def test_file_errors(tmp_path):
    with pytest.raises(DesignError, match="no such file"):
        load_design(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("format = 1\n[mesh\nsize = 2\n")
    with pytest.raises(DesignError, match=r"bad.toml: malformed TOML"):
        load_design(bad)
    with pytest.raises(DesignError, match="is a folder"):
        load_design(tmp_path)


def test_3d_primitives_are_validated():
    d = {"format": 1, "dim": 3, "materials": {"s": {"E": 1.0, "nu": 0.3}},
         "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [10, 10, 50]}}], "material": "s"},
         "pins": [{"name": "base", "region": [[-1, -1, -1], [11, 11, 0.1]]}]}
    design = parse_design(d, "arm.toml")
    assert design.dim == 3 and "box" in design.body.solids[0]
    for solid, expected in [({"box": {"min": [0, 0, 0], "max": [0, 10, 5]}}, "must exceed min"),
                            ({"cone": {}}, "must be one of"),
                            ({"sphere": {"center": [0, 0, 0], "radius": -1}}, "radius: must be > 0"),
                            ({"cylinder": {"from": [0, 0, 0], "to": [0, 0, 0], "radius": 1}}, "must differ")]:
        bad = copy.deepcopy(d)
        bad["body"]["solids"] = [solid]
        with pytest.raises(DesignError, match="arm.toml: body.solids"):
            parse_design(bad, "arm.toml")
        with pytest.raises(DesignError) as info:
            parse_design(bad, "arm.toml")
        assert expected in str(info.value)


def test_polygon_predicates():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    assert is_simple(square, 1e-12)
    assert not is_simple(np.array([[0, 0], [1, 1], [1, 0], [0, 1]], float), 1e-12)
    assert list(contains(square, np.array([[0.5, 0.5], [1.0, 0.5], [1.5, 0.5]]), 1e-12)) == [True, True, False]
    # a path leaving and re-entering between its vertices is sampled outside
    notch = np.array([[0, 0], [3, 0], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]], float)
    pts = sample_polyline(np.array([[0.5, 2.0], [2.5, 2.0]]), [notch])
    assert not np.all(contains(notch, pts, 1e-12))


def test_geometry_checks_are_remembered_only_when_they_pass():
    """Re-parsing (a live --set) repeats no geometry check; a failing check fails every time."""
    import skelfem.design.table as design_module
    good = _with_bones()
    parse_design(good, "a.toml")
    known = len(design_module._MEMO)
    parse_design(good, "a.toml", ["cables.flexor.contraction=0.2"])
    assert len(design_module._MEMO) == known                      # nothing checked again
    bad = _set(copy.deepcopy(good), ["bones", 1, "outline"], [[2, 30], [8, 55], [8, 30], [2, 55]])
    for _ in range(2):
        with pytest.raises(DesignError, match="not simple"):
            parse_design(bad, "a.toml")
    moved = _set(copy.deepcopy(good), ["bones", 1, "outline"], [[2, 30], [8, 30], [8, 55], [2, 58]])
    with pytest.raises(DesignError, match="outside|outline"):
        parse_design(_set(moved, ["bones", 1, "outline", 3], [2, 61]), "a.toml")
