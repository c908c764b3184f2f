"""Layering rules of the package (DESIGN.md), checked from the source with ``ast`` (nothing is imported).

* Each layer imports only the layers below it (:data:`ALLOWED`): ``core`` nothing; ``devices`` only
  ``core``; ``control`` and ``perception`` only ``core``; ``drivers`` only ``core`` and ``devices``;
  ``sim`` only ``core`` and ``devices``; ``mocks`` only ``core``, ``devices`` and ``sim``; only
  ``cli`` imports ``rig``.
* No function-level import of a ``tactile_rig`` module anywhere (they exist only to dodge a cycle or
  a layer rule); optional third-party extras may still be imported inside the function that needs them.
* No import cycle among modules executed at import time, nor through deferred imports.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

PKG_ROOT = Path(__file__).resolve().parent.parent
PKG_DIR = PKG_ROOT / "tactile_rig"
FORBIDDEN = ("tactile_rig.drivers", "tactile_rig.mocks")
RESTRICTED = ("tactile_rig.control", "tactile_rig.perception")

# Which layers each layer may import (besides itself). ``root`` is the package's own __init__ and
# _compat; ``testing`` is the public test helpers (drivers, mocks, sim: never the rig or the CLI).
LAYERS = ("root", "core", "devices", "control", "perception", "drivers", "sim", "mocks", "rig", "testing", "cli")
ALLOWED: dict[str, set[str]] = {
    "root": {"core"},
    "core": set(),
    "devices": {"core"},
    "control": {"core"},
    "perception": {"core"},
    "drivers": {"core", "devices"},
    "sim": {"core", "devices"},
    "mocks": {"core", "devices", "sim"},
    "rig": {"root", "core", "devices", "control", "perception", "drivers", "sim", "mocks"},
    "testing": {"root", "core", "devices", "drivers", "sim", "mocks"},
    "cli": {"root", "core", "devices", "control", "perception", "drivers", "sim", "mocks", "rig"},
}

def _module_name(path: Path, root: Path = PKG_ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


MODULES: dict[str, Path] = {_module_name(p): p for p in sorted(PKG_DIR.rglob("*.py"))}


def _in_package(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def _is_type_checking_block(node: ast.AST) -> bool:
    if not isinstance(node, ast.If):
        return False
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


@functools.lru_cache(maxsize=None)
def _parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def _imports(module: str, path: Path, *, top_level_only: bool) -> list[tuple[str, int]]:
    """Absolute names imported by ``module`` (``from a import b`` yields ``a`` and ``a.b``)."""
    tree = _parse(path)
    is_pkg = path.name == "__init__.py"
    found: list[tuple[str, int]] = []

    def visit(node: ast.AST, top: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.Import):
                if top or not top_level_only:
                    found.extend((a.name, child.lineno) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                if top or not top_level_only:
                    if child.level:
                        base = module.split(".") if is_pkg else module.split(".")[:-1]
                        base = base[: len(base) - (child.level - 1)]
                        target = ".".join(base + ([child.module] if child.module else []))
                    else:
                        target = child.module or ""
                    found.append((target, child.lineno))
                    found.extend((f"{target}.{a.name}", child.lineno) for a in child.names)
            elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                visit(child, False)
            elif _is_type_checking_block(child):
                visit(child, False)  # typing-only imports never run
            else:
                visit(child, top)

    visit(tree, True)
    return found


def _resolve(name: str) -> str | None:
    """The package module that executing ``import name`` would load last, or None if external."""
    while name and name not in MODULES:
        if "." not in name:
            return None
        name = name.rsplit(".", 1)[0]
    return name or None


def _graph(*, top_level_only: bool) -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for module, path in MODULES.items():
        deps: set[str] = set()
        for name, _ in _imports(module, path, top_level_only=top_level_only):
            if not _in_package(name, ("tactile_rig",)):
                continue
            target = _resolve(name)
            if target is not None and target != module:
                deps.add(target)
        graph[module] = deps
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    result: list[frozenset[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    result.append(frozenset(component))
    return result


def _layer(module: str) -> str:
    parts = module.split(".")
    if len(parts) < 2 or parts[1] in ("_compat",):
        return "root"
    return parts[1]


def test_every_module_belongs_to_a_known_layer():
    assert {_layer(m) for m in MODULES} <= set(LAYERS)


def test_each_layer_imports_only_the_layers_below_it():
    offences = []
    for module, path in MODULES.items():
        layer = _layer(module)
        for name, line in _imports(module, path, top_level_only=False):
            if not _in_package(name, ("tactile_rig",)):
                continue
            target = _resolve(name)
            if target is None:
                continue
            dep = _layer(target)
            if dep != layer and dep not in ALLOWED[layer]:
                offences.append(f"{path.relative_to(PKG_ROOT)}:{line} ({layer}) imports {name} ({dep})")
    assert offences == []


def _typing_only_lines(path: Path) -> set[int]:
    """Line numbers of imports inside ``if TYPE_CHECKING:`` blocks (read by the type checker, never run)."""
    lines: set[int] = set()
    for node in ast.walk(_parse(path)):
        if _is_type_checking_block(node):
            lines.update(n.lineno for n in ast.walk(node) if isinstance(n, (ast.Import, ast.ImportFrom)))
    return lines


def test_no_function_level_import_of_the_package():
    """A deferred import of our own module hides a cycle or a layer breach; third-party optional
    extras (mcap, matplotlib, scikit-learn, dask) may still be imported where they are needed.
    Typing-only imports (``if TYPE_CHECKING:``) never run and are still held to the layer rules."""
    offences = []
    for module, path in MODULES.items():
        top = set(_imports(module, path, top_level_only=True))
        typing_only = _typing_only_lines(path)
        for name, line in _imports(module, path, top_level_only=False):
            if _in_package(name, ("tactile_rig",)) and (name, line) not in top and line not in typing_only:
                offences.append(f"{path.relative_to(PKG_ROOT)}:{line} imports {name} inside a function")
    assert offences == []


def test_package_is_found():
    assert "tactile_rig.core.errors" in MODULES
    assert any(_in_package(m, ("tactile_rig.control",)) for m in MODULES)
    assert any(_in_package(m, ("tactile_rig.perception",)) for m in MODULES)


@pytest.mark.parametrize("layer", RESTRICTED)
def test_control_and_perception_never_import_drivers_or_mocks(layer):
    offences = [
        f"{path.relative_to(PKG_ROOT)}:{line} imports {name}"
        for module, path in MODULES.items()
        if _in_package(module, (layer,))
        for name, line in _imports(module, path, top_level_only=False)
        if _in_package(name, FORBIDDEN)
    ]
    assert offences == []


@pytest.mark.parametrize("layer", RESTRICTED)
def test_control_and_perception_do_not_load_drivers_or_mocks_through_other_modules(layer):
    """Importing the layer must not load drivers/mocks indirectly (module-level imports, and the
    parent packages' ``__init__`` that Python runs first)."""
    graph = _graph(top_level_only=True)
    for module in graph:
        parts = module.split(".")
        graph[module] |= {".".join(parts[:k]) for k in range(1, len(parts))} & set(MODULES)
    offences = []
    for start in (m for m in MODULES if _in_package(m, (layer,))):
        parent = {start: ""}
        todo = [start]
        while todo:
            node = todo.pop()
            for dep in graph[node]:
                if dep not in parent:
                    parent[dep] = node
                    todo.append(dep)
        for reached in parent:
            if _in_package(reached, FORBIDDEN):
                chain, node = [], reached
                while node:
                    chain.append(node)
                    node = parent[node]
                offences.append(" <- ".join(chain))
    assert offences == []


def test_no_import_cycle_at_import_time():
    assert _cycles(_graph(top_level_only=True)) == []


def test_no_cycle_through_deferred_imports_either():
    assert _cycles(_graph(top_level_only=False)) == []


def test_checker_detects_a_forbidden_import_and_a_cycle(tmp_path, monkeypatch):
    """The checker itself must be able to fail: feed it a tiny package that breaks both rules."""
    pkg = tmp_path / "tactile_rig"
    (pkg / "control").mkdir(parents=True)
    (pkg / "drivers").mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "control" / "__init__.py").write_text("")
    (pkg / "drivers" / "__init__.py").write_text("")
    (pkg / "control" / "bad.py").write_text(
        "def f():\n    from tactile_rig.drivers import scale\n"
    )
    (pkg / "drivers" / "scale.py").write_text("from . import loop\n")
    (pkg / "drivers" / "loop.py").write_text("from tactile_rig.drivers.scale import x\n")
    fake = {_module_name(p, tmp_path): p for p in sorted(pkg.rglob("*.py"))}
    monkeypatch.setitem(globals(), "MODULES", fake)
    bad = fake["tactile_rig.control.bad"]
    names = [n for n, _ in _imports("tactile_rig.control.bad", bad, top_level_only=False)]
    assert any(_in_package(n, FORBIDDEN) for n in names)
    assert _imports("tactile_rig.control.bad", bad, top_level_only=True) == []
    assert _cycles(_graph(top_level_only=True)) == [
        frozenset({"tactile_rig.drivers.scale", "tactile_rig.drivers.loop"})
    ]
    assert _layer("tactile_rig.control.bad") == "control" and "drivers" not in ALLOWED["control"]

