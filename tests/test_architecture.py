"""The rooms keep their one-way flow (issue 14, docs/architecture.md): `uam_fdm` imports none of the other
packages, `planners` and `rl` import only `uam_fdm` (and themselves), nothing imports `compare`; and no
two modules import each other at module level (no import circles)."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("uam_fdm", "planners", "rl", "compare")
MAY_IMPORT = {"uam_fdm": {"uam_fdm"}, "planners": {"uam_fdm", "planners"}, "rl": {"uam_fdm", "rl"},
              "compare": set(PACKAGES)}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, top_level_only: bool) -> set[str]:
    """Our modules that `path` imports (all of them, or only those imported when the module loads)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    here = _module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    nodes = []

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                continue  # for the type checker only
            if top_level_only and isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                nodes.append(child)
            visit(child)

    visit(tree)
    found = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        else:
            base = node.module or ""
            if node.level:  # relative import
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            found.add(base)
            found |= {f"{base}.{a.name}" for a in node.names}  # `from pkg import module`
    return {m for m in found if m.split(".")[0] in PACKAGES}


def _sources() -> list[Path]:
    return [p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))]


def test_packages_import_one_way() -> None:
    assert _wrong_imports() == []


def test_no_import_circles_at_module_level() -> None:
    assert _circles() == []


def _circles() -> list[str]:
    modules = {_module_name(p): p for p in _sources()}
    graph = {name: {m for m in _imports(path, top_level_only=True) if m in modules and m != name}
             for name, path in modules.items()}
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    circles: list[str] = []

    def walk(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                circles.append(" -> ".join([*path[path.index(nxt):], nxt]))
            elif nxt not in state:
                walk(nxt, [*path, nxt])
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            walk(name, [name])
    return circles


def test_the_checks_see_a_wrong_import_and_a_circle() -> None:
    """The scans themselves: a planners module importing rl, and two modules importing each other."""
    probes = {ROOT / "planners" / "_probe_a.py": "from rl.route import RouteConfig\nfrom planners import _probe_b\n",
              ROOT / "planners" / "_probe_b.py": "from planners._probe_a import RouteConfig\n"}
    try:
        for path, text in probes.items():
            path.write_text(text, encoding="utf-8")
        assert any("_probe_a.py imports rl.route" in w for w in _wrong_imports())
        assert any("planners._probe_a" in c and "planners._probe_b" in c for c in _circles())
    finally:
        for path in probes:
            path.unlink(missing_ok=True)


def _wrong_imports() -> list[str]:
    out = []
    for path in _sources():
        pkg = _module_name(path).split(".")[0]
        out += [f"{path.relative_to(ROOT)} imports {m}" for m in _imports(path, False)
                if m.split(".")[0] not in MAY_IMPORT[pkg]]
    return out
