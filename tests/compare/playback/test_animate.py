"""The 3D animation of a comparison cell, from a synthetic run folder: frame clock, options, MP4 and GIF output
(frame count, size and pixels), the GIF fallback without ffmpeg, atomic writes and determinism."""
from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from matplotlib.colors import to_rgb
from PIL import Image

from compare.playback import animate
from compare.playback.animate import AnimationConfig, ffmpeg_available, frame_times, render_animation
from compare.playback.flights import FlightGroup, flight_groups, select_group
from synthetic_run import write_run

SMALL = {"width_px": 320, "height_px": 240, "fps": 10.0, "duration_s": 0.8}  # 8 frames
PIXELS = {"width_px": 640, "height_px": 360, "fps": 10.0, "duration_s": 1.2}  # 12 frames, large enough for colour
# H.264 keeps colour at half resolution (4:2:0): thin lines and small text need a larger frame to keep theirs
PIXELS_MP4 = {**PIXELS, "width_px": 960, "height_px": 540}
PILOT_RGB = {"tab:orange": "#ff7f0e", "tab:blue": "#1f77b4"}

needs_ffmpeg = pytest.mark.skipif(not (ffmpeg_available() and shutil.which("ffprobe")),
                                  reason="ffmpeg/ffprobe not installed: MP4 output cannot be written or checked")


@pytest.fixture(scope="module")
def groups(tmp_path_factory: pytest.TempPathFactory) -> list[FlightGroup]:
    run_dir = tmp_path_factory.mktemp("animate") / "run"
    write_run(run_dir, None)
    return flight_groups(run_dir)


@pytest.fixture(scope="module")
def collided(groups: list[FlightGroup]) -> FlightGroup:
    """toy-quad episode 1: PPO collides at 12 s, RRT* + MPC arrives at 24 s."""
    return select_group(groups, "toy-quad:1")


def _files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _count_near(rgb: np.ndarray, color: str, tol: int) -> int:
    """Pixels of an (H, W, 3) uint8 image within `tol` of `color` in every channel."""
    target = np.round(np.array(to_rgb(color)) * 255.0)
    return int(np.sum(np.all(np.abs(rgb.astype(int) - target) <= tol, axis=-1)))


def _assert_pilot_colours(rgb: np.ndarray, tol: int) -> None:
    for name, hex_color in PILOT_RGB.items():
        assert _count_near(rgb, hex_color, tol) >= 20, f"too few {name} pixels in the frame"
    assert _count_near(rgb, "#ff00ff", tol) == 0  # control: a colour that is drawn nowhere


# ---- clock and options ----------------------------------------------------------------------------------
def test_frame_times_cover_the_flight_in_real_time_or_capped() -> None:
    t = frame_times(24.0, AnimationConfig(fps=10.0))
    assert len(t) == 240 and t[0] == 0.0 and t[-1] == 24.0
    np.testing.assert_allclose(np.diff(t), 24.0 / 239)
    assert len(frame_times(100.0, AnimationConfig(fps=10.0))) == 300  # capped at max_auto_duration_s
    assert len(frame_times(100.0, AnimationConfig(fps=10.0, max_auto_duration_s=5.0))) == 50
    t = frame_times(100.0, AnimationConfig(fps=20.0, duration_s=2.0))
    assert len(t) == 40 and t[-1] == 100.0
    assert len(frame_times(0.01, AnimationConfig(fps=20.0))) == 2  # never fewer than two frames
    np.testing.assert_array_equal(frame_times(0.0, AnimationConfig()), [0.0, 0.0])
    with pytest.raises(ValueError, match="flight_s"):
        frame_times(math.nan, AnimationConfig())


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"fps": 0.0}, "--fps 0: must be > 0"),
    ({"fps": -5.0}, "--fps -5: must be > 0"),
    ({"fps": math.nan}, "--fps nan"),
    ({"fps": 500.0}, "--fps 500: must be at most"),
    ({"duration_s": 0.0}, "--duration 0: must be > 0"),
    ({"duration_s": math.inf}, "--duration inf"),
    ({"width_px": 1281}, "--size 1281x720: width and height must be even"),
    ({"height_px": 721}, "--size 1280x721: width and height must be even"),
    ({"width_px": 100}, "--size 100x720: width and height must be between 160 and 3840"),
    ({"height_px": 4000}, "--size 1280x4000: width and height must be between"),
    ({"orbit_deg": math.nan}, "--orbit nan"),
    ({"max_auto_duration_s": 0.0}, "max_auto_duration_s 0"),
])
def test_options_validation_names_the_option(kwargs: dict, message: str) -> None:
    opts = AnimationConfig(**kwargs)
    with pytest.raises(ValueError) as err:
        opts.validate()
    assert message in str(err.value)
    with pytest.raises(ValueError):
        frame_times(10.0, opts)


