"""A 3D animation of one comparison cell: every pilot flying the same task on one clock, to MP4 or GIF.

`render_animation` draws one matplotlib `Figure` (Agg, no pyplot): a large 3D view of the city cropped
to the region around the flights, a small top-down map and live readouts (clock, speed, clearance,
status per pilot). The city is drawn once; each frame only moves the trails, markers and texts, which
are drawn over a saved copy of the static picture (blitting), so a frame costs ~12 ms at 1280x720
instead of ~80 ms for a full redraw. With a camera orbit the 3D panel is redrawn every frame (~40 ms).

Frames go to ffmpeg (`matplotlib.animation.FFMpegWriter`, H.264) or, without ffmpeg or when asked for,
to a GIF written frame by frame through Pillow. Output files are written atomically.
"""
from __future__ import annotations

import logging
import math
import shutil
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import matplotlib
import numpy as np
from matplotlib.animation import FFMpegWriter
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle
from matplotlib.text import Text
from mpl_toolkits.mplot3d import Axes3D
from mpl_toolkits.mplot3d.art3d import Line3D
from PIL import GifImagePlugin, Image
from tqdm import tqdm

from compare.playback.animation_config import AnimationConfig
from compare.playback.flights import Flight, FlightGroup, sample_flight
from compare.report.figures import GOAL_STYLE, START_STYLE, plain_text, trace_from_episode
from compare.results.run_info import WindInfo
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.city.plot import draw_map_3d, draw_map_topdown, missing_glyphs_unsaid
from uam_fdm.episode import Outcome
from uam_fdm.files.atomic import atomic_path
from uam_fdm.files.inside import inside_no_links

_log = logging.getLogger(__name__)

FORMATS = ("mp4", "gif")
VIDEO_CHOICES = ("scenario", "all", "none")  # which cells of a run `render_videos` animates
# The layout is in inches on a figure at least 12.8 x 7.2 in (scaled to the frame by the dpi): fonts are in
# points, so this keeps text, panels and markers in the same proportions at any frame size.
_MIN_FIG_IN = (12.8, 7.2)
_SIDE_IN = 3.85   # width of the side column (top-down map and readouts), from the right edge [in]
_HEAD_IN = 0.86   # height of the title lines [in]
_ELEV_DEG, _AZIM_DEG = 35.0, -60.0  # draw_map_3d's view
_MARKER: dict[str, Any] = {"linestyle": "none", "markersize": 9, "markeredgecolor": "k", "markeredgewidth": 1.0}


@dataclass(frozen=True)
class AnimationResult:
    """What `render_animation` wrote.

    Attributes:
        path: the file written (a ".gif" when an ".mp4" was asked for but ffmpeg is missing).
        format: "mp4" or "gif".
        frames: number of frames; width_px, height_px: frame size [px]; fps: frame rate [1/s].
        flight_s: simulated time covered [s] (until the last pilot's flight ended).
        speedup: simulated seconds per video second [-] (1: real time).
        seconds: wall time spent rendering and encoding [s].
    """

    path: Path
    format: str
    frames: int
    width_px: int
    height_px: int
    fps: float
    flight_s: float
    speedup: float
    seconds: float


def frame_times(flight_s: float, opts: AnimationConfig) -> np.ndarray:
    """Simulated time shown by each frame [s]: evenly from 0 to `flight_s`, both ends included.

    The video lasts `opts.duration_s`, or the flight's own length capped at `opts.max_auto_duration_s`
    (at least two frames); the last frame shows `flight_s`, when every flight has ended.

    Raises:
        ValueError: invalid options, or `flight_s` negative or not finite.
    """
    opts.validate()
    if not (math.isfinite(flight_s) and flight_s >= 0):
        raise ValueError(f"flight_s {flight_s!r}: must be a finite time >= 0 s")
    video_s = opts.duration_s if opts.duration_s is not None else min(flight_s, opts.max_auto_duration_s)
    video_s = max(video_s, 2.0 / opts.fps)
    n = max(2, round(video_s * opts.fps))
    return np.linspace(0.0, flight_s, n)


def ffmpeg_available() -> bool:
    """Whether matplotlib's ffmpeg (`rcParams["animation.ffmpeg_path"]`) can be found."""
    return shutil.which(str(matplotlib.rcParams["animation.ffmpeg_path"])) is not None


