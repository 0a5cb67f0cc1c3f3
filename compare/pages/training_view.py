"""Watching a policy learn: one self-contained HTML page of a policy folder's training (`view-training`).

The page holds plotly.js (from the installed package), its own script and style
(`compare/pages/viewer_assets/training.*`) and the data as JSON (through `compare.pages.embed`): the reward
curve (training return, validation success, the kept checkpoint marked), the recorded checkpoints
(`rl.policies.flights`: the flights of fixed validation tasks at step 0 and at every evaluation) and, per
fixed task, its city as a plotly mesh. A scrubber (or hovering the curve) selects a checkpoint; its flights
are listed by task, coloured by outcome, and the chosen task is drawn in 3D beside the same task flown by a
second checkpoint, both playable in time. It opens from disk with no network.

Flights are put in the page at `TrainingViewConfig.page_hz` (10 Hz: the pilot's decision rate), not at
the recorded control rate, to keep the page small, and with at most `TrainingViewConfig.max_points_per_flight`
samples each (2,000: 200 s at 10 Hz, longer than any recorded task's timeout; a longer flight is drawn thinned
further, its last sample kept). Checkpoints are read one at a time, each refused unread past
`rl.policies.flights.MAX_CHECKPOINT_BYTES`, so memory follows what the page draws, not what a file claims.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import plotly
import plotly.graph_objects as go
import plotly.io as pio

from compare.pages.embed import code_for_script, json_for_script, text_for_html
from compare.pages.viewer import GOAL_COLOR, START_COLOR, building_mesh, city_scene, rounded
from compare.report.report import read_reward_curve
from rl.policies.flights import CityBoxes, TrainingFlights
from rl.policies.folder import PolicyFolder
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.files.atomic import write_text_atomic

OUTCOME_COLORS = {"success": "#2ca02c", "collision": "#d62728", "timeout": "#ff7f0e",
                  "out_of_bounds": "#9467bd", "nonfinite": "#7f7f7f"}
OUTCOME_WORDS = {"success": "arrived", "collision": "collided", "timeout": "timed out",
                 "out_of_bounds": "left the bounds", "nonfinite": "diverged"}


@dataclass(frozen=True)
class TrainingViewConfig:
    """What the page holds: flights resampled to `page_hz` [Hz], at most `max_points_per_flight` samples each
    (thinned further past it), positions rounded to `round_m` [m]."""

    page_hz: float = 10.0
    round_m: float = 0.01
    max_points_per_flight: int = 2_000


def city_map(city: CityBoxes) -> BuildingMap:
    """A recorded city (boxes) as a `BuildingMap`, to draw it like any other."""
    buildings = [Building(i, (b[0], b[1]), (b[2], b[3]), b[4], b[5]) for i, b in enumerate(city.boxes)]
    return BuildingMap(buildings, city.bounds_min_m, city.bounds_max_m, name=city.name)


def default_out(policy_dir: Path) -> Path:
    """The page's default file: `<policy folder name>-training.html` in the current folder (a shipped policy's
    folder is part of the installed package, not a place to write)."""
    return Path(f"{Path(policy_dir).resolve().name}-training.html")


def _task_scene(flights: TrainingFlights, k: int) -> dict:
    """Task k's figure (plotly JSON): trace 0 its city, 1 start, 2 goal; the script adds the flight's traces."""
    task = flights.tasks.tasks[k]
    city = flights.tasks.cities[task.city]
    fig = go.Figure()
    fig.add_trace(building_mesh(city_map(city)))
    for name, xyz, color, symbol in (("start", task.start_m, START_COLOR, "diamond"),
                                     ("goal", task.goal_m, GOAL_COLOR, "circle")):
        fig.add_trace(go.Scatter3d(
            x=[xyz[0]], y=[xyz[1]], z=[xyz[2]], mode="markers", name=name, showlegend=False,
            marker={"size": 6, "color": color, "symbol": symbol, "line": {"color": "black", "width": 1}},
            hovertemplate=f"{name}<br>(%{{x:.1f}}, %{{y:.1f}}, %{{z:.1f}}) m<extra></extra>"))
    lo, hi = np.array(city.bounds_min_m), np.array(city.bounds_max_m)
    top = max([float(hi[2])] + [float(b[4]) for b in city.boxes])
    fig.update_layout(margin={"l": 0, "r": 0, "t": 0, "b": 0}, paper_bgcolor="white", showlegend=False,
                      uirevision=f"task{k}", scene=city_scene(lo, hi, top))
    return json.loads(pio.to_json(fig, validate=True, remove_uids=True))


def _curve(folder: PolicyFolder) -> dict:
    """The reward curve's columns for the page (None where a row has no value), and the kept checkpoint."""
    try:
        curve = read_reward_curve(folder.reward_curve)
    except (OSError, ValueError):
        curve = None  # drawn without: the flights are what the page is for
    try:
        prov = folder.provenance()
    except ValueError:
        prov = None
    out: dict = {"timesteps": [], "train_return": [], "val_success": [],
                 "kept": prov.kept_timesteps if prov is not None else None}
    if curve is not None:
        out["timesteps"] = [int(v) for v in curve.timesteps]
        out["train_return"] = rounded(curve.mean_episode_reward, 0.001)
        out["val_success"] = rounded(curve.success_rate, 0.0001)
    return out


