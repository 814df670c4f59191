"""skelfem fabricate --format 3mf: the whole robot as one multi-material 3MF (body and bones on their own
extruders, cable channels open), read back and checked independently; slicing it is in test_study_slice_check."""
import json
import zipfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from skelfem.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
GEOMETRY = ROOT / "geometry"
CORE = "{http://schemas.microsoft.com/3dmanufacturing/core/2015/02}"


def parse_3mf(path: Path) -> tuple[np.ndarray, np.ndarray, list[dict], list[str]]:
    """(vertices, triangles with their material index, the volumes of Slic3r_PE_model.config, base material
    names) of a 3MF, parsed here with the standard library."""
    with zipfile.ZipFile(path) as z:
        names = set(z.namelist())
        assert {"[Content_Types].xml", "_rels/.rels", "3D/3dmodel.model", "Metadata/Slic3r_PE_model.config"} <= names
        assert "3D/3dmodel.model" in z.read("_rels/.rels").decode()
        model = ET.fromstring(z.read("3D/3dmodel.model"))
        config = ET.fromstring(z.read("Metadata/Slic3r_PE_model.config"))
    assert model.get("unit") == "millimeter"
    objects = model.findall(f"{CORE}resources/{CORE}object")
    assert len(objects) == 1 and len(model.findall(f"{CORE}build/{CORE}item")) == 1     # one object: one assembly
    v = np.array([[float(e.get(k)) for k in "xyz"] for e in model.iter(f"{CORE}vertex")])
    t = np.array([[int(e.get(k)) for k in ("v1", "v2", "v3", "p1")] for e in model.iter(f"{CORE}triangle")])
    bases = [b.get("name") for b in model.iter(f"{CORE}base")]
    volumes = []
    for vol in config.iter("volume"):
        meta = {m.get("key"): m.get("value") for m in vol.iter("metadata")}
        volumes.append({"first": int(vol.get("firstid")), "last": int(vol.get("lastid")), **meta})
    return v, t, volumes, bases


def closed_volume(points: np.ndarray, tris: np.ndarray) -> tuple[float, int]:
    """(signed volume, number of edges not shared by exactly two triangles used in opposite directions)."""
    a, b, c = points[tris[:, 0]], points[tris[:, 1]], points[tris[:, 2]]
    vol = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)
    half = tris[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    forward = {tuple(e) for e in half}
    bad = sum((e[1], e[0]) not in forward for e in half) + (len(forward) != len(half))
    return vol, bad


@pytest.fixture(scope="module")
def printed(tmp_path_factory):
    done = {}

    def get(name):
        if name not in done:
            out = tmp_path_factory.mktemp(name) / "print"
            assert main(["fabricate", str(GEOMETRY / f"{name}.toml"), "--format", "3mf", "--out", str(out), "-q"]
                        + ([] if name == "finger" else ["--no-picture"])) == 0
            done[name] = out, json.loads((out / "fabrication.json").read_text())
        return done[name]
    return get


@pytest.mark.parametrize("name", ["finger", "thumb", "finger3d"])
def test_one_object_whose_volumes_are_the_body_and_each_bone(name, printed):
    from skelfem.design.parse import load_design
    design = load_design(GEOMETRY / f"{name}.toml", [])
    out, report = printed(name)
    assert sorted(p.name for p in out.iterdir()) == sorted([f"{name}.3mf", "fabrication.json"]
                                                           + (["fabrication.png"] if name == "finger" else []))
    v, t, volumes, bases = parse_3mf(out / f"{name}.3mf")
    assert [vol["name"] for vol in volumes] == ["body"] + [f"bone_{b.name}" for b in design.bones]
    assert volumes[0]["first"] == 0 and volumes[-1]["last"] == len(t) - 1
    assert all(a["last"] + 1 == b["first"] for a, b in zip(volumes[:-1], volumes[1:]))   # every triangle once
    assert [vol["extruder"] for vol in volumes] == ["1"] + ["2"] * len(design.bones)
    assert len(bases) == 2 and design.body.material in bases[0] and design.bones[0].material in bases[1]
    total = 0.0
    for vol in volumes:
        tris = t[vol["first"]:vol["last"] + 1]
        assert np.all(tris[:, 3] == (0 if vol["name"] == "body" else 1))          # the core spec's materials
        volume, bad = closed_volume(v, tris[:, :3])
        assert bad == 0, vol["name"]                                              # closed and oriented
        part = report["parts"][vol["name"]]
        assert volume == pytest.approx(part["volume"], rel=0.01)                  # the CAD volume
        total += part["volume"]
    c = report["checks"]["complement"]
    # body and bones fill the body exactly, less its open channels (CAD volumes)
    assert total == pytest.approx(c["body_volume"] - c["channels_volume"], rel=1e-6)
    assert c["complement"] and report["checks"]["passed"] and 0 < c["channels_volume"] < 0.05 * c["body_volume"]
    assert v[:, 2].min() == pytest.approx(0.0, abs=1e-9)                          # on the bed
    assert report["print"]["down"] == "-z"                                        # lying flat, as drawn
    assert {ch["cable"] for ch in report["channels"]} == {c.name for c in design.cables}


def test_every_cable_end_in_a_bone_has_a_hole_up_to_the_top(printed):
    """The channel reaches the top surface above each cable end that lies in a bone (finger: the flexor's
    end in the distal bone and each ligament's two ends): the body's top face has a hole there."""
    from skelfem.design.parse import load_design
    design = load_design(GEOMETRY / "finger.toml", [])
    out, report = printed("finger")
    v, t, volumes, _ = parse_3mf(out / "finger.3mf")
    body = t[volumes[0]["first"]:volumes[0]["last"] + 1, :3]
    top = float(v[:, 2].max())
    c = v[body]
    on_top = np.all(np.abs(c[:, :, 2] - top) < 1e-6, axis=1)
    area_top = 0.5 * np.linalg.norm(np.cross(c[on_top, 1] - c[on_top, 0], c[on_top, 2] - c[on_top, 0]), axis=1).sum()
    holes = sum(2 if cab.kind == "ligament" else 1 for cab in design.cables)   # ends in bones
    r = {"tendon": design.fabrication.channel_diameter / 2, "ligament": design.fabrication.anchor_diameter / 2}
    expected_holes = sum(np.pi * r[cab.kind] ** 2 * (2 if cab.kind == "ligament" else 1) for cab in design.cables)
    outline = design.body.outline
    x, y = np.asarray(outline, float).T
    area_outline = 0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))
    assert holes == 9
    # the top face is the outline less the holes (polygonal holes: within 5 % of the circles' area)
    assert area_outline - area_top == pytest.approx(expected_holes, rel=0.05)


