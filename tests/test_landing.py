"""Objects that land: a free object placed a gap above its support settles onto it in one static solve.

The object falls along the load until its contact forms, and the contact holds from that moment (stuck
until the lag gives its normal force): it stays where it touched if the load's tangential share is
below mu, and is reported not held otherwise, whatever the gap and the number of load steps. The slope
is a flat ground under gravity tilted by theta; the body (a pinned block) stands far away.
"""
import json
import math
import subprocess
import sys

import pytest

from skelfem import Session

from _designs import toml_text

G, RHO = 9.81, 1250.0
MATERIALS = {"soft": {"E": 1.0, "nu": 0.3, "density": 1000.0}, "pla": {"E": 1000.0, "nu": 0.35, "density": RHO}}


def _gravity(theta: float, dim: int) -> list:
    th = math.radians(theta)
    return [G * math.sin(th), -G * math.cos(th)] + [0.0] * (dim - 2)


def slope_2d(gap: float, theta: float, mu: float = 0.5, **extra) -> dict:
    """A 6 x 3 mm box (slab 10 mm) `gap` above a ground through y = 0, gravity tilted by theta along +x."""
    d = {"format": 1, "name": "landing", "dim": 2, "thickness": 10.0, "mesh": {"size": 1.0, "degree": 1},
         "materials": MATERIALS,
         "body": {"outline": [[0, 0], [10, 0], [10, 10], [0, 10]], "material": "soft"},
         "pins": [{"name": "base", "region": [[-1, -1], [11, 1e-6]], "kind": "fixed"}],
         "objects": [{"name": "box", "outline": [[20, gap], [26, gap], [26, 3 + gap], [20, 3 + gap]],
                      "material": "pla"}],
         "grounds": [{"name": "floor", "point": [0, 0], "normal": [0, 1], "stiffness": 100.0}],
         "gravity": {"acceleration": _gravity(theta, 2)}, "contact": {"dhat": 0.2}}
    if mu:
        d["grounds"][0]["friction"] = mu
    d.update(extra)
    return d


def slope_3d(gap: float, theta: float, mu: float = 0.5) -> dict:
    """A 4 mm cube `gap` above a ground through y = 0, gravity tilted by theta along +x."""
    d = {"format": 1, "name": "landing3d", "dim": 3, "mesh": {"size": 2.0, "degree": 1}, "materials": MATERIALS,
         "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [4, 4, 4]}}], "material": "soft"},
         "pins": [{"name": "base", "region": [[-1, -1, -1], [5, 1e-6, 5]], "kind": "fixed"}],
         "objects": [{"name": "cube", "solids": [{"box": {"min": [10, gap, 0], "max": [14, 4 + gap, 4]}}],
                      "material": "pla"}],
         "grounds": [{"name": "floor", "point": [0, 0, 0], "normal": [0, 1, 0], "stiffness": 100.0}],
         "gravity": {"acceleration": _gravity(theta, 3)}}
    if mu:
        d["grounds"][0]["friction"] = mu
    return d


def _solve(d: dict):
    with Session(d) as s:
        r = s.solve()
        return r, r.to_dict() if r.converged else None


def _lands_and_sticks(r, out, name: str, gap: float, theta: float, weight: float) -> None:
    """Converged; the piece moved down by the gap and along the slope by less than its fall along the
    load (gap tan theta) + 1e-3 mm; the ground's friction carries the tangential load."""
    assert r.converged, r.status
    disp = out["objects"][name]["displacement"]
    assert disp[1] == pytest.approx(-gap, abs=1e-3)
    assert abs(disp[0]) < gap * math.tan(math.radians(theta)) + 1e-3
    floor = out["grounds"]["floor"]
    assert floor["friction_force"][0] == pytest.approx(weight * math.sin(math.radians(theta)), rel=1e-3)


W_BOX = RHO * 1e-9 * G * 6 * 3 * 10
W_CUBE = RHO * 1e-9 * G * 4 ** 3


@pytest.mark.parametrize("gap", [0.01, 0.05, 0.5])
def test_a_box_placed_above_a_20_degree_slope_lands_and_sticks(gap):
    """mu = 0.5 (atan 0.5 = 26.6 deg): from each gap the box lands where its fall along gravity meets the
    slope and stays there (before, every load step failed after 100 Newton iterations: the box slid
    along the slope, which only its tether resists, before its contact carried a normal force)."""
    r, out = _solve(slope_2d(gap, 20.0))
    _lands_and_sticks(r, out, "box", gap, 20.0, W_BOX)
    assert r.report.newton_iterations <= 30


def test_the_landing_does_not_depend_on_the_load_steps():
    """The same box from 0.05 mm in 1 and 4 load steps: the same place (to 1e-5 mm)."""
    places = []
    for steps in (1, 4):
        r, out = _solve(slope_2d(0.05, 20.0, solver={"steps": steps}))
        assert r.converged, r.status
        places.append(out["objects"]["box"]["displacement"])
    assert places[0] == pytest.approx(places[1], abs=1e-5)


