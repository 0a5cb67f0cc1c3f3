"""Figures for docs/fidelity.md, drawn from the model's own functions: the ground-effect thrust gain
against rotor height, in hover and forward flight, beside the published Cheeseman-Bennett law.

    python docs/fidelity_figures.py [--out docs/ground_effect.png]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from uam_fdm import ground_effect as ge  # noqa: E402
from uam_fdm.city_plot import save_figure  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "ground_effect.png"


def ground_effect_figure() -> plt.Figure:
    """Thrust gain T_IGE/T_OGE against rotor height z/R for V/v_h = 0, 1, 2 (model solid, law dashed)."""
    fig, ax = plt.subplots(figsize=(7.0, 4.2), dpi=120)
    zr = np.linspace(0.3, 12.0, 600)
    for ratio, colour in ((0.0, "tab:blue"), (1.0, "tab:orange"), (2.0, "tab:green")):
        ax.plot(zr, ge.thrust_gain(zr, ratio), color=colour, lw=2.0, label=f"model, V/v_h = {ratio:g}")
        law = zr > 0.3
        ax.plot(zr[law], ge.cheeseman_bennett(zr[law], ratio), color=colour, lw=1.0, ls="--")
    ax.axvline(ge.MIN_HEIGHT_RADII, color="0.5", lw=0.8, ls=":")
    ax.axvline(ge.CUTOFF_RADII, color="0.5", lw=0.8, ls=":")
    ax.text(ge.MIN_HEIGHT_RADII + 0.1, 1.30, "floor R/2", fontsize=8, color="0.35")
    ax.text(ge.CUTOFF_RADII + 0.1, 1.30, "gain 1 beyond 10 R", fontsize=8, color="0.35")
    ax.plot([], [], color="k", lw=1.0, ls="--", label="Cheeseman & Bennett (1955)")
    ax.set_xlabel("rotor height above the surface z / R")
    ax.set_ylabel("thrust gain T_IGE / T_OGE")
    ax.set_ylim(0.99, 1.36)
    ax.set_xlim(0.0, 12.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Ground effect: thrust gain of one rotor")
    fig.tight_layout()
    return fig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args()
    save_figure(ground_effect_figure(), args.out)
    print(args.out)


if __name__ == "__main__":
    main()
