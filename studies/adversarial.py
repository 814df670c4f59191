"""An adversarial pass over objects, bodies, friction, calibration, stages and the editor's object handles.

Each probe is one design, command line or request, sent as a new user or a
hostile client would, with the class of answer the contract allows:

* ``ok``: exit 0 (HTTP 200) with a sane result (result.json or
  calibration.json strict JSON, every number finite);
* ``bad_input``: exit 1 with exactly one ``error:`` line and nothing written
  (HTTP 400/409/413/415/422 with ``{"error", "key"}``);
* ``failed``: exit 2 with its reason (an ``error:`` line, result.json's
  ``status``);
* ``interrupted``: a SIGINT sent after a delay ends the command within
  2 s with one ``error: interrupted`` line and 130.

Every command runs in a sandbox (the design in ``in/``, the working folder
``a/b/c``, ``TMPDIR`` inside it) with a timeout (a hang is a finding); the
whole sandbox is listed before and after, and anything new outside the
output folder is a finding, as is a traceback, exit 3, or an answer outside
the probe's classes. The editor's probes post to a live ``skelfem edit``
server (``/api/solve``, ``/api/save``, and draft solves over ``/api/live``,
as the page sends them while an object or a body vertex is dragged); after
each the server must still answer, and at the end SIGINT must stop it within
2 s, during a solve too.

``[[stages]]`` is probed only when the design format has it (it is skipped,
and the JSON says so, otherwise).

run(**params) returns the results; main(argv) also writes them to
studies/output/adversarial.json (docs/guide/robustness.md shows its table).

    python studies/adversarial.py [--only GROUP ...] [--limit N] [--out FILE]
    python studies/adversarial.py --merge PART.json ... [--out FILE]     # runs over disjoint groups
"""
from __future__ import annotations

import argparse
import asyncio
import copy
import http.client
import json
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GEOMETRY = ROOT / "geometry"
OUT = ROOT / "studies" / "output" / "adversarial.json"
SKELFEM = str(Path(sys.executable).parent / "skelfem")
ENV = {**os.environ, "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
       "OMPI_MCA_rmaps_base_oversubscribe": "1", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
       "MPLBACKEND": "Agg"}
SIGNAL_DEADLINE = 2.0               # s from a SIGINT to the process's end
EXIT_CLASS = {0: "ok", 1: "bad_input", 2: "failed", 130: "interrupted", 143: "interrupted"}
HTTP_CLASS = {200: "ok", 400: "bad_input", 403: "bad_input", 404: "bad_input", 409: "bad_input",
              413: "bad_input", 415: "bad_input", 422: "bad_input", 503: "failed"}
GROUPS = ("objects", "bodies", "friction", "calibration", "stages", "editor", "signals")

OK, BAD, FAILED = ("ok",), ("bad_input",), ("failed",)
SOLVED = ("ok", "failed")          # physics may fail to converge: exit 2 with a reason is an answer


# -- probes ---------------------------------------------------------------------------------------------
class Probe:
    """One adversarial input: a command line (args with {design}, {out}, {data}) or an editor request
    (request: {"how": "solve" | "draft" | "save" | "raw_ws" | "raw_http" | "interrupt", ...}); expect: the
    answer classes allowed; key: what a refusal must name; interrupt_after: SIGINT then (2 s deadline)."""

    def __init__(self, name: str, group: str, expect: tuple, args=None, design=None, files=None,
                 timeout: float = 60.0, interrupt_after: float | None = None, request: dict | None = None,
                 key: str = ""):
        self.name, self.group, self.expect = name, group, tuple(expect)
        self.args, self.design, self.files = list(args or []), design, dict(files or {})
        self.timeout, self.interrupt_after, self.request, self.key = timeout, interrupt_after, request, key


def key_of(changes: dict) -> str:
    """The section a probe's first change touches (what a refusal must name): 'objects', 'contact.dhat'."""
    if not changes:
        return ""
    path = next(iter(changes))
    return path if isinstance(path, str) else str(path[0])


def toml_text(d: dict) -> str:
    """TOML text of a design dict (skelfem.io.files.design_toml)."""
    from skelfem.io.files import design_toml
    return design_toml(d)


def load(name: str, **sets) -> dict:
    d = tomllib.loads((GEOMETRY / name).read_text())
    return variant(d, sets)


def variant(d: dict, changes: dict) -> dict:
    """A deep copy with changes {path: value}; a path is a tuple of keys and list indices (or a dotted str);
    a value of DELETE removes the key."""
    d = copy.deepcopy(d)
    for path, value in changes.items():
        path = tuple(path.split(".")) if isinstance(path, str) else path
        node = d
        for p in path[:-1]:
            node = node[p] if isinstance(node, list) else node.setdefault(p, {})
        if value is DELETE:
            del node[path[-1]]
        else:
            node[path[-1]] = value
    return d


DELETE = object()


def strip_with_object(**entry) -> dict:
    """A 10 x 60 mm soft strip with a tendon, pinned at its base, and a PLA box beside it; gravity on."""
    d = {
        "format": 1, "name": "strip", "dim": 2, "thickness": 10.0,
        "mesh": {"size": 4.0, "degree": 1},
        "materials": {"soft": {"E": 1.0, "nu": 0.3, "density": 1000.0},
                      "pla": {"E": 1000.0, "nu": 0.35, "density": 1200.0}},
        "body": {"outline": [[0, 0], [10, 0], [10, 60], [0, 60]], "material": "soft"},
        "cables": [{"name": "flexor", "kind": "tendon", "path": [[8, 0], [8, 60]], "stiffness": 1.0,
                    "contraction": 1.0}],
        "pins": [{"name": "base", "region": [[-1, -1], [11, 1e-6]], "kind": "fixed"}],
        "markers": {"tip": [5, 60]},
        "objects": [{"name": "box", "outline": [[12, 30], [22, 30], [22, 40], [12, 40]], "material": "pla",
                     **entry}],
        "grounds": [{"name": "floor", "point": [0, 0], "normal": [0, 1], "stiffness": 10.0, "friction": 0.5}],
        "contact": {"dhat": 0.5, "friction": 0.5},
        "gravity": {"acceleration": [0.0, -9.81]},
    }
    return d


def resting_box(**entry) -> dict:
    """A soft block on a fixed base and a PLA box resting on it under gravity (friction holds it)."""
    d = strip_with_object(**entry)
    d["body"]["outline"] = [[0, 0], [40, 0], [40, 10], [0, 10]]
    d["cables"] = []
    d["markers"] = {"top": [20, 10]}
    d["pins"][0]["region"] = [[-1, -1], [41, 1e-6]]
    d["objects"][0]["outline"] = [[15, 10.2], [25, 10.2], [25, 16], [15, 16]]
    d["grounds"] = []
    d["contact"] = {"dhat": 0.1, "friction": 0.8}
    return d


def _simulate(design, *extra, expect=OK, timeout=60.0, name="", group="objects", files=None, key="") -> Probe:
    if not key and "--set" in extra:
        key = extra[extra.index("--set") + 1].split("=")[0].split(".")[0]
    return Probe(name, group, expect, ["simulate", "{design}", "--out", "{out}", "-q", "--no-picture", *extra],
                 design, files or {}, timeout, key=key)


