"""The rooms keep their one-way flow (docs/architecture.md): `uam_fdm` imports none of the other
packages, `planners` and `rl` import only `uam_fdm` (and themselves), nothing imports `compare`; and no
two modules import each other (no import circles), counting every import: at module level, inside functions
and in `TYPE_CHECKING` blocks (an import moved into a function hides a circle, it does not remove it).
Inside a function (or for the type checker only) `compare` imports only what is slow to import or optional
(`DEFERRED_IMPORTS`)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("uam_fdm", "planners", "rl", "compare")
MAY_IMPORT = {"uam_fdm": {"uam_fdm"}, "planners": {"uam_fdm", "planners"}, "rl": {"uam_fdm", "rl"},
              "compare": set(PACKAGES)}
# What `compare` may import inside a function or a TYPE_CHECKING block: PyTorch, Ray, matplotlib and plotly
# (the figures, the viewer, the map plots), rerun-sdk (an optional extra) and the pilots' own packages (PyTorch,
# OMPL), so that printing help, checking a scenario or reading a run folder needs none of them.
DEFERRED_IMPORTS = ("torch", "ray", "compare.run.backends.ray", "compare.report",
                    "compare.playback", "compare.pages", "uam_fdm.city.plot", "rl", "planners",
                    "matplotlib", "rerun", "uam_fdm.sensing")  # the sensors: Embree and the filter, only when sensing
# What `rl` may import inside a function or for the type checker only: PyTorch (the network's module included,
# so reading a policy folder's settings needs none) and matplotlib (the env's rgb_array frames).
RL_DEFERRED_IMPORTS = ("torch", "rl.policies.network", "matplotlib", "uam_fdm.city.plot")
# The one import against the flow, named with its reason: the training env reads a scenario FILE (`gymnasium.make(
# "UAMNav-v0", scenario=FILE)`, which the issue asks for) with the one strict reader of that format, compare's, and
# only when a file is given (inside the function: `rl` never needs `compare` otherwise). A new one fails the test.
AGAINST_THE_FLOW = {("rl.env.ground", "compare.scenarios.scenario"): "the scenario file format's one reader"}
# The learned pilot's rooms, in the order they may import each other: a module imports only rooms before its own.
RL_ROOMS = ("sensing", "task", "policies", "env", "pilots", "training")
# The comparison's rooms, in the same sense: flying an episode, its results, what is flown (scenario files and the
# generated task sets), what is made of results (the PDF report, playback, HTML pages), running a campaign, the CLI.
COMPARE_ROOMS = ("flying", "results", "scenarios", "report", "playback", "pages", "run", "cli")


def _module_name(path: Path, root: Path = ROOT) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _sources(root: Path = ROOT) -> list[Path]:
    return [p for pkg in PACKAGES for p in sorted((root / pkg).rglob("*.py"))]


def _imported(path: Path, root: Path, deferred_only: bool = False, members: bool = True) -> set[str]:
    """What `path` imports: every module named, and (`members`) `pkg.name` for `from pkg import name`, which may
    be a module. Imports wherever they stand, or (`deferred_only`) those inside functions and TYPE_CHECKING
    blocks only."""
    here = _module_name(path, root)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    nodes: list[ast.Import | ast.ImportFrom] = []

    def visit(node: ast.AST, deferred: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inner = deferred or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) or (
                isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test))
            if isinstance(child, (ast.Import, ast.ImportFrom)) and (inner or not deferred_only):
                nodes.append(child)
            visit(child, inner)

    visit(ast.parse(path.read_text(encoding="utf-8")), False)
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
            if members:
                found |= {f"{base}.{a.name}" for a in node.names}  # `from pkg import module`
    return found


def _imports(path: Path, root: Path = ROOT) -> set[str]:
    """Our modules that `path` imports, wherever the import stands."""
    return {m for m in _imported(path, root) if m.split(".")[0] in PACKAGES}


def test_packages_import_one_way() -> None:
    assert _wrong_imports() == []


def test_no_import_circles() -> None:
    assert _circles() == []


def test_compare_and_rl_defer_only_slow_or_optional_imports() -> None:
    """An import inside a function in `compare` or `rl` defers something slow to import or optional (and says so
    in a comment), never dodges a circle."""
    assert _needless_deferred_imports() == []
    allowed = RL_DEFERRED_IMPORTS + tuple(mod for _, mod in AGAINST_THE_FLOW)
    assert _needless_deferred_imports(package="rl", allowed=allowed) == []


def test_the_learned_pilots_rooms_import_one_way() -> None:
    """rl/sensing, task, policies, env, pilots, training: each imports only the rooms before it (and `uam_fdm`)."""
    assert _rooms_out_of_order("rl", RL_ROOMS) == []


def test_the_comparisons_rooms_import_one_way() -> None:
    """compare/flying, results, scenarios, report, playback, pages, run, cli: each imports only the rooms before
    it (and the other packages); every module of compare stands in a room."""
    assert _rooms_out_of_order("compare", COMPARE_ROOMS) == []


def _rooms_out_of_order(package: str, rooms: tuple[str, ...], root: Path = ROOT) -> list[str]:
    """Imports of `package`'s modules that reach a room after their own, wherever the import stands, and modules
    outside every room (a package's `__init__.py` and `__main__.py` at its top level excepted)."""
    wrong = []
    for path in sorted((root / package).rglob("*.py")):
        parts = path.relative_to(root / package).parts
        if len(parts) < 2:
            if path.name not in ("__init__.py", "__main__.py"):
                wrong.append(f"{path.relative_to(root)} stands in no room")
            continue
        if parts[0] not in rooms:
            wrong.append(f"{path.relative_to(root)} stands in no room")
            continue
        rank = rooms.index(parts[0])
        for m in sorted(_imports(path, root)):
            room = m.split(".")[1] if m.startswith(f"{package}.") else None
            if room is not None and room in rooms and rooms.index(room) > rank:
                wrong.append(f"{path.relative_to(root)} imports {m}")
    return wrong


def _wrong_imports(root: Path = ROOT) -> list[str]:
    out = []
    for path in _sources(root):
        pkg = _module_name(path, root).split(".")[0]
        here, deferred = _module_name(path, root), _imported(path, root, True)
        out += [f"{path.relative_to(root)} imports {m}" for m in sorted(_imports(path, root))
                if m.split(".")[0] not in MAY_IMPORT[pkg] and not _named_exception(here, m, deferred)]
    return out


def _named_exception(here: str, module: str, deferred: set[str]) -> bool:
    """`here` imports `module` (or a member of it) inside a function, as `AGAINST_THE_FLOW` allows it."""
    return module in deferred and any(who == here and (module == mod or module.startswith(f"{mod}."))
                                      for who, mod in AGAINST_THE_FLOW)


def _circles(root: Path = ROOT) -> list[str]:
    modules = {_module_name(p, root): p for p in _sources(root)}
    graph = {name: {m for m in _imports(path, root) if m in modules and m != name} for name, path in modules.items()}
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


def _needless_deferred_imports(root: Path = ROOT, package: str = "compare",
                               allowed: tuple[str, ...] = DEFERRED_IMPORTS) -> list[str]:
    out = []
    for path in sorted((root / package).rglob("*.py")):
        out += [f"{path.relative_to(root)} defers {m}" for m in sorted(_imported(path, root, True, members=False))
                if not any(m == d or m.startswith(f"{d}.") for d in allowed)]
    return out


PROBES = {
    "planners/_probe_wrong.py": "from rl.sensing.route import RouteConfig\n",
    # a circle at module level
    "planners/_probe_a.py": "from planners import _probe_b\n",
    "planners/_probe_b.py": "from planners._probe_a import X\n",
    # a lazy circle: one side imports the other inside a function
    "compare/_probe_lazy_a.py": "from compare._probe_lazy_b import Y\n",
    "compare/_probe_lazy_b.py": "def f():\n    from compare._probe_lazy_a import X\n    return X\n",
    # a circle through a TYPE_CHECKING block
    "compare/_probe_typed_a.py": "from compare._probe_typed_b import Y\n",
    "compare/_probe_typed_b.py": ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                 "    from compare._probe_typed_a import X\n"),
}
# compare's rooms: results reaching forward into run (inside a function: still a room out of order), a module in
# no room
ROOM_PROBES = {
    "compare/results/__init__.py": "",
    "compare/run/__init__.py": "",
    "compare/run/campaign.py": "from compare.results import metrics\n",
    "compare/results/metrics.py": "def f():\n    from compare.run.campaign import run\n    return run\n",
    "compare/stray.py": "X = 1\n",
}


