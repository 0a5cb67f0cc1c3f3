"""Single-lever ablations of the learned pilot's environment, on validation cities only.

Each variant changes one lever of the shipped training set-up (`rl.training.config.TrainConfig` defaults)
and trains plain PPO from scratch with the same seed and the same number of decisions; the kept
checkpoint (chosen on validation, as `uam-compare train` chooses) is then flown on
`--episodes` validation tasks (never the test pool). Results are written to OUT/<variant>/result.json
and reused on the next call, so variants can be trained by separate invocations (e.g. two at a
time on two cores) and tabulated by a last call over all of them.

Variants:

=====================  ==========================================================================
base                   the shipped set-up
decision-50hz          decisions at 50 Hz (every control period) instead of 10 Hz; the discount
                       keeps its 10 s horizon (γ 0.998), as the reward keeps its per-second weights
euclidean-progress     progress along the straight-line distance to the goal instead of the geodesic
                       one around buildings (route field with buildings costing nothing extra: the
                       route's distance and direction in the observation become straight-line too)
no-height-map          the 9 x 9 height map reduced to its centre cell (the roof height right below)
no-curriculum          full-length legs from the start
no-speed-proximity     the proximity cost per second without its speed factor (the r3 design)
=====================  ==========================================================================

Equal decisions is not equal flight time: at 50 Hz a decision covers a fifth of the flight.

Prints a table, then (last line) one JSON object {variant: figures}.

    python perf/learned_pilot_ablations.py --out runs/ablations [--variants base,no-curriculum]
        [--timesteps 3000000] [--episodes 1000] [--seed 0]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from compare.report.report import read_reward_curve
from rl.pilots.learned import load_policy
from rl.policies.folder import PolicyFolder
from rl.training.config import Curriculum, TrainConfig
from rl.training.evaluation import evaluate
from rl.training.loop import train

FINAL_EVAL_SEED = 20_000  # the final validation flight's slot seeds (training-time selection uses seed + 10,000)


def variant_config(name: str, base: TrainConfig) -> TrainConfig:
    """`base` with the one lever of variant `name` changed (see the module table).

    Raises:
        ValueError: an unknown variant, naming the known ones.
    """
    nav = base.nav
    changes = {
        "base": base,
        "decision-50hz": replace(base, nav=replace(nav, decision_hz=nav.control_hz)),
        "euclidean-progress": replace(base, nav=replace(nav, route=replace(nav.route, blocked_speed=1.0))),
        "no-height-map": replace(base, nav=replace(nav, perception=replace(nav.perception, grid_cells=1))),
        "no-curriculum": replace(base, curriculum=Curriculum(start=1.0)),
        # factor 1 + 1e-10
        "no-speed-proximity": replace(base, nav=replace(nav, reward=replace(nav.reward, proximity_speed_m_s=1e6))),
    }
    if name not in changes:
        raise ValueError(f"unknown variant {name!r}; choose from {', '.join(changes)}")
    return changes[name]


VARIANTS = ("base", "decision-50hz", "euclidean-progress", "no-height-map", "no-curriculum", "no-speed-proximity")


def run_variant(name: str, out: Path, timesteps: int, episodes: int, seed: int) -> dict:
    """Train variant `name` (unless OUT/name/result.json exists) and fly its kept model on validation."""
    folder = out / name
    done = folder / "result.json"
    if done.is_file():
        return json.loads(done.read_text())
    cfg = variant_config(name, TrainConfig(total_timesteps=timesteps, seed=seed, eval_every=1_000_000,
                                           eval_episodes=200))
    train(cfg, folder, progress=False, command=" ".join([sys.executable, *sys.argv]),
          log=lambda msg: print(f"[{name}] {msg}", flush=True))
    policy = load_policy(folder)
    res = evaluate(lambda obs, _b: policy.act_batch(obs), policy.nav, episodes, seed=FINAL_EVAL_SEED,
                   pool="validation")
    curve = read_reward_curve(PolicyFolder(folder).reward_curve)
    hit = np.flatnonzero(curve.success_rate >= 0.90)
    prov = PolicyFolder(folder).provenance()
    fig = {"timesteps": timesteps, "seed": seed, "episodes": res.episodes,
           "success_rate": res.success_rate, "success_ci95": list(res.success_ci95),
           "collision_rate": res.collision_rate,
           "collision_ci95": list(res.collision_ci95), "outcomes": res.outcomes,
           "timesteps_to_90pct": int(curve.timesteps[hit[0]]) if len(hit) else None,
           "kept_timesteps": prov.kept_timesteps, "wall_s": prov.wall_time_s}
    done.write_text(json.dumps(fig, indent=2) + "\n")
    return fig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="folder for the variants' policies and results")
    ap.add_argument("--variants", default=",".join(VARIANTS),
                    help=f"comma-separated (default all: {','.join(VARIANTS)})")
    ap.add_argument("--timesteps", type=int, default=3_000_000, help="decisions per variant (default 3M)")
    ap.add_argument("--episodes", type=int, default=1000, help="validation episodes of the final flight (default 1000)")
    ap.add_argument("--seed", type=int, default=0, help="the one seed (default 0)")
    args = ap.parse_args()
    names = [v.strip() for v in args.variants.split(",") if v.strip()]
    for n in names:
        try:
            variant_config(n, TrainConfig())
        except ValueError as exc:
            ap.error(f"--variants: {exc}")
    if args.timesteps < 1 or args.episodes < 1:
        ap.error("--timesteps and --episodes must be >= 1")
    figs = {n: run_variant(n, args.out, args.timesteps, args.episodes, args.seed) for n in names}
    print(f"{'variant':<20} {'success':>22} {'collisions':>20} {'to 90 %':>10}  outcomes")
    for n, f in figs.items():
        s_lo, s_hi = f["success_ci95"]
        c_lo, c_hi = f["collision_ci95"]
        to90 = f"{f['timesteps_to_90pct'] / 1e6:.1f} M" if f["timesteps_to_90pct"] else "never"
        print(f"{n:<20} {f['success_rate']:6.1%} [{s_lo:5.1%}, {s_hi:5.1%}] {f['collision_rate']:5.1%} "
              f"[{c_lo:4.1%}, {c_hi:4.1%}] {to90:>10}  {f['outcomes']}")
    print(json.dumps(figs))


if __name__ == "__main__":
    main()
