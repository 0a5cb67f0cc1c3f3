"""The commands that show the pieces, nothing compared: `demo` (the vehicle presets fly a pattern) and `maps` (the
shipped maps drawn, or the city, legs and flight volume of scenario files)."""
from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from pathlib import Path

from compare.flying.demo import demo_flight
from compare.results.outputs import check_output_dir
from compare.scenarios.scenario import Scenario, load_scenario
from uam_fdm.vehicle.params import preset_names

DEFAULT_MAPS_DIR = "maps_png"
SCENARIO_SUFFIXES = (".yaml", ".yml")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `demo` and `maps` to the command line."""
    demo_parser = sub.add_parser("demo",
                                 help="fly the vehicle presets through a demo pattern and report what happened")
    demo_parser.add_argument("vehicles", nargs="*", default=preset_names(),
                             help=f"preset names or vehicle YAML paths (default: {' '.join(preset_names())})")
    demo_parser.add_argument("--seed", type=int, default=0, help="turbulence seed")
    demo_parser.set_defaults(func=demo)
    maps_parser = sub.add_parser("maps", help="render the shipped maps (top-down and 3D) to PNG",
                                 description="Render the shipped maps to OUT_DIR/map_<name>.png; or, given scenario "
                                             "files, each one's city (with its prior map's differences), legs "
                                             "(labelled by episode index) and flight volume, top view and 3D, to "
                                             "--out/scenario_<file name>.png. Every file is checked first.")
    maps_parser.add_argument("targets", nargs="*", metavar="OUT_DIR | SCENARIO.yaml",
                             help=f"an output folder for the shipped maps (default: {DEFAULT_MAPS_DIR}), or scenario "
                                  f"files (.yaml, .yml) to preview")
    maps_parser.add_argument("--out", default=None, metavar="DIR",
                             help=f"the output folder (default: {DEFAULT_MAPS_DIR})")
    maps_parser.set_defaults(func=maps)


def demo(args: argparse.Namespace) -> int:
    """`demo`: each vehicle flies the demo waypoints; what happened, in four lines per vehicle."""
    for preset in args.vehicles:
        r = demo_flight(preset, seed=args.seed)
        print(f"{r.vehicle}: {r.mass_kg:g} kg, {r.n_rotors} rotors, hover at {r.hover_rotor_speed_rad_s:.1f} rad/s "
              f"({r.backend} dynamics)")
        print(f"  reached {r.waypoints_reached}/{r.waypoints} waypoints (climb, square, return, descend) in "
              f"{r.flight_time_s:.1f} s through light turbulence: flew {r.path_length_m:.0f} m, "
              f"max speed {r.max_speed_m_s:.1f} m/s, max tilt {r.max_tilt_deg:.1f} deg")
        print(f"  largest distance from the square {r.max_cross_track_m:.2f} m, ended at "
              f"({r.final_position_m[0]:.1f}, {r.final_position_m[1]:.1f}, {r.final_position_m[2]:.1f}) m")
        print(f"  rotor shaft energy {r.energy_kj:.1f} kJ (mean {r.mean_shaft_power_kw:.2f} kW); "
              f"simulated {r.flight_time_s / r.wall_time_s:.0f}x faster than real time")
    return 0


def maps(args: argparse.Namespace) -> int:
    """`maps`: the shipped maps, or each scenario file's preview, as PNG files, one path per line."""
    files = [t for t in args.targets if Path(t).suffix in SCENARIO_SUFFIXES]
    if files and len(files) != len(args.targets):
        raise ValueError(f"maps {' '.join(args.targets)}: give either OUT_DIR or scenario files (.yaml, .yml), not "
                         f"both (--out DIR names the folder for the previews)")
    if not files and len(args.targets) > 1:
        raise ValueError(f"maps {' '.join(args.targets)}: one OUT_DIR, or scenario files (.yaml, .yml)")
    if not files and args.targets and args.out is not None:
        raise ValueError(f"maps {args.targets[0]} --out {args.out}: give the output folder once")
    option = "--out" if args.out is not None or files else "OUT_DIR"
    out = Path(args.out or (args.targets[0] if args.targets and not files else DEFAULT_MAPS_DIR))
    check_output_dir(out, option)
    if files:
        for path in preview_scenarios(files, out):
            print(path)
        return 0
    from uam_fdm.city.plot import render_named_maps  # matplotlib

    for path in render_named_maps(out):
        print(path)
    return 0


def preview_scenarios(files: Sequence[str], out_dir: Path) -> list[Path]:
    """Check every scenario file, then draw each to `out_dir`/scenario_<file name>.png (`task_preview_figure`:
    its true city, the prior map's differences, its legs labelled by episode index, its flight volume).

    Raises:
        ConfigError: a bad file, before anything is drawn; ValueError: two files of the same name.
    """
    scenarios = [load_scenario(f) for f in files]  # every file checked before the first figure
    names = [f"scenario_{Path(f).stem}.png" for f in files]
    for i, name in enumerate(names):
        if name in names[:i]:
            raise ValueError(f"maps: {files[names.index(name)]} and {files[i]} would both be drawn to "
                             f"{out_dir / name}; preview them one at a time, each with its own --out")
    from uam_fdm.city.plot import save_figure, task_preview_figure  # matplotlib

    written = []
    for sc, name in zip(scenarios, names):
        drawn = " drawn at random" if isinstance(sc.raw.get("episodes"), Mapping) else ""
        n = len(sc.episodes)
        title = (f"{sc.name} ({sc.source}): map {sc.city.name or 'from the file'}, {len(sc.city.building_ids)} "
                 f"buildings, vehicle {sc.vehicle_name} (collision radius {sc.vehicle.collision_radius_m:g} m), {n} "
                 f"episode{'s' if n != 1 else ''}{drawn}\n{_volume(sc)}"
                 + ("" if sc.prior_map is sc.city else f"; map error {sc.map_error.label}, {len(sc.unmapped_ids)} "
                                                       f"obstacles not in the prior map"))
        fig = task_preview_figure(sc.city, [ep.task for ep in sc.episodes], prior=sc.prior_map,
                                  labels=[str(ep.index) for ep in sc.episodes], title=title)
        written.append(save_figure(fig, out_dir / name))
    return written


def _volume(sc: Scenario) -> str:
    lo, hi = sc.city.bounds_min_m, sc.city.bounds_max_m
    return (f"flight volume x [{lo[0]:g}, {hi[0]:g}], y [{lo[1]:g}, {hi[1]:g}], z [{lo[2]:g}, {hi[2]:g}] m "
            f"(ENU, above the field)")
