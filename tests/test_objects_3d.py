"""Free objects in 3D: a cube resting on a pinned block (its weight through the contact, no
interpenetration, a marker on it following it), the incline check (sticks iff tan theta <= mu) with the
friction on the contact's triangles, and the design errors of 3D [[objects]]."""
import math

import numpy as np
import pytest

from skelfem import Session
from skelfem.design import DesignError, parse_design

from _designs import land_and_tilt

G = 9.81
RHO = 1250.0
SIDE = 4.0


def _design(gravity, mu=0.5, side=SIDE, **extra):
    """The block with a cube of this side centred over it, 0.1 mm above it."""
    lo, hi, c = 5.0 - side / 2, 5.0 + side / 2, 4.1 + side / 2
    d = {"format": 1, "name": "cube3d", "dim": 3, "mesh": {"size": 2.0, "degree": 1},
         "materials": {"soft": {"E": 1.0, "nu": 0.3, "density": 1000.0},
                       "pla": {"E": 1000.0, "nu": 0.35, "density": RHO}},
         "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [10, 4, 10]}}], "material": "soft"},
         "pins": [{"name": "base", "region": [[-1, -1, -1], [11, 1e-6, 11]], "kind": "fixed"}],
         "objects": [{"name": "cube", "solids": [{"box": {"min": [lo, 4.1, lo], "max": [hi, 4.1 + side, hi]}}],
                      "material": "pla"}],
         "contact": {"dhat": 0.05, "friction": mu}, "gravity": {"acceleration": gravity},
         "markers": {"on_cube": [5.0, c, 5.0], "corner": [5.0 + 0.375 * side, c + 0.375 * side, 5.0 + 0.375 * side]}}
    d.update(extra)
    return d


def _weight(side=SIDE) -> float:
    return RHO * 1e-9 * G * side ** 3


@pytest.mark.slow
def test_a_cube_rests_on_the_block_clear_of_it_and_carries_its_weight_through_the_contact():
    with Session(_design([0.0, -G, 0.0])) as s:
        r = s.solve()
        assert r.converged, r.status
        d = r.to_dict()
        contact = s.model.term("contacts", "pieces")
        u = s.model.u.x.array
        gap = contact.min_distance(u)
        assert 0.0 < gap < 0.05 and not contact.intersects(u)
    W = _weight()
    cube = d["objects"]["cube"]
    assert cube["weight"] == pytest.approx([0.0, -W, 0.0], abs=1e-12)
    assert len(cube["rotation"]) == 3 and np.linalg.norm(cube["rotation"]) < 1e-3      # a rotation vector
    assert cube["displacement"][1] == pytest.approx(-(0.1 - gap), abs=2e-3)
    (pair,) = d["contacts"]
    assert pair["between"] == ["body", "cube"]
    assert pair["normal_force"][1] == pytest.approx(-W, rel=1e-5)             # the cube presses the block
    assert abs(pair["normal_force"][0]) < 1e-3 * W and abs(pair["normal_force"][2]) < 1e-3 * W
    assert d["markers"]["on_cube"]["position"] == pytest.approx(cube["position"], abs=1e-4)
    R = _rotation(cube["rotation"])
    expected = np.array(cube["position"]) + R @ np.array([1.5, 1.5, 1.5])
    assert np.allclose(d["markers"]["corner"]["position"], expected, atol=1e-4)


def _rotation(w) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(w).as_matrix()


