"""The import graph of ``va_plugin`` and ``method_configs`` has no circle, and every module imports on its
own in a fresh interpreter with its dependencies imported first (dependency order).

Imports inside functions count as edges too (an import moved into a function to dodge a circle is still a
circle); imports under ``if TYPE_CHECKING:`` do not (they never run)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("va_plugin", "method_configs")


def _modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            parts = list(path.relative_to(REPO).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
        (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imported_names(tree: ast.AST, module: str, is_package: bool) -> set[str]:
    names: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against this module's package
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[:len(base) - node.level + 1]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module or ""
            names.add(prefix)
            names.update(f"{prefix}.{alias.name}" for alias in node.names)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return names


def import_graph() -> dict[str, set[str]]:
    """module -> the modules of our packages it imports."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        edges = {target for target in _imported_names(tree, name, path.name == "__init__.py") if target in modules}
        # a module's parent packages run first, but an ``__init__`` that imports its own submodules is
        # no circle: only the imports a file writes count
        edges -= {".".join(name.split(".")[:i]) for i in range(1, name.count(".") + 1)}
        edges.discard(name)
        graph[name] = edges
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str]:
    """One circle of the graph as a list of modules (first repeated at the end), or []."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str]:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        stack.pop()
        state[node] = 2
        return []

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return []


def dependency_order(graph: dict[str, set[str]]) -> list[str]:
    order: list[str] = []
    done: set[str] = set()

    def visit(node: str) -> None:
        if node in done:
            return
        done.add(node)
        for nxt in sorted(graph[node]):
            visit(nxt)
        order.append(node)

    for node in sorted(graph):
        visit(node)
    return order


def test_no_import_circle():
    cycle = find_cycle(import_graph())
    assert not cycle, "import circle: " + " -> ".join(cycle)


def test_every_module_imports_in_dependency_order_in_a_fresh_interpreter():
    order = dependency_order(import_graph())
    script = ("import importlib, sys\n"
              f"for name in {order!r}:\n"
              "    importlib.import_module(name)\n"
              "print('ok', len(sys.modules))\n")
    result = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and result.stdout.startswith("ok"), result.stderr[-2000:]


BELOW_THE_TRAINER = ("va_plugin.adaptive", "va_plugin.models", "va_plugin.fields", "va_plugin.model_components",
                     "va_plugin.data", "va_plugin.pipelines")


def test_nothing_below_the_trainer_imports_it():
    """Data flows one way: the layers below the trainer get what they need at setup or through a callback's
    attributes, never the trainer itself."""
    graph = import_graph()
    reached = {}
    for module in graph:
        if module.startswith(BELOW_THE_TRAINER):
            seen, todo = set(), [module]
            while todo:
                for nxt in graph[todo.pop()] - seen:
                    seen.add(nxt)
                    todo.append(nxt)
            if "va_plugin.engine.trainer" in seen:
                reached[module] = sorted(seen)
    assert not reached, f"these reach va_plugin.engine.trainer: {sorted(reached)}"
