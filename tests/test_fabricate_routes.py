"""Cable routes held while the silicone is cast (skelfem.fabricate.routes): the cast line's distance from its
sketch against closed forms, the guide post in the mould, and routes that cannot be held."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from skelfem.cli.main import main
from skelfem.fabricate.routes import ARC_STEP, cast_route, hausdorff

ROOT = Path(__file__).resolve().parents[1]
GEOMETRY = ROOT / "geometry"


@pytest.mark.parametrize("theta_deg", [60.0, 90.0, 135.0, 170.0])
@pytest.mark.parametrize("rho", [0.5, 1.6])
def test_a_line_round_a_post_misses_the_corner_by_rho_times_cosecant_minus_one(theta_deg, rho):
    theta = math.radians(theta_deg)
    d2 = np.array([math.cos(math.pi - theta), math.sin(math.pi - theta), 0.0])   # turning by pi - theta
    sketch = np.array([[-20.0, 0.0, 0.0], [0.0, 0.0, 0.0], 20.0 * d2])
    held = np.array([True, False, True])
    dev, where = hausdorff(sketch, cast_route(sketch, held, {1: rho}), 0.01)
    sag = rho * (1 - math.cos(ARC_STEP / 2))                            # the sampled arc's chords lie inside it
    assert abs(dev - rho * (1 / math.sin(theta / 2) - 1)) <= sag + 1e-9
    assert np.linalg.norm(where) < 1e-9 or dev < 1e-3                   # the corner is the farthest point
    straight, _ = hausdorff(sketch, cast_route(sketch, held, {}), 0.01)
    assert straight == pytest.approx(20 * math.cos(theta / 2), rel=1e-6)   # unheld: the chord


@pytest.fixture(scope="module")
def finger(tmp_path_factory):
    out = tmp_path_factory.mktemp("routes") / "fab"
    assert main(["fabricate", str(GEOMETRY / "finger.toml"), "--out", str(out), "-q", "--no-picture"]) == 0
    return out, json.loads((out / "fabrication.json").read_text())


def test_finger_flexor_cut_its_corner_by_2_9_mm_and_a_post_holds_it_within_0_3(finger):
    """The flexor [3,0] -> [3,78] -> [9,84] runs in silicone until it enters the distal bone (x = 6) at
    (6, 81): held by its spool end and that crossing alone, it lies 3 * 78 / |(3, 81)| off its bend."""
    out, report = finger
    route = report["routes"]["flexor"]
    assert route["unheld_deviation"] == pytest.approx(3 * 78 / math.hypot(3, 81), rel=1e-3)
    (post,) = route["posts"]
    assert post["at"][:2] == [3.0, 78.0] and post["half"] == "bottom" and post["diameter"] == 2.0
    assert post["angle_deg"] == pytest.approx(135.0)
    rho = 1.0 + 0.6                                         # post radius + line radius (its 1.2 mm channel)
    assert route["deviation"] == pytest.approx(rho * (1 / math.sin(math.radians(67.5)) - 1), abs=1e-3 * rho)
    assert route["deviation"] <= 0.3 and report["checks"]["routes_held"] and report["checks"]["passed"]
    # the post: on the bend's inner bisector, rho / sin(theta/2) from the bend, reaching rho past the line
    b = np.array([math.cos(math.radians(-22.5)), math.sin(math.radians(-22.5))])
    axis = np.array([3.0, 78.0]) + b * rho / math.sin(math.radians(67.5))
    (mould_post,) = report["mould"]["posts"]
    assert mould_post["cable"] == "flexor" and mould_post["half"] == "bottom"
    assert mould_post["tip"] == pytest.approx([*axis, 10.0 + rho], abs=1e-6)
    # ... and it is part of the bottom half as printed: the point on its axis at the line's height is solid
    from skelfem.fabricate import read_stl
    from skelfem.fabricate.surfaces import inside, Surface
    pts, tris = read_stl(out / "mould_bottom.stl")
    pose = report["parts"]["mould_bottom"]["print"]
    x = np.array([*axis, 10.0]) @ np.array(pose["rotation"]).T + np.array(pose["translation"])
    assert inside(x, Surface(pts, tris, None), 1e-9)[0]


def test_a_bend_too_sharp_to_hold_is_refused_with_the_cable_and_the_point(tmp_path, capsys):
    out = tmp_path / "sub" / "fab"
    # a bend of 126.3 degrees in silicone, then into the middle bone: round a 2 mm post the line misses the
    # corner by 1.6 (1 / sin(63.1 deg) - 1) = 0.19 mm, and round the thinnest (0.6 mm) by 0.9 x 0.121 =
    # 0.11 mm: both more than a 0.1 mm tolerance (a 1 mm post holds a 133 degree bend within it)
    assert main(["fabricate", str(GEOMETRY / "finger.toml"), "--out", str(out), "-q",
                 "--set", "cables.flexor.path=[[3,0],[3,39.5],[10.5,45]]",
                 "--set", "fabrication.route_tolerance=0.1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and ": cables.flexor.path: cast, its line" in err[0], err
    assert "0.19 mm off its sketch near (3, 39.5, 10)" in err[0] and "fabrication.route_tolerance 0.1 mm" in err[0]
    assert "even round a guide post" in err[0]
    assert not (tmp_path / "sub").exists()


@pytest.mark.parametrize("value", ["0.01", "-1", "1e9"])
def test_a_route_tolerance_out_of_bounds_is_one_error_line(value, tmp_path, capsys):
    assert main(["fabricate", str(GEOMETRY / "finger.toml"), "--out", str(tmp_path / "fab"), "-q",
                 "--set", f"fabrication.route_tolerance={value}"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "fabrication.route_tolerance" in err[0], err


def test_a_sharp_bend_gets_a_post_thin_enough_for_the_tolerance():
    """The same kind of bend at 133.1 degrees: a 2 mm post would hold it 0.14 mm off, more than a 0.1 mm
    tolerance; a 1 mm one (rho 1.1) holds it 1.1 (1 / sin(66.6 deg) - 1) = 0.099 mm off."""
    import gmsh  # noqa: F401 - imported on the main thread (it sets a signal handler)
    from skelfem import fabricate as fab
    from skelfem.design import load_design
    # (lig1_palmar moved off the flexor's way into the middle bone: the two lines would cross in the silicone)
    plan = fab.plan(load_design(GEOMETRY / "finger.toml", ["cables.flexor.path=[[3,0],[3,39.5],[11,47]]",
                                                           "cables.lig1_palmar.path=[[10,34],[10,52]]",
                                                           "fabrication.route_tolerance=0.1"]))
    (post,) = plan.routes["flexor"]["posts"]
    assert post["diameter"] == pytest.approx(1.0) and post["kind"] == "post"
    theta = math.radians(post["angle_deg"])
    assert plan.routes["flexor"]["deviation"] == pytest.approx(1.1 * (1 / math.sin(theta / 2) - 1), abs=2e-3)
    assert plan.routes["flexor"]["deviation"] <= 0.1


def _halves(out, report):
    """solid(points (k, 3) in design coordinates, "mould_bottom" | "mould_top") -> is each in that printed half."""
    from skelfem.fabricate import read_stl
    from skelfem.fabricate.surfaces import inside, Surface
    halves = {}
    for half in ("mould_bottom", "mould_top"):
        pts, tris = read_stl(out / f"{half}.stl")
        pose = report["parts"][half]["print"]
        halves[half] = (Surface(pts, tris, None), np.array(pose["rotation"]), np.array(pose["translation"]))

    def solid(x, half):
        s, R, t = halves[half]
        return inside(np.asarray(x, float) @ R.T + t, s, 1e-9)
    return solid


def test_pry_slots_cut_both_halves_at_the_parting_line(finger):
    """Two round slots across the parting plane on the block's long sides, wall/2 deep: a point on a slot's
    axis is in neither printed half; one a slot's radius and a bit above or below it is in a half."""
    out, report = finger
    slots = report["mould"]["pry_slots"]
    assert len(slots) == 2
    halves = _halves(out, report)

    def solid(x, half):
        return bool(halves(np.asarray(x, float)[None], half)[0])

    for slot in slots:
        a, b, r = np.array(slot["from"]), np.array(slot["to"]), slot["diameter"] / 2
        assert a[2] == b[2] == 10.0 and abs(a[1] - 50.0) < 1e-9          # on the parting plane, mid-side
        mid = a + 0.75 * (b - a)                                         # inside the wall, on the slot's axis
        assert not solid(mid, "mould_bottom") and not solid(mid, "mould_top")
        assert solid(mid - [0, 0, 1.5 * r], "mould_bottom") and solid(mid + [0, 0, 1.5 * r], "mould_top")


