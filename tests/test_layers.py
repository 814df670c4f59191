"""The package's import graph holds to its layers (docs: architecture).

Every ``import`` in skelfem, function-local ones included, is read from the
source (nothing is imported). A module may import its own layer or a lower
one, never a higher one; no modules import each other, directly or round a
longer cycle; no module imports another module's private (``_name``) names.
The checks are run on hand-made graphs too, so each one is seen to fail.
"""
from __future__ import annotations

import ast
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "skelfem"

# Lowest first. A module's layer is its sub-package (or, at the top, its own name).
LAYERS = [
    ("runtime",),                       # signals, MPI guard, JIT cache
    ("io",),                            # files, XDMF, output folders
    ("design",),                        # design files, validation (no DOLFINx)
    ("mesh",),                          # Gmsh -> DOLFINx mesh, material points
    ("terms",),                         # one module per physical ingredient
    ("fem",),                           # model, matrix, linear solves, Newton, time steps
    ("result", "session", "observables", "estimate"),   # the live Session, its Result, observables, their errors
    ("analysis", "viz"),                # sensitivities, control, optimisation; pictures
    ("accuracy", "fabricate"),          # --tol ladders; printable parts
    ("jobs",),                          # one run to files, sweeps, bench
    ("editor",),                        # the browser editor
    ("cli",),                           # the command line
    ("__init__", "__main__"),           # the public surface and python -m skelfem
]
RANK = {name: i for i, names in enumerate(LAYERS) for name in names}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer(module: str) -> str:
    parts = module.split(".")
    if len(parts) == 1:
        return "__init__"
    return parts[1]


def is_module(name: str) -> bool:
    path = ROOT.parent / Path(*name.split("."))
    return path.with_suffix(".py").exists() or (path / "__init__.py").exists()


def imports(path: Path) -> list[tuple[str, list[str], int]]:
    """(imported skelfem module, names taken from it, line) for every import statement in the file."""
    mod = module_name(path)
    package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names if a.name.split(".")[0] == "skelfem"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "skelfem":
                continue
            names = [a.name for a in node.names]
            modules = [n for n in names if is_module(f"{target}.{n}")]   # `from . import x`: the module x
            out += [(f"{target}.{n}", [], node.lineno) for n in modules]
            if len(modules) < len(names):
                out.append((target, [n for n in names if n not in modules], node.lineno))
    return out


def graph() -> dict[str, dict[str, list]]:
    g: dict[str, dict[str, list]] = {}
    for path in sorted(ROOT.rglob("*.py")):
        mod = module_name(path)
        g.setdefault(mod, {})
        for target, names, line in imports(path):
            if target != mod:
                g[mod].setdefault(target, []).append((names, line))
    return g


def upward(g) -> list[str]:
    bad = []
    for mod, targets in g.items():
        for target in targets:
            if target not in g:
                bad.append(f"{mod} imports {target}, which does not exist")
            elif RANK[layer(target)] > RANK[layer(mod)]:
                bad.append(f"{mod} ({layer(mod)}) imports {target} ({layer(target)}), a higher layer")
    return bad


def cycles(g) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan). Importing a package's
    __init__ and its sub-modules is not a cycle by itself: an edge to a package counts as an edge to it."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in g.get(v, {}):
            if w not in g:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in list(g):
        if v not in index:
            visit(v)
    return out


def private(g) -> list[str]:
    return [f"{mod} imports {n} from {target} (line {line})"
            for mod, targets in g.items() for target, uses in targets.items()
            for names, line in uses for n in names if n.startswith("_") and not n.startswith("__")]


def test_every_module_has_a_layer():
    assert [m for m in graph() if layer(m) not in RANK] == []


def test_no_module_imports_a_higher_layer():
    assert upward(graph()) == []


def test_no_import_cycles():
    assert cycles(graph()) == []


def test_no_private_names_cross_modules():
    assert private(graph()) == []


# Module length follows from the concept a module holds: past SOFT_LINES a module is worth a second
# look (a warning, unless it is one of the agreed exceptions below, each with its reason); past
# HARD_LINES it fails.
SOFT_LINES, HARD_LINES = 600, 800
LONG_MODULES = {
    "skelfem.fem.linear": "the direct and the iterative solve share the low-rank (Woodbury) and border algebra",
    "skelfem.fem.model": "the one place the terms meet: their summed energy and derivatives, the state, the "
                         "constraints, the live parameters and the terms found by ability (Model.having)",
    "skelfem.terms.object_friction": "the potential, its lag, the anchors' return map and the landing of objects "
                                     "all read and write the one per-vertex anchor state (facet, b, T, N, fresh)",
}


def module_lengths() -> dict[str, int]:
    return {module_name(p): len(p.read_text().splitlines()) for p in ROOT.rglob("*.py")}


def length_findings(lengths: dict[str, int], agreed: dict[str, str]) -> tuple[list[str], list[str]]:
    """(failures, warnings): modules over HARD_LINES; modules over SOFT_LINES not agreed, and agreed
    exceptions that are no longer long or no longer exist (the list kept honest)."""
    failures = [f"{m}: {n} lines > {HARD_LINES}" for m, n in sorted(lengths.items()) if n > HARD_LINES]
    warns = [f"{m}: {n} lines > {SOFT_LINES} (split it by concept, or agree it in LONG_MODULES with a reason)"
             for m, n in sorted(lengths.items()) if SOFT_LINES < n <= HARD_LINES and m not in agreed]
    warns += [f"{m} is listed in LONG_MODULES but has {lengths.get(m, 0)} lines: take it off the list"
              for m in sorted(agreed) if lengths.get(m, 0) <= SOFT_LINES]
    return failures, warns


