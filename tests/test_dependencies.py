"""Runtime dependencies are what skelfem imports; what only the tests and studies import is an extra that
`make setup` installs."""
from __future__ import annotations

import ast
import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IMPORT_NAMES = {"scikit-fem": "skfem"}                  # distribution -> module, where they differ
USED_THROUGH = {"websockets": "uvicorn's websocket protocol (skelfem edit)"}


def distribution(spec: str) -> str:
    return re.match(r"[A-Za-z0-9_.-]+", spec).group(0).lower()


def imported_modules(folder: Path) -> set:
    out = set()
    for path in folder.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                out |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                out.add(node.module.split(".")[0])
    return out


def test_every_runtime_dependency_is_imported_by_skelfem():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    used = imported_modules(ROOT / "skelfem")
    for spec in project["dependencies"]:
        name = distribution(spec)
        module = IMPORT_NAMES.get(name, name)
        assert module in used or name in USED_THROUGH, f"{name} is a runtime dependency that skelfem never imports"


def test_what_the_suite_and_studies_import_is_an_extra_that_make_setup_installs():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = {distribution(s): group for group, specs in project["optional-dependencies"].items() for s in specs}
    make = (ROOT / "Makefile").read_text()
    installed = set(re.search(r'pip install .*-e "\.\[([\w,]+)\]"', make).group(1).split(","))
    outside = imported_modules(ROOT / "tests") | imported_modules(ROOT / "studies")
    for name in ("hypothesis", "scikit-fem"):
        assert IMPORT_NAMES.get(name, name) in outside
        assert name in extras, f"{name} is not an optional dependency"
        assert extras[name] in installed, f"make setup does not install the {extras[name]!r} extra ({name})"
