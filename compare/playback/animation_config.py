"""How a clip is rendered (`AnimationConfig`), apart from the renderer: reading it (the command line's help and
checks) needs no matplotlib."""
from __future__ import annotations

import math
from dataclasses import dataclass

MIN_SIZE_PX, MAX_SIZE_PX = 160, 3840
MAX_FPS = 120.0
MAX_DURATION_S = 600.0  # video length: 12,000 frames at 20 fps already take minutes to render


@dataclass(frozen=True)
class AnimationConfig:
    """How to render a clip.

    Attributes:
        fps: frames per second of the video [1/s].
        duration_s: video length [s], at most MAX_DURATION_S; None: the flight's own length (real
            time), capped at `max_auto_duration_s` (longer flights play faster).
        max_auto_duration_s: cap of the automatic video length [s].
        width_px, height_px: frame size [px]; even (H.264 with yuv420p needs even sizes).
        orbit_deg: camera azimuth swept over the clip [deg] (0: fixed camera, much faster to render).
    """

    fps: float = 20.0
    duration_s: float | None = None
    max_auto_duration_s: float = 30.0
    width_px: int = 1280
    height_px: int = 720
    orbit_deg: float = 0.0

    def validate(self) -> None:
        """Raise ValueError naming the option as the command line spells it (`--fps`, `--size`, ...)."""
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"--fps {self.fps:g}: must be > 0")
        if self.fps > MAX_FPS:
            raise ValueError(f"--fps {self.fps:g}: must be at most {MAX_FPS:g}")
        if self.duration_s is not None and not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ValueError(f"--duration {self.duration_s:g}: must be > 0 seconds")
        if self.duration_s is not None and self.duration_s > MAX_DURATION_S:
            raise ValueError(f"--duration {self.duration_s:g}: must be at most {MAX_DURATION_S:g} seconds")
        if not (math.isfinite(self.max_auto_duration_s) and 0 < self.max_auto_duration_s <= MAX_DURATION_S):
            raise ValueError(f"max_auto_duration_s {self.max_auto_duration_s:g}: must be in (0, {MAX_DURATION_S:g}] "
                             f"seconds")
        size = f"--size {self.width_px}x{self.height_px}"
        if not all(MIN_SIZE_PX <= s <= MAX_SIZE_PX for s in (self.width_px, self.height_px)):
            raise ValueError(f"{size}: width and height must be between {MIN_SIZE_PX} and {MAX_SIZE_PX} px")
        if self.width_px % 2 or self.height_px % 2:
            raise ValueError(f"{size}: width and height must be even (H.264 video)")
        if not math.isfinite(self.orbit_deg):
            raise ValueError(f"--orbit {self.orbit_deg:g}: must be a finite angle in degrees")
