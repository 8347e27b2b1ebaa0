"""The package layout stays a map of the tool: each package's subpackages in layers that import
only downwards, an import graph without cycles, a numerics core that never imports the
simulator, the web UI or the app, and no module past ~400 lines (issues 8 and 38).

Imports count wherever they are: at module level, inside functions (a lazy import is still a
dependency) and in strings that name a module (code run with ``python -c``, a multiprocessing
preload). Only imports under ``if TYPE_CHECKING:`` are left out: they never run. Each rule has
a self-test below that feeds it a breach, so none of them passes by accident.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MAX_LINES = 420  # "~400": a few lines of slack so a docstring edit does not force a split
PACKAGES = ("bt_pipeline", "bt_teleop")

LAYERS: dict[str, tuple[tuple[str, ...], ...]] = {
    # Lowest first. A module may import its own layer and the layers before it, never a later
    # one. An entry names a subpackage or module relative to the package ("" is the package's
    # own __init__); a module belongs to its longest entry, so `clean.driver` is not `clean`.
    "bt_pipeline": (
        ("exceptions", "execute"),  # errors; running jobs in processes or on Ray
        ("data",),  # recordings, demos, tasks, synthetic crowds
        ("score",),  # mutual information, losses, the utility Ũ
        ("clean",),  # segmentation, guide fits, Stage 1, Stage 2, one task end to end
        ("evaluate",),  # learners on noisy vs cleaned demos, protocol, reports and figures
        ("viz", "interop"),  # the edges: Rerun, tables; LeRobot and robomimic files
        ("clean.driver", "evaluate.driver"),  # `bt clean` / `bt evaluate`: files in, files out
        ("cli", "__main__"),  # the `bt` command: parses and dispatches
        ("testing", ""),  # harnesses for tests and benchmarks; the package's public names
    ),
    "bt_teleop": (
        ("proc",),  # child-process plumbing
        ("sim",),  # scene, workspace, IK
        ("takes",),  # a take and its file
        ("session",),  # the control loop, in-process or in a child
        ("rerun",),  # live Rerun, off the control loop
        ("clean",),  # the Clean button's job
        ("library",),  # a task's takes as listed; replay
        ("ui",),  # one browser tab
        ("app", "app_options", "cli"),  # the viser server; `bt teleop`
        ("testing", ""),  # harnesses for tests and benchmarks; the package's docstring
    ),
}

FOREIGN = {
    "bt_pipeline": ("viser", "mujoco", "mink", "bt_teleop"),
    "bt_teleop": (),
}
"""Top-level packages a package never imports."""

_MODULE_IN_STRING = re.compile(r"\b(?:bt_pipeline|bt_teleop)(?:\.[A-Za-z_]\w*)+")


def _modules(package: str) -> dict[str, Path]:
    out = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _resolve(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    if not node.level:
        return node.module or ""
    here = module.split(".") if is_package else module.split(".")[:-1]
    base = here[: len(here) - (node.level - 1)]
    return ".".join([*base, node.module] if node.module else base)


def _imports(
    source: str, module: str, *, is_package: bool = False, in_functions: bool = True
) -> dict[str, bool]:
    """Module names `source` imports, each mapped to whether only inside a function.

    Counted: ``import`` and ``from ... import`` anywhere (``from a import b`` counts ``a`` and
    ``a.b``), and dotted ``bt_pipeline.*`` / ``bt_teleop.*`` names in string constants that are
    not docstrings. Left out: the body of ``if TYPE_CHECKING:``, and with `in_functions` False,
    everything inside a function.
    """
    found: dict[str, bool] = {}

    def add(name: str, in_function: bool) -> None:
        found[name] = found.get(name, True) and in_function

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child.test):
                for other in child.orelse:
                    visit_one(other, in_function)
                continue
            visit_one(child, in_function)

    def visit_one(node: ast.AST, in_function: bool) -> None:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            if in_functions:
                visit(node, True)
            return
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name, in_function)
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(node, module, is_package)
            add(base, in_function)
            for alias in node.names:
                add(f"{base}.{alias.name}", in_function)
        elif isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            return  # a docstring (of a module, class, function or attribute): prose
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            for name in _MODULE_IN_STRING.findall(node.value):
                add(name, in_function)
        visit(node, in_function)

    visit(ast.parse(source), False)
    return found


def _graph(package: str) -> dict[str, set[str]]:
    """Each module of `package` -> the modules of `package` it imports (not itself, not the
    packages it sits in: Python imports those first anyway)."""
    modules = _modules(package)
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        imported = _imports(path.read_text(), name, is_package=path.name == "__init__.py")
        known = {_known(i, modules) for i in imported if i.split(".")[0] == package}
        graph[name] = {
            m for m in known if m is not None and m != name and not name.startswith(m + ".")
        }
    return graph


def _known(name: str, modules: dict[str, Path]) -> str | None:
    """The longest prefix of `name` that is a module (``a.b.func`` -> ``a.b``)."""
    parts = name.split(".")
    for end in range(len(parts), 0, -1):
        if (candidate := ".".join(parts[:end])) in modules:
            return candidate
    return None


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*stack[stack.index(nxt) :], nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def _layer(module: str, package: str, layers: tuple[tuple[str, ...], ...]) -> int | None:
    """The index of `module`'s layer (its longest entry), or None when no entry holds it."""
    relative = module.removeprefix(package).removeprefix(".")
    holding = [
        (len(entry), index)
        for index, entries in enumerate(layers)
        for entry in entries
        if relative == entry or (entry and relative.startswith(entry + "."))
    ]
    return max(holding)[1] if holding else None