@plain_text
def render_animation(group: FlightGroup, out: Path, opts: AnimationConfig = AnimationConfig(),
                     progress: bool = True, *, root: Path | None = None) -> AnimationResult:
    """Render the pilots of `group` flying on one clock to `out` (".mp4" or ".gif").

    An ".mp4" asked for without ffmpeg is written as a GIF beside it (`out.with_suffix(".gif")`, with a
    logged warning); the result's `path` and `format` say what was written. Nothing is left behind if
    rendering fails.

    Args:
        group: the comparison cell (`compare.playback.flights.flight_groups`).
        out: output file; its suffix chooses the format.
        opts: frame rate, length, size and camera orbit.
        progress: show a tqdm progress bar on stderr.
        root: the run folder `out` lies in (None: a file the user named): no link in it is followed
            (`uam_fdm.files.atomic.atomic_path`).

    Raises:
        ValueError: invalid options, an unsupported suffix or a link below `root` (naming the path).
    """
    opts.validate()
    out = Path(out)
    fmt = out.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise ValueError(f"{out}: unsupported animation format {out.suffix!r}; use .mp4 or .gif")
    if fmt == "mp4" and not ffmpeg_available():
        gif = out.with_suffix(".gif")
        _log.warning("ffmpeg (%s) not found: writing a GIF, %s, instead of %s",
                     matplotlib.rcParams["animation.ffmpeg_path"], gif, out)
        out, fmt = gif, "gif"
    t0 = time.perf_counter()
    times = frame_times(group.duration_s, opts)
    n = len(times)
    scene = _Scene(group, times, opts)
    bar = tqdm(total=n, desc=f"animate {group.spec}", unit="frame", disable=not progress, leave=False)
    try:
        with atomic_path(out, suffix=f".{fmt}", root=root) as tmp:
            frames = (scene.draw(k) for k in range(n))
            if fmt == "mp4":
                _write_mp4(frames, tmp, scene.figure, opts.fps, bar, title=group.spec)
            else:
                _write_gif(frames, tmp, (opts.width_px, opts.height_px), opts.fps, scene.key_colors, bar)
    finally:
        bar.close()
    result = AnimationResult(out, fmt, n, opts.width_px, opts.height_px, opts.fps, group.duration_s,
                             scene.speedup, time.perf_counter() - t0)
    _log.info("wrote %s: %d frames %dx%d at %g fps, x%.2f, %.1f s", out, n, opts.width_px, opts.height_px,
              opts.fps, scene.speedup, result.seconds)
    return result


# ---- the picture -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Track:
    """One pilot's flight prepared for playback: sampled at the frame times, plus a dense path for the trail."""

    flight: Flight
    pos_m: np.ndarray        # (n, 3) at the frame times, ENU [m]
    speed_m_s: np.ndarray    # (n,)
    clearance_m: np.ndarray  # (n,)
    ended: np.ndarray        # (n,) the flight has ended at or before the frame's time
    path_m: np.ndarray       # (K, 3) the flown path (up to MAX_PLOT_POINTS rows), ENU [m]
    path_count: np.ndarray   # (n,) rows of path_m flown by each frame's time


def _track(flight: Flight, times: np.ndarray) -> _Track:
    s = sample_flight(flight.episode, times)
    trace = trace_from_episode(flight.episode, flight.label, flight.color)
    # ended from the end time, not sample_flight's strict t > end: the last frame (t = end) shows the outcome
    return _Track(flight, s.pos_m, s.speed_m_s, s.clearance_m, times >= flight.end_t_s, trace.pos_m,
                  np.searchsorted(trace.t_s, times, side="right"))


def _figure_inches(px: int, dpi: float) -> float:
    """Size [in] whose pixel count at `dpi` truncates to exactly `px` (Agg and ffmpeg's -s both use int())."""
    inches = px / dpi
    while int(inches * dpi) < px:  # px / dpi * dpi can round to just below px
        inches = float(np.nextafter(inches, math.inf))
    return inches


def _wind_words(wind: WindInfo | None) -> str:
    if wind is None or (wind.steady_enu_m_s is None and wind.turbulence is None):
        return "wind not recorded"
    words = []
    if wind.steady_enu_m_s is not None:
        v = np.asarray(wind.steady_enu_m_s, float)
        words.append(f"wind ({', '.join(f'{c:.1f}' for c in v)}) m/s ENU" if np.any(v) else "no steady wind")
    turb = wind.turbulence
    words.append(f"{turb} turbulence" if turb not in (None, "", "none") else "no turbulence")
    return ", ".join(words)


