"""The learned pilot's training in the report: its reward curve read from a policy folder, and the page that draws
it ("PPO training: reward convergence", `compare.report.figures.reward_curve_figure`)."""
from __future__ import annotations

import csv
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from compare.report import figures as F
from compare.results.run_info import PolicyRecord, RunInfo
from rl.policies.folder import PolicyFolder, Provenance


def _float(v: object) -> float:
    try:
        return float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return math.nan


def read_reward_curve(path: Path) -> F.RewardCurve | None:
    """A policy's `reward_curve.csv` as a `RewardCurve`, or None if the file is absent.

    Reads `rl.training.loop`'s format (one row per PPO update: timesteps, mean_episode_reward,
    train_success_rate, train_collision_rate, train_timeout_rate, train_episodes, difficulty,
    success_rate, collision_rate, eval_episodes, wall_s; the validation columns empty on rows without
    an evaluation) and older files with only some of these columns: an absent column or an empty or
    unreadable cell is NaN. Rows without a timestep (e.g. a half-written last line) are left out.

    Raises:
        ValueError: the file exists but lacks `timesteps` or `mean_episode_reward`, or has no rows,
            naming the file.
    """
    path = Path(path)
    if not path.is_file():
        return None
    with path.open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    need = ("timesteps", "mean_episode_reward")
    if not rows or any(k not in rows[0] for k in need):
        raise ValueError(f"{path}: needs columns {', '.join(need)} and at least one row")
    names = (*need, "success_rate", *F.CURVE_FIELDS)
    col = {k: np.array([_float(r.get(k)) for r in rows]) for k in names}
    keep = np.isfinite(col["timesteps"])
    if not np.any(keep):
        raise ValueError(f"{path}: no row has a timestep")
    return F.RewardCurve(**{k: v[keep] for k, v in col.items()})


def ppo_policies(info: RunInfo, pilot: str | None = None) -> list[PolicyRecord]:
    """The policies run.json records (vehicle, policy_dir, decision_hz), one per vehicle, of `pilot`
    (None: of every pilot that flies policies); a run written before policies per vehicle has one,
    without its vehicle."""
    return [pol for m in ([pilot] if pilot is not None else list(info.pilots)) for pol in info.policies(m)]


def training_figure(policy: PolicyRecord | None, name_vehicle: bool, shown: Callable[[Path], str] = str) -> Figure:
    """The reward convergence page of one policy the run flew (`name_vehicle`: its vehicle in the title; `shown`: a
    path as the page shows it); a page saying why when there is no curve."""
    title = "PPO training: reward convergence"
    if name_vehicle and policy is not None and policy.vehicle:
        title += f" ({policy.vehicle})"
    policy_dir = policy.policy_dir if policy is not None else ""
    if not policy_dir:
        return F.reward_curve_figure(title, None,
                                     "No PPO policy folder is recorded in run.json: no reward curve.")
    folder = PolicyFolder(Path(policy_dir))
    path = folder.reward_curve
    try:
        curve = read_reward_curve(path)
    except (OSError, ValueError) as exc:
        return F.reward_curve_figure(title, None, f"The reward curve could not be read: {exc}")
    if curve is None:
        return F.reward_curve_figure(title, None, f"No reward curve: the policy folder the run recorded "
                                                  f"({shown(Path(policy_dir))}) holds no reward_curve.csv here.")
    try:
        prov = folder.provenance()  # None: an older policy folder without provenance, no marker
    except ValueError:
        prov = None  # unreadable: drawn as without
    kept = prov.kept_timesteps if prov is not None else None
    return F.reward_curve_figure(title, curve, _training_note(shown(path), curve, prov),
                                 kept_timesteps=float(kept) if kept is not None else None,
                                 subtitle=_training_subtitle(prov, curve))


def _training_subtitle(prov: Provenance | None, curve: F.RewardCurve) -> str:
    method = (prov.method if prov is not None else None) or ""
    # a run still training has no provenance yet; its per-update columns say rl.training.loop wrote it (plain PPO)
    assert curve.difficulty is not None  # RewardCurve.__post_init__ fills an absent column with NaN
    per_update = prov is None and bool(np.any(np.isfinite(curve.difficulty)))
    if method.lower() == "ppo from scratch" or per_update:
        what = "Plain PPO from scratch (no demonstrations, no pre-trained weights)"
    elif method:
        what = f"Training method: {method}"
    elif prov is not None and prov.preset:
        what = f"Training preset {prov.preset!r} (an older policy folder: method not recorded)"
    else:
        what = "Training method not recorded (an older policy folder)"
    return (f"{what}.\nTraining episodes (training cities, at the curriculum's difficulty) vs. "
            "validation (held-out cities, full difficulty).")


def _training_note(path: str, curve: F.RewardCurve, prov: Provenance | None) -> str:
    parts = [f"from {path}"]
    steps = _float(prov.timesteps if prov is not None else None)
    wall = _float(prov.wall_time_s if prov is not None else None)
    if not math.isfinite(steps):  # no provenance (a run still in progress): its last row
        steps = float(curve.timesteps[-1])
        assert curve.wall_s is not None  # RewardCurve.__post_init__ fills an absent column with NaN
        wall = float(curve.wall_s[-1])
        parts.append("no provenance.json (run in progress?)")
    if math.isfinite(steps):
        parts.append(f"{steps / 1e6:.1f} M timesteps"
                     + (f" in {wall / 60:.0f} min" if math.isfinite(wall) else ""))
    seed = prov.seed if prov is not None else None
    if seed is not None:
        parts.append(f"seed {seed}")
    return " · ".join(parts)
