"""Named, frozen results across module boundaries (issue 57): a function of the core that returns a tuple of three
or more, used by another module, is listed here with why, and the list cannot grow.

On cb7fa7a seven module-level functions of ``nifo_core`` returned tuples of three or more to other modules (this
scan); five of them (``parameter_space``, ``period_and_transient``, ``fixed_point_solve``, ``judge_alternatives``,
``base_fit``) now return :class:`~nifo_core.predict.refine_space.ParameterSpace`, :class:`~nifo_core.settings.Timing`,
:class:`~nifo_core.predict.fixed_point.FixedPoint`, :class:`~nifo_core.loop.gates.Judgement`,
:class:`~nifo_core.characterize.score.BaseFit`. A tuple inside one module (a private helper's) is that module's
business and is not counted; nor are methods, and tests and benchmarks are not users.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WIDTH = 3
#: core functions still returning a tuple of WIDTH or more to another module, each with why
KNOWN = {
    "nifo_core.kinds.strut_forces:strut_arrays": "the compiled strut-force kernels take the kinds' codes, "
                                                 "coefficients and parameters as separate flat arrays",
    "nifo_core.predict.timesim:march_outputs": "the output buffers of the compiled march, filled in place by "
                                               "the kernel of either engine (one lane or many)",
    "nifo_core.kinds.strut_forces:g_partials": "compiled (numba, inlined in the sensitivity march's step): a "
                                               "tuple is what a compiled function returns without an allocation",
    "nifo_core.predict.timesim:march_start": "compiled (numba, inlined at the start of either march): a tuple is "
                                             "what a compiled function returns",
}


def _module(p: Path, root: Path) -> str:
    parts = list(p.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _width(fn: ast.FunctionDef) -> int:
    """The widest tuple ``fn`` itself returns: a tuple literal in its own ``return``s, or its annotation."""
    widths, todo = [0], list(fn.body)
    while todo:
        n = todo.pop()
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue
        if isinstance(n, ast.Return) and isinstance(n.value, ast.Tuple) and not any(
                isinstance(e, ast.Starred) for e in n.value.elts):
            widths.append(len(n.value.elts))
        todo.extend(ast.iter_child_nodes(n))
    a = fn.returns
    if isinstance(a, ast.Constant) and isinstance(a.value, str):
        a = ast.parse(a.value, mode="eval").body
    if isinstance(a, ast.BinOp):            # X | None
        a = a.left if isinstance(a.left, ast.Subscript) else a.right
    if isinstance(a, ast.Subscript) and ast.unparse(a.value) in ("tuple", "Tuple"):
        elts = a.slice.elts if isinstance(a.slice, ast.Tuple) else [a.slice]
        if not any(isinstance(e, ast.Constant) and e.value is Ellipsis for e in elts):
            widths.append(len(elts))
    return max(widths)


def _imported_from(m: str, p: Path, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = m.split(".") if p.name == "__init__.py" else m.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def crossing_tuple_returns(root: Path = ROOT) -> dict[str, set[str]]:
    """{"module:function": the other modules of nifo, nifo_core, nifo_nodes using it} for every module-level
    function of ``nifo_core`` returning a tuple of WIDTH or more that another module imports or calls."""
    files = {_module(p, root): p for pkg in ("nifo_core", "nifo", "nifo_nodes") for p in (root / pkg).rglob("*.py")}
    trees = {m: ast.parse(p.read_text(encoding="utf-8")) for m, p in files.items()}
    wide = {(m, n.name) for m, t in trees.items() if m.startswith("nifo_core") for n in t.body
            if isinstance(n, ast.FunctionDef) and _width(n) >= WIDTH}
    users: dict[str, set[str]] = {}
    for m, t in trees.items():
        modules: dict[str, str] = {}
        for node in ast.walk(t):
            if isinstance(node, ast.ImportFrom):
                src = _imported_from(m, files[m], node)
                for a in node.names:
                    if (src, a.name) in wide and src != m:
                        users.setdefault(f"{src}:{a.name}", set()).add(m)
                    if f"{src}.{a.name}" in files:
                        modules[a.asname or a.name] = f"{src}.{a.name}"
            elif isinstance(node, ast.Import):
                modules.update({a.asname: a.name for a in node.names if a.asname})
        for node in ast.walk(t):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in modules:
                src = modules[node.value.id]
                if (src, node.attr) in wide and src != m:
                    users.setdefault(f"{src}:{node.attr}", set()).add(m)
    return users


def test_no_new_core_function_returns_a_wide_tuple_to_another_module():
    found = crossing_tuple_returns()
    new = {k: sorted(v) for k, v in found.items() if k not in KNOWN}
    assert new == {}, (f"core functions returning a tuple of {WIDTH}+ to other modules (return a frozen dataclass, "
                       f"or state why in KNOWN): {new}")
    assert set(KNOWN) <= set(found), f"no longer crossing (remove from KNOWN): {set(KNOWN) - set(found)}"


def test_the_scan_finds_a_wide_tuple_crossing_a_module(tmp_path):
    """The scan is not blind: a tuple of three returned by one module is found by its annotation or its return
    statement (not a nested function's), and counted where another module imports it (relative import) or calls it
    through a module alias; a pair, or a wide tuple used only at home, is not."""
    src = ast.parse("def f(x) -> 'tuple[int, int, float] | None':\n    return None\n"
                    "def g(x):\n    def inner():\n        return 1, 2, 3, 4\n    return x, x, x\n"
                    "def h(x):\n    def inner():\n        return 1, 2, 3, 4\n    return (x, x)\n")
    assert [_width(n) for n in src.body] == [3, 3, 2]
    for pkg in ("nifo_core/sub", "nifo", "nifo_nodes"):
        (tmp_path / pkg).mkdir(parents=True)
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / "nifo_core" / "__init__.py").write_text("")
    (tmp_path / "nifo_core" / "sub" / "a.py").write_text(ast.unparse(src) + "\ndef home():\n    return 1, 2, 3\n"
                                                         "def _use():\n    return home()\n")
    (tmp_path / "nifo_core" / "sub" / "b.py").write_text("from .a import f, h\n")
    (tmp_path / "nifo" / "c.py").write_text("import nifo_core.sub.a as A\nA.g(1)\n")
    assert crossing_tuple_returns(tmp_path) == {"nifo_core.sub.a:f": {"nifo_core.sub.b"},
                                                "nifo_core.sub.a:g": {"nifo.c"}}
