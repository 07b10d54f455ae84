"""The house's dependency rules, read from the sources (``ast``, no import is run).

- no import cycle between modules (imports inside functions count: they only postpone the cycle; imports under
  ``if TYPE_CHECKING:`` do not: they never run);
- drivers (``backend/devices``) never import a simulator (``backend/sim``);
- ``backend/`` never imports ``studio/``;
- the studio and the API never import a solver: from a problem's folder (``backend/calib/<problem>/``) they
  import its services only (``service``, ``guided_service``, ``sweep_corners_service``, ``capture``); what they draw
  comes from ``backend/plots``.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("backend", "studio")
SERVICE_MODULES = {"service", "guided_service", "sweep_corners_service", "capture"}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@cache
def modules() -> dict[str, Path]:
    return {module_name(p): p for package in PACKAGES for p in (ROOT / package).rglob("*.py")}


def imported(tree: ast.AST, known: dict[str, Path]) -> set[str]:
    """The project modules a module's code imports (``from a import b`` names ``a.b`` when that is a module)."""
    found: set[str] = set()
    for node in runtime_nodes(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                name = f"{node.module}.{alias.name}"
                found.add(name if name in known else node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return {name for name in found if name in known}


def runtime_nodes(tree: ast.AST):
    """Every node of ``tree`` except what sits under ``if TYPE_CHECKING:``."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            yield from (n for orelse in node.orelse for n in [orelse, *runtime_nodes(orelse)])
            continue
        yield node
        yield from runtime_nodes(node)


@cache
def graph() -> dict[str, frozenset[str]]:
    known = modules()
    return {name: frozenset(imported(ast.parse(path.read_text()), known)) for name, path in known.items()}


def cycles(edges: dict[str, frozenset[str]]) -> list[list[str]]:
    """Every strongly connected component of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in edges.get(node, ()):
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
                found.append(sorted(component))

    for node in sorted(edges):
        if node not in index:
            visit(node)
    return found


def is_package_init(name: str) -> bool:
    return modules()[name].name == "__init__.py"


def violations(importer_prefix: str, forbidden) -> list[str]:
    return sorted(f"{a} -> {b}" for a, targets in graph().items() if a.startswith(importer_prefix)
                  for b in targets if forbidden(b))


def is_solver(name: str) -> bool:
    parts = name.split(".")
    return len(parts) == 4 and parts[:2] == ["backend", "calib"] and parts[3] not in SERVICE_MODULES


def test_no_import_cycle() -> None:
    # A package's __init__ importing its own modules (a registry) is not a cycle between modules.
    edges = {a: frozenset(b for b in targets if not (is_package_init(b) and a.startswith(b + ".")))
             for a, targets in graph().items()}
    assert cycles(edges) == []


def test_drivers_never_import_simulators() -> None:
    assert violations("backend.devices", lambda b: b.startswith("backend.sim")) == []


def test_backend_never_imports_the_studio() -> None:
    assert violations("backend", lambda b: b.startswith("studio")) == []


def test_the_studio_never_imports_a_solver() -> None:
    assert violations("studio", is_solver) == []


def test_the_api_never_imports_a_solver() -> None:
    assert violations("backend.api", is_solver) == []


def test_the_rules_see_what_they_forbid() -> None:
    """The checks above are only as good as the graph: it must hold the edges they look for."""
    assert cycles({"a": frozenset({"b"}), "b": frozenset({"c"}), "c": frozenset({"a"}), "d": frozenset()}) \
        == [["a", "b", "c"]]
    assert "backend.calib.lidar_camera.service" in graph()["backend.api.routes.lidar_camera"]
    assert is_solver("backend.calib.lidar_camera.target") and not is_solver("backend.calib.lidar_camera.service")
