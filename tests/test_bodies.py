"""Several soft bodies in one design ([[bodies]]): parsing, regions and materials, contact between bodies
(each body in equilibrium with its own pins, loads and contacts), and the one-line errors."""
import copy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from skelfem.design import DesignError, parse_design
from skelfem.session import Session

ROOT = Path(__file__).resolve().parents[1]


def _two(gap=0.25, push=0.02, mu=0.5, E=(0.1, 0.4), size=2.0, load_on="left"):
    """Two strips side by side, each pinned at its base; a load at the top of one pushes it sideways."""
    w, L = 10.0, 40.0
    x1 = w + gap
    d = {
        "format": 1, "name": "two", "dim": 2, "thickness": 10.0, "mesh": {"size": size},
        "materials": {"a": {"E": E[0], "nu": 0.45}, "b": {"E": E[1], "nu": 0.45},
                      "hard": {"E": 1000.0, "nu": 0.35}},
        "bodies": [{"name": "left", "outline": [[0, 0], [w, 0], [w, L], [0, L]], "material": "a"},
                   {"name": "right", "outline": [[x1, 0], [x1 + w, 0], [x1 + w, L], [x1, L]], "material": "b"}],
        "bones": [{"name": "rb", "outline": [[x1 + 3, 10], [x1 + 7, 10], [x1 + 7, 25], [x1 + 3, 25]],
                   "material": "hard"}],
        "pins": [{"name": "left_base", "region": [[-1, -1], [w + 0.1, 1e-6]]},
                 {"name": "right_base", "region": [[x1 - 0.1, -1], [x1 + w + 1, 1e-6]]}],
        "loads": [{"name": "push", "at": [0.0, 35.0] if load_on == "left" else [x1 + w, 35.0],
                   "force": [push if load_on == "left" else -push, 0.0]}],
        "contact": {"dhat": 0.2, "friction": mu},
        "markers": {"left_top": [w / 2, L], "right_top": [x1 + w / 2, L]},
    }
    return d


def _pins_in(design, body):
    from skelfem.design import polygons
    out = []
    for p in design.pins:
        (x0, y0), (x1, y1) = p.region
        box = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
        if polygons.overlap(body.outline, box, 1e-9):
            out.append(p.name)
    return out


def _balance(result, design):
    """For each body: the sum of its pins' reactions, its loads and the contact forces on it (N)."""
    out = {}
    for body in design.bodies:
        total = np.zeros(2)
        for name in _pins_in(design, body):
            total += result.pins[name]["reaction"]
        for ld in design.loads:
            from skelfem.design import polygons
            if polygons.contains(body.outline, ld.at[None], 1e-9)[0]:
                total += ld.force
        for c in result.contacts:
            a, b = c["between"]
            f = np.asarray(c.get("normal_force", np.zeros(2))) + np.asarray(c.get("friction_force", np.zeros(2)))
            if a == body.name:
                total += f
            elif b == body.name:
                total -= f
        out[body.name] = total
    return out


@pytest.mark.parametrize("load_on, mu", [("left", 0.5), ("right", 0.0), ("right", 1.5)])
def test_each_body_is_in_equilibrium_with_its_pins_loads_and_contacts(load_on, mu):
    design = parse_design(_two(push=0.03, mu=mu, load_on=load_on))
    s = Session(design)
    r = s.solve()
    assert r.converged
    pair = next(c for c in r.contacts if c["between"] == ["left", "right"])
    N = float(np.linalg.norm(pair["normal_force"]))
    assert N > 0.002                                    # the bodies press on each other ...
    assert pair["min_distance"] > 0                     # ... and never interpenetrate
    for name, total in _balance(r, design).items():
        assert np.linalg.norm(total) <= 1e-6 * 0.03, (name, total)
    # the pushed body bends into the other one, which takes part of the load through the contact
    pushed, other = ("left", "right") if load_on == "left" else ("right", "left")
    reaction = np.asarray(r.pins[f"{other}_base"]["reaction"])
    assert 0.1 * 0.03 < abs(reaction[0]) < 0.03
    s.close()


def test_a_corner_sliding_on_a_face_rubs_with_all_of_mu_n():
    """The left strip's top corner presses on the right strip's face and slides: |friction| = mu N."""
    mu = 0.5
    s = Session(parse_design(_two(mu=mu)))
    r = s.solve()
    pair = next(c for c in r.contacts if c["between"] == ["left", "right"])
    assert pair["sticking"] == 0.0
    f, N = np.linalg.norm(pair["friction_force"]), pair["normal_magnitude"]
    assert f == pytest.approx(mu * N, rel=0.02)
    s.close()


