"""Scenario sets by name: the shipped folders of scenario files and the generated benchmark sets.

The shipped sets are the folders of ``compare/scenarios/<set>/*.yaml`` (`SCENARIO_DIR`), each file checked by
the strict loader (`compare.scenarios.scenario`); the benchmark sets
(`compare.scenarios.benchmark.BENCHMARK_SETS`) and the robustness sweep's (`compare.scenarios.sweep.SWEEP_SETS`)
are generated and checked by the same loader. `builtin_sets()` lists them all; `resolve_scenarios` accepts a set
name, a YAML file or a folder of YAML files. This module sits above the loader and the generators (which import
the loader); none of them imports it.
"""
from __future__ import annotations

from pathlib import Path

from compare.scenarios.benchmark import BENCHMARK_SETS, build_task_set
from compare.scenarios.scenario import Scenario, load_scenario
from compare.scenarios.sweep import SWEEP_SETS, build_sweep
from uam_fdm.errors import ConfigError

SCENARIO_DIR = Path(__file__).parent


def builtin_sets() -> list[str]:
    """Names of the built-in scenario sets (folders of `compare/scenarios` holding YAML files, and the
    generated `BENCHMARK_SETS` and `compare.scenarios.sweep.SWEEP_SETS`), sorted."""
    folders = [p.name for p in SCENARIO_DIR.iterdir() if p.is_dir() and any(p.glob("*.yaml"))]
    return sorted([*folders, *BENCHMARK_SETS, *SWEEP_SETS])


def resolve_scenarios(spec: str | Path) -> list[Scenario]:
    """Load the scenarios named by `spec`.

    Args:
        spec: a built-in set name (`builtin_sets()`; a benchmark set is generated, `compare.scenarios.benchmark`),
            a scenario YAML file, or a folder whose ``*.yaml`` / ``*.yml`` files are loaded in sorted file-name
            order. A bare set name that is also a file or folder here is refused (write ``./default`` for it).

    Returns:
        The scenarios, in order.

    Raises:
        ValueError: when `spec` is neither a set nor an existing file or folder (the message lists
            the built-in sets), both a set and a file or folder here, or the folder holds no YAML file.
        ConfigError: for any bad scenario, or two scenarios with the same name.
    """
    text = str(spec)
    local = Path(text)
    if text in builtin_sets() and local.exists() and local.resolve() != (SCENARIO_DIR / text).resolve():
        kind = "folder" if local.is_dir() else "file"
        raise ValueError(f"{text!r} names both a built-in scenario set and the {kind} ./{text} here: write ./{text} "
                         f"for the {kind}; for the built-in set, run from a folder without a {text!r} in it")
    if text in BENCHMARK_SETS:
        return list(build_task_set(text).scenarios)
    if text in SWEEP_SETS:
        return list(build_sweep(text).scenarios)
    if text in builtin_sets():
        files = _yaml_files(SCENARIO_DIR / text)
    else:
        path = Path(spec)
        if path.is_file():
            files = [path]
        elif path.is_dir():
            files = _yaml_files(path)
            if not files:
                raise ValueError(f"scenario folder {text!r} holds no .yaml or .yml file")
        else:
            raise ValueError(f"{text!r} is neither a built-in scenario set ({', '.join(builtin_sets())}) "
                             f"nor an existing scenario YAML file or folder")
    scenarios: list[Scenario] = []
    for f in files:
        scenario = load_scenario(f)
        for other in scenarios:
            if other.name == scenario.name:
                raise ConfigError(scenario.source, "name", f"duplicate scenario name {scenario.name!r} "
                                                           f"(also in {other.source})")
        scenarios.append(scenario)
    return scenarios


def _yaml_files(folder: Path) -> list[Path]:
    return sorted((p for p in folder.iterdir() if p.suffix in (".yaml", ".yml") and p.is_file()),
                  key=lambda p: p.name)
