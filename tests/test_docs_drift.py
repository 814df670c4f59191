"""Docs that cannot drift: the API page, the architecture's module table, and the README's and the guide's
code blocks are held to the code.

- docs/api.md documents exactly the names of ``skelfem.__all__``.
- docs/architecture.md's module table names exactly the modules of skelfem/.
- Every ```python block of README.md and docs/**/*.md runs, from the repository's root (slow: they solve
  the bundled designs at their own mesh sizes).
- Every shell block's commands are checked without running them (they run long jobs, write results/ and
  install packages): a ``skelfem ...`` line is parsed by the command's own argument parser (as ``--help``
  would read it) and the files it names exist; ``python studies/X.py`` and ``examples/X.py`` exist;
  ``make TARGET`` is a Makefile target.
"""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

import skelfem
from skelfem.design import DesignError, load_design

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "docs" / "guide").glob("*.md"))]
SHELLS = ("sh", "bash", "shell", "console")


def blocks(path: Path, languages) -> list[tuple[int, str]]:
    """(line number, text) of every fenced block of the given languages."""
    out, lines = [], path.read_text().splitlines()
    i = 0
    while i < len(lines):
        m = re.match(r"^```(\w+)\s*$", lines[i])
        if m and m.group(1) in languages:
            j = i + 1
            while not lines[j].startswith("```"):
                j += 1
            out.append((i + 1, "\n".join(lines[i + 1:j])))
            i = j
        i += 1
    return out


# -- the API page ---------------------------------------------------------------------------------------
def documented_api() -> set:
    text = (ROOT / "docs" / "api.md").read_text()
    return set(re.findall(r"^\.\. (?:auto\w+|py:\w+):: skelfem\.(\w+)\s*$", text, re.M))


def test_the_api_page_documents_every_public_name_and_no_other():
    documented, public = documented_api(), set(skelfem.__all__)
    assert public - documented == set(), f"in skelfem.__all__, not in docs/api.md: {sorted(public - documented)}"
    assert documented - public == set(), f"in docs/api.md, not in skelfem.__all__: {sorted(documented - public)}"


def test_the_api_check_sees_a_missing_name():
    assert "Linearization" in documented_api()
    text = (ROOT / "docs" / "api.md").read_text().replace(".. autoclass:: skelfem.Linearization", "")
    assert "Linearization" not in set(re.findall(r"^\.\. (?:auto\w+|py:\w+):: skelfem\.(\w+)\s*$", text, re.M))


# -- the architecture's module table --------------------------------------------------------------------
def table_modules(text: str) -> set:
    """Modules named by the table under '### Modules' as 'folder/module' ('module' at the top)."""
    start = text.index("| layer | modules | what they do |")
    out = set()
    for line in text[start:].splitlines()[2:]:
        if not line.startswith("|"):
            break
        layer, modules = [c.strip() for c in line.strip().strip("|").split("|")][:2]
        folders = re.findall(r"`(\w+)/`", layer) or [""]                # "top" and "package": the top level
        groups = modules.split(";")
        assert len(groups) == len(folders), f"one ';'-separated group of modules per folder: {line}"
        for folder, group in zip(folders, groups):
            for name in re.findall(r"`(\w+)`", group):
                out.add(f"{folder}/{name}" if folder else name)
    return out


def package_modules() -> set:
    out = set()
    for path in (ROOT / "skelfem").rglob("*.py"):
        rel = path.relative_to(ROOT / "skelfem").with_suffix("")
        if rel.name == "__init__" and rel.parent != Path("."):
            continue                                                   # a sub-package's __init__
        out.add(rel.as_posix())
    return out


def test_the_architecture_module_table_names_every_module_and_no_other():
    table, package = table_modules((ROOT / "docs" / "architecture.md").read_text()), package_modules()
    assert package - table == set(), f"modules missing from docs/architecture.md's table: {sorted(package - table)}"
    assert table - package == set(), f"docs/architecture.md names modules that do not exist: {sorted(table - package)}"