def test_each_body_has_its_own_material():
    """Two equal strips apart, the same load on each: the stiffer one (E 4x) moves 4x less (small loads)."""
    d = _two(gap=5.0, push=0.0005, E=(0.1, 0.4))
    del d["bones"]
    d["loads"] = [{"name": "a", "at": [0.0, 35.0], "force": [0.0005, 0.0]},
                  {"name": "b", "at": [15.0, 35.0], "force": [0.0005, 0.0]}]
    s = Session(parse_design(d))
    r = s.solve()
    ua = r.markers["left_top"]["displacement"][0]
    ub = r.markers["right_top"]["displacement"][0]
    assert ua / ub == pytest.approx(4.0, rel=0.01)
    assert not r.contacts                        # 5 mm apart: nothing touches
    s.close()


def test_one_entry_of_bodies_is_the_same_as_body():
    from _designs import strip
    d = strip(contraction=1.0, bones=True)
    body = d.pop("body")
    d1 = copy.deepcopy(d)
    d1["body"] = body
    d2 = copy.deepcopy(d)
    d2["bodies"] = [dict(body, name="finger")]
    a, b = Session(parse_design(d1)), Session(parse_design(d2))
    ra, rb = a.solve(), b.solve()
    assert ra.dofs == rb.dofs
    assert np.allclose(ra.markers["tip"]["position"], rb.markers["tip"]["position"], atol=1e-10)
    assert "body:finger" in b.model.tm.tags and "body" in a.model.tm.tags
    a.close(), b.close()


def test_bones_belong_to_the_body_around_them():
    s = Session(parse_design(_two()))
    tm = s.model.tm
    cells = tm.cell_tags
    assert set(tm.tags) == {"body:left", "body:right", "bone:rb"}
    x = s.model.mesh.geometry.x[:, 0]
    dofmap = s.model.mesh.geometry.dofmap.array.reshape(-1, 3)
    mid = x[dofmap].mean(axis=1)
    for name in tm.tags:
        ids = cells.indices[cells.values == tm.tags[name]]
        assert len(ids)
        if name == "body:left":
            assert mid[ids].max() < 10.0
        else:
            assert mid[ids].min() > 10.25
    s.close()


@pytest.mark.parametrize("change, key", [
    ({"body": {"outline": [[0, 0], [1, 0], [1, 1]], "material": "a"}}, "bodies: give either"),
    ({"bodies.1.outline": [[5, 0], [15, 0], [15, 40], [5, 40]]}, "bodies.right.outline: overlaps or touches body 'left'"),
    ({"bodies.1.outline": [[10, 0], [20, 0], [20, 40], [10, 40]]}, "bodies.right.outline: overlaps or touches body 'left'"),
    ({"bones.0.outline": [[30, 10], [32, 10], [32, 12], [30, 12]]}, "bones.rb.outline: a bone must lie strictly inside one body"),
    ({"bones.0.outline": [[9, 10], [13, 10], [13, 12], [9, 12]]}, "bones.rb.outline"),
    ({"pins": [{"name": "left_base", "region": [[-1, -1], [10.1, 1e-6]]}]}, "bodies.right: nothing holds this body"),
    ({"dim": 3, "thickness": None}, "bodies.left.solids: missing (required)"),     # 3D bodies are solids
    ({"bodies.0.material": "steel"}, "bodies.left.material: unknown material"),
    ({"solver": {"line_search": "residual"}}, "solver.line_search"),
])
def test_bad_bodies_are_one_error_naming_the_key(change, key):
    d = _two()
    for k, v in change.items():
        if "." in k:
            section, index, field = k.split(".")
            d[section][int(index)][field] = v
        elif v is None:
            d.pop(k)
        else:
            d[k] = v
    with pytest.raises(DesignError) as e:
        parse_design(d, "two.toml")
    assert key in str(e.value) and "\n" not in str(e.value)


def test_the_bundled_two_fingers_press_on_each_other(tmp_path):
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "skelfem", "simulate", str(ROOT / "geometry" / "two_fingers.toml"),
                        "--out", str(out), "-q", "--set", "mesh.size=3"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    import json
    data = json.loads((out / "result.json").read_text())
    pair = next(c for c in data["contacts"] if c["between"] == ["left", "right"])
    assert np.linalg.norm(pair["normal_force"]) > 0.1 and pair["min_distance"] > 0
    # the tendons pull inside each finger: each pin holds exactly what the other finger pushes
    f = np.asarray(pair["normal_force"]) + np.asarray(pair["friction_force"])
    assert np.allclose(np.asarray(data["pins"]["left_base"]["reaction"]), -f, atol=1e-6)
    assert np.allclose(np.asarray(data["pins"]["right_base"]["reaction"]), f, atol=1e-6)