def training_payload(policy_dir: Path, opts: TrainingViewConfig = TrainingViewConfig()) -> dict:
    """Everything the page shows, as JSON-ready data (see the module docstring).

    Raises:
        ValueError: the folder has no recorded flights (naming it and how to get them), or a file is malformed.
    """
    folder = PolicyFolder(Path(policy_dir))
    flights = TrainingFlights.open(folder.path)
    tasks = flights.tasks
    stride = max(1, int(round(tasks.control_hz / opts.page_hz)))
    dt = stride / tasks.control_hz
    checkpoints = []
    for step in flights.steps:
        ckpt = flights.checkpoint(step)
        rows = []
        for f in ckpt.flights:
            every = max(stride, -(-len(f.pos_m) // opts.max_points_per_flight))  # the cap on samples drawn
            keep = np.unique(np.r_[np.arange(0, len(f.pos_m), every), len(f.pos_m) - 1])
            p, v = f.pos_m[keep].astype(float), f.vel_m_s[keep].astype(float)
            rows.append({"task": f.task, "outcome": f.outcome, "words": OUTCOME_WORDS.get(f.outcome, f.outcome),
                         "color": OUTCOME_COLORS.get(f.outcome, "#333333"), "time_s": round(f.time_s, 3),
                         "min_clearance_m": round(f.min_clearance_m, 3),
                         "x": rounded(p[:, 0], opts.round_m), "y": rounded(p[:, 1], opts.round_m),
                         "z": rounded(p[:, 2], opts.round_m),
                         "speed": rounded(np.linalg.norm(v, axis=1), 0.01),
                         "clearance": rounded(f.clearance_m[keep], 0.01)})
        n_ok = sum(f.outcome == "success" for f in ckpt.flights)
        checkpoints.append({"timesteps": step, "flights": rows, "successes": n_ok})
    task_rows = [{"leg": t.leg, "turbulence": t.turbulence, "city": tasks.cities[t.city].name,
                  "distance_m": round(math.dist(t.start_m, t.goal_m), 1), "timeout_s": t.timeout_s,
                  "wind_m_s": rounded(t.wind_m_s, 0.01),
                  "elevation_m": t.elevation_m if math.isfinite(t.elevation_m) else None,
                  "isa_offset_k": t.isa_offset_k if math.isfinite(t.isa_offset_k) else None,
                  "figure": _task_scene(flights, k)} for k, t in enumerate(tasks.tasks)]
    return {"policy": {"folder": folder.path.name, "vehicle": tasks.vehicle, "rule": tasks.rule, "seed": tasks.seed},
            "dt_s": dt, "curve": _curve(folder), "tasks": task_rows, "checkpoints": checkpoints,
            "outcome_colors": OUTCOME_COLORS}


def training_html(policy_dir: Path, opts: TrainingViewConfig = TrainingViewConfig()) -> str:
    """The page of a policy folder's training, as one HTML string (plotly.js, script, style and data inline)."""
    payload = training_payload(policy_dir, opts)
    assets = resources.files("compare.pages") / "viewer_assets"
    page = (assets / "training.html").read_text(encoding="utf-8")
    parts = {
        "TITLE": text_for_html(f"uam-compare: watching {payload['policy']['folder']} learn"),
        "STYLE": (assets / "training.css").read_text(encoding="utf-8"),
        "PLOTLY_JS": code_for_script(plotly.offline.get_plotlyjs()),
        "PLOTLY_VERSION": text_for_html(plotly.__version__),
        "DATA_JSON": json_for_script(payload),  # every text from the policy folder goes in here
        "PLAYER_JS": code_for_script((assets / "player.js").read_text(encoding="utf-8")),
        "TRAINING_JS": code_for_script((assets / "training.js").read_text(encoding="utf-8")),
    }
    for key, text in parts.items():  # one pass per placeholder; inserted texts are never rescanned
        head, sep, tail = page.partition("{{" + key + "}}")
        if not sep:
            raise RuntimeError(f"training page template lacks {{{{{key}}}}}")
        page = head + text + tail
    return page


def build_training_view(policy_dir: Path, out: Path, opts: TrainingViewConfig = TrainingViewConfig()) -> Path:
    """Write the page of `policy_dir`'s training to `out` atomically; returns `out`.

    Raises:
        ValueError: as `training_payload`.
    """
    return write_text_atomic(Path(out), training_html(policy_dir, opts))