def object_probes() -> list[Probe]:
    """Objects: names, coordinates, sizes, overlaps, gaps, dhat, rigid/material switches."""
    base = strip_with_object()
    probes = []

    def obj(name, changes, expect=BAD, *extra, d=None, timeout=60.0, key=None):
        probes.append(_simulate(variant(d or base, changes), *extra, expect=expect, timeout=timeout,
                                name=name, group="objects", key=key_of(changes) if key is None else key))

    o = ("objects", 0)
    obj("the base design solves", {}, SOLVED)
    for label, nm in [("slash", "a/b"), ("empty", ""), ("5000 bytes", "x" * 5000), ("control char", "bo\x01x"),
                      ("the body's name", "body"), ("a ground's name", "floor"), ("pipe", "a|b"),
                      ("dot-dot", ".."), ("space only", " "), ("newline", "a\nb"), ("dot", "a.b"),
                      ("markup", "<form action=x>"), ("a marker's name", "tip")]:
        obj(f"object named {label}", {o + ("name",): nm}, BAD if label != "a marker's name" else ("ok", "failed",
                                                                                                    "bad_input"))
    obj("object named with accents", {o + ("name",): "bôîte"}, SOLVED)
    obj("two objects with one name", {"objects": base["objects"] + [
        {"name": "box", "outline": [[12, 45], [22, 45], [22, 55], [12, 55]], "material": "pla"}]})
    obj("object name an integer", {o + ("name",): 7})
    obj("object without a name", {o + ("name",): DELETE})
    for label, v in [("nan", math.nan), ("inf", math.inf), ("1e8", 1e8), ("-1e300", -1e300)]:
        obj(f"object coordinate {label}", {o + ("outline", 0, 0): v})
    obj("object coordinate a string", {o + ("outline", 0, 0): "12"})
    obj("object coordinate a bool", {o + ("outline", 0, 0): True})
    obj("object point with three coordinates", {o + ("outline", 0): [12, 30, 0]})
    obj("object outline of two points", {o + ("outline",): [[12, 30], [22, 30]]})
    obj("object outline collinear", {o + ("outline",): [[12, 30], [17, 30], [22, 30]]})
    obj("object outline self-intersecting", {o + ("outline",): [[12, 30], [22, 40], [22, 30], [12, 40]]})
    obj("object outline with a repeated point", {o + ("outline",): [[12, 30], [22, 30], [22, 30], [22, 40],
                                                                    [12, 40]]}, ("ok", "failed", "bad_input"))
    obj("object outline clockwise", {o + ("outline",): [[12, 30], [12, 40], [22, 40], [22, 30]]}, SOLVED)
    obj("object outline empty", {o + ("outline",): []})
    obj("object outline a table", {o + ("outline",): {"a": 1}})
    obj("object 400 x 200 m", {o + ("outline",): [[12, 30], [400012, 30], [400012, 200030], [12, 200030]]},
        key="mesh.size")
    obj("object 1 km away", {o + ("outline",): [[1e6, 30], [1e6 + 10, 30], [1e6 + 10, 40], [1e6, 40]]},
        ("ok", "failed", "bad_input"))
    obj("object overlapping the body", {o + ("outline",): [[8, 30], [22, 30], [22, 40], [8, 40]]})
    obj("object inside the body", {o + ("outline",): [[2, 30], [6, 30], [6, 40], [2, 40]]})
    obj("object around the body", {o + ("outline",): [[-5, 20], [15, 20], [15, 70], [-5, 70]]})
    obj("object touching the body", {o + ("outline",): [[10, 30], [22, 30], [22, 40], [10, 40]]},
        ("ok", "failed", "bad_input"))
    obj("object 1e-9 mm from the body", {o + ("outline",): [[10 + 1e-9, 30], [22, 30], [22, 40], [10 + 1e-9, 40]]},
        ("ok", "failed", "bad_input"))
    obj("object dhat/2 from the body", {o + ("outline",): [[10.25, 30], [22, 30], [22, 40], [10.25, 40]]}, BAD,
        key="contact.dhat")
    obj("object 2 dhat from the body", {o + ("outline",): [[11, 30], [22, 30], [22, 40], [11, 40]]}, SOLVED)
    obj("object 1 m away", {o + ("outline",): [[1e3, 30], [1e3 + 10, 30], [1e3 + 10, 40], [1e3, 40]]}, SOLVED)
    obj("object 10 m away", {o + ("outline",): [[1e4, 30], [1e4 + 10, 30], [1e4 + 10, 40], [1e4, 40]]}, SOLVED)
    obj("object 1 nm wide at mesh.size 4", {o + ("outline",): [[12, 30], [12 + 1e-6, 30], [12 + 1e-6, 40],
                                                               [12, 40]]}, BAD, key="mesh.size")
    obj("two objects overlapping", {"objects": base["objects"] + [
        {"name": "box2", "outline": [[15, 35], [25, 35], [25, 45], [15, 45]], "material": "pla"}]})
    obj("two objects one inside the other", {"objects": base["objects"] + [
        {"name": "box2", "outline": [[14, 32], [16, 32], [16, 34], [14, 34]], "material": "pla"}]})
    obj("object cut by the ground", {o + ("outline",): [[12, -5], [22, -5], [22, 5], [12, 5]]}, key="")
    obj("400 objects", {"objects": [{"name": f"o{i}", "outline": [[20 + 3 * (i % 20), 3 * (i // 20)],
                                                                  [21 + 3 * (i % 20), 3 * (i // 20)],
                                                                  [21 + 3 * (i % 20), 1 + 3 * (i // 20)],
                                                                  [20 + 3 * (i % 20), 1 + 3 * (i // 20)]],
                                     "material": "pla"} for i in range(400)], "mesh.size": 100.0,
                         "contact.dhat": 0.1}, ("ok", "failed", "bad_input"), timeout=120)
    obj("objects an empty list", {"objects": []}, SOLVED)
    obj("objects a table", {"objects": {"box": {"material": "pla"}}})
    obj("objects a list of numbers", {"objects": [1, 2]})
    obj("object with an unknown key", {o + ("rigd",): True})
    obj("object without an outline", {o + ("outline",): DELETE})
    obj("object with 3D solids in 2D", {o + ("outline",): DELETE,
                                        o + ("solids",): [{"box": {"min": [12, 30, 0], "max": [22, 40, 10]}}]})
    obj("object rigid a string", {o + ("rigid",): "yes"})
    obj("object rigid an integer", {o + ("rigid",): 1})
    obj("object rigid false (elastic)", {o + ("rigid",): False}, SOLVED)
    obj("object material unknown", {o + ("material",): "steel"})
    obj("object material missing", {o + ("material",): DELETE})
    obj("object material an array", {o + ("material",): ["pla"]})
    obj("object material soft (the body's)", {o + ("material",): "soft"}, SOLVED)
    obj("rigid object without density under gravity", {"materials.pla": {"E": 1000.0, "nu": 0.35}},
        ("ok", "failed", "bad_input"))
    obj("object density negative", {"materials.pla.density": -1.0})
    obj("object density nan", {"materials.pla.density": math.nan})
    obj("object density 1e30", {"materials.pla.density": 1e30}, ("failed", "bad_input"))
    obj("object falling free (no ground)", {"grounds": []}, ("ok", "failed", "bad_input"))
    obj("elastic object nu 0.4999999", {o + ("rigid",): False, "materials.pla.nu": 0.4999999},
        ("ok", "failed", "bad_input"))
    obj("marker on the object", {"markers.on_box": [17, 35]}, SOLVED)
    obj("marker in the gap", {"markers.gap": [11, 35]})
    obj("pin over the object (fixed, rigid)", {"pins": base["pins"] + [
        {"name": "hold", "region": [[11, 29], [23, 41]], "kind": "fixed"}]}, key="")
    obj("pin over the object (spring, rigid)", {"pins": base["pins"] + [
        {"name": "hold", "region": [[11, 29], [23, 41]], "kind": "spring", "stiffness": 10.0}]}, SOLVED)
    obj("load on the object", {"loads": [{"name": "push", "at": [17, 35], "force": [-0.01, 0.0]}]},
        ("ok", "failed", "bad_input"))
    obj("cable through the object", {("cables", 0, "path"): [[8, 0], [8, 30], [15, 35]]})
    # contact.dhat
    for label, v, expect in [("0", 0.0, BAD), ("-1", -1.0, BAD), ("nan", math.nan, BAD), ("inf", math.inf, BAD),
                             ("1e-300", 1e-300, BAD), ("1e9", 1e9, BAD), ("a string", "0.5", BAD),
                             ("true", True, BAD), ("at its lower bound 0.004", 0.004, SOLVED),
                             ("just below its lower bound", 0.0039, BAD), ("0.1 of the box", 1.0, SOLVED)]:
        obj(f"contact.dhat {label}", {"contact.dhat": v}, expect)
    obj("contact.self a string", {"contact.self": "no"})
    obj("contact with an unknown key", {"contact.dhta": 0.5})
    # --set on objects
    for label, kv, expect in [("rigid false", "objects.box.rigid=false", SOLVED),
                              ("rigid maybe", "objects.box.rigid=maybe", BAD),
                              ("material steel", "objects.box.material=steel", BAD),
                              ("a missing object", "objects.nobox.rigid=true", BAD),
                              ("outline into the body", "objects.box.outline=[[5,30],[22,30],[22,40],[5,40]]", BAD),
                              ("an index past the end", "objects.7.rigid=true", BAD),
                              ("the list itself", "objects=3", BAD),
                              ("dhat nan", "contact.dhat=nan", BAD)]:
        probes.append(_simulate(base, "--set", kv, expect=expect, name=f"--set object {label}", group="objects"))
    # 3D
    b3 = load("gripper3d.toml")
    if b3.get("objects"):
        k = ("objects", 0)
        for label, changes in [("sphere radius 0", {k + ("solids",): [{"sphere": {"center": [0, 0, 0],
                                                                                  "radius": 0}}]}),
                               ("box min above max", {k + ("solids",): [{"box": {"min": [5, 5, 5],
                                                                                 "max": [0, 0, 0]}}]}),
                               ("sphere radius nan", {k + ("solids",): [{"sphere": {"center": [0, 0, 0],
                                                                                    "radius": math.nan}}]}),
                               ("an outline in 3D", {k + ("outline",): [[0, 0], [1, 0], [1, 1]]}),
                               ("a huge sphere", {k + ("solids",): [{"sphere": {"center": [0, 0, -1e6],
                                                                                "radius": 5e5}}]})]:
            probes.append(_simulate(variant(b3, changes), expect=BAD, name=f"3D object {label}", group="objects"))
    return probes


def body_probes() -> list[Probe]:
    """[[bodies]]: names, overlaps, gaps, materials, pins."""
    base = load("two_fingers.toml", **{"mesh.size": 6.0})
    probes = []
    b0, b1 = ("bodies", 0), ("bodies", 1)

    def body(name, changes, expect=BAD, *extra, key=None):
        probes.append(_simulate(variant(base, changes), *extra, expect=expect, name=name, group="bodies",
                                key=key_of(changes) if key is None else key))

    body("two_fingers at mesh.size 6 solves", {}, SOLVED)
    body("two bodies with one name", {b1 + ("name",): "left"})
    body("body named a/b", {b0 + ("name",): "a/b"})
    body("body named body", {b0 + ("name",): "body"}, ("ok", "failed", "bad_input"))
    body("body name 5000 bytes", {b0 + ("name",): "x" * 5000})
    body("body name with a pipe", {b0 + ("name",): "l|r"})
    body("body name empty", {b0 + ("name",): ""})
    body("bodies overlapping", {b1 + ("outline",): [[15, 110], [15, 8], [35, 0], [40, 110]]})
    body("body inside the other", {"bodies": base["bodies"] + [
        {"name": "inner", "outline": [[2, 40], [4, 40], [4, 45], [2, 45]], "material": "ecoflex"}]})
    body("bodies touching along an edge", {b1 + ("outline",): [[20, 110], [20, 8], [35, 0], [40, 110]]})
    body("body material unknown", {b0 + ("material",): "rubber"})
    body("body material missing", {b0 + ("material",): DELETE})
    body("body with an unknown key", {b0 + ("materail",): "ecoflex"})
    body("body and bodies both", {"body": copy.deepcopy(base["bodies"][0])})
    body("bodies empty", {"bodies": []})
    body("body outline nan", {b0 + ("outline", 0, 0): math.nan})
    body("body outline 1e8", {b0 + ("outline", 0, 0): 1e8})
    body("body without pins", {"pins": [{"name": "palm", "region": [[-1, 109], [21, 111]], "kind": "fixed"}]})
    body("bone across both bodies", {("bones", 0, "outline"): [[14, 92], [6, 92], [6, 62], [40, 62]]})
    body("cable from one body into the other", {("cables", 0, "path"): [[17, 110], [17, 22], [44, 16]]})
    body("marker between the bodies", {"markers": {"gap": [27, 50]}})
    body("a body named like an object", {"objects": [{"name": "left", "outline": [[22, -20], [32, -20], [32, -10],
                                                                                  [22, -10]], "material": "pla"}]})
    body("a pin move of 1e300", {("pins", 0, "move"): [1e300, 0.0]})
    body("a pin move of 2e7 mm", {("pins", 0, "move"): [0.0, 2e7]})
    body("E of 1e300 MPa", {"materials.ecoflex.E": 1e300})
    body("E of 1e-300 MPa", {"materials.ecoflex.E": 1e-300})
    body("E of 1e-6 MPa (1 Pa)", {"materials.ecoflex.E": 1e-6}, SOLVED)
    body("nu of 0.5", {"materials.ecoflex.nu": 0.5})
    body("gravity of 1e300 m/s^2", {"gravity": {"acceleration": [0.0, -1e300]},
                                     "materials.ecoflex.density": 1070.0, "materials.dragonskin.density": 1070.0,
                                     "materials.pla.density": 1240.0})
    for label, kv, expect in [("material switch", "bodies.left.material=dragonskin", SOLVED),
                              ("material unknown", "bodies.left.material=rubber", BAD),
                              ("a missing body", "bodies.middle.material=pla", BAD),
                              ("outline a string", "bodies.left.outline=square", BAD)]:
        probes.append(_simulate(base, "--set", kv, expect=expect, name=f"--set body {label}", group="bodies"))
    return probes


def friction_probes() -> list[Probe]:
    """Coulomb friction at contacts and grounds, and in cable channels, at and beyond its bounds."""
    base = strip_with_object()
    probes = []

    def fr(name, changes, expect=BAD, *extra, d=None, key=None):
        probes.append(_simulate(variant(d or base, changes), *extra, expect=expect, name=name, group="friction",
                                key=key_of(changes) if key is None else key))

    for label, v, expect in [("0", 0.0, SOLVED), ("100 (its bound)", 100.0, SOLVED), ("100.0001", 100.0001, BAD),
                             ("1e300", 1e300, BAD), ("-0.1", -0.1, BAD), ("nan", math.nan, BAD),
                             ("inf", math.inf, BAD), ("a string", "0.5", BAD), ("true", True, BAD)]:
        fr(f"contact.friction {label}", {"contact.friction": v}, expect)
    fr("friction_static below friction", {"contact.friction_static": 0.1})
    fr("friction_static nan", {"contact.friction_static": math.nan})
    fr("friction_static 1e9", {"contact.friction_static": 1e9})
    fr("friction_static without friction", {"contact.friction": DELETE, "contact.friction_static": 0.6},
       ("ok", "failed", "bad_input"))
    fr("friction_static equal to friction", {"contact.friction_static": 0.5}, SOLVED)
    pairs = {"[contact.pairs] unknown material": {"steel:pla": 0.5},
             "[contact.pairs] three names": {"soft:pla:soft": 0.5},
             "[contact.pairs] one name": {"soft": 0.5},
             "[contact.pairs] a pair twice": {"soft:pla": 0.5, "pla:soft": 0.6},
             "[contact.pairs] negative": {"soft:pla": -0.5},
             "[contact.pairs] 1e9": {"soft:pla": 1e9},
             "[contact.pairs] unknown key in a table": {"soft:pla": {"frcition": 0.5}},
             "[contact.pairs] static below kinetic": {"soft:pla": {"friction": 0.5, "friction_static": 0.1}},
             "[contact.pairs] a string": {"soft:pla": "0.5"},
             "[contact.pairs] empty key": {"": 0.5}}
    for label, v in pairs.items():
        fr(label, {"contact.pairs": v})
    fr("[contact.pairs] a valid table", {"contact.pairs": {"soft:pla": {"friction": 0.5, "friction_static": 0.6}}},
       SOLVED)
    g = ("grounds", 0)
    for label, v, expect in [("-1", -1.0, BAD), ("101", 101.0, BAD), ("nan", math.nan, BAD), ("a string", "x", BAD),
                             ("100", 100.0, SOLVED)]:
        fr(f"ground friction {label}", {g + ("friction",): v}, expect)
    fr("ground normal zero", {g + ("normal",): [0, 0]})
    fr("ground normal nan", {g + ("normal",): [0, math.nan]})
    fr("ground normal 1e300 long", {g + ("normal",): [0, 1e300]}, ("ok", "failed", "bad_input"))
    fr("ground point inf", {g + ("point",): [0, -math.inf]})
    fr("ground stiffness 0", {g + ("stiffness",): 0.0})
    fr("ground with an unknown key", {g + ("frction",): 0.5})
    fr("resting box, mu 0.8, 4 load steps", {"solver.steps": 4}, SOLVED, d=resting_box())
    fr("resting box, mu 100", {"contact.friction": 100.0}, SOLVED, d=resting_box())
    fr("resting box, mu 0", {"contact.friction": 0.0}, SOLVED, d=resting_box())
    # cable friction
    ff = load("finger_friction.toml", **{"mesh.size": 4.0})
    c = ("cables", 0, "friction")
    for label, v, expect in [("0", 0.0, SOLVED), ("10 (its bound)", 10.0, SOLVED), ("10.0001", 10.0001, BAD),
                             ("-0.1", -0.1, BAD), ("nan", math.nan, BAD), ("inf", math.inf, BAD),
                             ("a by-material table", {"ecoflex": 0.2}, SOLVED),
                             ("a table with an unknown material", {"steel": 0.2}, BAD),
                             ("a table with a negative value", {"ecoflex": -0.2}, BAD),
                             ("an empty table", {}, ("ok", "failed", "bad_input")),
                             ("a list", [0.1, 0.2], BAD), ("2.5", 2.5, SOLVED)]:
        fr(f"cable friction {label}", {c: v}, expect, d=ff)
    fr("ligament with friction", {("cables", 1, "friction"): 0.3}, ("ok", "failed", "bad_input"), d=ff)
    fr("cable friction on a zigzag", {("cables", 0, "path"): [[3, 0], [5, 20], [3, 40], [5, 60], [3, 78], [9, 84]],
                                      c: 0.3}, SOLVED, d=ff)
    for label, kv, expect in [("nan", "cables.flexor.friction=nan", BAD),
                              ("11", "cables.flexor.friction=11", BAD),
                              ("a table", "cables.flexor.friction={ecoflex=0.1}", SOLVED)]:
        probes.append(_simulate(ff, "--set", kv, expect=expect, name=f"--set cable friction {label}",
                                group="friction"))
    for label, kv, expect in [("contact friction -1", "contact.friction=-1", BAD),
                              ("ground friction 1e9", "grounds.floor.friction=1e9", BAD),
                              ("a missing ground", "grounds.nofloor.friction=0.1", BAD)]:
        probes.append(_simulate(base, "--set", kv, expect=expect, name=f"--set {label}", group="friction"))
    return probes


CAL_HEADER = "cables.flexor.contraction,markers.tip.x,markers.tip.y\n"
CAL_ROWS = ("2.0,-1.99,97.66\n4.0,-13.86,94.44\n6.0,-25.17,89.36\n8.0,-35.52,82.53\n")


def calibration_probes() -> list[Probe]:
    """skelfem calibrate: CSV cells, sigma, bounds, starts."""
    finger = load("finger.toml", **{"mesh.size": 6.0})
    probes = []

    def cal(name, csv, *extra, expect=BAD, timeout=120.0):
        probes.append(Probe(name, "calibration", expect,
                            ["calibrate", "{design}", "--data", "{data}", "--fit", "materials.ecoflex.E",
                             *extra, "--out", "{out}", "-q"], finger, {"data.csv": csv}, timeout))

    def cell(text):
        return CAL_HEADER + CAL_ROWS.replace("97.66", text)

    cal("a clean fit", CAL_HEADER + CAL_ROWS, expect=("ok", "failed"))
    cal("CSV cell empty (not measured)", cell(""), expect=("ok", "failed"))
    cal("CSV cell a quoted number (CSV quoting)", cell('"97.66"'), expect=("ok", "failed"))
    for label, text in [("1_000", "1_000"), ("Arabic-Indic digits", "\u0669\u0667"), ("nan", "nan"),
                        ("inf", "inf"), ("1e999", "1e999"), ("hex", "0x10"),
                        ("full-width digits", "\uff19\uff17"),
                        ("a comma decimal", "97,66"), ("NUL", "97\x0066"), ("a space inside", "97 66"),
                        ("two dots", "97..66"), ("a lone minus", "-")]:
        cal(f"CSV cell {label}", cell(text))
    cal("CSV cell with surrounding spaces", cell(" 97.66 "), expect=("ok", "failed", "bad_input"))
    cal("CSV cell subnormal 1e-400", cell("1e-400"), expect=("ok", "failed", "bad_input"))
    cal("CSV with a BOM", "\ufeff" + CAL_HEADER + CAL_ROWS, expect=("ok", "failed", "bad_input"))
    cal("CSV with CRLF", (CAL_HEADER + CAL_ROWS).replace("\n", "\r\n"), expect=("ok", "failed", "bad_input"))
    cal("CSV header only", CAL_HEADER)
    cal("CSV empty", "")
    cal("CSV a column twice", "markers.tip.x," + CAL_HEADER.replace("\n", "") + "\n"
        + "".join(f"1.0,{r}" for r in CAL_ROWS.splitlines(True)))
    cal("CSV an unknown column", CAL_HEADER.replace("markers.tip.y", "markers.nail.y") + CAL_ROWS)
    cal("CSV a short row", CAL_HEADER + "2.0,-1.99\n" + CAL_ROWS)
    cal("CSV a long row", CAL_HEADER + "2.0,-1.99,97.66,5\n" + CAL_ROWS)
    cal("CSV invalid UTF-8", (CAL_HEADER + CAL_ROWS).encode() + b"\xff\xfe\n")
    cal("CSV a condition column nan", CAL_HEADER + CAL_ROWS.replace("2.0,", "nan,"))
    cal("CSV a condition beyond the design's range", CAL_HEADER + CAL_ROWS.replace("2.0,", "1e9,"))
    cal("CSV a pin move of 1e300 as a condition", "pins.base.move.x," + CAL_HEADER.replace("\n", "") + "\n"
        + "".join(f"{v},{r}" for v, r in zip(("0", "1e300", "0", "0"), CAL_ROWS.splitlines(True))))
    cal("CSV a condition on an object key", "objects.box.rigid," + CAL_HEADER.replace("\n", "") + "\n"
        + "".join(f"1,{r}" for r in CAL_ROWS.splitlines(True)))
    good = CAL_HEADER + CAL_ROWS
    for label, args in [("sigma 0", ["--sigma", "markers.*=0"]), ("sigma -1", ["--sigma", "markers.*=-1"]),
                        ("sigma nan", ["--sigma", "markers.*=nan"]), ("sigma inf", ["--sigma", "markers.*=inf"]),
                        ("sigma 1e-200", ["--sigma", "markers.*=1e-200"]),
                        ("sigma 1e200", ["--sigma", "markers.*=1e200"]),
                        ("sigma without a value", ["--sigma", "markers.*="]),
                        ("sigma of no column", ["--sigma", "cables.nope.tension=1"]),
                        ("sigma without =", ["--sigma", "markers.tip.x"]),
                        ("bounds reversed", ["--bounds", "materials.ecoflex.E=1,0.01"]),
                        ("bounds equal", ["--bounds", "materials.ecoflex.E=0.1,0.1"]),
                        ("bounds nan", ["--bounds", "materials.ecoflex.E=nan,1"]),
                        ("bounds negative on E", ["--bounds", "materials.ecoflex.E=-1,1"]),
                        ("bounds three numbers", ["--bounds", "materials.ecoflex.E=0.01,1,2"]),
                        ("bounds of a key not fitted", ["--bounds", "materials.pla.E=1,1e4"]),
                        ("bounds 1e-300 to 1e300", ["--bounds", "materials.ecoflex.E=1e-300,1e300"]),
                        ("starts 0", ["--starts", "0"]), ("starts -1", ["--starts", "-1"]),
                        ("starts 1e9", ["--starts", "1000000000"]), ("starts nan", ["--starts", "nan"]),
                        ("max-iterations 0", ["--max-iterations", "0"]),
                        ("max-iterations 1e9", ["--max-iterations", "1000000000"]),
                        ("holdout 1", ["--holdout", "1"]), ("holdout nan", ["--holdout", "nan"]),
                        ("fit an unknown key", ["--fit", "materials.steel.E"]),
                        ("fit a key twice", ["--fit", "materials.ecoflex.E"]),
                        ("fit a pattern of nothing", ["--fit", "cables.zz*.stiffness"]),
                        ("fit a non-live key", ["--fit", "mesh.size"])]:
        cal(label, good, *args)
    cal("bounds with an infinite upper end (documented)", good, "--bounds", "materials.ecoflex.E=0.01,inf",
        expect=("ok", "failed"))
    cal("bounds -inf as the lower end of E", good, "--bounds", "materials.ecoflex.E=-inf,1")
    return probes


def stage_probes() -> tuple[list[Probe], str]:
    """[[stages]] if the design format has it; (probes, why skipped)."""
    from skelfem.design.parse import parse_design
    from skelfem.design.spec import DesignError
    d = variant(strip_with_object(), {"stages": [{"name": "push", "set": {"cables.flexor.contraction": 2.0}}]})
    try:
        parse_design(d, "x.toml")
    except DesignError as exc:
        return [], f"[[stages]] is not part of this version's design format ({exc})"
    base = d
    probes = []

    def st(name, stages, expect=BAD):
        probes.append(_simulate(variant(base, {"stages": stages}), expect=expect, name=name, group="stages"))

    st("one stage", base["stages"], SOLVED)
    st("two stages with one name", base["stages"] * 2)
    st("a stage named a/b", [{"name": "a/b", "set": {"cables.flexor.contraction": 2.0}}])
    st("a stage setting an unknown key", [{"name": "s", "set": {"cables.nope.contraction": 2.0}}])
    st("a stage setting nan", [{"name": "s", "set": {"cables.flexor.contraction": math.nan}}])
    st("a stage setting a non-live key", [{"name": "s", "set": {"mesh.size": 2.0}}])
    st("a stage with steps 0", [{"name": "s", "set": {"cables.flexor.contraction": 2.0}, "steps": 0}])
    st("a stage with steps 1e9", [{"name": "s", "set": {"cables.flexor.contraction": 2.0}, "steps": 10 ** 9}])
    st("a stage with an unknown key", [{"name": "s", "sett": {}}])
    st("a stage setting the object's friction", [{"name": "s", "set": {"contact.friction": 0.2}}], SOLVED)
    st("a stage moving a pin 1e300 mm", [{"name": "s", "set": {"pins.base.move": [1e300, 0.0]}}])
    st("a stage setting E to 1e-300", [{"name": "s", "set": {"materials.soft.E": 1e-300}}])
    st("a stage setting friction 1e9", [{"name": "s", "set": {"contact.friction": 1e9}}])
    st("a stage set that is a list", [{"name": "s", "set": [1, 2]}])
    st("a stage with a lone surrogate name", [{"name": "s\ud800", "set": {"cables.flexor.contraction": 2.0}}])
    return probes, ""


def signal_probes() -> list[Probe]:
    """SIGINT after a delay, in each phase: validation, meshing, solve, calibration."""
    many = variant(strip_with_object(), {"objects": [
        {"name": f"o{i}", "outline": [[20 + 3 * (i % 60), 3 * (i // 60)], [21 + 3 * (i % 60), 3 * (i // 60)],
                                      [21 + 3 * (i % 60), 1 + 3 * (i // 60)], [20 + 3 * (i % 60), 1 + 3 * (i // 60)]],
         "material": "pla"} for i in range(3000)], "grounds": [], "mesh.size": 1000.0})
    fine = load("gripper.toml", **{"mesh.size": 1.0})
    ff = load("finger_friction.toml", **{"mesh.size": 1.0})
    run = ["simulate", "{design}", "--out", "{out}", "-q", "--no-picture"]
    probes = [Probe("SIGINT while validating 3000 objects", "signals", ("interrupted", "bad_input", "ok", "failed"),
                    run, many, interrupt_after=0.8),
              Probe("SIGINT while solving the gripper", "signals", ("interrupted", "ok"), run, fine,
                    interrupt_after=4.0, timeout=120),
              Probe("SIGINT while meshing the gripper finely", "signals", ("interrupted", "ok"),
                    run, load("gripper.toml", **{"mesh.size": 0.3}), interrupt_after=2.5, timeout=120),
              Probe("SIGINT in cable friction", "signals", ("interrupted", "ok", "failed"), run, ff,
                    interrupt_after=4.0, timeout=120),
              Probe("SIGINT while calibrating", "signals", ("interrupted", "ok", "failed"),
                    ["calibrate", "{design}", "--data", "{data}", "--fit", "materials.ecoflex.E", "--out", "{out}",
                     "-q"], load("finger.toml", **{"mesh.size": 3.0}), {"data.csv": CAL_HEADER + CAL_ROWS},
                    interrupt_after=4.0, timeout=120)]
    return probes


def editor_probes() -> list[Probe]:
    """Requests to a live editor serving a gripper with a box (objects), plus two_fingers designs (bodies)."""
    g = load("gripper.toml", **{"mesh.size": 6.0})
    tf = load("two_fingers.toml", **{"mesh.size": 6.0})
    box = ("objects", 0)
    probes = []

    def req(label, how, design=None, expect=OK, **extra):
        probes.append(Probe(label, "editor", expect, request={"how": how, "design": design, **extra}, timeout=90))

    moved = variant(g, {box + ("outline",): [[x + 1.0, y] for x, y in g["objects"][0]["outline"]]})
    req("solve the design", "solve", g, SOLVED)
    req("draft: the box moved 1 mm", "draft", moved, SOLVED)
    req("draft: the box moved back", "draft", g, SOLVED)
    for k in range(3):
        req(f"draft: box vertex {k} dragged", "draft",
            variant(g, {box + ("outline", k, 1): g["objects"][0]["outline"][k][1] + 0.5 * (k + 1)}), SOLVED)
    req("final: the box moved 1 mm", "solve", moved, SOLVED)
    req("draft: box rigid false", "draft", variant(g, {box + ("rigid",): False}), SOLVED)
    req("draft: box rigid true", "draft", variant(g, {box + ("rigid",): True}), SOLVED)
    req("draft: box material pla", "draft", variant(g, {box + ("material",): "pla"}), SOLVED)
    req("draft: box material unknown", "draft", variant(g, {box + ("material",): "steel"}), BAD)
    req("draft: box rigid a string", "draft", variant(g, {box + ("rigid",): "yes"}), BAD)
    req("draft: box into a finger", "draft",
        variant(g, {box + ("outline",): [[0, -10], [74, -10], [74, 14], [0, 14]]}), BAD)
    req("draft: box 400 x 200 m", "draft",
        variant(g, {box + ("outline",): [[26, -10], [400026, -10], [400026, 200000], [26, 200000]]}), BAD)
    req("draft: box coordinate 1e300", "draft", variant(g, {box + ("outline", 0, 0): 1e300}), BAD)
    req("draft: box coordinate a string", "draft", variant(g, {box + ("outline", 0, 0): "26"}), BAD)
    req("draft: box coordinate null", "draft", variant(g, {box + ("outline", 0, 0): None}), BAD)
    req("draft: box named <form>", "draft", variant(g, {box + ("name",): "<form action=x>"}), BAD)
    req("draft: box named a lone surrogate", "draft", variant(g, {box + ("name",): "b\ud800x"}), BAD)
    req("draft: box named body", "draft", variant(g, {box + ("name",): "body"}), BAD)
    req("draft: dhat 1e-300", "draft", variant(g, {"contact.dhat": 1e-300}), BAD)
    req("draft: friction 1e9", "draft", variant(g, {"contact.friction": 1e9}), BAD)
    req("draft: friction 0", "draft", variant(g, {"contact.friction": 0.0}), SOLVED)
    req("draft: friction back to 0.8", "draft", g, SOLVED)
    req("draft: a second box", "draft", variant(g, {"objects": g["objects"] + [
        {"name": "box2", "outline": [[40, 20], [60, 20], [60, 30], [40, 30]], "material": "pla"}]}), SOLVED)
    req("draft: 1000 objects", "draft", variant(g, {"objects": [
        {"name": f"o{i}", "outline": [[200 + 3 * (i % 40), 3 * (i // 40)], [201 + 3 * (i % 40), 3 * (i // 40)],
                                      [201 + 3 * (i % 40), 1 + 3 * (i // 40)], [200 + 3 * (i % 40), 1 + 3 * (i // 40)]],
         "material": "pla"} for i in range(1000)]}), ("ok", "failed", "bad_input"))
    req("draft: objects a table", "draft", variant(g, {"objects": {"box": {}}}), BAD)
    req("draft: object with an unknown key", "draft", variant(g, {box + ("colour",): "red"}), BAD)
    req("draft: ground friction 101", "draft", variant(g, {"grounds": [
        {"name": "floor", "point": [0, -11], "normal": [0, 1], "friction": 101.0}]}), BAD)
    req("draft: a ground cutting the box", "draft", variant(g, {"grounds": [
        {"name": "floor", "point": [0, 0], "normal": [0, 1]}]}), BAD)
    req("solve: two_fingers (bodies)", "solve", tf, SOLVED)
    req("draft: a body vertex dragged", "draft",
        variant(tf, {("bodies", 1, "outline", 0, 0): tf["bodies"][1]["outline"][0][0] + 0.5}), SOLVED)
    req("draft: a body's material switched", "draft", variant(tf, {("bodies", 0, "material"): "dragonskin"}), SOLVED)
    req("draft: a body into the other", "draft",
        variant(tf, {("bodies", 1, "outline", 1, 0): 10.0}), BAD)
    req("draft: two bodies with one name", "draft", variant(tf, {("bodies", 1, "name"): "left"}), BAD)
    req("draft: a body named a/b", "draft", variant(tf, {("bodies", 1, "name"): "a/b"}), BAD)
    req("draft: a body's material unknown", "draft", variant(tf, {("bodies", 0, "material"): "rubber"}), BAD)
    req("draft: the design null", "draft", None, BAD)
    req("draft: the design a list", "draft", [1, 2], BAD)
    req("ws: a message without an id", "raw_ws", text='{"kind": "solve"}', expect=BAD)
    req("ws: an unknown kind", "raw_ws", text='{"id": 1, "kind": "drag"}', expect=BAD)
    req("ws: NaN in a draft", "raw_ws", text='{"id": 1, "kind": "solve", "draft": true, "design": {"x": NaN}}',
        expect=BAD)
    req("solve: JSON nested 100000 deep", "raw_http", path="/api/solve", body="[" * 100000 + "]" * 100000,
        expect=BAD)
    req("solve: not JSON", "raw_http", path="/api/solve", body="objects = []", expect=BAD)
    # saves: written only in the design's folder
    req("save: a copy", "save", g, OK, name="copy.toml")
    req("save: the copy again (now the editor's own file)", "save", g, OK, name="copy.toml")
    req("save: design.toml again without overwrite", "save", g, BAD, name="design.toml")
    req("save: the copy with overwrite", "save", moved, OK, name="copy.toml", overwrite=True)
    for label, nm in [("../up.toml", "../up.toml"), ("/tmp/abs.toml", "/tmp/abs.toml"), ("a/b.toml", "a/b.toml"),
                      ("x.txt", "x.txt"), ("a lone surrogate", "c\ud800.toml"), ("300 bytes", "x" * 300 + ".toml"),
                      (".toml", ".toml"), ("a NUL", "a\x00.toml"), ("a number", 7), ("..", "..")]:
        req(f"save: name {label}", "save", g, BAD, name=nm)
    req("save: an object named <form>", "save", variant(g, {box + ("name",): "<form action=x>"}), BAD,
        name="markup.toml")
    req("save: an object name with a lone surrogate", "save", variant(g, {box + ("name",): "b\ud800"}), BAD,
        name="surrogate.toml")
    req("save: a material name with a lone surrogate", "save",
        variant(g, {"materials": {**g["materials"], "e\ud800": {"E": 1.0, "nu": 0.3}}}), BAD, name="m.toml")
    req("save: a body-vertex edit of two_fingers", "save",
        variant(tf, {("bodies", 1, "outline", 0, 0): tf["bodies"][1]["outline"][0][0] + 0.5}), OK,
        name="tf_copy.toml")
    req("save: a design with a dhat of 1e-300", "save", variant(g, {"contact.dhat": 1e-300}), BAD, name="d.toml")
    req("save: overwrite true as a string", "save", g, ("ok", "bad_input"), name="copy.toml", overwrite="no")
    req("SIGINT during a long solve", "interrupt", load("gripper.toml", **{"mesh.size": 0.9}),
        ("interrupted",), after=2.0)
    return probes


# -- running ---------------------------------------------------------------------------------------------
def listing(root: Path) -> set[str]:
    out = set()
    for dirpath, dirnames, filenames in os.walk(root):
        rel = Path(dirpath).relative_to(root)
        out |= {str(rel / n) for n in dirnames + filenames}
    return out


def _write(path: Path, content) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_bytes(content.encode("utf-8", "surrogatepass"))


def _design_bytes(design) -> bytes:
    if isinstance(design, bytes):
        return design
    return toml_text(design).encode("utf-8", "surrogatepass")


def _strict(text: str):
    def bad(name):
        raise ValueError(f"{name} in JSON")
    return json.loads(text, parse_constant=bad)


def _sane(out: Path, args: list) -> str:
    """'' if a finished command left a sane result in out, else what is wrong."""
    name = "calibration.json" if args[0] == "calibrate" else "result.json"
    path = out / name
    if not path.is_file():
        return f"no {name} in the output folder"
    try:
        res = _strict(path.read_text())
    except ValueError as exc:
        return f"{name} is not strict JSON: {exc}"
    if name == "result.json" and res.get("converged") is not True:
        return f"exit 0 but result.json says converged={res.get('converged')!r}"
    return ""


def _settled(new, grace: float = 3.0) -> list:
    """new() once it stays empty, or after grace seconds: Open MPI's daemon removes its session folder
    from TMPDIR a moment after the process it served has gone."""
    t_end = time.monotonic() + grace
    found = new()
    while found and time.monotonic() < t_end:
        time.sleep(0.25)
        found = new()
    return found


def run_command(probe: Probe, sandbox: Path) -> dict:
    """Run one command-line probe in sandbox; its record."""
    inp, work, tmp, out = sandbox / "in", sandbox / "a" / "b" / "c", sandbox / "tmp", sandbox / "out"
    for p in (inp, work, tmp):
        p.mkdir(parents=True, exist_ok=True)
    _write(inp / "design.toml", _design_bytes(probe.design))
    for name, content in probe.files.items():
        _write(inp / name, content)
    before = listing(sandbox)
    fill = {"{design}": str(inp / "design.toml"), "{out}": str(out), "{data}": str(inp / "data.csv")}
    args = [fill.get(a, a) for a in probe.args]
    env = {**ENV, "TMPDIR": str(tmp)}
    t0 = time.perf_counter()
    proc = subprocess.Popen([SKELFEM, *args], cwd=work, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)
    signalled, late, killed = None, False, False
    try:
        if probe.interrupt_after is not None:
            try:
                proc.wait(probe.interrupt_after)
            except subprocess.TimeoutExpired:
                proc.send_signal(signal.SIGINT)
                signalled = time.perf_counter()
                try:
                    proc.wait(SIGNAL_DEADLINE)
                except subprocess.TimeoutExpired:
                    late = True
        stdout, stderr = proc.communicate(timeout=max(1.0, probe.timeout - (time.perf_counter() - t0)))
        hung = False
    except subprocess.TimeoutExpired:           # a hang: asked to stop (SIGINT), then killed
        proc.send_signal(signal.SIGINT)
        try:
            stdout, stderr = proc.communicate(timeout=SIGNAL_DEADLINE)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            stdout, stderr = proc.communicate()
            killed = True
        hung = True
    seconds = time.perf_counter() - t0
    stdout, stderr = stdout.decode("utf-8", "replace"), stderr.decode("utf-8", "replace")
    rc = proc.returncode
    answer = ("hang" if killed else "slow") if hung else EXIT_CLASS.get(rc, f"exit {rc}")
    findings = []
    if hung and killed:
        findings.append(("hang", f"no answer within {probe.timeout:g} s, and still running "
                                 f"{SIGNAL_DEADLINE:g} s after SIGINT"))
    elif hung:
        findings.append(("slow", f"no answer within {probe.timeout:g} s (stopped by SIGINT within "
                                 f"{SIGNAL_DEADLINE:g} s)"))
    elif rc not in EXIT_CLASS:
        findings.append(("exit3" if rc == 3 else "exit", f"exit {rc}"))
    elif answer not in probe.expect:
        findings.append(("wrong_class", f"{answer} where {' or '.join(probe.expect)} was expected"))
    if late:
        findings.append(("signal", f"still running {SIGNAL_DEADLINE:g} s after SIGINT"))
    if "Traceback" in stdout + stderr:
        findings.append(("traceback", "a traceback was printed"))
    errors = [line for line in stderr.splitlines() if line.startswith("error:")]
    outside = _settled(lambda: sorted(p for p in listing(sandbox) - before if p != "out" and not p.startswith("out/")))
    if outside and not killed:                   # SIGKILL leaves its lock and MPI's session folder
        findings.append(("write_outside", f"written outside the output folder: {outside[:5]}"))
    if not hung:
        if rc == 1 and probe.key and errors and probe.key not in errors[0].split(": ", 2)[-1]:
            findings.append(("wrong_reason", f"refused, but not for {probe.key}: {errors[0][-200:]}"))
        if rc == 1 and len(errors) != 1:
            findings.append(("error_lines", f"{len(errors)} error: lines for bad input"))
        if rc == 1 and out.exists():
            findings.append(("write_outside", "bad input created the output folder"))
        if rc == 2 and not errors and "status" not in stderr:
            findings.append(("no_reason", "exit 2 without a reason"))
        if rc in (130, 143) and errors != ["error: interrupted"]:
            findings.append(("error_lines", f"interrupted with {errors}"))
        if rc == 0 and probe.args[0] in ("simulate", "calibrate"):
            why = _sane(out, probe.args)
            if why:
                findings.append(("insane", why))
    return {"answer": answer, "exit": rc, "seconds": round(seconds, 3), "error": (errors or [""])[-1][:300],
            "after_signal": None if signalled is None else round(time.perf_counter() - signalled, 3)
            if not late else None,
            "findings": [{"class": c, "what": w} for c, w in findings],
            "stderr_tail": "" if not findings else stderr[-1500:]}


# -- the editor ---------------------------------------------------------------------------------------------
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _http(port, method, path, body: bytes | None = None, timeout=90.0):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    conn.request(method, path, body=body, headers={"Content-Type": "application/json"} if body is not None else {})
    r = conn.getresponse()
    data = r.read()
    conn.close()
    try:
        return r.status, _strict(data)
    except ValueError:
        return r.status, data[:200]


def _encode(value) -> bytes:
    return json.dumps(value).encode()          # \ud800 escapes: JSON can carry a lone surrogate


async def _ws_exchange(port: int, text: str, timeout: float):
    import websockets
    async with websockets.connect(f"ws://127.0.0.1:{port}/api/live", max_size=None, open_timeout=10,
                                  ping_interval=None) as ws:
        await ws.send(text)
        while True:
            reply = _strict(await asyncio.wait_for(ws.recv(), timeout))
            if reply.get("dropped"):
                continue
            return reply


class LiveEditor:
    """`skelfem edit` on a copy of a design in its own folder, in a subprocess."""

    def __init__(self, sandbox: Path, design: dict):
        self.folder = sandbox / "editor"
        self.work = sandbox / "a" / "b" / "c"
        self.folder.mkdir(parents=True)
        self.work.mkdir(parents=True)
        (sandbox / "tmp").mkdir()
        _write(self.folder / "design.toml", _design_bytes(design))
        self.sandbox = sandbox
        self.port = free_port()
        self.stderr = open(sandbox / "editor.log", "wb")
        self.before = listing(sandbox)
        self.proc = subprocess.Popen([SKELFEM, "edit", str(self.folder / "design.toml"), "--port", str(self.port),
                                      "--no-browser", "-q", "--max-seconds", "30"], cwd=self.work,
                                     env={**ENV, "TMPDIR": str(sandbox / "tmp")}, stdout=self.stderr,
                                     stderr=subprocess.STDOUT, start_new_session=True)
        t_end = time.monotonic() + 120
        while True:
            try:
                if _http(self.port, "GET", "/api/design", timeout=10)[0] == 200:
                    break
            except OSError:
                pass
            if self.proc.poll() is not None or time.monotonic() > t_end:
                raise RuntimeError(f"the editor did not start: {self.log()[-2000:]}")
            time.sleep(0.2)

    def log(self) -> str:
        self.stderr.flush()
        return (self.sandbox / "editor.log").read_bytes().decode("utf-8", "replace")

    def alive(self) -> bool:
        try:
            return _http(self.port, "GET", "/api/design", timeout=30)[0] == 200
        except OSError:
            return False

    def outside(self, running: bool = True) -> list[str]:
        """New files outside the design's folder (the editor's output folder); while it runs, its TMPDIR
        holds MPI's session folder, which must be gone once it has stopped."""
        new = listing(self.sandbox) - self.before
        return sorted(p for p in new if not p.startswith("editor/") and p != "editor.log"
                      and not (running and (p == "tmp" or p.startswith("tmp/"))))

    def interrupt(self) -> tuple[int | None, float | None]:
        """SIGINT; (exit status, seconds to exit) or (None, None) past the deadline (then killed)."""
        t0 = time.perf_counter()
        self.proc.send_signal(signal.SIGINT)
        try:
            rc = self.proc.wait(SIGNAL_DEADLINE)
            return rc, time.perf_counter() - t0
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
            return None, None

    def close(self):
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
        self.stderr.close()


def run_request(probe: Probe, ed: LiveEditor) -> dict:
    """One request to the live editor; its record (answer class, status, findings)."""
    r = probe.request
    how = r["how"]
    t0 = time.perf_counter()
    findings, status, error = [], None, ""
    log_before = len(ed.log())
    try:
        if how == "draft" or how == "raw_ws":
            text = (r["text"] if how == "raw_ws" else
                    json.dumps({"id": 1, "kind": "solve", "draft": True, "design": r["design"]}))
            reply = asyncio.run(_ws_exchange(ed.port, text, probe.timeout))
            status = 200 if reply.get("ok") else reply.get("status")
            error = "" if reply.get("ok") else str(reply.get("error", ""))
            answer_body = reply.get("answer")
        elif how == "solve":
            status, answer_body = _http(ed.port, "POST", "/api/solve?mesh=0", _encode(r["design"]), probe.timeout)
            error = answer_body.get("error", "") if isinstance(answer_body, dict) and status != 200 else ""
        elif how == "raw_http":
            status, answer_body = _http(ed.port, "POST", r["path"], r["body"].encode(), probe.timeout)
            error = answer_body.get("error", "") if isinstance(answer_body, dict) else str(answer_body)
        elif how == "save":
            body = {"design": r["design"]}
            for k in ("name", "overwrite"):
                if k in r:
                    body[k] = r[k]
            status, answer_body = _http(ed.port, "POST", "/api/save", _encode(body), probe.timeout)
            error = answer_body.get("error", "") if isinstance(answer_body, dict) and status != 200 else ""
        elif how == "interrupt":
            import threading
            threading.Thread(target=lambda: _swallow(ed.port, r["design"]), daemon=True).start()
            time.sleep(r["after"])
            rc, took = ed.interrupt()
            status = rc
            answer = "interrupted" if rc in (0, 130, 143) and took is not None else (
                "hang" if took is None else f"exit {rc}")
            if took is None:
                findings.append(("signal", f"the editor still ran {SIGNAL_DEADLINE:g} s after SIGINT"))
            left = _settled(lambda: ed.outside(running=False))
            if left and took is not None:
                findings.append(("write_outside", f"left outside the design's folder: {left[:5]}"))
            if "Traceback" in ed.log():
                findings.append(("traceback", "the editor's log holds a traceback"))
            return {"answer": answer, "exit": rc, "seconds": round(time.perf_counter() - t0, 3),
                    "after_signal": None if took is None else round(took, 3),
                    "error": "", "findings": [{"class": c, "what": w} for c, w in findings]}
        else:
            raise ValueError(how)
    except (TimeoutError, asyncio.TimeoutError, socket.timeout):
        return {"answer": "hang", "status": None, "seconds": round(time.perf_counter() - t0, 3), "error": "",
                "findings": [{"class": "hang", "what": f"no answer within {probe.timeout:g} s"}]}
    except Exception as exc:  # noqa: BLE001 - a dropped connection is a finding, not the study's end
        return {"answer": "dropped", "status": None, "seconds": round(time.perf_counter() - t0, 3),
                "error": f"{type(exc).__name__}: {exc}"[:300],
                "findings": [{"class": "dropped", "what": f"{type(exc).__name__}: {exc}"[:300]}]}
    answer = HTTP_CLASS.get(status, f"HTTP {status}")
    if status == 500:
        findings.append(("http500", error[:300]))
    elif answer not in probe.expect:
        findings.append(("wrong_class", f"HTTP {status} ({error[:200]}) where {' or '.join(probe.expect)} "
                                        "was expected"))
    if status == 200 and how in ("solve", "draft") and isinstance(answer_body, dict) \
            and answer_body.get("converged") is False and "failed" not in probe.expect:
        findings.append(("wrong_class", "not converged"))
    if status not in (200, None) and isinstance(error, str) and not error:
        findings.append(("no_reason", f"HTTP {status} without an error"))
    if "Traceback" in ed.log()[log_before:]:
        findings.append(("traceback", "the editor's log holds a traceback"))
    if not ed.alive():
        findings.append(("dead", "the editor no longer answers"))
    outside = ed.outside()
    if outside:
        findings.append(("write_outside", f"written outside the design's folder: {outside[:5]}"))
    if status == 200 and how in ("solve", "draft") and isinstance(answer_body, dict):
        answer = "ok" if answer_body.get("converged", True) else "failed"
    return {"answer": answer, "status": status, "seconds": round(time.perf_counter() - t0, 3), "error": error[:300],
            "findings": [{"class": c, "what": w} for c, w in findings]}


def _swallow(port, design):
    try:
        _http(port, "POST", "/api/solve?mesh=0", _encode(design), timeout=60)
    except Exception:  # noqa: BLE001 - the server goes away under it
        pass


# -- the pass -------------------------------------------------------------------------------------------------
def probes_by_group(only=None) -> tuple[dict, str]:
    groups = {"objects": object_probes, "bodies": body_probes, "friction": friction_probes,
              "calibration": calibration_probes, "signals": signal_probes, "editor": editor_probes}
    out, skipped = {}, ""
    for g in only or GROUPS:
        if g == "stages":
            out["stages"], skipped = stage_probes()
        else:
            out[g] = groups[g]()
    return out, skipped


def run(only=None, limit: int | None = None, names=None, progress=False) -> dict:
    """Run the probes (of the groups in only, the first `limit` of each, or those named); the results."""
    groups, stages_skipped = probes_by_group(only)
    records = []
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="skelfem-adversarial-") as tmp:
        tmp = Path(tmp)
        for group, probes in groups.items():
            probes = [p for p in probes if names is None or p.name in names][:limit]
            if not probes:
                continue
            if group == "editor":
                ed = LiveEditor(tmp / "editor", load("gripper.toml", **{"mesh.size": 6.0}))
                try:
                    for p in probes:
                        records.append(_record(p, run_request(p, ed), progress))
                        if p.request["how"] == "interrupt":
                            break
                    else:
                        p = Probe("SIGINT to an idle editor", "editor", ("interrupted",))
                        rc, took = ed.interrupt()
                        rec = {"answer": "interrupted" if took is not None else "hang", "exit": rc,
                               "after_signal": None if took is None else round(took, 3), "seconds": took,
                               "error": "", "findings": [] if took is not None else
                               [{"class": "signal", "what": "still running 2 s after SIGINT"}]}
                        records.append(_record(p, rec, progress))
                finally:
                    ed.close()
                continue
            for i, p in enumerate(probes):
                records.append(_record(p, run_command(p, tmp / f"{group}-{i}"), progress))
    summary = summarise(records)
    return {"probes": len(records), "seconds": round(time.perf_counter() - t_start, 1),
            "stages_skipped": stages_skipped, **summary, "results": records}


def _record(p: Probe, rec: dict, progress: bool) -> dict:
    rec = {"group": p.group, "name": p.name, "expect": list(p.expect), **rec}
    if progress:
        mark = "ok " if not rec["findings"] else "BAD"
        print(f"{mark} {p.group:11s} {rec['answer']:12s} {rec['seconds'] or 0:7.2f}s  {p.name}"
              + "".join(f"\n      {f['class']}: {f['what']}" for f in rec["findings"]), flush=True)
    return rec


def summarise(records: list) -> dict:
    by_class: dict = {}
    for r in records:
        for f in r["findings"]:
            by_class[f["class"]] = by_class.get(f["class"], 0) + 1
    groups: dict = {}
    for r in records:
        g = groups.setdefault(r["group"], {"probes": 0, "clean": 0, "answers": {}})
        g["probes"] += 1
        g["clean"] += not r["findings"]
        g["answers"][r["answer"]] = g["answers"].get(r["answer"], 0) + 1
    signals = [r["after_signal"] for r in records if r.get("after_signal") is not None]
    return {"clean": sum(not r["findings"] for r in records), "findings_by_class": by_class, "groups": groups,
            "slowest_signal_s": max(signals) if signals else None}


def merge(parts: list) -> dict:
    """One result from the results of runs over disjoint groups (run side by side: --only, then --merge)."""
    records = [r for part in parts for r in part["results"]]
    skipped = next((p["stages_skipped"] for p in parts if p.get("stages_skipped")), "")
    return {"probes": len(records), "seconds": round(sum(p["seconds"] for p in parts), 1),
            "stages_skipped": skipped, **summarise(records), "results": records}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", choices=GROUPS, default=None)
    ap.add_argument("--limit", type=int, default=None, help="the first N probes of each group")
    ap.add_argument("--merge", nargs="*", type=Path, default=None,
                    help="write the union of these results (runs of --only over disjoint groups) instead")
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args(argv)
    if a.merge:
        res = merge([json.loads(f.read_text()) for f in a.merge])
    else:
        res = run(only=a.only, limit=a.limit, progress=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"{res['probes']} probes, {res['clean']} clean, findings by class {res['findings_by_class']}, "
          f"{res['seconds']} s; wrote {a.out}")
    return res


if __name__ == "__main__":
    main()