def _rate_words(speedup: float) -> str:
    return "x1.0 real time" if abs(speedup - 1.0) < 0.05 else f"x{speedup:.1f}"


def _status_words(track: _Track, k: int) -> str:
    """Readout of one pilot at frame k: speed, clearance and status."""
    clear = track.clearance_m[k]
    clear_txt = f"{clear:5.1f} m" if math.isfinite(clear) else "  n/a"
    status = (f"{track.flight.outcome_words} at {track.flight.end_t_s:.1f} s" if track.ended[k] else "flying")
    return f"speed {track.speed_m_s[k]:5.1f} m/s   clearance {clear_txt}\n{status}"


class _Scene:
    """The figure and its moving artists; `draw(k)` renders frame k and returns its RGBA pixels."""

    def __init__(self, group: FlightGroup, times: np.ndarray, opts: AnimationConfig) -> None:
        self.times, self.opts = times, opts
        self.tracks = [_track(p, times) for p in group.flights]
        self.key_colors = [p.color for p in group.flights] + [START_STYLE["color"], GOAL_STYLE["color"],
                                                              "white", "black"]  # kept in a GIF's palette
        self.speedup = group.duration_s * opts.fps / max(len(times) - 1, 1)
        dpi = min(opts.width_px / _MIN_FIG_IN[0], opts.height_px / _MIN_FIG_IN[1])
        fig = Figure(figsize=(_figure_inches(opts.width_px, dpi), _figure_inches(opts.height_px, dpi)), dpi=dpi)
        self.w_in, self.h_in = fig.get_size_inches()
        self.figure, self.canvas = fig, FigureCanvasAgg(fig)
        if self.canvas.get_width_height() != (opts.width_px, opts.height_px):
            raise RuntimeError(f"figure is {self.canvas.get_width_height()} px, not "
                               f"{opts.width_px}x{opts.height_px}")  # _figure_inches failed: a bug
        region, lo, hi = group.region()
        self._title(group)
        self.ax3: Axes3D = fig.add_axes(self._box(0.0, _HEAD_IN, self.w_in - _SIDE_IN - 0.6, self.h_in - _HEAD_IN),
                                projection="3d")
        self.ax2 = fig.add_axes(self._box(self.w_in - _SIDE_IN, _HEAD_IN, _SIDE_IN - 0.27, 3.02))
        self._static(group, region, lo, hi)
        self.moving: list = []
        self._moving_artists()
        for a in self.moving:
            a.set_animated(True)  # left out of the full draw; drawn per frame over the saved background
        # with an orbit only the 3D panel changes: save the rest, redraw that panel alone each frame
        self.ax3.set_visible(not opts.orbit_deg)
        with missing_glyphs_unsaid():  # a name from a file in a script the font lacks: a box on the frame
            self.canvas.draw()
        self._background = self.canvas.copy_from_bbox(fig.bbox)
        self.ax3.set_visible(True)

    def _box(self, left_in: float, top_in: float, width_in: float,
             height_in: float) -> tuple[float, float, float, float]:
        """Figure fractions (left, bottom, width, height) of a box given in inches from the top-left corner."""
        w, h = self.w_in, self.h_in
        return (left_in / w, 1.0 - (top_in + height_in) / h, width_in / w, height_in / h)

    def _side_text(self, top_in: float, text: str, **kw) -> Text:
        """A text in the side column, its top `top_in` below the figure's top [in]."""
        left, bottom, _, _ = self._box(self.w_in - _SIDE_IN, top_in, 0.0, 0.0)
        return self.figure.text(left, bottom, text, va="top", **kw)

    def _title(self, group: FlightGroup) -> None:
        meta = group.meta
        left, top, _, _ = self._box(0.13, 0.11, 0.0, 0.0)
        self.figure.text(left, top, f"{group.scenario}  ·  episode {group.episode}  ·  seed {group.seed}  ·  "
                         f"{meta.vehicle}  ·  {_wind_words(group.wind)}", fontsize=12, fontweight="bold",
                         va="top")
        if group.description:
            self.figure.text(left, self._box(0.0, 0.40, 0.0, 0.0)[1], group.description, fontsize=10, va="top",
                             color="0.25")

    def _static(self, group: FlightGroup, region: BuildingMap, lo: np.ndarray, hi: np.ndarray) -> None:
        ax3, ax2, meta = self.ax3, self.ax2, group.meta
        ax3.computed_zorder = False  # paths drawn after the buildings stay visible in front of them
        draw_map_3d(ax3, region)
        spans = [abs(b - a) for a, b in (ax3.get_xlim(), ax3.get_ylim(), ax3.get_zlim())]
        ax3.set_box_aspect(spans, zoom=0.94)  # true scale; room for the tick labels beside the box
        ax3.tick_params(labelsize=7, pad=0)
        for axis in (ax3.xaxis, ax3.yaxis, ax3.zaxis):
            axis.label.set_size(8)
        draw_map_topdown(ax2, region, show_bounds=False)
        ax2.set_xlim(lo[0], hi[0])
        ax2.set_ylim(lo[1], hi[1])
        ax2.tick_params(labelsize=7)
        ax2.xaxis.label.set_fontsize(8)
        ax2.yaxis.label.set_fontsize(8)
        ax2.add_patch(Circle(meta.goal_m[:2], meta.goal_radius_m, fill=False, ec="k", lw=0.8, ls=":"))
        s, g = np.asarray(meta.start_m, float), np.asarray(meta.goal_m, float)
        ax3.plot(*s, **START_STYLE)
        ax3.plot(*g, **GOAL_STYLE)
        ax2.plot(*s[:2], **{**START_STYLE, "markersize": 7})
        ax2.plot(*g[:2], **{**GOAL_STYLE, "markersize": 10})
        handles = [Line2D([], [], **START_STYLE, label="start"), Line2D([], [], **GOAL_STYLE, label="goal"),
                   Line2D([], [], marker="o", color="0.5", **_MARKER, label="flying"),
                   Line2D([], [], marker="o", color="0.5", **{**_MARKER, "markerfacecolor": "white"},
                          label="arrived"),
                   Line2D([], [], marker="X", color="0.5", **_MARKER, label="ended otherwise")]
        # in the side column, not on the 3D panel: a legend costs ~14 ms to draw, too much to redraw when orbiting
        self.figure.legend(handles=handles, loc="lower left", ncol=3, fontsize=8, frameon=False,
                           bbox_to_anchor=self._box(self.w_in - _SIDE_IN - 0.05, self.h_in - 0.04, 0, 0)[:2])

    def _moving_artists(self) -> None:
        ax3, ax2 = self.ax3, self.ax2
        self.clock = self._side_text(4.32, "", fontsize=13, fontweight="bold", family="monospace")
        step_in = min(0.76, 1.87 / max(len(self.tracks), 1))
        self.trail3: list[Line3D] = []
        self.drop3: list[Line3D] = []
        self.mark3: list[Line3D] = []
        self.trail2: list[Line2D] = []
        self.mark2: list[Line2D] = []
        self.readouts: list[Text] = []
        for i, tr in enumerate(self.tracks):
            c, top_in = tr.flight.color, 4.75 + i * step_in
            self._side_text(top_in, tr.flight.label, fontsize=11, fontweight="bold", color=c)
            self.readouts.append(self._side_text(top_in + 0.24, "", fontsize=9.5, family="monospace", color=c,
                                                 linespacing=1.3))
            self.trail3 += ax3.plot([], [], [], color=c, lw=2.0)
            self.drop3 += ax3.plot([], [], [], color=c, lw=0.8, ls=":")  # height cue: a line to the ground
            self.mark3 += ax3.plot([], [], [], marker="o", color=c, **_MARKER)
            self.trail2 += ax2.plot([], [], color=c, lw=1.6)
            self.mark2 += ax2.plot([], [], marker="o", color=c, **{**_MARKER, "markersize": 7})
        self.moving = [*self.drop3, *self.trail3, *self.mark3, *self.trail2, *self.mark2, self.clock,
                       *self.readouts]

    def draw(self, k: int) -> memoryview:
        """Render frame k; returns the canvas's (height, width, 4) RGBA buffer (valid until the next draw)."""
        self.canvas.restore_region(self._background)
        if self.opts.orbit_deg:  # the view moves: the 3D panel is redrawn (without the moving artists)
            frac = k / max(len(self.times) - 1, 1)
            self.ax3.view_init(elev=_ELEV_DEG, azim=_AZIM_DEG + self.opts.orbit_deg * frac)
            self.figure.draw_artist(self.ax3)
        self._update(k)
        with missing_glyphs_unsaid():
            for a in self.moving:
                self.figure.draw_artist(a)
        return self.canvas.buffer_rgba()

    def _update(self, k: int) -> None:
        self.clock.set_text(f"t = {self.times[k]:5.1f} s   {_rate_words(self.speedup)}")
        for i, tr in enumerate(self.tracks):
            p = tr.pos_m[k]
            trail = np.vstack([tr.path_m[:tr.path_count[k]], p])
            self.trail3[i].set_data_3d(trail[:, 0], trail[:, 1], trail[:, 2])
            self.trail2[i].set_data(trail[:, 0], trail[:, 1])
            self.drop3[i].set_data_3d([p[0], p[0]], [p[1], p[1]], [0.0, p[2]])
            self.mark3[i].set_data_3d([p[0]], [p[1]], [p[2]])
            self.mark2[i].set_data([p[0]], [p[1]])
            for mark in (self.mark3[i], self.mark2[i]):
                _set_marker_state(mark, tr, k)
            self.readouts[i].set_text(_status_words(tr, k))


