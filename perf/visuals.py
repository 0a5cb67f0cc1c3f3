"""Cost of seeing the flights: animation frames and the HTML viewer, on a real run of downtown-quad.

Flies the `default` set's downtown-quad scenario (2 episodes x both pilots, ~20 s) into a temporary
run folder (or uses RUN_DIR), then measures on its first cell (209-building map, cropped):

- ms per 1280x720 frame: fixed camera (the city drawn once, only moving parts drawn per frame),
  with a camera orbit (3D panel redrawn), and the baseline of a full figure redraw per frame;
- a whole MP4 (ffmpeg, H.264) and GIF, per frame, encoding included;
- building the viewer: seconds and size.

Prints a table, then (last line) one JSON object of the figures.

    python perf/visuals.py [RUN_DIR] [--frames 200]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from compare.pages.viewer import build_viewer
from compare.playback.animate import AnimationConfig, _Scene, ffmpeg_available, frame_times, render_animation
from compare.playback.flights import flight_groups
from compare.run.campaign import RunConfig, run_comparison
from compare.scenarios.sets import resolve_scenarios

SCENARIO = Path(__file__).resolve().parents[1] / "compare" / "scenarios" / "default" / "downtown-quad.yaml"


def per_frame_ms(scene: _Scene, frames: int, full_redraw: bool = False) -> float:
    """Mean wall time of rendering `frames` frames [ms]; `full_redraw` draws the whole figure each time."""
    t0 = time.perf_counter()
    for k in range(frames):
        if full_redraw:
            for a in scene.moving:
                a.set_animated(False)
            scene._update(k)
            scene.canvas.draw()
            bytes(scene.canvas.buffer_rgba()[:1])
        else:
            scene.draw(k)
    return 1e3 * (time.perf_counter() - t0) / frames


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", nargs="?", type=Path, default=None)
    ap.add_argument("--frames", type=int, default=200, help="frames per timing (default 200)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = args.run_dir
        if run_dir is None:
            run_dir = Path(tmp) / "run"
            run_comparison(resolve_scenarios(str(SCENARIO)),
                           RunConfig(out_dir=run_dir, progress=False, report=False, videos="none"))
        group = flight_groups(run_dir)[0]
        opts = AnimationConfig(duration_s=args.frames / 20.0)
        times = frame_times(group.duration_s, opts)
        fixed = per_frame_ms(_Scene(group, times, opts), args.frames)
        orbit_opts = AnimationConfig(duration_s=args.frames / 20.0, orbit_deg=60.0)
        orbit = per_frame_ms(_Scene(group, times, orbit_opts), args.frames)
        full = per_frame_ms(_Scene(group, times, opts), max(args.frames // 4, 10), full_redraw=True)
        mp4 = None
        if ffmpeg_available():
            r = render_animation(group, Path(tmp) / "clip.mp4", opts, progress=False)
            mp4 = 1e3 * r.seconds / r.frames
        r = render_animation(group, Path(tmp) / "clip.gif", opts, progress=False)
        gif = 1e3 * r.seconds / r.frames
        t0 = time.perf_counter()
        page = build_viewer(run_dir, Path(tmp) / "viewer.html")
        viewer_s = time.perf_counter() - t0
        viewer_mb = page.stat().st_size / 1e6
    figures = {
        "anim_frame_ms_1280x720": round(fixed, 2),
        "anim_orbit_frame_ms_1280x720": round(orbit, 2),
        "anim_full_redraw_frame_ms_1280x720": round(full, 2),
        "anim_speedup_vs_full_redraw": round(full / fixed, 2),
        "mp4_ms_per_frame_with_encoding": None if mp4 is None else round(mp4, 2),
        "gif_ms_per_frame_with_encoding": round(gif, 2),
        "viewer_build_s": round(viewer_s, 2),
        "viewer_mb": round(viewer_mb, 2),
        "cell": group.spec, "buildings_in_map": len(group.city.buildings),
    }
    rows = [("frame, fixed camera (draw moving parts only)", f"{fixed:.1f} ms"),
            ("frame, camera orbit (3D panel redrawn)", f"{orbit:.1f} ms"),
            ("frame, full redraw (baseline)", f"{full:.1f} ms  (fixed camera x{full / fixed:.1f} faster)"),
            ("MP4 incl. H.264 encoding, per frame", "ffmpeg missing" if mp4 is None else f"{mp4:.1f} ms"),
            ("GIF incl. encoding, per frame", f"{gif:.1f} ms"),
            ("viewer.html build (2 cells)", f"{viewer_s:.2f} s, {viewer_mb:.1f} MB")]
    print(f"cell {group.spec} ({len(group.city.buildings)} buildings before cropping), 1280x720")
    width = max(len(a) for a, _ in rows)
    for a, b in rows:
        print(f"  {a.ljust(width)}  {b}")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
