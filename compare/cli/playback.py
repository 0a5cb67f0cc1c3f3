"""The commands that show flights after they were flown: `animate` (a video of one cell of a run, or of every cell),
`view` (a run's interactive 3D viewer, one HTML file), `view-training` (a policy's training curves and recorded
flights, one HTML file) and `export` (a run's, or a policy's recorded training flights, as a Rerun recording, the one
export format)."""
from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from compare.results.outputs import check_not_replacing, check_output_dir, check_output_file
from compare.results.run_info import RUN_INFO_NAME
from compare.run.campaign import VIDEOS_DIR
from rl.policies.flights import TrainingFlights
from rl.policies.folder import CONFIG


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `animate`, `view`, `view-training` and `export` to the command line."""
    anim = sub.add_parser("animate", help="render both pilots flying one cell of a run to MP4 (GIF without ffmpeg)",
                          help_values=_animation_defaults)
    anim.add_argument("run_dir", type=Path, help="a folder written by `uam-compare run`")
    anim.add_argument("--episode", default=None, metavar="SCENARIO:EPISODE[:SEED]",
                      help="the cell to show, e.g. suburb-quad:0 (default: the run's first)")
    anim.add_argument("--all", action="store_true", help="every cell of the run, one file each")
    anim.add_argument("--out", type=Path, default=None,
                      help="output file (.mp4 or .gif); with --all a folder (default: RUN_DIR/videos/)")
    anim.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    anim.add_argument("--format", choices=("mp4", "gif"), default="mp4", help="format of default file names")
    # the clip's settings default to `AnimationConfig`'s
    anim.add_argument("--fps", type=float, default=None, help="frames per second (default {fps})")
    anim.add_argument("--duration", type=float, default=None,
                      help="video length [s] (default: real time, sped up to fit {max_auto_duration} s)")
    anim.add_argument("--size", type=parse_size, default=None, help="WIDTHxHEIGHT in pixels (default {size})")
    anim.add_argument("--orbit", type=float, default=None, help="camera turn over the clip [deg] (default {orbit})")
    anim.add_argument("--no-progress", action="store_true", help="no progress bar")
    anim.set_defaults(func=animate)
    vw = sub.add_parser("view", help="write a run folder's interactive 3D viewer (one self-contained HTML file)")
    vw.add_argument("run_dir", type=Path, help="a folder written by `uam-compare run`")
    vw.add_argument("--out", type=Path, default=None, help="HTML file to write (default: RUN_DIR/viewer.html)")
    vw.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    vw.set_defaults(func=view)
    vt = sub.add_parser("view-training", help="write one offline HTML page of a policy's training: the curves, and "
                        "the recorded flights of every checkpoint in 3D, scrubbable")
    vt.add_argument("policy_dir", type=Path, help="a policy folder trained with recorded flights (uam-compare train)")
    vt.add_argument("--out", type=Path, default=None,
                    help="HTML file to write (default: <policy folder name>-training.html here)")
    vt.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    vt.set_defaults(func=view_training)
    ex = sub.add_parser("export", help="write a run's flights, or a policy's recorded training flights, as a Rerun "
                        "recording (.rrd; needs the rerun extra)")
    ex.add_argument("folder", type=Path, help="a run folder (uam-compare run) or a policy folder with training flights")
    ex.add_argument("--rerun", action="store_true",
                    help="write a Rerun .rrd recording: the one format, written without it too (the default)")
    ex.add_argument("--out", type=Path, default=None,
                    help="file to write (default: RUN_DIR/flights.rrd, or <policy folder name>-training.rrd here)")
    ex.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    ex.set_defaults(func=export)


def _animation_defaults() -> dict[str, str]:
    """`animate --help`'s defaults, `AnimationConfig`'s."""
    from compare.playback.animation_config import AnimationConfig

    c = AnimationConfig()
    return {"fps": f"{c.fps:g}", "max_auto_duration": f"{c.max_auto_duration_s:g}",
            "size": f"{c.width_px}x{c.height_px}", "orbit": f"{c.orbit_deg:g}"}


def parse_size(text: str) -> tuple[int, int]:
    """`--size`: WIDTHxHEIGHT in pixels."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, e.g. 1280x720, got {text!r}") from None
    return w, h