def _set_marker_state(mark: Line2D, track: _Track, k: int) -> None:
    """Filled circle while flying; hollow once arrived; a cross once ended any other way."""
    color = track.flight.color
    if not track.ended[k]:
        mark.set_marker("o")
        mark.set_markerfacecolor(color)
        mark.set_markeredgecolor("k")
    elif track.flight.episode.meta.outcome == Outcome.SUCCESS:
        mark.set_marker("o")
        mark.set_markerfacecolor("white")
        mark.set_markeredgecolor(color)
    else:
        mark.set_marker("X")
        mark.set_markerfacecolor(color)
        mark.set_markeredgecolor("k")


# ---- writers ---------------------------------------------------------------------------------------------
class _PipeWriter(FFMpegWriter):
    """FFMpegWriter fed with pixels already rendered (its grab_frame would redraw the whole figure)."""

    @property
    def _ffmpeg(self) -> subprocess.Popen:
        """The ffmpeg process (`MovieWriter.setup` starts it; matplotlib's stubs omit the attribute)."""
        return self._proc  # type: ignore[attr-defined]

    def write_rgba(self, rgba: memoryview) -> None:
        stdin = self._ffmpeg.stdin
        assert stdin is not None  # the writer opens ffmpeg with stdin=PIPE
        stdin.write(rgba)

    def abort(self) -> None:
        """Stop ffmpeg without waiting for it to finish the file (the caller discards it)."""
        self._ffmpeg.kill()
        self._ffmpeg.communicate()


