"""The design reference (docs/guide/design-files.md) and the design layer name the same keys.

Two lists are compared. The documented keys are the first column of the
reference's tables (`cables.NAME.friction`, `SOLID.box.min`, ...). The keys
the design layer reads are recorded while it parses every bundled design and
every complete example on the reference page: each ``Table.take`` and
``Table.has`` names one key of one table, whatever the design holds (an
optional key absent from the file is still asked for). A key that only a
branch the examples never reach reads is caught by a third list, the string
literals given to ``take``/``has`` in skelfem/design/*.py.
"""
from __future__ import annotations

import ast
import re
import tomllib
from pathlib import Path

import pytest

from skelfem.design import table as design_table
from skelfem.design.parse import parse_design, read_toml
from skelfem.design.spec import SECTIONS_BY_NAME

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "docs" / "guide" / "design-files.md"
FIRST_OBJECT = ROOT / "docs" / "guide" / "first-object.md"
README = ROOT / "README.md"
DESIGN_LAYER = ROOT / "skelfem" / "design"
HEADER = re.compile(r"^\|\s*key\s*\|\s*type\s*\|\s*default\s*\|\s*unit\s*\|\s*meaning\s*\|\s*$")
# keys whose children the design layer reads as a free-form table (by material), not one take() each
FREE_FORM = {"cables.NAME.friction.MATERIAL": "cables.NAME.friction"}


def documented_keys(text: str) -> dict:
    """{key: row} of every reference table (the header | key | type | default | unit | meaning |)."""
    keys, in_table = {}, False
    for line in text.splitlines():
        if HEADER.match(line):
            in_table = True
            continue
        if in_table and line.startswith("|"):
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", line.strip()[1:-1])]   # \| is text
            if set(cells[0]) <= set("-: "):
                continue
            key = re.fullmatch(r"`([^`]+)`", cells[0])
            assert key, f"the first column must be one `key`: {line}"
            assert len(cells) >= 5 and cells[4], f"a row needs type, default, unit and meaning: {line}"
            assert cells[1], f"no type: {line}"
            assert key.group(1) not in keys, f"{key.group(1)} documented twice"
            keys[key.group(1)] = cells
        else:
            in_table = False
    return keys


def normalised(where: str, name: str) -> str:
    """A Table's (where, key) as the reference writes it: entries and free names as NAME, PAIR, SOLID."""
    if "solids[" in where:                                   # body.solids[0].box -> SOLID.box.min
        return f"SOLID.{where.rsplit('.', 1)[1]}.{name}"
    if where in ("materials", "markers"):
        return f"{where}.NAME"
    if where == "contact.pairs":
        return "contact.pairs.PAIR"
    if where.startswith("contact.pairs."):
        return f"contact.pairs.PAIR.{name}"
    parts = where.split(".") if where else []
    if parts and (parts[0] in SECTIONS_BY_NAME or parts[0] == "materials") and len(parts) >= 2:
        parts[1] = "NAME"                                    # pins.base.rotate -> pins.NAME.rotate
    return ".".join([*parts, name])


def toml_blocks(path: Path) -> list[str]:
    """The complete designs among a page's ```toml blocks (those that give `format`)."""
    blocks = re.findall(r"```toml\n(.*?)```", path.read_text(), re.S)
    return [b for b in blocks if re.search(r"^format\s*=", b, re.M)]


def corpus() -> list[tuple[str, dict]]:
    designs = [(p.name, read_toml(p)) for p in sorted((ROOT / "geometry").glob("*.toml"))]
    for page in (REFERENCE, FIRST_OBJECT, README):
        designs += [(f"{page.name}[{i}]", tomllib.loads(b)) for i, b in enumerate(toml_blocks(page))]
    return designs


@pytest.fixture(scope="module")
def read_keys():
    """Every key the design layer asks for while parsing the corpus (each parses)."""
    seen: set = set()
    take, has = design_table.Table.take, design_table.Table.has

    def recording_take(self, name, *args, **kwargs):
        seen.add(normalised(self.where, name))
        return take(self, name, *args, **kwargs)

    def recording_has(self, name):
        seen.add(normalised(self.where, name))
        return has(self, name)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(design_table.Table, "take", recording_take)
        mp.setattr(design_table.Table, "has", recording_has)
        for source, data in corpus():
            parse_design(data, source)
    return seen


