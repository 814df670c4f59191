"""Adversarial inputs, the third round's leftovers: one name rule for materials too, a live solve whose
warm start fails solved again from rest, numerics that do not follow Python's hash seed.

Every test says what the code did before it (each failed then).
"""
from __future__ import annotations

import copy
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from _hardening import ENV, strip2d
from conftest import GEOMETRY
from skelfem.design.parse import parse_design
from skelfem.design.spec import DesignError


def refused(d: dict, key: str, match: str) -> str:
    with pytest.raises(DesignError) as err:
        parse_design(d, "x.toml")
    message = str(err.value)
    assert message.startswith(f"x.toml: {key}: "), message
    assert match in message and "\n" not in message, message
    return message


def renamed_material(name: str, old: str = "soft") -> dict:
    """strip2d with material `old` renamed to name wherever it is used."""
    d = copy.deepcopy(strip2d())
    assert old in d["materials"]
    d["materials"][name] = d["materials"].pop(old)
    for section in ("body",):
        if d[section].get("material") == old:
            d[section]["material"] = name
    for entry in d.get("bones", []):
        if entry.get("material") == old:
            entry["material"] = name
    return d


# == material names follow the one name rule ===========================================================
# Before: material names were checked by nothing: 'a/b', control characters, 5000 bytes, '<form ...=...>'
# and names a --set key or a contact pair cannot address ('a.b', 'a=b', 'a:b') were accepted.
@pytest.mark.parametrize("name, key, match", [
    ("a/b", "materials.a/b", "must not contain '/'"),
    ("x\x01", "materials.x\\x01", "must not contain"),
    ("y" * 5000, "materials." + "y" * 25 + "...", "longer than 100 bytes"),
    ("a.b", "materials.a.b", "without '.' or '=' or ':'"),
    ("<form action=x>", "materials.<form action=x>", "without '.' or '=' or ':'"),
    ("a:b", "materials.a:b", "without '.' or '=' or ':'"),
    (".hidden", "materials..hidden", "without '.'"),
    (" soft", "materials. soft", "white space"),
], ids=["slash", "control", "long", "dot", "markup", "pair", "hidden", "space"])
def test_material_names_follow_the_name_rule(name, key, match):
    refused(renamed_material(name), key, match)


def test_every_bundled_material_name_passes_the_rule():
    from skelfem.design import load_design
    for path in sorted(GEOMETRY.glob("*.toml")):
        assert load_design(path).materials


def test_one_name_rule_for_entries_materials_and_markers():
    """The same name gets the same answer wherever a design gives it (an entry, a material, a marker)."""
    for bad in ("a.b", "a=b", "a/b", "\x7f", "z" * 101):
        messages = []
        d = copy.deepcopy(strip2d())
        d["cables"][0]["name"] = bad
        messages.append(_message(d))
        messages.append(_message(renamed_material(bad)))
        d = copy.deepcopy(strip2d())
        d["markers"][bad] = d["markers"].pop(next(iter(d["markers"])))
        messages.append(_message(d))
        tails = {m.split(": ", 2)[2].replace("a marker name", "a name").replace("a material name", "a name")
                 .replace(" or ':'", "") for m in messages}
        assert len(tails) == 1, messages


def _message(d: dict) -> str:
    with pytest.raises(DesignError) as err:
        parse_design(d, "x.toml")
    return str(err.value)


# == a live solve whose warm start fails is solved again from rest ======================================
# Before: Session.solve after an edit returned the warm start's failure (inverted_elements) where the
# same design from rest converges; only the --tol ladder retried.
def test_a_failed_warm_start_is_solved_again_from_rest():
    from skelfem import Session
    with Session(GEOMETRY / "finger.toml", ["mesh.size=4"]) as s:
        cold = s.solve()
        assert cold.converged and getattr(cold, "retried_from_rest", None) is None
        x = s.model.V.tabulate_dof_coordinates()[:, :2]
        u = s.model.u.x.array.reshape(-1, 2)
        u[:, 0] = -2.0 * (x[:, 0] - x[:, 0].mean())           # a carried-over start turning elements over
        s.set({"cables.flexor.contraction": 3.0})
        r = s.solve()
        assert r.converged, r.status
        assert r.retried_from_rest["warm_status"] == "inverted_elements"
        assert any("solved again from rest" in w for w in r.warnings)
        with type(s)(GEOMETRY / "finger.toml", ["mesh.size=4", "cables.flexor.contraction=3.0"]) as ref:
            expected = ref.solve()
        assert np.allclose(r.marker("tip"), expected.marker("tip"), atol=1e-9)


