"""`validate`: read scenario files strictly, as `run` does, and say what each holds; nothing flies."""
from __future__ import annotations

import argparse
from collections.abc import Mapping

from compare.scenarios.sets import resolve_scenarios


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `validate` to the command line."""
    val = sub.add_parser("validate", help="check scenario files strictly without flying anything")
    val.add_argument("scenario", help="a built-in set, a scenario YAML or a folder of them")
    val.set_defaults(func=validate)


def validate(args: argparse.Namespace) -> int:
    """`validate`: one line per scenario: its file, map, vehicle, episodes, seeds, pilots, turbulence, and its sensing
    and map-error levels where they are not perfect and exact."""
    for sc in resolve_scenarios(args.scenario):
        levels = "" if sc.sensing.perfect else f", sensing {sc.sensing.label}"
        if not sc.map_error.exact or sc.unmapped_ids:
            levels += f", map error {sc.map_error.label} ({len(sc.unmapped_ids)} obstacles not in the prior map)"
        drawn = sc.raw.get("episodes")
        if isinstance(drawn, Mapping):  # `episodes: {random: N, ...}`
            levels = f", legs drawn at random from seed {drawn.get('seed', sc.seeds[0])}" + levels
        print(f"{sc.source}: ok ({sc.name}: map {sc.city.name or '-'} with {len(sc.city.buildings)} buildings, "
              f"vehicle {sc.vehicle_name}, {len(sc.episodes)} episodes x {len(sc.seeds)} seeds, "
              f"pilots {', '.join(sc.pilots)}, turbulence {sc.wind.turbulence.value}{levels})")
    return 0