@pytest.mark.parametrize("gap, steps", [(0.01, 1), (0.5, 4)])
def test_a_box_placed_above_a_35_degree_slope_is_not_held(gap, steps):
    """tan 35 = 0.70 > mu: not held, from any gap and in any number of load steps."""
    r, _ = _solve(slope_2d(gap, 35.0, solver={"steps": steps}))
    assert r.status == "no equilibrium: object box is not held"


def test_not_held_from_a_gap_is_exit_2_with_the_reason(tmp_path):
    path = tmp_path / "slope.toml"
    path.write_text(toml_text(slope_2d(0.05, 35.0)))
    run = subprocess.run([sys.executable, "-m", "skelfem", "simulate", str(path), "--out", str(tmp_path / "out"),
                          "--no-picture", "-q"], capture_output=True, text=True)
    assert run.returncode == 2, run.stderr
    assert "no equilibrium: object box is not held" in run.stderr and "Traceback" not in run.stderr
    assert json.loads((tmp_path / "out" / "result.json").read_text())["converged"] is False


def test_a_box_dropped_1_mm_onto_a_frictionless_ground_lands():
    r, out = _solve(slope_2d(1.0, 0.0, mu=0.0))
    assert r.converged, r.status
    assert out["objects"]["box"]["displacement"][1] == pytest.approx(-1.0, abs=1e-3)
    assert out["grounds"]["floor"]["force"][1] == pytest.approx(-W_BOX, rel=1e-5)   # the tether: 5e-7


def test_a_box_placed_above_the_soft_block_under_tilted_gravity_lands_and_is_held():
    """The load path of a grasp's test (land first, then tilt) is no longer needed: a box 0.5 mm above the
    soft block, gravity tilted 17 deg, mu = 1, is held from rest (before: `not held` after 50 Newton
    iterations, the box sliding off before its contacts carried a normal force), in 1 and 4 load steps;
    the block carries its weight through the contact."""
    for steps in (1, 4):
        d = slope_2d(0.5, 17.0, mu=0.0, solver={"steps": steps}, contact={"dhat": 0.2, "friction": 1.0})
        d["objects"][0]["outline"] = [[2, 10.5], [8, 10.5], [8, 13.5], [2, 13.5]]
        d.pop("grounds")
        r, out = _solve(d)
        assert r.converged, r.status
        assert r.report.newton_iterations <= 40
        (pair,) = out["contacts"]
        assert pair["between"] == ["body", "box"]
        total = [a + b for a, b in zip(pair["normal_force"], pair["friction_force"])]
        assert total == pytest.approx([W_BOX * math.sin(math.radians(17)), -W_BOX * math.cos(math.radians(17))],
                                      rel=1e-5)


def test_a_cube_placed_above_a_tilted_3d_ground_lands_and_sticks_or_is_not_held():
    """3D: from 0.05 mm a cube lands and sticks at 20 deg (before: 152 Newton iterations) and is not held
    at 35 deg; dropped 1 mm onto a frictionless ground it lands."""
    r, out = _solve(slope_3d(0.05, 20.0))
    _lands_and_sticks(r, out, "cube", 0.05, 20.0, W_CUBE)
    assert abs(out["objects"]["cube"]["displacement"][2]) < 1e-6
    assert r.report.newton_iterations <= 30
    r, _ = _solve(slope_3d(0.05, 35.0))
    assert r.status == "no equilibrium: object cube is not held"
    r, out = _solve(slope_3d(1.0, 0.0, mu=0.0))
    assert r.converged, r.status
    assert out["objects"]["cube"]["displacement"][1] == pytest.approx(-1.0, abs=1e-3)


def test_a_cube_placed_above_the_soft_block_under_tilted_gravity_lands_and_is_held():
    """3D: a cube 0.1 mm above the pinned block, gravity tilted 20 deg, mu = 0.5 on the block: held from
    rest (before: `not held`)."""
    d = slope_3d(0.1, 20.0, mu=0.0)
    d["body"]["solids"] = [{"box": {"min": [0, 0, 0], "max": [10, 4, 10]}}]
    d["pins"][0]["region"] = [[-1, -1, -1], [11, 1e-6, 11]]
    d["objects"][0]["solids"] = [{"box": {"min": [3, 4.1, 3], "max": [7, 8.1, 7]}}]
    d["contact"] = {"dhat": 0.05, "friction": 0.5}
    d.pop("grounds")
    r, out = _solve(d)
    assert r.converged, r.status
    assert abs(out["objects"]["cube"]["displacement"][0]) < 0.05     # the block shears a little
    (pair,) = out["contacts"]
    assert pair["friction_force"][0] + pair["normal_force"][0] == pytest.approx(
        W_CUBE * math.sin(math.radians(20)), rel=1e-4)