def _write_mp4(frames: Iterator[memoryview], path: Path, fig: Figure, fps: float, bar: tqdm,
               title: str) -> None:
    """H.264 (yuv420p, CRF 23, moov atom first so browsers start playing at once) through ffmpeg."""
    # matplotlib's stub says int; the writer passes the rate to ffmpeg as given, fractions included
    writer = _PipeWriter(fps=fps, codec="libx264", metadata={"title": title},  # type: ignore[arg-type]
                         extra_args=["-pix_fmt", "yuv420p", "-crf", "23", "-preset", "medium",
                                     "-movflags", "+faststart"])
    writer.setup(fig, str(path), dpi=fig.dpi)
    try:
        for rgba in frames:
            writer.write_rgba(rgba)
            bar.update()
    except BrokenPipeError:  # ffmpeg quit early: finish() raises CalledProcessError with its error output
        writer.finish()
        raise
    except BaseException:
        writer.abort()
        raise
    writer.finish()  # raises CalledProcessError (with ffmpeg's stderr) if ffmpeg failed


def _write_gif(frames: Iterator[memoryview], path: Path, size: tuple[int, int], fps: float,
               key_colors: list[str], bar: tqdm) -> None:
    """A looping GIF written frame by frame with one palette, so memory stays at a frame or two.

    Pillow's `save(save_all=True)` would keep every (paletted) frame until the end and merge identical
    frames; Pillow's documented frame-level writers (`getheader`, `getdata`) write each frame as it
    comes, cropped to the part that changed. One palette (`_gif_palette`) serves every frame, used without
    dithering so still parts do not shimmer.
    """
    delay_ms = 10 * max(1, round(100.0 / fps))  # GIF delays are whole hundredths of a second
    frames = iter(frames)
    first = _rgb(next(frames), size)
    palette = _gif_palette(first, key_colors)
    frame = first.quantize(palette=palette, dither=Image.Dither.NONE)
    box, prev = (0, 0, *size), np.asarray(frame)
    with open(path, "wb") as fp:
        _write_all(fp, GifImagePlugin.getheader(frame, info={"loop": 0, "duration": delay_ms})[0])
        while True:
            _write_all(fp, GifImagePlugin.getdata(frame.crop(box), offset=box[:2], duration=delay_ms,
                                                  disposal=1))
            bar.update()
            rgba = next(frames, None)
            if rgba is None:
                break
            frame = _rgb(rgba, size).quantize(palette=palette, dither=Image.Dither.NONE)
            idx = np.asarray(frame)
            box, prev = _changed_box(prev, idx), idx
        fp.write(b";")  # GIF trailer