def test_bad_suffix_or_options_write_nothing(collided: FlightGroup, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"clip\.avi.*\.mp4 or \.gif"):
        render_animation(collided, tmp_path / "clip.avi", AnimationConfig(**SMALL), progress=False)
    with pytest.raises(ValueError, match="--fps"):
        render_animation(collided, tmp_path / "clip.gif", AnimationConfig(fps=0.0), progress=False)
    assert _files(tmp_path) == []


# ---- what the frames show -------------------------------------------------------------------------------
def test_readouts_follow_the_clock(collided: FlightGroup) -> None:
    opts = AnimationConfig(**SMALL)
    times = frame_times(collided.duration_s, opts)
    scene = animate._Scene(collided, times, opts)
    ppo, mpc = scene.readouts
    scene.draw(0)
    assert scene.clock.get_text().startswith("t =   0.0 s") and "x34.3" in scene.clock.get_text()
    assert ppo.get_text().endswith("flying") and mpc.get_text().endswith("flying")
    scene.draw(len(times) - 1)
    assert scene.clock.get_text().startswith("t =  24.0 s")
    assert ppo.get_text().endswith("collided at 12.0 s") and mpc.get_text().endswith("arrived at 24.0 s")
    assert "speed   0.0 m/s" in ppo.get_text() and "clearance" in mpc.get_text()
    assert scene.mark3[0].get_marker() == "X" and scene.mark3[1].get_markerfacecolor() == "white"
    real_time = AnimationConfig(**{**SMALL, "duration_s": None, "max_auto_duration_s": 60.0})
    scene = animate._Scene(collided, frame_times(collided.duration_s, real_time), real_time)
    scene.draw(3)
    assert "x1.0 real time" in scene.clock.get_text()


# ---- MP4 ------------------------------------------------------------------------------------------------
def _ffprobe(path: Path) -> dict:
    out = subprocess.run(["ffprobe", "-v", "error", "-count_frames", "-select_streams", "v:0", "-show_entries",
                          "stream=nb_read_frames,width,height,codec_name,pix_fmt", "-of", "json", str(path)],
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out)["streams"][0]


def _decode_mp4(path: Path, size: tuple[int, int]) -> np.ndarray:
    """All frames as (N, H, W, 3) uint8 RGB."""
    raw = subprocess.run(["ffmpeg", "-v", "error", "-i", str(path), "-f", "rawvideo", "-pix_fmt", "rgb24", "-"],
                         capture_output=True, check=True).stdout
    w, h = size
    return np.frombuffer(raw, np.uint8).reshape(-1, h, w, 3)


@needs_ffmpeg
def test_mp4_has_every_frame_at_the_size_with_both_pilots(collided: FlightGroup, tmp_path: Path) -> None:
    out = tmp_path / "clip.mp4"
    res = render_animation(collided, out, AnimationConfig(**PIXELS_MP4), progress=False)
    assert (res.path, res.format, res.frames, res.width_px, res.height_px) == (out, "mp4", 12, 960, 540)
    assert res.flight_s == pytest.approx(24.0) and res.speedup == pytest.approx(24.0 * 10.0 / 11)
    assert res.seconds > 0
    probe = _ffprobe(out)
    assert (probe["codec_name"], probe["pix_fmt"]) == ("h264", "yuv420p")
    assert (int(probe["nb_read_frames"]), probe["width"], probe["height"]) == (12, 960, 540)
    frames = _decode_mp4(out, (960, 540))
    assert len(frames) == 12
    _assert_pilot_colours(frames[-1], tol=40)
    assert _files(tmp_path) == ["clip.mp4"]


# ---- GIF ------------------------------------------------------------------------------------------------
def _gif_frame(path: Path, k: int) -> np.ndarray:
    with Image.open(path) as im:
        im.seek(k)
        return np.asarray(im.convert("RGB"))


def test_gif_frames_size_pixels_and_determinism(collided: FlightGroup, tmp_path: Path) -> None:
    opts = AnimationConfig(**PIXELS)
    a = render_animation(collided, tmp_path / "a.gif", opts, progress=False)
    b = render_animation(collided, tmp_path / "b.gif", opts, progress=False)
    assert (a.format, a.frames, a.path) == ("gif", 12, tmp_path / "a.gif")
    with Image.open(a.path) as im:
        assert (im.n_frames, im.size, im.info["loop"], im.info["duration"]) == (12, (640, 360), 0, 100)
    assert a.path.read_bytes() == b.path.read_bytes()
    _assert_pilot_colours(_gif_frame(a.path, 11), tol=3)  # the pilots' colours are palette entries
    first = _gif_frame(a.path, 0)
    assert not np.array_equal(first, _gif_frame(a.path, 11))  # the clip moves
    assert _files(tmp_path) == ["a.gif", "b.gif"]