def animate(args: argparse.Namespace) -> int:
    """`animate`: one cell (or with --all every cell) of a run as a video; one line per file written."""
    from compare.playback.animate import AnimationConfig, render_animation, render_videos  # matplotlib
    from compare.playback.flights import flight_groups, select_group

    given = {"fps": args.fps, "duration_s": args.duration, "orbit_deg": args.orbit}
    if args.size is not None:
        given["width_px"], given["height_px"] = args.size
    opts = AnimationConfig(**{k: v for k, v in given.items() if v is not None})  # the rest: the config's defaults
    opts.validate()  # before loading anything
    if args.all and args.episode is not None:
        raise ValueError("--all and --episode: give one or the other")
    groups = flight_groups(args.run_dir)
    if args.all:
        out_dir = args.out if args.out is not None else args.run_dir / VIDEOS_DIR
        check_output_dir(out_dir, "--out")
        results = render_videos(groups, out_dir, "all", opts, progress=not args.no_progress, fmt=args.format,
                                root=args.run_dir if args.out is None else None)
    else:
        group = select_group(groups, args.episode) if args.episode is not None else groups[0]
        out = args.out if args.out is not None else args.run_dir / VIDEOS_DIR / f"{group.stem}.{args.format}"
        check_output_file(out, "--out")
        check_not_replacing(args.out, "--out", args.overwrite)
        results = [render_animation(group, out, opts, progress=not args.no_progress,
                                    root=args.run_dir if args.out is None else None)]
    for r in results:
        print(f"{r.path}  ({r.format}, {r.frames} frames {r.width_px}x{r.height_px} at {r.fps:g} fps, "
              f"x{r.speedup:.2f} real time, rendered in {r.seconds:.1f} s)")
    return 0


def view(args: argparse.Namespace) -> int:
    """`view`: the run's viewer page; its path."""
    from compare.pages.viewer import VIEWER_NAME, build_viewer  # plotly and matplotlib

    check_output_file(args.out if args.out is not None else args.run_dir / VIEWER_NAME, "--out")
    check_not_replacing(args.out, "--out", args.overwrite)
    print(build_viewer(args.run_dir, args.out))
    return 0


def view_training(args: argparse.Namespace) -> int:
    """`view-training`: the policy's training page; its path."""
    from compare.pages.training_view import build_training_view, default_out  # plotly and matplotlib

    if not args.policy_dir.is_dir():
        raise ValueError(f"{args.policy_dir}: not a policy folder (no such folder)")
    TrainingFlights.open(args.policy_dir)  # no flights: one line naming the folder and how to record them
    out = args.out if args.out is not None else default_out(args.policy_dir)
    check_output_file(out, "--out")
    check_not_replacing(out, "--out", args.overwrite)  # the default file too: it is in the user's folder
    print(build_training_view(args.policy_dir, out))
    return 0


def export(args: argparse.Namespace) -> int:
    """`export`: a run folder's flights, or a policy folder's recorded training flights, as one Rerun .rrd (the one
    format, so --rerun is the default)."""
    from compare.playback.rerun_export import require_rerun, run_recording, training_recording  # matplotlib

    require_rerun()  # a missing extra is said before anything is read
    folder = args.folder
    write: Callable[[Path, Path], Path]
    if (folder / RUN_INFO_NAME).is_file():
        out = args.out if args.out is not None else folder / "flights.rrd"  # the run folder's own file
        write = run_recording
    elif folder.is_dir() and (folder / CONFIG).is_file():
        TrainingFlights.open(folder)  # no flights: one line naming the folder and how to record them
        out = args.out if args.out is not None else Path(f"{folder.resolve().name}-training.rrd")
        write = training_recording
    else:
        raise ValueError(f"{folder}: neither a run folder ({RUN_INFO_NAME}) nor a policy folder ({CONFIG})")
    check_output_file(out, "--out")
    # a file the user named, or the policy's default file in their folder, is never replaced unasked
    check_not_replacing(out if args.out is not None or write is training_recording else None, "--out",
                        args.overwrite)
    print(write(folder, out))
    return 0