# == numerics that do not follow Python's hash seed ====================================================
# A state once differed at 1e-13 between two processes with objects (docs: objects' limits); a set of
# names iterated without sorting is the usual cause. Two processes with other hash seeds make the same
# state bit for bit: a solve with an object, contacts and friction, then an edit of several live keys
# at once (Model.refresh sets them in sorted order, not a set's).
HASH_SCRIPT = textwrap.dedent("""
    import copy, hashlib, json, sys
    from skelfem import Session
    from skelfem.design import load_design
    d = load_design(sys.argv[1], ["mesh.size=4"])
    raw = copy.deepcopy(d.raw)
    with Session(d) as s:
        first = s.solve()
        for c in raw["cables"]:
            if c.get("kind", "tendon") == "tendon":
                c["contraction"] = c.get("contraction", 0.0) + 1.0
            c["stiffness"] = c["stiffness"] * 1.5
        for m in raw["materials"].values():
            m["E"] = m["E"] * 1.2
        how = s.edit(raw)
        second = s.solve()
        print(json.dumps({"how": how, "its": [first.newton_iterations, second.newton_iterations],
                          "status": second.status,
                          "u": hashlib.sha256(s.model.u.x.array.tobytes()).hexdigest(),
                          "observables": second.observables()}, sort_keys=True))
""")


@pytest.mark.slow
@pytest.mark.parametrize("design", ["finger_block.toml", "gripper.toml"])
def test_two_hash_seeds_make_the_same_state_bit_for_bit(design, tmp_path):
    runs = []
    for seed in ("0", "4242"):
        p = subprocess.run([sys.executable, "-c", HASH_SCRIPT, str(GEOMETRY / design)], cwd=tmp_path,
                           env={**ENV, "PYTHONHASHSEED": seed}, capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, p.stderr
        runs.append(p.stdout.strip().splitlines()[-1])
    assert '"how": "same mesh"' in runs[0] and '"status": "converged"' in runs[0], runs[0]
    assert runs[0] == runs[1]


# == a friction solve that does not settle says why ======================================================
# Before: a tendon zigzagging through 90-degree turns with mu = 0.3 (finger_friction's flexor, h = 2 mm)
# exited 2 with "friction_not_converged ... try more [solver].steps or a finer mesh", after cutting the
# load to 1/256 (3481 Newton iterations): advice that does not help. The rounds are forced to fail here.
@pytest.mark.slow
def test_friction_that_does_not_settle_says_why(tmp_path, capsys, monkeypatch):
    from skelfem.cli.main import main
    from skelfem.fem import newton
    monkeypatch.setattr(newton, "MAX_LAG_UPDATES", 1)
    out = tmp_path / "out"
    code = main(["simulate", str(GEOMETRY / "finger_friction.toml"), "--set", "mesh.size=4", "--set",
                 "solver.steps=1", "--out", str(out), "-q", "--no-picture"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert code == 2 and len(err) == 1, err
    assert "friction_not_converged" in err[0] and "the friction limits did not settle" in err[0], err
    assert "try more [solver].steps" not in err[0]


# == cable friction on a zigzag tendon and in bench ======================================================
# Reported: cable friction crashed at mu = 0.3 on a zigzag tendon and in `skelfem bench`. Neither case
# below failed on the code before the mixing's restarts either (the report's exact files are not kept):
# they hold the symptom down. A tendon through four 90-degree turns in the soft finger converges (25
# Newton iterations at h = 4 mm); bench with cable friction measures it (exit 0).
def zigzag_finger(tmp_path) -> str:
    text = (GEOMETRY / "finger_soft.toml").read_text()
    old = "path = [[3, 0], [3, 78], [9, 84]]"
    assert old in text
    text = text.replace(old, "path = [[3, 0], [3, 20], [17, 20], [17, 40], [3, 40], [3, 60], [17, 60], [17, 80]]\n"
                             "friction = 0.3")
    path = tmp_path / "zigzag.toml"
    path.write_text(text)
    return str(path)


@pytest.mark.slow
def test_a_zigzag_tendon_with_friction_converges(tmp_path):
    from skelfem import Session
    with Session(zigzag_finger(tmp_path), ["mesh.size=4"]) as s:
        r = s.solve()
    assert r.converged, r.status
    tensions = r.cables["flexor"]["tensions"]      # friction holds tension back: it falls from the actuator
    assert tensions[0] > 1.5 * tensions[-1] > 0.0, tensions


@pytest.mark.slow
@pytest.mark.parametrize("design", ["finger_friction.toml", "zigzag"])
def test_bench_with_cable_friction(tmp_path, capsys, design):
    import json
    from skelfem.cli.main import main
    path = zigzag_finger(tmp_path) if design == "zigzag" else str(GEOMETRY / design)
    out = tmp_path / "bench"
    code = main(["bench", path, "--sizes", "4", "--repeats", "1", "--out", str(out), "-q"])
    assert code == 0, capsys.readouterr().err
    assert json.loads((out / "bench.json").read_text())
