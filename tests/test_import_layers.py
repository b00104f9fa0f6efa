"""The packages stand on floors (:data:`FLOORS`, bottom to top, as docs/architecture.md draws them): a module
imports only from its own floor or below. The import graph has no circle, and every module imports on its
own in a fresh interpreter with its dependencies imported first (dependency order).

Imports inside functions count as edges too (an import moved into a function to dodge a circle or a floor
is still one); imports under ``if TYPE_CHECKING:`` do not count for the floors (they never run), but they
make circles too: two modules that name each other's types share types that belong a floor down.
Imports inside functions are few, and each says why on its line."""

from __future__ import annotations

import ast
import importlib.util
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("va_plugin", "method_configs")
OPTIONAL = {"va_plugin.nerfstudio": "nerfstudio"}
"""Subpackages that import an optional package (imported here only where it is installed)."""


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


def _imported_names(tree: ast.AST, module: str, is_package: bool, type_only: bool = False) -> set[str]:
    """The names a module imports; ``type_only``: those under ``if TYPE_CHECKING:`` too."""
    names: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node) and not type_only:
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


def import_graph(type_only: bool = False) -> dict[str, set[str]]:
    """module -> the modules of our packages it imports (``type_only``: for type annotations too)."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        edges = {target for target in _imported_names(tree, name, path.name == "__init__.py", type_only)
                 if target in modules}
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


def test_no_circle_through_type_only_imports_either():
    """Two modules that name each other's types belong on one floor: the shared types move down."""
    cycle = find_cycle(import_graph(type_only=True))
    assert not cycle, "circle through type-only imports: " + " -> ".join(cycle)


def _importable(module: str) -> bool:
    return all(importlib.util.find_spec(needs) is not None for prefix, needs in OPTIONAL.items()
               if module == prefix or module.startswith(prefix + "."))


def test_every_module_imports_in_dependency_order_in_a_fresh_interpreter():
    order = [module for module in dependency_order(import_graph()) if _importable(module)]
    script = ("import importlib, sys\n"
              f"for name in {order!r}:\n"
              "    importlib.import_module(name)\n"
              "print('ok', len(sys.modules))\n")
    result = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and result.stdout.startswith("ok"), result.stderr[-2000:]


FLOORS = [
    ("va_plugin.errors", "va_plugin.config", "va_plugin.rays", "va_plugin.cameras", "va_plugin.utils",
     "va_plugin.registry", "va_plugin.callbacks", "method_configs"),
    ("va_plugin.fields", "va_plugin.model_components", "va_plugin.raycast"),
    ("va_plugin.models", "va_plugin.adaptive", "va_plugin.data"),
    ("va_plugin.pipelines", "va_plugin.engine"),
    ("va_plugin.export", "va_plugin.eval"),
    ("va_plugin.api", "va_plugin"),
    ("va_plugin.analysis", "va_plugin.bench"),
    ("va_plugin.cli", "va_plugin.batch", "va_plugin.app", "va_plugin.nerfstudio", "method_configs.*"),
]
"""Bottom to top. A module's floor is that of the longest prefix naming it; ``method_configs.*`` (the
method configs under the package, which name any part of the package) is the top floor, the package's
``__init__`` (the list of built-in methods, no imports) the bottom one."""
MAX_FUNCTION_IMPORTS = 10


def floor_of(module: str) -> int:
    best, floor = -1, None
    for index, names in enumerate(FLOORS):
        for name in names:
            if name.endswith(".*"):
                hit = module.startswith(name[:-1])
                length = len(name) - 1
            else:
                hit = module == name or module.startswith(name + ".")
                length = len(name)
            if hit and length > best:
                best, floor = length, index
    assert floor is not None, f"{module} stands on no floor: add it to FLOORS"
    return floor


def _function_imports() -> list[str]:
    """``path:line`` of every import of our packages inside a function (TYPE_CHECKING blocks aside)."""
    found = []
    for path in _modules().values():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for func in ast.walk(tree):
            if not isinstance(func, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(func):
                module = node.module if isinstance(node, ast.ImportFrom) else (
                    node.names[0].name if isinstance(node, ast.Import) else None)
                if module and module.split(".")[0] in PACKAGES:
                    found.append(f"{path.relative_to(REPO)}:{node.lineno}")
    return sorted(set(found))


def test_no_import_climbs_a_floor():
    graph = import_graph()
    climbs = [f"{module} (floor {floor_of(module) + 1}) imports {target} (floor {floor_of(target) + 1})"
              for module, targets in sorted(graph.items()) for target in sorted(targets)
              if floor_of(target) > floor_of(module)]
    assert not climbs, "imports that climb the floors:\n" + "\n".join(climbs)


def test_imports_inside_functions_are_few_and_say_why():
    found = _function_imports()
    assert len(found) <= MAX_FUNCTION_IMPORTS, f"{len(found)} imports inside functions: {found}"
    lines = {}
    for place in found:
        path, line = place.rsplit(":", 1)
        lines.setdefault(path, (REPO / path).read_text(encoding="utf-8").splitlines())
        text = lines[path][int(line) - 1]
        assert "#" in text, f"{place} imports inside a function without a one-line reason: {text.strip()}"


def test_argparse_is_cli_only():
    users = [name for name, path in _modules().items()
             if "argparse" in _imported_names(ast.parse(path.read_text(encoding="utf-8")), name, False)
             and not name.startswith("va_plugin.cli.")]
    assert not users, f"argparse outside va_plugin/cli/: {users}"


def test_every_module_stands_on_a_floor():
    for module in _modules():
        floor_of(module)


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