def test_clamp_bolt_holes_go_through_both_halves_in_the_wall(finger):
    """Four clamp holes along the normal, two on each long side of the block, centred in its wall band: a
    point on a hole's axis is in neither half, points a millimetre round it are in the half at their height;
    the bolt is the thickest whose hole leaves a millimetre of wall (wall 5 mm: M2.5, 2.9 mm)."""
    out, report = finger
    clamps, wall = report["mould"]["clamps"], report["fabrication"]["wall"]
    assert len(clamps) == 4 and {c["bolt"] for c in clamps} == {"M2.5"} and wall == 5.0
    block = report["mould"]["block"]
    lo, hi = np.array(block["min"]), np.array(block["max"])           # (x, y, z): the frame is the axes here
    solid = _halves(out, report)

    r = clamps[0]["diameter"] / 2
    ring = np.array([[math.cos(a), math.sin(a), 0.0] for a in np.linspace(0, 2 * math.pi, 8, endpoint=False)])
    for c in clamps:
        a = np.array(c["at"])
        assert min(abs(a[0] - lo[0]), abs(a[0] - hi[0])) == pytest.approx(wall / 2)    # mid-wall, long sides
        for half, z in (("mould_bottom", 0.5 * (lo[2] + 10.0)), ("mould_top", 0.5 * (hi[2] + 10.0))):
            x = np.array([a[0], a[1], z])
            assert not solid(x[None], half).any()
            assert solid(x + (r + 0.5) * ring, half).all()
    ys = sorted({round(c["at"][1], 6) for c in clamps})
    assert len(ys) == 2 and ys[1] - ys[0] >= (hi[1] - lo[1]) / 3 - 1e-6


def test_a_wall_too_thin_for_bolts_says_so():
    import gmsh  # noqa: F401 - imported on the main thread (it sets a signal handler)
    from skelfem import fabricate as fab
    from skelfem.design import load_design
    plan = fab.plan(load_design(GEOMETRY / "finger.toml", ["fabrication.wall=4"]))
    assert not [t for t in plan.mould_tools if t.kind == "clamp"]
    assert any("too thin for clamp bolts" in n and "clips" in n for n in plan.notes)
