"""What recording the checkpoints' flights costs training: wall time with and without it.

The same small training run twice, in this process (one torch thread): once recording `--tasks` fixed
validation tasks at step 0 and at every evaluation (`rl.training.recording`), once not. The recorder's own
time (building its world, flying, writing) is also timed directly, per checkpoint, by wrapping it.

The scale is SMALL so that the whole benchmark takes about a minute: 64 vehicles, 65,536 timesteps, an
evaluation every 32,768 (so 3 recordings: 0, 32,768, 65,536) on 50 validation episodes, a pool of 16 cities.
Between two evaluations a real run (the shipped policies: 256 vehicles, an evaluation every 1,000,000
timesteps of 10,000,000 at ~8,100 timesteps/s, 1,235 s in all) trains for ~120 s; here for ~10 s, so
`recording_overhead_pct` of this run overstates the real one. `projected_overhead_pct` is the recorder's
measured time per checkpoint times the real run's 12 recordings (0, ten evaluations, the final one), over
the shipped small-quad policy's training wall time (its provenance.json).

Prints a table, then (last line) one JSON object of the figures.

    python perf/training_recording.py [--tasks 8] [--timesteps 65536]
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import rl.training.loop as loop
from rl.policies.folder import DEFAULT_POLICY_DIR, PolicyFolder
from rl.task.config import NavConfig
from rl.training.config import TrainConfig
from rl.training.recording import FlightRecorder

SHIPPED_RECORDINGS = 12  # step 0, ten evaluations (every 1 M of 10 M timesteps), the final evaluation


def timed_recorder(spent: list[float]) -> type[FlightRecorder]:
    """A FlightRecorder that adds its construction's and each recording's wall time to `spent`."""

    class Timed(FlightRecorder):
        def __init__(self, *args, **kwargs) -> None:
            t0 = time.perf_counter()
            super().__init__(*args, **kwargs)
            spent.append(time.perf_counter() - t0)

        def record(self, *args, **kwargs):
            t0 = time.perf_counter()
            out = super().record(*args, **kwargs)
            spent.append(time.perf_counter() - t0)
            return out

    return Timed


def run(cfg: TrainConfig, out: Path) -> tuple[float, list[float]]:
    """Train `cfg` into `out`: (wall time [s], the recorder's times [s]: construction, then each checkpoint)."""
    spent: list[float] = []
    original = loop.FlightRecorder
    loop.FlightRecorder = timed_recorder(spent)  # type: ignore[misc]
    try:
        t0 = time.perf_counter()
        loop.train(cfg, out, progress=False, command="benchmark", log=lambda *_: None)
        return time.perf_counter() - t0, spent
    finally:
        loop.FlightRecorder = original  # type: ignore[misc]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tasks", type=int, default=8, help="fixed tasks recorded per checkpoint")
    ap.add_argument("--timesteps", type=int, default=65_536)
    args = ap.parse_args()
    nav = NavConfig(city_pool_size=16, wind_pool_size=2)
    base = TrainConfig(total_timesteps=args.timesteps, n_envs=64, nav=nav, eval_every=args.timesteps // 2,
                       eval_episodes=50, checkpoint_every=0, seed=0)
    with tempfile.TemporaryDirectory() as tmp:
        # without first: the compiled model's cache is then warm for both
        wall_off, _ = run(TrainConfig(**{**vars(base), "record_flights": 0}), Path(tmp) / "off")
        wall_on, spent = run(TrainConfig(**{**vars(base), "record_flights": args.tasks}), Path(tmp) / "on")
        size = sum(p.stat().st_size for p in (Path(tmp) / "on" / "training_flights").iterdir())
    build_s, per_ckpt = spent[0], spent[1:]
    per_s = sum(per_ckpt) / len(per_ckpt)
    shipped = PolicyFolder(DEFAULT_POLICY_DIR).provenance()
    shipped_wall = shipped.wall_time_s if shipped and shipped.wall_time_s else None
    figures = {
        "scale": f"small: 64 vehicles, {args.timesteps} timesteps, evaluation every {args.timesteps // 2}",
        "tasks": args.tasks, "train_wall_s": round(wall_off, 2), "train_wall_recording_s": round(wall_on, 2),
        "recording_overhead_pct": round(100.0 * (wall_on - wall_off) / wall_off, 2),
        "recorder_total_s": round(sum(spent), 3), "recorder_build_s": round(build_s, 3),
        "recording_per_checkpoint_s": round(per_s, 3), "checkpoints": len(per_ckpt),
        "recorder_share_pct": round(100.0 * sum(spent) / wall_on, 2),
        "bytes_per_checkpoint": int(size / len(per_ckpt)),
        "projected_overhead_pct": (round(100.0 * (build_s + SHIPPED_RECORDINGS * per_s) / shipped_wall, 2)
                                   if shipped_wall else None),
    }
    print(f"{'figure':30s} value")
    for k, v in figures.items():
        print(f"{k:30s} {v}")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
