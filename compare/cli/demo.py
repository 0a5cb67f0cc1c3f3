"""The commands that show the pieces, nothing compared: `demo` (the vehicle presets fly a pattern) and `maps` (the
shipped maps drawn)."""
from __future__ import annotations

import argparse
from pathlib import Path

from compare.flying.demo import demo_flight
from compare.results.outputs import check_output_dir
from uam_fdm.vehicle.params import preset_names


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `demo` and `maps` to the command line."""
    demo_parser = sub.add_parser("demo",
                                 help="fly the vehicle presets through a demo pattern and report what happened")
    demo_parser.add_argument("vehicles", nargs="*", default=preset_names(),
                             help=f"preset names or vehicle YAML paths (default: {' '.join(preset_names())})")
    demo_parser.add_argument("--seed", type=int, default=0, help="turbulence seed")
    demo_parser.set_defaults(func=demo)
    maps_parser = sub.add_parser("maps", help="render the shipped maps (top-down and 3D) to PNG")
    maps_parser.add_argument("out_dir", nargs="?", default="maps_png", help="output folder (default: maps_png)")
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
    """`maps`: the shipped maps as PNG files, one path per line."""
    from uam_fdm.city.plot import render_named_maps  # matplotlib

    check_output_dir(Path(args.out_dir), "OUT_DIR")
    for path in render_named_maps(args.out_dir):
        print(path)
    return 0