@pytest.mark.slow
@pytest.mark.parametrize("theta, held", [(26.2, True), (27.0, False)])
def test_a_cube_on_the_block_sticks_iff_tan_theta_below_mu(theta, held):
    """mu = 0.5 (atan 0.5 = 26.6 deg): the cube lands under vertical gravity, then gravity tilts in the x-y
    plane (the load path: friction acts from where the cube came to rest). At 26.2 deg the cube stays and
    the friction on the block's triangles carries W sin theta; at 27.0 deg nothing holds it: the
    threshold within 0.4 deg. A 2 mm cube (the threshold does not depend on its size): lost, it must go
    further than its own size before Newton's verdict, which the 4 mm cube did only after three cuts of the
    tilt (95 s to the 2 mm cube's 17 s on a loaded machine)."""
    th = math.radians(theta)
    side = 2.0
    # 30 Newton iterations an attempt (20 are too few to see the cube go)
    _, r = land_and_tilt(_design([0.0, -G, 0.0], side=side, solver={"max_iterations": 30}), theta, G)
    if not held:
        assert r.status == "no equilibrium: object cube is not held"
        return
    assert r.converged, r.status
    out = r.to_dict()
    W = _weight(side)
    (pair,) = out["contacts"]
    assert pair["friction_force"][0] == pytest.approx(W * math.sin(th), rel=1e-3)     # on the block, along +x
    assert pair["normal_force"][1] == pytest.approx(-W * math.cos(th), rel=1e-3)
    assert abs(pair["friction_force"][2]) < 1e-3 * W
    assert pair["min_distance"] > 0
    assert abs(out["objects"]["cube"]["displacement"][0]) < 0.05      # it stays (the block shears a little)


@pytest.mark.parametrize("change, key", [
    (lambda d: d["objects"][0].update(solids=[{"box": {"min": [3, 3, 3], "max": [7, 7, 7]}}]), "objects.cube.solids"),
    (lambda d: d["objects"].append({"name": "b2", "solids": [{"sphere": {"center": [5, 6, 5], "radius": 1}}],
                                    "material": "pla"}), "objects.b2.solids"),
    (lambda d: d["objects"][0].update(outline=[[0, 5], [1, 5], [1, 6]]), "objects.cube.outline"),
    (lambda d: d["objects"][0].pop("solids"), "objects.cube.solids"),
    (lambda d: d["objects"][0].update(solids=[{"sphere": {"center": [5, 9, 5], "radius": -1}}]),
     "objects.cube.solids[0].sphere.radius"),
    (lambda d: d["markers"].update(nowhere=[20.0, 20.0, 20.0]), "markers"),
])
def test_bad_3d_objects_input_is_one_error_naming_the_key(change, key):
    d = _design([0.0, -G, 0.0])
    change(d)
    with pytest.raises(DesignError) as e:
        parse_design(d)
    assert key in str(e.value)


def test_a_marker_on_a_3d_object_is_accepted_and_follows_it():
    design = parse_design(_design([0.0, -G, 0.0]))
    assert design.objects[0].outline is None and design.objects[0].size == pytest.approx(SIDE * math.sqrt(3))
    assert set(design.markers) == {"on_cube", "corner"}


@pytest.mark.slow
def test_a_stiff_elastic_cube_rests_like_a_rigid_one():
    """rigid = false in 3D: with E 1e3 times the block's, where the cube rests, its rotation and the contact
    force are the rigid cube's (gravity ramped over 4 load steps), clear of the block. It lands, and
    sticks, where Newton's first steps take it, with their round-off on its rigid motions (which only the
    tether resists until it touches): 2.2e-4 mm aside, turned by 7e-6 rad."""
    out = []
    for rigid in (True, False):
        d = _design([0.0, -G, 0.0], solver={"steps": 4})
        d["objects"][0]["rigid"] = rigid
        with Session(d) as s:
            r = s.solve()
            assert r.converged, r.status
            contact = s.model.term("contacts", "pieces")
            assert contact.min_distance(s.model.u.x.array) > 0 and not contact.intersects(s.model.u.x.array)
            out.append(r.to_dict())
    a, b = (o["objects"]["cube"] for o in out)
    assert np.allclose(a["position"], b["position"], atol=5e-4)
    assert np.allclose(a["rotation"], b["rotation"], atol=2e-5)
    assert np.allclose(out[0]["contacts"][0]["normal_force"], out[1]["contacts"][0]["normal_force"], rtol=1e-4,
                       atol=1e-9)
    assert out[1]["contacts"][0]["normal_force"][1] == pytest.approx(-_weight(), rel=1e-4)

