"""The layers of docs/DESIGN.md hold: who may import whom, and no import circle.

Read from the source (every ``import`` statement, those inside functions included), so a lazy
import cannot hide a dependency that runs upward.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("navkit", "navtopo", "baselines", "scenarios", "runners", "reports")

# what each package may import of the project besides itself (DESIGN.md, "Layout and layers")
ALLOWED = {
    "navkit": set(),
    "navtopo": {"navkit"},
    "baselines": {"navkit"},
    "scenarios": {"navkit"},
    "reports": {"navkit"},
    "runners": {"navkit", "navtopo", "baselines", "scenarios", "reports"},
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def project_imports(path: Path, name: str) -> set[str]:
    """The project modules ``path`` (module ``name``) imports, resolved to the deepest module that exists."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{alias.name}" for alias in node.names] + [base]
        else:
            continue
        for target in targets:
            if target.split(".")[0] in PACKAGES:
                found.add(target)
    return found


def modules() -> dict[str, Path]:
    return {module_name(path): path for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))}


def resolve(target: str, known: dict[str, Path]) -> str | None:
    """``a.b.c`` -> the deepest known module among ``a.b.c``, ``a.b``, ``a`` (a name imported from a module)."""
    parts = target.split(".")
    for end in range(len(parts), 0, -1):
        candidate = ".".join(parts[:end])
        if candidate in known:
            return candidate
    return None


def import_graph() -> dict[str, set[str]]:
    known = modules()
    graph: dict[str, set[str]] = {}
    for name, path in known.items():
        targets = {resolve(t, known) for t in project_imports(path, name)}
        # a package's __init__ is imported on the way to any of its modules: count only real modules
        graph[name] = {t for t in targets if t is not None and t != name and not name.startswith(f"{t}.")}
    return graph


@pytest.mark.parametrize("package", PACKAGES)
def test_a_package_imports_only_the_layers_below_it(package):
    wrong = sorted(
        f"{module} imports {target}"
        for module, targets in import_graph().items()
        if module.split(".")[0] == package
        for target in targets
        if target.split(".")[0] not in ALLOWED[package] | {package}
    )
    assert wrong == []


def test_the_baseline_depends_on_nothing_of_navtopo():
    graph = import_graph()
    assert not [m for m, targets in graph.items() if m.startswith("baselines") and any(t.startswith("navtopo") for t in targets)]


def test_no_import_circle():
    graph = import_graph()
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def visit(node: str) -> None:  # Tarjan's strongly connected components
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    assert circles == []