def test_objects_among_bodies_touch_the_body_they_lie_on():
    """A box resting on the right strip (gravity on): the pair (right, box) carries its weight, the left
    strip and the box do not touch, and each body is still in equilibrium."""
    d = _two(push=0.0)
    for m in d["materials"].values():
        m["density"] = 1000.0
    d["objects"] = [{"name": "box", "outline": [[12, 40.3], [19, 40.3], [19, 43], [12, 43]], "material": "hard"}]
    d["gravity"] = {"acceleration": [0.0, -9.81]}
    del d["loads"]
    design = parse_design(d)
    with Session(design) as s:
        r = s.solve()
        assert r.converged, r.status
        pairs = {tuple(c["between"]): c for c in r.contacts}
    W = 1000e-9 * 9.81 * 7 * 2.7 * 10
    assert ("right", "box") in pairs and ("left", "box") not in pairs
    assert pairs["right", "box"]["normal_force"][1] == pytest.approx(-W, rel=1e-4)
    assert r.objects["box"]["weight"][1] == pytest.approx(-W)


def test_solution_xdmf_holds_the_contact_forces_and_tractions(tmp_path):
    """contact_force sums to the pair's force on each body (and to zero over both); the traction times
    the nodes' boundary shares gives the force back."""
    import meshio

    from skelfem.io.xdmf import write_xdmf
    for degree in (1, 2):
        d = _two()
        d["mesh"]["degree"] = degree
        with Session(parse_design(d)) as s:
            r = s.solve()
            write_xdmf(tmp_path / "s.xdmf", s.model)
            x_mid = 10.125
        pair = next(c for c in r.contacts if c["between"] == ["left", "right"])
        f_left = np.asarray(pair["normal_force"]) + np.asarray(pair["friction_force"])
        m = meshio.read(tmp_path / "s.xdmf")
        F = m.point_data["contact_force"][:, :2]
        left = m.points[:, 0] < x_mid
        assert np.abs(F).max() > 0
        assert np.allclose(F[left].sum(axis=0), f_left, atol=1e-9 + 1e-6 * np.linalg.norm(f_left))
        assert np.allclose(F.sum(axis=0), 0.0, atol=1e-9 + 1e-6 * np.linalg.norm(f_left))
        T = m.point_data["contact_traction"][:, :2]
        assert np.all((np.linalg.norm(T, axis=1) > 0) == (np.linalg.norm(F, axis=1) > 0))
        ratio = np.linalg.norm(F, axis=1)[np.linalg.norm(F, axis=1) > 0] / \
            np.linalg.norm(T, axis=1)[np.linalg.norm(F, axis=1) > 0] / 10.0     # share of the boundary, mm
        assert np.all(ratio > 0.2) and np.all(ratio < 2.5 * 2.0)               # about the mesh size


def test_a_frictional_design_on_a_finer_mesh_solves_its_load_path_again():
    """Friction's history lives on the old boundary: the same outlines re-meshed (a --tol ladder's next
    level) start from rest; an edited outline starts from the carried-over state."""
    d = _two(mu=0.5)
    with Session(parse_design(d)) as s:
        assert s.solve().converged
        s.edit(parse_design(dict(d, mesh={"size": 1.5})))
        assert not s.solved                                   # cold: the load path from rest
        r = s.solve()
        assert r.converged and r.contacts
        d2 = copy.deepcopy(d)
        d2["mesh"] = {"size": 1.5}
        d2["bodies"][1]["outline"][2][0] += 1.0              # the right strip's top corner moves out
        s.edit(parse_design(d2))
        assert s.solved                                       # warm: the carried-over state
        assert s.solve().converged


@pytest.mark.parametrize("change, key", [
    (lambda d: d.update(bodies=[]), "bodies: at least one entry"),
    (lambda d: d.update(bodies=[1, 2]), "bodies: must be an array of tables"),
    (lambda d: d["bodies"][1].update(name="left"), "bodies.left.name: duplicate name"),
    (lambda d: d["bodies"][1].update(colour="red"), "bodies.right.colour: unknown key"),
    (lambda d: d["bodies"][1].update(outline=[[float("nan"), 0], [1, 0], [1, 1]]), "bodies.right.outline: must be finite"),
    (lambda d: d["bodies"][1].update(outline=[[2, 2], [4, 2], [4, 4], [2, 4]]), "bodies.right.outline: overlaps"),
    (lambda d: d.update(objects=[{"name": "o", "outline": [[12, 5], [14, 5], [14, 7]], "material": "hard"}]),
     "objects.o.outline: overlaps the body"),
    (lambda d: d.update(grounds=[{"name": "g", "point": [15, 0], "normal": [-1, 0], "stiffness": 1.0}]),
     "grounds.g.point: the plane cuts the body"),
    (lambda d: d.update(markers={"m": [10.1, 5]}), "markers.m: the marker lies outside"),
    (lambda d: d.update(cables=[{"name": "c", "kind": "tendon", "path": [[5, 5], [15, 5]], "stiffness": 1.0}]),
     "cables.c.path: the cable leaves the body"),
])
def test_every_section_checks_itself_against_every_body(change, key):
    """The sections that look at the body look at all of them: objects, grounds, markers and cables."""
    d = _two()
    change(d)
    with pytest.raises(DesignError) as e:
        parse_design(d, "two.toml")
    assert key in str(e.value) and "\n" not in str(e.value), str(e.value)
