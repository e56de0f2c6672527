"""The map of the code: imports point down, no cycles, and no tuning in the shell.

Walks every module's imports with :mod:`ast` (module-level and inside functions
alike: a lazy import is still a dependency) and fails on

- an import cycle between modules;
- the core (``plant_sim``, ``controller``) importing the shell (``services``, ``api``);
- ``plant_sim`` importing ``controller``;
- anything but the command line importing the offline tools: seed reproduction,
  benchmarks, soak and campaigns (``services.reproduce``, ``services.bench``,
  ``services.soak``, ``services.campaign``), each of which may import itself;
- anything outside the command line importing the command line (``services.cli``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("plant_sim", "controller", "services", "api")
OFFLINE = ("services.reproduce", "services.bench", "services.soak", "services.campaign")


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules(root: Path = REPO) -> dict[str, Path]:
    found = {}
    for pkg in PACKAGES:
        for path in (root / pkg).rglob("*.py"):
            found[_module_name(path, root)] = path
    return found


def _resolve(name: str, known: dict[str, Path]) -> str | None:
    """The longest known module that ``name`` (a module or module.attribute) names."""
    while name:
        if name in known:
            return name
        name = name.rpartition(".")[0]
    return None


def _edges(known: dict[str, Path]) -> dict[str, set[str]]:
    edges: dict[str, set[str]] = {m: set() for m in known}
    for mod, path in known.items():
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    pkg = mod.split(".") if is_pkg else mod.split(".")[:-1]
                    pkg = pkg[: len(pkg) - (node.level - 1)]
                    base = ".".join([*pkg, base] if base else pkg)
                targets = [f"{base}.{a.name}" for a in node.names] or [base]
            for t in targets:
                hit = _resolve(t, known)
                if hit is not None and hit != mod:
                    edges[mod].add(hit)
    return edges


def _within(mod: str, prefix: str) -> bool:
    return mod == prefix or mod.startswith(prefix + ".")


@pytest.fixture(scope="module")
def graph():
    known = _modules()
    assert "controller.units.te.control" in known and "services.registry" in known
    return _edges(known)


def _is_ancestor_package(a: str, b: str) -> bool:
    """``a`` is a package that contains ``b`` (a submodule importing its package's
    ``__init__`` for shared records is not a cycle of the design)."""
    return b.startswith(a + ".")


def test_no_import_cycles(graph):
    order: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(mod: str, stack: list[str]) -> None:
        order[mod] = 1
        stack.append(mod)
        for dep in sorted(graph[mod]):
            if _is_ancestor_package(dep, mod) or _is_ancestor_package(mod, dep):
                continue
            if order.get(dep) == 1:
                cycles.append(stack[stack.index(dep):] + [dep])
            elif dep not in order:
                visit(dep, stack)
        stack.pop()
        order[mod] = 2

    for mod in sorted(graph):
        if mod not in order:
            visit(mod, [])
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_imports_point_down(graph):
    bad = []
    for mod, deps in graph.items():
        for dep in deps:
            if _within(mod, "plant_sim") and not _within(dep, "plant_sim"):
                bad.append((mod, dep))
            elif _within(mod, "controller") and (_within(dep, "services") or _within(dep, "api")):
                bad.append((mod, dep))
    assert not bad, "the core imports the shell: " + ", ".join(f"{a} -> {b}" for a, b in bad)


def test_only_the_command_line_imports_offline_tools(graph):
    bad = []
    for mod, deps in graph.items():
        for dep in deps:
            for tool in OFFLINE:
                if _within(dep, tool) and not (_within(mod, tool) or _within(mod, "services.cli")):
                    bad.append((mod, dep))
            if _within(dep, "services.cli") and not _within(mod, "services.cli"):
                bad.append((mod, dep))
    assert not bad, "forbidden edges: " + ", ".join(f"{a} -> {b}" for a, b in sorted(bad))


def test_service_builds_every_unit_controller_from_the_core(graph):
    # the registry maps names to controller.units; it holds no tuning of its own
    deps = graph["services.registry"]
    assert any(_within(d, "controller.units") for d in deps)
    assert not any(_within(d, "services.reproduce") for d in deps)


def test_the_walker_sees_a_cycle_and_a_lazy_forbidden_edge(tmp_path):
    # the checks above can fail: a synthetic tree with a cycle and an upward edge
    for pkg in PACKAGES:
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / "controller" / "a.py").write_text("from controller import b\n")
    (tmp_path / "controller" / "b.py").write_text(
        "def f():\n    import controller.a\n    from services.reproduce import x\n")
    (tmp_path / "services" / "reproduce.py").write_text("x = 1\n")
    edges = _edges(_modules(tmp_path))
    assert "controller.b" in edges["controller.a"] and "controller.a" in edges["controller.b"]
    assert "services.reproduce" in edges["controller.b"]
