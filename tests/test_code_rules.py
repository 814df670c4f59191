"""Rules of the code read from the source (nothing is imported): no function over MAX_FUNCTION_LINES
lines, and no module reaching into another's private attributes (``obj._name`` where obj is not
``self``/``cls`` and ``_name`` is not defined in the module itself). Each rule has a short list of
agreed exceptions, each with its reason; a listed exception that no longer occurs fails too, so the
lists only shrink. Each rule is also run on hand-made source, so it is seen to fail.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "skelfem"

MAX_FUNCTION_LINES = 100
# (module path, function name): reason it holds one idea at its length, until it is split
LONG_FUNCTIONS: dict[tuple[str, str], str] = {}

# (module path, attribute): why the module reads another's private attribute
REACH_INS = {
    ("skelfem/cli/__init__.py", "_exit"): "os._exit: the documented exit without clean-up",
    ("skelfem/cli/edit.py", "_exit"): "os._exit: the documented exit without clean-up",
    ("skelfem/cli/main.py", "_exit"): "os._exit: the documented exit without clean-up",
    ("skelfem/design/occ.py", "_pointer_type_cache"):
        "ctypes' cache of pointer types, which Gmsh's ctypes calls grow (forget_array_types)",
    ("skelfem/fem/assembly.py", "_cpp_object"): "DOLFINx 0.5.2 has no public handle on a space's C++ object",
    ("skelfem/fem/multigrid.py", "_cpp_object"): "DOLFINx 0.5.2 has no public handle on a space's C++ object",
    ("skelfem/fem/release.py", "_petsc_x"): "DOLFINx's PETSc vector over a Function's array: freed by hand",
    ("skelfem/terms/cable_route.py", "_mesh"): "DOLFINx 0.5.2's entities_to_geometry takes the C++ mesh",
    ("skelfem/accuracy/ladder.py", "_mesh"): "DOLFINx 0.5.2's entities_to_geometry takes the C++ mesh",
    ("skelfem/analysis/cable_shape.py", "_mesh"): "DOLFINx 0.5.2's entities_to_geometry takes the C++ mesh",
}


def sources() -> dict[str, str]:
    return {str(p.relative_to(ROOT.parent)): p.read_text() for p in sorted(ROOT.rglob("*.py"))}


def long_functions(files: dict[str, str], limit: int = MAX_FUNCTION_LINES) -> dict[tuple[str, str], int]:
    """{(module, qualified name): lines} of every function longer than limit (its def line to its last,
    nested functions included)."""
    out = {}
    for path, text in files.items():
        def visit(node, prefix):
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    name = f"{prefix}{child.name}"
                    if not isinstance(child, ast.ClassDef):
                        lines = child.end_lineno - child.lineno + 1
                        if lines > limit:
                            out[path, name] = lines
                    visit(child, name + ".")
                else:
                    visit(child, prefix)
        visit(ast.parse(text, path), "")
    return out


def _defined_here(tree: ast.AST) -> set[str]:
    """The underscore names a module defines: functions, classes, variables, self./cls. attributes."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif (isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store)
              and isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
            names.add(node.attr)
    return {n for n in names if n.startswith("_")}


def reach_ins(files: dict[str, str]) -> dict[tuple[str, str], list[str]]:
    """{(module, attribute): [expression (line)]} of every private attribute read or written on
    something other than self/cls that the module does not define itself."""
    out: dict[tuple[str, str], list[str]] = {}
    for path, text in files.items():
        tree = ast.parse(text, path)
        own = _defined_here(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute):
                obj, name = node.value, node.attr
            elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and len(node.args) >= 2
                  and node.func.id in ("getattr", "setattr", "hasattr", "delattr")
                  and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)):
                obj, name = node.args[0], node.args[1].value          # the same reach by a name in a string
            else:
                continue
            if not name.startswith("_") or name.startswith("__"):
                continue
            if isinstance(obj, ast.Name) and obj.id in ("self", "cls"):
                continue
            if name not in own:
                out.setdefault((path, name), []).append(f"{ast.unparse(node)} (line {node.lineno})")
    return out


def test_no_function_is_over_100_lines():
    found = long_functions(sources())
    assert {k: v for k, v in found.items() if k not in LONG_FUNCTIONS} == {}
    assert [k for k in LONG_FUNCTIONS if k not in found] == [], "no longer long: take it off the list"


def test_no_module_reaches_into_another_ones_private_attributes():
    found = reach_ins(sources())
    assert {k: v for k, v in found.items() if k not in REACH_INS} == {}
    assert [k for k in REACH_INS if k not in found] == [], "no longer reached: take it off the list"
    assert all(reason.strip() for reason in REACH_INS.values())


def test_the_rules_catch_a_long_function_and_a_reach_in():
    long = "def f(x):\n" + "    x += 1\n" * 100 + "    return x\n\n\ndef g():\n    return 1\n"
    assert long_functions({"m.py": long}) == {("m.py", "f"): 102}
    nested = "class A:\n    def f(self):\n        def inner():\n" + "            pass\n" * 120
    assert set(long_functions({"n.py": nested})) == {("n.py", "A.f"), ("n.py", "A.f.inner")}
    reach = ("class Mine:\n    def __init__(self):\n        self._own = 1\n\n"
             "    def same(self, other):\n        return other._own\n\n\n"
             "def poke(model, cable):\n    cable._version += 1\n    return model._free, self_._x\n\n\n"
             "def hide(mesh):\n    setattr(mesh, '_tree', 1)\n    return getattr(mesh, 'public', None)\n")
    found = reach_ins({"r.py": reach})
    assert set(found) == {("r.py", "_version"), ("r.py", "_free"), ("r.py", "_x"), ("r.py", "_tree")}
    assert found["r.py", "_version"] == ["cable._version (line 10)"]
