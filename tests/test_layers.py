"""The layers point one way: no import cycle between modules or between packages, and the
bottom layers import only the core.

Edges are the imports a module runs when it is imported: its top-level ``import`` and
``from … import`` statements (also inside a top-level ``if``/``try``; not under
``if TYPE_CHECKING``). An import inside a function runs when the function is called, after
both modules are loaded, so it cannot create an import-time cycle; those lazy imports are
excluded, and the ones that would close a cycle are listed in ``LAZY_CYCLES`` (each says why).

Package level: every top-level package is a node (``firmware_io``, ``hil_sim``, ``testkit``,
``tests``, ``benchmarks``), except ``rtlift``, whose sub-packages (``rtlift.core``,
``rtlift.blocks``, ``rtlift.observer`` …) and top-level modules (``rtlift.model.hybrid``,
``rtlift.app.live`` …) are nodes of their own: ``rtlift`` holds every layer from the core to the
applications, and ``hil_sim`` sits between its core and its demo.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rtlift", "firmware_io", "hil_sim", "testkit", "tests", "benchmarks")
LAZY_CYCLES: dict[tuple[str, str], str] = {}
"""(importer, imported) of function-level imports that would close a cycle, with the reason."""


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _target(name: str) -> str | None:
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imported(statements) -> set[str]:
    out = set()
    for node in statements:
        if isinstance(node, ast.Import):
            out |= {_target(a.name) for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out |= {_target(f"{node.module}.{a.name}") for a in node.names}
    return out - {None}


def _top_level(tree: ast.Module):
    for node in tree.body:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            continue
        if isinstance(node, (ast.If, ast.Try)):
            yield from (n for n in ast.walk(node) if isinstance(n, (ast.Import, ast.ImportFrom)))
        else:
            yield node


def _graphs() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    eager, lazy = defaultdict(set), defaultdict(set)
    for name, path in MODULES.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        top = _imported(_top_level(tree)) - {name}
        eager[name] |= top
        lazy[name] |= _imported(ast.walk(tree)) - top - {name}
    return eager, lazy


EAGER, LAZY = _graphs()


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
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

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _node(module: str) -> str:
    parts = module.split(".")
    if parts[0] != "rtlift" or len(parts) == 1:
        return parts[0]
    return ".".join(parts[:2])


def _package_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    out = defaultdict(set)
    for a, targets in graph.items():
        out[_node(a)] |= {_node(b) for b in targets if _node(b) != _node(a)}
    return out


def test_no_import_cycle_between_modules():
    assert _cycles(EAGER) == []


def test_no_import_cycle_between_packages():
    assert _cycles(_package_graph(EAGER)) == []


def test_no_import_cycle_between_packages_counting_imports_inside_functions():
    """A function-level import is a dependency all the same: identify and diagnose (and every
    other pair of packages) do not lean on each other through one."""
    assert _cycles(_package_graph({m: EAGER[m] | LAZY[m] for m in MODULES})) == []


def test_lazy_imports_close_no_cycle_but_the_listed_ones():
    """With the function-level imports added, every cycle goes through a listed lazy import."""
    both = {m: EAGER[m] | {t for t in LAZY[m] if (m, t) not in LAZY_CYCLES} for m in MODULES}
    assert _cycles(both) == []


@pytest.mark.parametrize("package", ["firmware_io", "hil_sim"])
def test_the_io_and_bench_packages_import_only_the_core_of_rtlift(package):
    used = {t for m, targets in EAGER.items() if _node(m) == package for t in targets | LAZY[m]
            if t.startswith("rtlift")}
    assert used and all(t.startswith("rtlift.core") for t in used), sorted(used)


def test_the_core_imports_nothing_of_ours():
    ours = {t for m in MODULES if m.startswith("rtlift.core") for t in EAGER[m] | LAZY[m]}
    assert all(t.startswith("rtlift.core") for t in ours), sorted(ours)


def test_tests_and_benchmarks_share_helpers_through_testkit_only():
    bench = {t for m in MODULES if m.startswith("benchmarks") for t in EAGER[m] | LAZY[m]}
    assert not any(t.startswith("tests") for t in bench), sorted(bench)


def test_importing_firmware_io_loads_neither_scipy_nor_the_model():
    code = ("import sys, firmware_io, firmware_io.links; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "{'scipy', 'filterpy', 'numba'} or m in {'rtlift.model.hybrid', 'rtlift.observer'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=ROOT, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert out.stdout.strip() == "[]"


LAYERS = (("rtlift.core",), ("rtlift.blocks",), ("rtlift.model",), ("rtlift.residual",), ("rtlift.identify",),
          ("rtlift.effects",), ("rtlift.diagnose",), ("rtlift.sysid",), ("rtlift.observer",), ("rtlift.export",),
          ("rtlift.app", "rtlift.api"))
"""rtlift's folders bottom up, the data flow: the core; the model's blocks; the model (hybrid,
file, domain, prediction, the single-input models); the model's own residual (its tests and
fingerprint, which identification stores and diagnosis compares with); identification (which
diagnosis uses to re-fit); the effects and structures, one module each (their fits re-identify;
the diagnosis and the observer use them); diagnosis; the generic ``t,u,y`` systems (identified and diagnosed
with both); the observer (run on an identified model); its export to C and MATLAB; the
applications and their Python API.
``rtlift`` itself and ``rtlift.data`` hold no code of a layer."""


def _layer(module: str) -> int | None:
    node = _node(module)
    return next((i for i, names in enumerate(LAYERS) if node in names), None)


def test_rtlift_is_its_layers_and_each_imports_only_its_own_or_lower_ones():
    """Every module of rtlift sits in one of the layer folders, and every import it makes — at
    load time or inside a function — goes to its own layer or one below."""
    loose = [m for m in MODULES if m.startswith("rtlift.") and _layer(m) is None
             and m not in ("rtlift.__main__",)]
    assert loose == [], loose
    upward = sorted((m, t) for m in MODULES if _layer(m) is not None
                    for t in EAGER[m] | LAZY[m] if t.startswith("rtlift.") and (_layer(t) or 0) > _layer(m))
    assert upward == [], upward


STRING_IMPORTERS = frozenset({"import_module", "__import__", "resolve_name", "locate", "find_spec"})
"""Calls that import a module named by a string (importlib, builtins, pkgutil, pydoc)."""
MODULE_STRING = r"rtlift(\.\w+)+(:\w+)?"
"""A string that is a module of ours, or a ``"module:attr"`` reference to one."""


def _docstrings(tree: ast.Module) -> set[int]:
    nodes = [tree, *(n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)))]
    return {id(n.body[0].value) for n in nodes if n.body and isinstance(n.body[0], ast.Expr)
            and isinstance(n.body[0].value, ast.Constant)}


def _imports_by_string(module: str) -> list[str]:
    """What ``module`` imports through a string: every argument of a :data:`STRING_IMPORTERS`
    call (a constant, or an f-string's constant head) and every other string (not a docstring)
    that names a module of ours, as written."""
    import re

    tree = ast.parse(MODULES[module].read_text(encoding="utf-8"))
    docs = _docstrings(tree)
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and node.args:
            fn = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
            if fn in STRING_IMPORTERS:
                arg = node.args[0]
                if isinstance(arg, ast.JoinedStr) and arg.values and isinstance(arg.values[0], ast.FormattedValue) \
                        and ast.unparse(arg.values[0].value) == "__name__":
                    out.append(module)                  # its own package: f"{__name__}.{name}"
                elif isinstance(arg, ast.JoinedStr) and arg.values and isinstance(arg.values[0], ast.Constant):
                    out.append(arg.values[0].value.rstrip("."))
                else:
                    out.append(arg.value if isinstance(arg, ast.Constant) else f"<{ast.unparse(arg)}>")
        elif (isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs
              and re.fullmatch(MODULE_STRING, node.value)):
            out.append(node.value.partition(":")[0])
    return out


def test_no_floor_imports_an_upper_one_by_string():
    """The ties a string makes are invisible to the import graph above: no floor of rtlift
    imports a module of a floor above it by a string (importlib, ``"module:attr"``), and below
    the applications no string import names a module we cannot check (a variable). A model file
    names stages that may live a floor above its reader (an effect's own); they come down
    through the stage providers instead (next test)."""
    top = len(LAYERS) - 1
    upward = {}
    for m in MODULES:
        if _layer(m) is None:
            continue
        bad = [s for s in _imports_by_string(m) if s.startswith("<") and _layer(m) < top
               or not s.startswith("<") and (_layer(_target(s) or s) or 0) > _layer(m)]
        if bad:
            upward[m] = bad
    assert upward == {}


def test_the_effects_stages_come_down_through_the_one_stage_provider():
    """The stage registry is filled by the stage classes themselves (never assigned into by
    rtlift's code) and the one provider that hands the effects' stages down is the package's
    entry's: ``import rtlift`` registers it, and running it imports :mod:`rtlift.effects`."""
    calls = sorted(m for m, p in MODULES.items() if m.startswith("rtlift") and m != "rtlift.core.registry"
                   and "add_stage_provider(" in p.read_text(encoding="utf-8"))
    assert calls == ["rtlift"], calls
    writing = ("STAGES[name] =", "STAGES.update", "STAGES.setdefault")
    writes = sorted(m for m, p in MODULES.items() if m.startswith("rtlift")
                    and any(s in p.read_text(encoding="utf-8") for s in writing))
    assert writes == ["rtlift.blocks.stage_base"], writes
    code = ("import sys; from rtlift.model.modelfile import load_model; import rtlift.core.registry as r; "
            "before = 'rtlift.effects' in sys.modules; n = r.run_stage_providers(); "
            "print(before, n, 'rtlift.effects' in sys.modules, r.run_stage_providers())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=ROOT, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert out.stdout.split() == ["False", "1", "True", "0"], out.stdout + out.stderr