def _rgb(rgba: memoryview, size: tuple[int, int]) -> Image.Image:
    """An RGB copy of a canvas buffer (the buffer itself changes with the next frame)."""
    # Pillow reads any buffer; its stub lists bytes and array-interface objects only
    return Image.frombuffer("RGBA", size, rgba, "raw", "RGBA", 0, 1).convert("RGB")  # type: ignore[arg-type]


def _write_all(fp: IO[bytes], chunks: list[bytes]) -> None:
    for chunk in chunks:
        fp.write(chunk)


def _gif_palette(first: Image.Image, key_colors: list[str]) -> Image.Image:
    """A palette image: the key colours, then the first frame's median-cut colours (256 in all)."""
    keys = np.array(list(dict.fromkeys(tuple(round(255 * v) for v in to_rgb(c)) for c in key_colors)), int)
    # median cut averages each box of colours: the pilots' colours could come out a shade off, or merged
    adaptive = first.quantize(colors=256 - len(keys), method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    rest = np.array(adaptive.getpalette() or [], int).reshape(-1, 3)
    # Pillow maps a pixel to the entry nearest the low corner of its 4-level cache cell, so a colour close to
    # a key colour would take its pixels (white as 252 grey): colours within 12 levels of one are left out
    near = np.abs(rest[:, None, :] - keys[None, :, :]).max(axis=2).min(axis=1) <= 12
    out = Image.new("P", (1, 1))
    out.putpalette(np.concatenate([keys, rest[~near]])[:256].astype(np.uint8).ravel().tolist())
    return out


def _changed_box(prev: np.ndarray, cur: np.ndarray) -> tuple[int, int, int, int]:
    """Bounding box (left, top, right, bottom) of the pixels that differ; a 1 px box when none do."""
    diff = prev != cur
    rows, cols = np.flatnonzero(diff.any(axis=1)), np.flatnonzero(diff.any(axis=0))
    if len(rows) == 0:  # still write a frame: the frame count must match the clock
        return (0, 0, 1, 1)
    return (int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1)



@plain_text
def render_videos(groups: list[FlightGroup], out_dir: Path, which: str = "scenario",
                  opts: AnimationConfig = AnimationConfig(), progress: bool = True,
                  fmt: str = "mp4", *, root: Path | None = None) -> list[AnimationResult]:
    """Render several cells of a run to `out_dir/<cell stem>.<fmt>`.

    Args:
        groups: the run's cells (`compare.playback.flights.flight_groups`), in run order.
        out_dir: folder of the videos (created if missing).
        which: "scenario" (the first cell of each scenario), "all" or "none".
        opts: frame rate, length, size and camera orbit of every video.
        progress: show a progress bar per video.
        fmt: "mp4" (GIF when ffmpeg is missing) or "gif".
        root: the run folder `out_dir` lies in (None: a folder the user named): no link in it is followed, and
            it is checked before anything is rendered.

    Raises:
        ValueError: unknown `which` or `fmt`, invalid options, or a link below `root` on the way to `out_dir`,
            before anything is rendered.
    """
    if which not in VIDEO_CHOICES:
        raise ValueError(f"--videos {which!r}: choose from {', '.join(VIDEO_CHOICES)}")
    if fmt not in FORMATS:
        raise ValueError(f"--format {fmt!r}: choose from {', '.join(FORMATS)}")
    opts.validate()
    if root is not None:
        inside_no_links(root, out_dir)
    if which == "none":
        return []
    chosen, seen = [], set()
    for g in groups:
        if which == "all" or g.scenario not in seen:
            chosen.append(g)
            seen.add(g.scenario)
    return [render_animation(g, Path(out_dir) / f"{g.stem}.{fmt}", opts, progress, root=root) for g in chosen]