def test_a_channel_too_close_to_the_surface_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "sub" / "print"
    assert main(["fabricate", str(GEOMETRY / "finger.toml"), "--format", "3mf", "--out", str(out), "-q",
                 "--set", "cables.flexor.path=[[0.8,0],[0.8,78],[9,84]]"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and ": cables.flexor.path: printed, its" in err[0], err
    assert "fabrication.min_wall" in err[0]
    assert not (tmp_path / "sub").exists()


def test_orient_turns_a_cavity_inward():
    """A cube with a cubic void: the outer shell encloses positive volume, the void's negative."""
    from skelfem.fabricate import check_mesh, orient
    unit = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                      [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    pts = np.vstack([4 * unit, 1 + 2 * unit])
    tris = np.vstack([faces, faces + 8])               # both shells outward: the void counted as solid
    r = check_mesh(pts, orient(pts, tris))
    assert r["oriented"] and r["outer_shells"] == 1 and r["cavities"] == 1
    assert r["volume"] == pytest.approx(64 - 8)


def test_the_folder_holds_one_complete_result_when_the_format_changes(tmp_path):
    """A cast run's folder re-used for a print holds the print alone, and back again."""
    out = tmp_path / "fab"
    design = str(GEOMETRY / "thumb.toml")
    assert main(["fabricate", design, "--out", str(out), "-q", "--no-picture"]) == 0
    assert {p.suffix for p in out.iterdir()} == {".json", ".stl", ".step"}
    assert main(["fabricate", design, "--format", "3mf", "--out", str(out), "-q", "--no-picture"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["fabrication.json", "thumb.3mf"]
    assert main(["fabricate", design, "--out", str(out), "-q", "--no-picture"]) == 0
    assert not (out / "thumb.3mf").exists() and (out / "mould_top.stl").exists()


def _without_cables(tmp_path: Path) -> Path:
    """finger_soft.toml without its tendon: a body and nothing else."""
    text = (GEOMETRY / "finger_soft.toml").read_text()
    path = tmp_path / "plain.toml"
    path.write_text(text[:text.index("[[cables]]")] + text[text.index("[[pins]]"):])
    return path


@pytest.mark.parametrize("which", ["no_cables", pytest.param("finger_soft", marks=pytest.mark.slow)])
def test_a_design_without_bones_prints_its_body_alone(which, tmp_path):
    """Without bones (finger_soft), and without cables too, the 3MF holds the body alone: no boolean
    with an empty list of tools, one volume on extruder 1, closed, its volume the body's less its channels."""
    design = GEOMETRY / "finger_soft.toml" if which == "finger_soft" else _without_cables(tmp_path)
    out = tmp_path / "print"
    assert main(["fabricate", str(design), "--format", "3mf", "--out", str(out), "-q", "--no-picture"]) == 0
    report = json.loads((out / "fabrication.json").read_text())
    v, t, volumes, bases = parse_3mf(out / "finger_soft.3mf")
    assert [(vol["name"], vol["extruder"]) for vol in volumes] == [("body", "1")] and len(bases) == 1
    assert volumes[0]["first"] == 0 and volumes[0]["last"] == len(t) - 1 and np.all(t[:, 3] == 0)
    volume, bad = closed_volume(v, t[:, :3])
    assert bad == 0
    c = report["checks"]["complement"]
    assert report["checks"]["passed"] and list(report["parts"]) == ["body"]
    assert volume == pytest.approx(c["body_volume"] - c["channels_volume"], rel=0.01)
    assert (c["channels_volume"] > 0) == (which == "finger_soft")
    assert v[:, 2].min() == pytest.approx(0.0, abs=1e-9)