def test_gif_with_orbit_moves_the_camera(collided: FlightGroup, tmp_path: Path) -> None:
    still = render_animation(collided, tmp_path / "still.gif", AnimationConfig(**SMALL), progress=False)
    orbit = render_animation(collided, tmp_path / "orbit.gif", AnimationConfig(**SMALL, orbit_deg=90.0),
                             progress=False)
    assert orbit.frames == still.frames == 8
    np.testing.assert_array_equal(_gif_frame(still.path, 0), _gif_frame(orbit.path, 0))  # same start view
    last_still, last_orbit = _gif_frame(still.path, 7), _gif_frame(orbit.path, 7)
    panel = (slice(30, 240), slice(0, 200))  # the 3D panel: the camera turned
    assert not np.array_equal(last_still[panel], last_orbit[panel])
    side = (slice(0, 240), slice(230, 320))  # the side column: same map, readouts and clock
    np.testing.assert_array_equal(last_still[side], last_orbit[side])


def test_mp4_without_ffmpeg_falls_back_to_gif(collided: FlightGroup, tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch,
                                             caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setitem(matplotlib.rcParams, "animation.ffmpeg_path", str(tmp_path / "no-such-ffmpeg"))
    assert not ffmpeg_available()
    with caplog.at_level("WARNING", logger="compare.playback.animate"):
        res = render_animation(collided, tmp_path / "clip.mp4", AnimationConfig(**SMALL), progress=False)
    assert (res.path, res.format, res.frames) == (tmp_path / "clip.gif", "gif", 8)
    assert "clip.gif" in caplog.text and "instead of" in caplog.text
    with Image.open(res.path) as im:
        assert (im.n_frames, im.size) == (8, (320, 240))
    assert _files(tmp_path) == ["clip.gif"]


# ---- failures leave nothing -----------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [
    ".gif", pytest.param(".mp4", marks=needs_ffmpeg)])
def test_error_while_rendering_leaves_no_file(collided: FlightGroup, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch, suffix: str) -> None:
    real = animate._status_words
    calls = []

    def failing(track, k):  # fails on the fourth frame, after frames went to the writer
        calls.append(k)
        if len(calls) > 2 * 3:
            raise RuntimeError("boom")
        return real(track, k)

    monkeypatch.setattr(animate, "_status_words", failing)
    (tmp_path / "out").mkdir()
    with pytest.raises(RuntimeError, match="boom"):
        render_animation(collided, tmp_path / "out" / f"clip{suffix}", AnimationConfig(**SMALL), progress=False)
    assert _files(tmp_path / "out") == []


def test_ffmpeg_failure_raises_and_leaves_no_file(collided: FlightGroup, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    fake = tmp_path / "bin" / "ffmpeg"  # an ffmpeg that quits at once, as a broken install would
    fake.parent.mkdir()
    fake.write_text("#!/bin/sh\necho 'no encoder here' >&2\nexit 3\n")
    fake.chmod(0o755)
    monkeypatch.setitem(matplotlib.rcParams, "animation.ffmpeg_path", str(fake))
    (tmp_path / "out").mkdir()
    with pytest.raises(subprocess.CalledProcessError) as err:
        render_animation(collided, tmp_path / "out" / "clip.mp4", AnimationConfig(**SMALL), progress=False)
    assert "no encoder here" in err.value.stderr
    assert _files(tmp_path / "out") == []


# ---- the command line ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("animate_cli") / "run"
    write_run(out, None)
    return out


def test_animate_command_writes_the_chosen_cell(run_dir: Path, capsys: pytest.CaptureFixture) -> None:
    from compare.cli import main

    args = ["animate", str(run_dir), "--size", "320x240", "--fps", "5", "--duration", "1", "--no-progress"]
    assert main([*args, "--episode", "toy-quad:1", "--format", "gif"]) == 0
    out = run_dir / "videos" / "toy-quad__ep001__s0.gif"
    assert str(out) in capsys.readouterr().out
    with Image.open(out) as im:
        assert (im.n_frames, im.size) == (5, (320, 240))
    assert main([*args, "--all", "--format", "gif", "--out", str(run_dir / "all")]) == 0
    assert _files(run_dir / "all") == ["toy-quad__ep000__s0.gif", "toy-quad__ep001__s0.gif"]


@pytest.mark.parametrize(("extra", "message"), [
    (["--episode", "toy-quad:7"], "no such flight in this run; there are: toy-quad:0:0, toy-quad:1:0"),
    (["--episode", "toy-quad"], "expected SCENARIO:EPISODE[:SEED]"),
    (["--fps", "-1"], "--fps -1: must be > 0"),
    (["--size", "321x240"], "must be even"),
    (["--all", "--episode", "toy-quad:0"], "give one or the other"),
    (["--out", "clip.avi"], "unsupported animation format"),
])
def test_animate_command_rejects_bad_input(run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture,
                                           extra: list[str], message: str) -> None:
    from compare.cli import main

    extra = [str(tmp_path / e) if e.endswith(".avi") else e for e in extra]
    assert main(["animate", str(run_dir), "--no-progress", *extra]) == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