def test_no_module_is_over_the_hard_cap_and_long_ones_are_agreed():
    failures, warns = length_findings(module_lengths(), LONG_MODULES)
    for w in warns:
        warnings.warn(w, UserWarning, stacklevel=1)
    assert failures == []
    assert all(reason.strip() for reason in LONG_MODULES.values())


def test_the_length_rule_fails_warns_and_keeps_its_list_honest():
    lengths = {"skelfem.a": 900, "skelfem.b": 700, "skelfem.c": 650, "skelfem.d": 100}
    failures, warns = length_findings(lengths, {"skelfem.c": "why", "skelfem.d": "was long once"})
    assert failures == ["skelfem.a: 900 lines > 800"]
    assert len(warns) == 2 and warns[0].startswith("skelfem.b: 700 lines") and "skelfem.d is listed" in warns[1]


# -- the checks themselves fail when they should --------------------------------------------------------
def test_the_checks_catch_an_upward_import_a_cycle_and_a_private_name():
    g = {"skelfem.fem.model": {"skelfem.analysis.control": [([], 1)]},
         "skelfem.analysis.control": {"skelfem.fem.model": [(["_packs"], 2)]}}
    assert upward(g) == ["skelfem.fem.model (fem) imports skelfem.analysis.control (analysis), a higher layer"]
    assert cycles(g) == [["skelfem.analysis.control", "skelfem.fem.model"]]
    assert private(g) == ["skelfem.analysis.control imports _packs from skelfem.fem.model (line 2)"]
    three = {"skelfem.a.x": {"skelfem.a.y": []}, "skelfem.a.y": {"skelfem.a.z": []}, "skelfem.a.z": {"skelfem.a.x": []}}
    assert cycles(three) == [["skelfem.a.x", "skelfem.a.y", "skelfem.a.z"]]


def test_function_local_imports_are_read(tmp_path):
    pkg = tmp_path / "skelfem"
    (pkg / "fem").mkdir(parents=True)
    (pkg / "analysis").mkdir()
    for p in (pkg / "__init__.py", pkg / "fem" / "__init__.py", pkg / "analysis" / "__init__.py",
              pkg / "analysis" / "control.py"):
        p.write_text("")
    (pkg / "fem" / "model.py").write_text("def f():\n    from ..analysis import control\n")
    global ROOT
    saved, ROOT = ROOT, pkg
    try:
        assert any("a higher layer" in b for b in upward(graph()))
    finally:
        ROOT = saved


@pytest.mark.parametrize("module", ["skelfem"])
def test_importing_the_library_changes_no_global_state(module):
    """`import skelfem` (and the public names' modules) installs no signal handler, sets no
    PETSc option, no matplotlib backend and no environment variable."""
    import subprocess
    import sys
    code = r'''
import os, signal, sys
env0 = dict(os.environ)
handlers0 = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
import matplotlib
backend0 = matplotlib.rcParams._get_backend_or_none() if hasattr(matplotlib.rcParams, "_get_backend_or_none") else None
import skelfem
from skelfem import Session, Result, Design, DesignError
import skelfem.session, skelfem.fem.model, skelfem.analysis.control, skelfem.viz.plots, skelfem.io.xdmf
from petsc4py import PETSc
opts = PETSc.Options().getAll()
assert opts == {} or set(opts) <= {"no_signal_handler"}, opts
assert {s: signal.getsignal(s) for s in handlers0} == handlers0, "signal handlers changed"
assert dict(os.environ) == env0, set(os.environ.items()) ^ set(env0.items())
after = matplotlib.rcParams._get_backend_or_none() if hasattr(matplotlib.rcParams, "_get_backend_or_none") else None
assert after == backend0, (backend0, after)
from ffcx.codegeneration import jit
assert not hasattr(jit.get_cached_module, "lookup"), "FFCx patched at import"
print("ok")
'''
    env = {k: v for k, v in __import__("os").environ.items() if k != "MPLBACKEND"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0 and r.stdout.strip().endswith("ok"), r.stderr[-2000:]


def test_a_misspelt_term_hook_is_refused_when_the_class_is_defined():
    from skelfem.terms import BUILDERS  # noqa: F401 (every registered term defined without complaint)
    from skelfem.terms.base import Term

    with pytest.raises(TypeError, match="did you mean end_step"):
        class Misspelt(Term):
            def end_steps(self, model):
                pass

    with pytest.raises(TypeError, match="did you mean readout"):
        class Plural(Term):
            def readouts(self, model):
                return {}

    class Fine(Term):                 # a new helper name far from any hook is fine
        def stiffness_of(self, x):
            return x


def test_a_hook_of_an_ability_the_term_does_not_declare_is_refused():
    """Optional hooks belong to abilities (skelfem.terms.capabilities) that the model finds with
    isinstance: a term defining end_step without declaring History would never be told of a step."""
    from skelfem.terms.base import Term
    from skelfem.terms.capabilities import CAPABILITIES, History

    with pytest.raises(TypeError, match="a hook of History"):
        class Undeclared(Term):
            def end_step(self, model):
                pass

    class Declared(Term, History):
        def end_step(self, model):
            pass

    hooks = [n for n, v in vars(Term).items() if not n.startswith("_") and callable(v)]
    assert len(hooks) <= 13, hooks           # the small contract: energy, pattern, parameters, read-outs
    assert len(CAPABILITIES) >= 10