def _upward(
    graph: dict[str, set[str]], package: str, layers: tuple[tuple[str, ...], ...]
) -> list[str]:
    """Every import of a later layer by an earlier one, as ``a (layer) -> b (layer)``."""

    def name(index: int | None) -> str:
        return "?" if index is None else "/".join(layers[index])

    bad = []
    for module, imported in sorted(graph.items()):
        here = _layer(module, package, layers)
        for other in sorted(imported):
            there = _layer(other, package, layers)
            if here is not None and there is not None and there > here:
                bad.append(f"{module} ({name(here)}) -> {other} ({name(there)})")
    return bad


@pytest.mark.parametrize("package", PACKAGES)
def test_import_graph_is_acyclic(package: str) -> None:
    graph = _graph(package)
    assert _cycle(graph) is None, f"import cycle: {' -> '.join(_cycle(graph) or [])}"


@pytest.mark.parametrize("package", PACKAGES)
def test_every_module_has_a_layer(package: str) -> None:
    loose = [m for m in _modules(package) if _layer(m, package, LAYERS[package]) is None]
    assert not loose, f"declare the layer of {loose} in LAYERS (tests/project/test_layout.py)"


@pytest.mark.parametrize("package", PACKAGES)
def test_no_layer_imports_a_later_one(package: str) -> None:
    bad = _upward(_graph(package), package, LAYERS[package])
    assert not bad, "imports of a later layer:\n" + "\n".join(bad)


def test_pipeline_never_imports_the_simulator_the_ui_or_the_app() -> None:
    bad = []
    for package, forbidden in FOREIGN.items():
        for module, path in _modules(package).items():
            imported = _imports(path.read_text(), module, is_package=path.name == "__init__.py")
            for name in imported:
                if name.split(".")[0] not in forbidden:
                    continue
                bad.append(f"{module} imports {name}")
    assert not bad, "\n".join(sorted(set(bad)))


# Self-tests: each rule above, fed a breach, reports it.


def test_imports_are_found_in_functions_and_strings_but_not_under_type_checking() -> None:
    source = '''"""Docstring naming bt_teleop.app, which is prose."""
from typing import TYPE_CHECKING
import bt_pipeline.data.demo
if TYPE_CHECKING:
    from bt_pipeline.score import utility
def run():
    from bt_teleop.session.script import run_script
    code = "from bt_teleop.app import serve"
    return run_script, code
X = 1
"""An attribute docstring naming bt_teleop.ui, also prose."""
'''
    found = _imports(source, "bt_pipeline.testing.x")
    assert found["bt_pipeline.data.demo"] is False  # at module level
    assert found["bt_teleop.session.script"] is True  # only inside a function
    assert found["bt_teleop.app"] is True  # in a string, inside a function
    assert not any(name.startswith("bt_pipeline.score") for name in found)
    assert "bt_teleop.ui" not in found
    assert "bt_teleop.session.script" not in _imports(source, "m", in_functions=False)


def test_relative_imports_resolve() -> None:
    found = _imports("from . import a\nfrom ..b import c\n", "p.q.mod")
    assert {"p.q", "p.q.a", "p.b", "p.b.c"} <= set(found)
    assert "p.q.a" in _imports("from . import a\n", "p.q", is_package=True)


def test_cycle_detector_finds_a_cycle() -> None:
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_layer_check_finds_an_upward_import() -> None:
    layers = (("low",), ("mid", "mid2"), ("mid.top",), ("",))
    graph = {
        "p.low.x": {"p.low.y"},
        "p.mid.a": {"p.low.x", "p.mid2"},
        "p.mid.top.b": {"p.mid.a"},
        "p.low.y": {"p.mid.top.b"},  # the breach: low -> mid.top
        "p": {"p.mid.a"},
    }
    assert _layer("p.mid.top.b", "p", layers) == 2  # the longest entry wins
    assert _layer("p", "p", layers) == 3
    assert _layer("p.other", "p", layers) is None
    assert _upward(graph, "p", layers) == ["p.low.y (low) -> p.mid.top.b (mid.top)"]


def test_a_foreign_import_is_found_in_a_string() -> None:
    # What bt_pipeline/testing/faults.py did before it moved to bt_teleop/testing.
    source = 'SCRIPT = """\nfrom bt_teleop.session.script import run_script\n"""\n'
    assert "bt_teleop.session.script" in _imports(source, "bt_pipeline.testing.faults")


@pytest.mark.parametrize("package", PACKAGES)
def test_no_module_over_about_400_lines(package: str) -> None:
    long = _long_modules(_modules(package).values(), MAX_LINES)
    assert not long, f"modules over {MAX_LINES} lines (split them along their seams): {long}"


def _long_modules(paths: Iterable[Path], max_lines: int) -> dict[str, int]:
    return {
        str(p.relative_to(ROOT)): n
        for p in paths
        if (n := len(p.read_text().splitlines())) > max_lines
    }


def test_line_count_finds_a_long_module() -> None:
    path = Path(__file__).resolve()
    lines = len(path.read_text().splitlines())
    assert _long_modules([path], lines - 1) == {"tests/project/test_layout.py": lines}
    assert _long_modules([path], lines) == {}
