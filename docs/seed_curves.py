"""Training curves of several seeds in one figure, for the docs: mean and min–max band across seeds.

Reads each policy folder's `reward_curve.csv` (written by `uam-compare train`) and draws
`compare.report.figures.seed_curves_figure`: (a) the training return (centred moving average over 2 % of
each run's updates) and (b) the validation success rate, each seed thin, the mean and the
min–max band on a common timestep grid. Seeds are labelled from each folder's provenance.json
("seed 3"), or by the folder name. The PNG is written atomically.

    python docs/seed_curves.py runs/seed0 runs/seed1 runs/seed2 [--out docs/learned_pilot_seeds.png]
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from compare.report.figures import seed_curves_figure
from compare.report.report import read_reward_curve
from rl.policies.folder import PolicyFolder
from uam_fdm.city.plot import save_figure

DEFAULT_OUT = Path(__file__).resolve().parent / "learned_pilot_seeds.png"


def seed_label(folder: Path) -> str:
    """"seed N" from the folder's provenance.json, else the folder's name."""
    try:
        prov = PolicyFolder(folder).provenance()
    except ValueError:
        prov = None
    seed = prov.seed if prov is not None else None
    return f"seed {seed}" if seed is not None else folder.name


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("policy_dirs", nargs="+", type=Path, metavar="POLICY_DIR",
                    help="policy folders (each with a reward_curve.csv)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"PNG to write (default {DEFAULT_OUT})")
    ap.add_argument("--dpi", type=int, default=130, help="resolution (default 130)")
    ap.add_argument("--title", default=None, help="figure title (default: the figure's own)")
    args = ap.parse_args(argv)
    curves, labels = [], []
    for folder in args.policy_dirs:
        try:
            curve = read_reward_curve(PolicyFolder(folder).reward_curve)
        except (OSError, ValueError) as exc:
            print(f"seed_curves: error: {exc}", file=sys.stderr)
            return 2
        if curve is None:
            print(f"seed_curves: error: {PolicyFolder(folder).reward_curve} does not exist", file=sys.stderr)
            return 2
        label = seed_label(folder)
        if label in labels:  # two folders of the same seed: tell them apart
            label = f"{label} ({folder.name})"
        curves.append(curve)
        labels.append(label)
    kwargs = {"title": args.title} if args.title else {}
    fig = seed_curves_figure(curves, labels, **kwargs)
    print(save_figure(fig, args.out, dpi=args.dpi))
    return 0


if __name__ == "__main__":
    sys.exit(main())