# -- what the architecture page says about imports --------------------------------------------------------
def test_importing_the_contact_term_leaves_ipctk_threads_alone():
    """ipctk runs one thread once contact is built, not from the import on (it set 1 at import)."""
    code = ("import ipctk; ipctk.set_num_threads(2); n = ipctk.get_num_threads(); "
            "import skelfem.terms.contact, skelfem.terms; print(n, ipctk.get_num_threads())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    before, after = out.stdout.split()[-2:]
    if before == "1":
        pytest.skip("one core: ipctk runs one thread whatever is set")
    assert after == before


# -- code blocks --------------------------------------------------------------------------------------------
PYTHON_BLOCKS = [(page, line, text) for page in PAGES for line, text in blocks(page, ("python",))]


def test_python_blocks_found():
    assert {p.name for p, _, _ in PYTHON_BLOCKS} >= {"README.md", "api.md", "session.md", "first-object.md"}


@pytest.mark.slow
@pytest.mark.parametrize("page, line, text", [pytest.param(*b, id=f"{b[0].name}:{b[1]}") for b in PYTHON_BLOCKS])
def test_python_block_runs(page, line, text, tmp_path):
    script = tmp_path / "block.py"
    script.write_text(text + "\n")
    env = {**os.environ, "MPLBACKEND": "Agg", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    before = set(os.listdir(ROOT))
    proc = subprocess.run([sys.executable, str(script)], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, f"{page.name}:{line}:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    assert set(os.listdir(ROOT)) == before, "a code block wrote into the repository"


def shell_commands(text: str) -> list[str]:
    """The commands of a shell block: comments and prompts dropped, continuation lines joined."""
    text = re.sub(r"\\\n\s*", " ", text)
    out = []
    for raw in text.splitlines():
        line = raw.strip()
        line = line[2:] if line.startswith("$ ") else line
        line = re.sub(r"\s\[[^\[\]]*\]", "", line)          # a synopsis' [optional] parts
        if not line or line.startswith("#"):
            continue
        try:
            words = shlex.split(line, comments=True)
        except ValueError as exc:
            raise AssertionError(f"not a shell command: {raw!r} ({exc})") from None
        if words:
            out.append(words)
    return out


def skelfem_args(words: list[str]) -> list[str] | None:
    """The arguments after `skelfem` (bare, .venv/bin/skelfem, python -m skelfem, under mpirun), or None."""
    for i, w in enumerate(words):
        if Path(w).name == "skelfem" and (i == 0 or words[i - 1] not in ("-m",)):
            return words[i + 1:]
        if w == "skelfem" and i >= 1 and words[i - 1] == "-m":
            return words[i + 1:]
    return None


SHELL_BLOCKS = [(page, line, text) for page in PAGES for line, text in blocks(page, SHELLS)]


def test_shell_blocks_found():
    assert len(SHELL_BLOCKS) >= 20


@pytest.mark.parametrize("page, line, text", [pytest.param(*b, id=f"{b[0].name}:{b[1]}") for b in SHELL_BLOCKS])
def test_shell_block_commands_parse(page, line, text):
    from skelfem.cli.main import _parser
    targets = set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.M))
    for words in shell_commands(text):
        where = f"{page.name}:{line}: {' '.join(words)}"
        args = skelfem_args(words)
        if args is not None:
            if not args or args[0] in ("-h", "--help"):
                continue
            try:
                ns = _parser().parse_args(args)
            except SystemExit as exc:            # --help of a sub-command
                assert exc.code == 0, where
                continue
            except Exception as exc:             # the command's one-line input error
                pytest.fail(f"{where}: {exc}")
            for key in ("design", "data", "spec"):
                value = getattr(ns, key, None)
                if isinstance(value, Path) and str(value).startswith(("geometry/", "studies/", "examples/")):
                    assert (ROOT / value).exists(), f"{where}: no file {value}"
            design = getattr(ns, "design", None)
            if isinstance(design, Path) and str(design).startswith("geometry/") and design.suffix == ".toml":
                try:                                 # the design with the command's --set keys: no meshing
                    load_design(ROOT / design, getattr(ns, "overrides", None) or ())
                except DesignError as exc:
                    pytest.fail(f"{where}: {exc}")
            continue
        if words[0] in ("python", "python3", ".venv/bin/python") and len(words) > 1 and words[1].endswith(".py"):
            assert (ROOT / words[1]).exists(), f"{where}: no script {words[1]}"
        elif words[0] == "make" and len(words) > 1:
            assert all(t in targets for t in words[1:] if not t.startswith("-") and "=" not in t), where
