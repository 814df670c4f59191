"""Live sets and edits that keep the mesh, for every design section: named lists flatten by name, terms
follow whatever keys changed, a value in another form is an edit (or one DesignError), friction switched on
live holds the state; the floor: every live key of every bundled design, every handle the editor drags."""
import copy
import json
import re
import shutil
import sys
import tomllib

import numpy as np
import pytest
from _hardening import ws_connect, ws_send
from conftest import GEOMETRY, ROOT

from skelfem import Session
from skelfem.design import DesignError, load_design
from skelfem.design.parse import flatten, read_toml
from skelfem.design.spec import SECTIONS_BY_NAME

DESIGNS = sorted(p.name for p in GEOMETRY.glob("*.toml"))
# mesh sizes for the live-key and editor floors (else 4 mm): every key still sets and solves on them, at
# a fraction of the cost (hand 18 s at 6 mm to 32 s at 4; two_fingers3d 8.5 s at 12 mm, one element
# across a finger, to 18 s at 8; two_fingers' live keys 12 s at 6 mm to 18 s at 4, two_finger_roll's handles
# 23 s to 45 s, where one drag's friction fails and is solved again from rest)
COARSE = {"arm3d.toml": 14.0, "finger3d.toml": 6.0, "gripper3d.toml": 6.0, "pillar3d.toml": 5.0,
          "post3d.toml": 4.0, "two_fingers3d.toml": 12.0, "finger_knuckles.toml": 3.0, "finger_knuckles3d.toml": 8.0,
          "hand.toml": 6.0, "gripper.toml": 6.0, "two_fingers.toml": 6.0, "two_finger_roll.toml": 6.0}


def coarse(name: str) -> list:
    return [f"mesh.size={COARSE.get(name, 4.0)}"]


def tip(r, marker="tip"):
    return np.array(r.markers[marker]["position"])


# -- named lists: one path, every section ---------------------------------------------------------------
def test_every_named_list_of_the_contract_flattens_by_name():
    """Every [[section]] the design-file guides show is a named section, and no bundled design flattens
    to a key holding a list of tables (objects and bodies were one un-dotted key)."""
    guide = "".join((ROOT / "docs" / "guide" / page).read_text() for page in ("design-files.md", "objects.md"))
    shown = set(re.findall(r"^#?\s*\[\[(\w+)\]\]", guide, flags=re.M))
    assert {"bodies", "objects"} <= shown and shown <= set(SECTIONS_BY_NAME)
    for name in DESIGNS:
        flat = flatten(load_design(GEOMETRY / name).raw)
        lists = [k for k, v in flat.items() if isinstance(v, (list, tuple)) and v and isinstance(v[0], dict)
                 and not k.endswith(".solids")]
        assert not lists, (name, lists)
        for section in ("objects", "bodies"):
            assert section not in flat


@pytest.mark.slow
def test_set_of_objects_and_bodies_keys_keeps_the_mesh():
    """objects.NAME.rigid / .material and bodies.NAME.material are set on the kept mesh (they raised a bare
    IndexError), and a drag of an object or a body vertex moves the mesh's nodes."""
    with Session(GEOMETRY / "gripper.toml", ["mesh.size=6"]) as s:
        assert s.solve().converged
        mesh = s.model.mesh
        s.set({"objects.box.material": "pla"})
        assert s.model.mesh is mesh and s.solve().converged
        s.set({"objects.box.rigid": False})       # an elastic box that nothing holds: a singular start warm
        assert s.model.mesh is mesh and s.solve().status
        s.set({"objects.box.rigid": True})
        assert s.model.mesh is mesh and s.solve().converged
        d = s.design.raw
        d["objects"][0]["outline"][0][0] += 0.5
        assert s.edit(d, morph=True) == "moved nodes" and s.model.mesh is mesh
        assert s.solve().converged
    with Session(GEOMETRY / "two_fingers.toml", ["mesh.size=6"]) as s:
        assert s.solve().converged
        mesh = s.model.mesh
        s.set({"bodies.left.material": "dragonskin"})
        r = s.solve()
        assert s.model.mesh is mesh and r.converged
        d = s.design.raw
        d["bodies"][0]["outline"][1][0] -= 0.3
        assert s.edit(d, morph=True) == "moved nodes" and s.solve().converged


