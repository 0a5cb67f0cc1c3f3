"""Library code changes no process-wide state: no working-directory changes, no
matplotlib backend choice, no torch thread count, no printing, except in the entry points that own
the process (the CLI, a run's worker processes, the training job, a module's `main`)."""
from __future__ import annotations

import ast
import os
from pathlib import Path

import casadi as ca

from planners.mpc import _nlp_functions_c

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("uam_fdm", "planners", "rl", "compare")
# (file, function) pairs that own their process and may set process-wide state, with the reason
ALLOWED = {
    ("compare/cli/", "*"): "the command line owns its process (every module of the package)",
    ("compare/run/backends/worker.py", "prepare_process"): "a run's worker process is the run's own",
    ("rl/training/loop.py", "train"): "the training job owns its process (its config names the thread count)",
}
GLOBAL_CALLS = {("os", "chdir"), ("matplotlib", "use"), ("torch", "set_num_threads")}


def _offences(path: Path) -> list[str]:
    rel = str(path.relative_to(ROOT))
    # a package whose every module owns its process is named by its folder
    owner = next((f for f, func in ALLOWED if func == "*" and f.endswith("/") and rel.startswith(f)), rel)
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []

    def visit(node: ast.AST, func: str) -> None:
        for child in ast.iter_child_nodes(node):
            name = child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else func
            if isinstance(child, ast.If) and "__main__" in ast.unparse(child.test):
                continue  # a script's entry point
            if isinstance(child, ast.Call) and (owner, "*") not in ALLOWED and (rel, func) not in ALLOWED:
                f = child.func
                if (isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name)
                        and (f.value.id, f.attr) in GLOBAL_CALLS):
                    found.append(f"{rel}:{child.lineno} {f.value.id}.{f.attr} in {func or 'module level'}")
                if isinstance(f, ast.Name) and f.id == "print" and func not in ("main", "_main"):
                    found.append(f"{rel}:{child.lineno} print in {func or 'module level'}")
            visit(child, name)

    visit(tree, "")
    return found


def test_library_code_sets_no_process_wide_state() -> None:
    offences = [o for pkg in PACKAGES for path in sorted((ROOT / pkg).rglob("*.py")) for o in _offences(path)]
    assert offences == []


def test_the_scan_catches_what_it_looks_for(tmp_path: Path, monkeypatch) -> None:
    bad = ROOT / "uam_fdm" / "_scan_probe.py"
    try:
        bad.write_text("import os\n\ndef f():\n    os.chdir('/')\n    print('x')\n")
        assert _offences(bad) == ["uam_fdm/_scan_probe.py:4 os.chdir in f", "uam_fdm/_scan_probe.py:5 print in f"]
    finally:
        bad.unlink()


def test_mpc_code_generation_leaves_the_working_directory_alone(tmp_path: Path) -> None:
    """The MPC's C source comes from a child process: this process's directory never moves, and the
    source is byte for byte what CasADi writes in-process."""
    x, p = ca.SX.sym("x", 2), ca.SX.sym("p")
    solver = ca.nlpsol("mpc", "ipopt", {"x": x, "p": p, "f": (x[0] - p) ** 2 + x[1] ** 2, "g": x[0] + x[1]},
                       {"print_time": False})
    cwd = os.getcwd()
    source = _nlp_functions_c(solver)
    assert os.getcwd() == cwd
    os.chdir(tmp_path)  # the reference, the old way (here, in a test that owns its process)
    try:
        reference = Path(solver.generate_dependencies("mpc_nlp.c")).read_bytes()
    finally:
        os.chdir(cwd)
    assert source == reference
