"""`validate`: read scenario files strictly, as `run` does, and say what each holds; nothing flies."""
from __future__ import annotations

import argparse

from compare.scenarios.sets import resolve_scenarios


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `validate` to the command line."""
    val = sub.add_parser("validate", help="check scenario files strictly without flying anything")
    val.add_argument("scenario", help="a built-in set, a scenario YAML or a folder of them")
    val.set_defaults(func=validate)


def validate(args: argparse.Namespace) -> int:
    """`validate`: one line per scenario: its file, map, vehicle, episodes, seeds, pilots and turbulence."""
    for sc in resolve_scenarios(args.scenario):
        print(f"{sc.source}: ok ({sc.name}: map {sc.city.name or '-'} with {len(sc.city.buildings)} buildings, "
              f"vehicle {sc.vehicle_name}, {len(sc.episodes)} episodes x {len(sc.seeds)} seeds, "
              f"pilots {', '.join(sc.pilots)}, turbulence {sc.wind.turbulence.value})")
    return 0