def test_a_renamed_region_is_meshed_again():
    """Same polygons under another name: the mesh's regions are tagged by name, so it re-meshes."""
    with Session(GEOMETRY / "gripper.toml", ["mesh.size=6"]) as s:
        assert s.solve().converged
        d = s.design.raw
        d["objects"][0]["name"] = "crate"
        assert s.edit(d) == "re-meshed" and s.solve().converged


def test_a_value_in_another_form_is_an_edit_or_one_design_error():
    """cables.NAME.friction as a by-material table (documented) is taken by building the cable anew (a bare
    TypeError before); a value of the wrong type is one DesignError naming the key."""
    with Session(GEOMETRY / "finger.toml", ["mesh.size=4"]) as s:
        assert s.solve().converged
        mesh = s.model.mesh
        s.set({"cables.flexor.friction": {"ecoflex": 0.1}})
        r = s.solve()
        assert r.converged and s.model.mesh is mesh
        assert r.cables["flexor"]["friction"] == {"ecoflex": 0.1}
        for changes in ({"cables.flexor.contraction": {"ecoflex": 1.0}}, {"cables.flexor.contraction": "7"},
                        {"cables.flexor.contraction": [1.0, 2.0]}, {"materials.pla.E": None},
                        {"cables.flexor.contraction": object()}, {"gravity.acceleration": 9.81}):
            key = next(iter(changes))
            with pytest.raises(DesignError) as e:
                s.set(changes)
            assert key in str(e.value) and "\n" not in str(e.value)
        for changes in ({3: 1.0}, {"": 1.0}):
            with pytest.raises(DesignError):
                s.set(changes)
        assert s.solve().converged


# -- friction switched on live ------------------------------------------------------------------------------
@pytest.mark.slow
def test_cable_friction_switched_on_from_zero_holds_the_state():
    """Switched on at a loaded state, friction holds it (the cable had slid freely there): the tip moved
    2.3 mm before (the history read as stuck since rest). The later path is the limit of a vanishing
    coefficient before the switch, and the result says friction depends on the path."""
    ends = []
    for mu0 in (0.0, 1e-6):
        with Session(GEOMETRY / "finger_friction.toml", ["mesh.size=4", f"cables.flexor.friction={mu0}"]) as s:
            before = tip(s.solve())
            s.set({"cables.flexor.friction": 0.3})
            r = s.solve()
            assert r.converged and np.linalg.norm(tip(r) - before) < 1e-6
            if mu0 == 0.0:
                assert any("cables.flexor.friction" in w for w in r.to_dict()["warnings"])
            s.set({"cables.flexor.contraction": 4.0})
            r = s.solve()
            assert r.converged and "warnings" not in r.to_dict()
            ends.append(tip(r))
    assert np.linalg.norm(ends[0] - ends[1]) < 1e-4


def test_ground_friction_switched_on_from_zero_holds_the_state():
    """A block pulled 0.3 mm along a frictionless floor: friction switched on holds it where it is (its
    anchors were at rest: it was pulled back 0.05 mm)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from test_friction import block
    with Session(block(mu=0.0, kp=1.0, steps=1, size=2.0)) as s:
        assert s.solve().converged
        s.set({"pins.pull.move": [0.3, 0.0]})
        before = tip(s.solve(), "c")
        s.set({"grounds.floor.friction": 0.5})
        r = s.solve()
        assert r.converged and np.linalg.norm(tip(r, "c") - before) < 1e-6
        assert any("grounds.floor.friction" in w for w in r.to_dict()["warnings"])


# -- the floor: every live key of every bundled design --------------------------------------------------
def perturbed(value):
    """A small change of a live parameter's value: 2 % less, or a little more than 0."""
    a = np.asarray(value, dtype=float)
    b = np.where(a != 0.0, 0.98 * a, 0.01)
    return float(b) if a.ndim == 0 else b.tolist()


@pytest.mark.slow
@pytest.mark.parametrize("name", DESIGNS)
def test_every_live_key_of_every_bundled_design(name):
    """Each parameter the Session exposes as live, changed a little through Session.set (one DesignError or
    nothing), then a warm solve after each section's keys: converged, or a failure the result reports."""
    with Session(GEOMETRY / name, coarse(name)) as s:
        assert s.solve().converged
        live = s.model.parameters()
        assert live
        groups = {}
        for key in sorted(live):                 # one warm solve per section: every key set on its own
            groups.setdefault(key.split(".", 1)[0], []).append(key)
        for section, keys in groups.items():
            for key in keys:
                try:
                    s.set({key: perturbed(live[key])})
                except DesignError as exc:
                    assert "\n" not in str(exc)
            r = s.solve()
            assert r.converged or r.status, section