def literal_keys() -> set:
    """String literals given as the first argument of take()/has() in the design layer."""
    out = set()
    for path in DESIGN_LAYER.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr in ("take", "has") and node.args
                    and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
                out.add(node.args[0].value)
    return out


def test_the_complete_designs_on_the_pages_are_valid():
    for page in (REFERENCE, README):
        blocks = toml_blocks(page)
        assert blocks, f"{page.name} has no complete design"
        for i, block in enumerate(blocks):
            parse_design(tomllib.loads(block), f"{page.name}[{i}]")


def test_every_key_the_design_layer_reads_is_documented(read_keys):
    documented = documented_keys(REFERENCE.read_text())
    missing = sorted(k for k in read_keys
                     if k not in documented and not any(d.startswith(k + ".") for d in documented))
    assert not missing, f"keys the design layer reads that docs/guide/design-files.md does not list: {missing}"


def test_every_documented_key_is_read(read_keys):
    documented = documented_keys(REFERENCE.read_text())
    unread = sorted(k for k in documented if k not in read_keys and FREE_FORM.get(k) not in read_keys)
    assert not unread, f"keys documented in design-files.md that the design layer never reads: {unread}"


def test_every_literal_key_in_the_design_layer_is_documented():
    """A key read only in a branch the examples never reach is still in the reference."""
    documented = documented_keys(REFERENCE.read_text())
    parts = {part for k in documented for part in k.split(".")}
    missing = sorted(literal_keys() - parts)
    assert not missing, f"keys read in skelfem/design that design-files.md does not list: {missing}"


def test_the_reference_rows_are_complete():
    documented = documented_keys(REFERENCE.read_text())
    assert len(documented) > 100
    for key, (_, kind, default, unit, meaning) in documented.items():
        assert kind and meaning, key
        if "mm" in meaning.split("(")[0] and unit == "":
            pytest.fail(f"{key}: a length without a unit")


def test_every_bundled_design_is_listed():
    text = REFERENCE.read_text()
    listed = set(re.findall(r"^\| `geometry/([^`]+)` \|", text, re.M))
    bundled = {p.name for p in (ROOT / "geometry").iterdir() if p.suffix in (".toml", ".csv")}
    assert bundled == listed, (sorted(bundled - listed), sorted(listed - bundled))


@pytest.mark.slow
def test_gravity_ramps_with_the_load_steps_as_the_reference_says():
    """design-files.md: "Gravity is ramped with the load steps, as contractions and loads are"."""
    from skelfem import Session
    assert "Gravity is ramped with the load steps" in REFERENCE.read_text()
    factors = {"gravity": [], "cables": []}
    with Session(ROOT / "geometry" / "finger_block.toml", ["solver.steps=4", "mesh.size=5"]) as s:
        for section, name in (("gravity", "gravity"), ("cables", "flexor")):
            term = s.model.term(section, name)
            real = term.set_factor
            term.set_factor = lambda a, real=real, seen=factors[section]: (seen.append(a), real(a))[1]
        assert s.solve().converged
    for section in factors:
        ramp = sorted(set(factors[section]) - {0.0})
        assert ramp[:4] == [0.25, 0.5, 0.75, 1.0], (section, factors[section])


def _within(part, whole) -> bool:
    """Every key and value of part is in whole (entries of a [[...]] list matched by name)."""
    if isinstance(part, dict):
        return isinstance(whole, dict) and all(k in whole and _within(v, whole[k]) for k, v in part.items())
    if isinstance(part, list) and part and all(isinstance(e, dict) and "name" in e for e in part):
        named = {e.get("name"): e for e in whole if isinstance(e, dict)} if isinstance(whole, list) else {}
        return all(e["name"] in named and _within(e, named[e["name"]]) for e in part)
    return part == whole


def test_the_first_object_recipe_quotes_its_design_file():
    """The recipe's snippets are the bundled design's own keys and values (a change to one shows here)."""
    design = read_toml(ROOT / "geometry" / "finger_block.toml")
    snippets = re.findall(r"```toml\n(.*?)```", FIRST_OBJECT.read_text(), re.S)
    assert len(snippets) >= 3
    for text in snippets:
        assert _within(tomllib.loads(text), design), text
    assert "geometry/finger_block.toml" in FIRST_OBJECT.read_text()
