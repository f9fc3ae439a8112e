"""The package's layout holds: no import cycle (imports inside functions included), and systems/ stays a room of
presets and pipelines (no simulator, dataset loader, evaluation, report or CLI import; under 3,000 lines)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "fusegraph"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in PACKAGE.rglob("*.py")}


def _imports(path: Path, modules: dict[str, Path]) -> set[str]:
    """Every fusegraph module this file imports, at any depth of the file (``from p import m`` names module p.m
    when m is a module, else p itself). A parent package that Python also runs is not counted: it is not an
    edge the file chose."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.startswith("fusegraph")}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if not target.startswith("fusegraph"):
                continue
            subs = {f"{target}.{alias.name}" for alias in node.names} & set(modules)
            found |= subs or {target}
            if subs and len(subs) < len(node.names):
                found.add(target)
    return {m for m in found if m in modules and m != name}


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(path, modules) for name, path in modules.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle, as the list of modules around it, or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle_in_the_package() -> None:
    cycle = _cycle(_graph())
    assert cycle is None, " -> ".join(cycle or [])


FORBIDDEN_FOR_SYSTEMS = ("fusegraph.scenarios", "fusegraph.datasets", "fusegraph.evaluation", "fusegraph.report", "fusegraph.cli",
                         "fusegraph.live")


def test_systems_import_no_simulator_loader_evaluation_or_report() -> None:
    graph = _graph()
    bad = {name: sorted(m for m in deps if m.startswith(FORBIDDEN_FOR_SYSTEMS))
           for name, deps in graph.items() if name.startswith("fusegraph.systems")}
    assert not any(bad.values()), {k: v for k, v in bad.items() if v}


def test_report_draws_what_it_is_handed_and_imports_neither_systems_nor_evaluation() -> None:
    graph = _graph()
    bad = {name: sorted(m for m in deps if m.startswith(("fusegraph.systems", "fusegraph.evaluation")))
           for name, deps in graph.items() if name.startswith("fusegraph.report")}
    assert not any(bad.values()), {k: v for k, v in bad.items() if v}


def test_the_library_imports_nothing_from_the_cli() -> None:
    graph = _graph()
    assert not [name for name, deps in graph.items() if "fusegraph.cli" in deps]


def test_systems_stay_under_3000_lines() -> None:
    lines = sum(len(p.read_text().splitlines()) for p in (PACKAGE / "systems").glob("*.py"))
    assert lines < 3000, lines


def test_systems_hold_no_table_figure_or_bench() -> None:
    for path in (PACKAGE / "systems").glob("*.py"):
        tree = ast.parse(path.read_text())
        names = [n.name for n in tree.body if isinstance(n, ast.FunctionDef | ast.ClassDef)]
        offending = [n for n in names if n.startswith(("format_", "plot_", "bench_", "simulate_", "load_")) or n.endswith(("_report", "_picture"))]
        assert not offending, f"{path.name}: {offending}"


def test_what_other_tools_read_stays_importable() -> None:
    import fusegraph
    from fusegraph.systems.head import OnlineHeadTracker

    assert fusegraph.OnlineHeadTracker is OnlineHeadTracker
    assert callable(fusegraph.load_session) and hasattr(fusegraph.Session, "stream")