# -- the floor: every handle the editor drags ------------------------------------------------------------
def handles(d: dict) -> list:
    """(what, path into the design, move) of every handle the 2D editor page draws (editor.js drawSketch):
    vertices of bodies, holes, bones, objects and cables, whole objects and pin boxes, loads, grounds,
    markers."""
    out = []

    def polygon(path, pts):
        for i in range(len(pts)):
            out.append(("vertex", path + [i]))

    if "body" in d:
        polygon(["body", "outline"], d["body"]["outline"])
        for k, h in enumerate(d["body"].get("holes", [])):
            polygon(["body", "holes", k], h)
    for k, b in enumerate(d.get("bodies", [])):
        polygon(["bodies", k, "outline"], b["outline"])
        for j, h in enumerate(b.get("holes", [])):
            polygon(["bodies", k, "holes", j], h)
    for section in ("bones", "objects"):
        for k, b in enumerate(d.get(section, [])):
            polygon([section, k, "outline"], b["outline"])
    for k, o in enumerate(d.get("objects", [])):
        out.append(("box", ["objects", k, "outline"]))
    for k, c in enumerate(d.get("cables", [])):
        polygon(["cables", k, "path"], c["path"])
    for k, _ in enumerate(d.get("pins", [])):
        out.append(("box", ["pins", k, "region"]))
    for k, _ in enumerate(d.get("loads", [])):
        out.append(("point", ["loads", k, "at"]))
    for k, _ in enumerate(d.get("grounds", [])):
        out.append(("point", ["grounds", k, "point"]))
    for name in d.get("markers", {}):
        out.append(("point", ["markers", name]))
    return out


def dragged(d: dict, what: str, path: list, delta=(0.1, -0.1)) -> dict:
    """d with one handle moved by delta mm, as the page's onMove does."""
    d = copy.deepcopy(d)
    node = d
    for p in path[:-1]:
        node = node[p]
    last = path[-1]
    if what == "box":
        node[last] = [[c[0] + delta[0], c[1] + delta[1]] for c in node[last]]
    else:
        node[last] = [node[last][0] + delta[0], node[last][1] + delta[1]]
    return d


def ws_message(s) -> bytes:
    """One whole text message from the server: its frames up to FIN; pings answered."""
    import struct

    def exact(n):
        data = b""
        while len(data) < n:
            chunk = s.recv(n - len(data))
            if not chunk:
                raise ConnectionError("closed")
            data += chunk
        return data
    message = b""
    while True:
        b0, b1 = exact(2)
        n = b1 & 0x7F
        if n == 126:
            n = struct.unpack(">H", exact(2))[0]
        elif n == 127:
            n = struct.unpack(">Q", exact(8))[0]
        payload = exact(n)
        if b0 & 0x0F == 9:                    # a ping: answered, or the server closes the connection
            ws_send(s, payload, opcode=10)
            continue
        if b0 & 0x0F >= 8:                    # pong, close
            continue
        message += payload
        if b0 & 0x80:
            return message


TWO_D = [n for n in DESIGNS if tomllib.loads((GEOMETRY / n).read_text()).get("dim", 2) == 2]


@pytest.mark.slow
@pytest.mark.parametrize("name", TWO_D)
def test_every_editor_handle_through_the_draft_api(name, tmp_path):
    """Each handle dragged a little over the websocket (draft solves, as while dragging), then let go (a
    solve without draft): every answer is a result (converged or not) or a 422 naming a key, never a 500."""
    from skelfem.editor.server import Editor
    d = read_toml(GEOMETRY / name)
    d.setdefault("mesh", {})["size"] = COARSE.get(name, 4.0)
    shutil.copy(GEOMETRY / name, tmp_path / name)
    ed = Editor(tmp_path / name, port=0).start()
    try:
        s = ws_connect(ed.port)
        moves = [(True, dragged(d, what, where)) for what, where in handles(d)]
        for mid, (draft, design) in enumerate([(False, d)] + moves + [(False, moves[-1][1])]):
            ws_send(s, json.dumps({"id": mid, "kind": "solve", "design": design, "draft": draft}).encode())
            reply = json.loads(ws_message(s))
            assert reply["id"] == mid
            assert reply.get("ok") or (reply.get("status") == 422 and reply["key"]), (mid, reply)
            assert not reply.get("ok") or "converged" in reply["answer"]
        s.close()
    finally:
        ed.stop()