@pytest.fixture
def probe_tree(tmp_path: Path) -> Path:
    """A source tree of the four packages holding only the probe modules."""
    for pkg in PACKAGES:
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("", encoding="utf-8")
    for name, text in PROBES.items():
        (tmp_path / name).write_text(text, encoding="utf-8")
    return tmp_path


def test_the_checks_see_a_wrong_import_and_every_kind_of_circle(probe_tree: Path) -> None:
    """The scans themselves: a planners module importing rl; two modules importing each other at module level,
    inside a function, and in a TYPE_CHECKING block; an import inside a function that dodges a circle."""
    assert _wrong_imports(probe_tree) == ["planners/_probe_wrong.py imports rl.sensing.route",
                                          "planners/_probe_wrong.py imports rl.sensing.route.RouteConfig"]
    circles = _circles(probe_tree)
    for a, b in (("planners._probe_a", "planners._probe_b"), ("compare._probe_lazy_a", "compare._probe_lazy_b"),
                 ("compare._probe_typed_a", "compare._probe_typed_b")):
        assert any(a in c and b in c for c in circles), (a, b, circles)
    assert len(circles) == 3
    assert _needless_deferred_imports(probe_tree) == ["compare/_probe_lazy_b.py defers compare._probe_lazy_a",
                                                      "compare/_probe_typed_b.py defers compare._probe_typed_a"]


def test_the_room_check_sees_a_room_out_of_order_and_a_module_in_no_room(tmp_path: Path) -> None:
    """The room scan itself, on a scratch tree: an import reaching a later room (inside a function too) and a
    module outside every room are named; an import of an earlier room is not."""
    (tmp_path / "compare").mkdir()
    for name, text in ROOM_PROBES.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text, encoding="utf-8")
    assert _rooms_out_of_order("compare", COMPARE_ROOMS, tmp_path) == [
        "compare/results/metrics.py imports compare.run.campaign",
        "compare/results/metrics.py imports compare.run.campaign.run",
        "compare/stray.py stands in no room",
    ]
