"""The `uam-compare` command line."""
from __future__ import annotations

import argparse
import logging
import sys

from uam_fdm.params import preset_names


def _cmd_demo(args: argparse.Namespace) -> int:
    from compare.demo import demo_flight

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


def _cmd_maps(args: argparse.Namespace) -> int:
    from uam_fdm.city_plot import render_named_maps

    for path in render_named_maps(args.out_dir):
        print(path)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="uam-compare", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress (INFO)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    demo = sub.add_parser("demo", help="fly the vehicle presets through a demo pattern and report what happened")
    demo.add_argument("vehicles", nargs="*", default=preset_names(),
                      help=f"preset names or vehicle YAML paths (default: {' '.join(preset_names())})")
    demo.add_argument("--seed", type=int, default=0, help="turbulence seed")
    demo.set_defaults(func=_cmd_demo)
    maps = sub.add_parser("maps", help="render the shipped maps (top-down and 3D) to PNG")
    maps.add_argument("out_dir", nargs="?", default="maps_png", help="output folder (default: maps_png)")
    maps.set_defaults(func=_cmd_maps)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if args.command is None:
        args = parser.parse_args(["demo", *(argv or [])])
    try:
        return args.func(args)
    except ValueError as exc:   # bad user input (ConfigError is a ValueError): one clear line, non-zero exit
        print(f"uam-compare: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
