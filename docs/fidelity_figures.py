"""Figures for docs/fidelity.md, drawn from the model's own functions: the ground-effect thrust gain
against rotor height, in hover and forward flight, beside the published Cheeseman-Bennett law; and
the wind over height: steady profiles of the shear laws at city parameters, and the turbulence
intensities of MIL-F-8785C's low-altitude model beside the RMS of a generated JSBSim stack.

    python docs/fidelity_figures.py [--out docs/ground_effect.png] [--wind-out docs/wind_profile.png]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from uam_fdm.air.wind import (  # noqa: E402
    PROBE_HEIGHTS_M,
    ShearLaw,
    TurbulenceLevel,
    WindConditions,
    WindShear,
    gust_stack,
    milspec_low_altitude,
)
from uam_fdm.city.plot import save_figure  # noqa: E402
from uam_fdm.vehicle import ground_effect as ge  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "ground_effect.png"
DEFAULT_WIND_OUT = Path(__file__).resolve().parent / "wind_profile.png"


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


def wind_profile_figure(seconds: float = 1800.0, airspeed_m_s: float = 12.0, seed: int = 1) -> plt.Figure:
    """Left: u(z) / u(10 m) for the power and log laws at town and city-centre parameters. Right: light
    turbulence sigma_u (= sigma_v) and sigma_w against height, MIL-F-8785C (lines) and the RMS of a
    `seconds`-long JSBSim stack at `airspeed_m_s` (markers)."""
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(9.0, 4.4), dpi=120, sharey=True)
    z = np.geomspace(0.5, 300.0, 400)
    laws = [(WindShear(ShearLaw.POWER, 10.0, exponent=0.28), "power, alpha 0.28 (towns)", "-"),
            (WindShear(ShearLaw.POWER, 10.0, exponent=0.40), "power, alpha 0.40 (city centre)", "-"),
            (WindShear(ShearLaw.LOG, 10.0, roughness_m=0.7), "log, z0 0.7 m (towns)", "--"),
            (WindShear(ShearLaw.LOG, 10.0, roughness_m=2.0), "log, z0 2 m (city centre)", "--")]
    for shear, label, style in laws:
        ax0.plot(shear.factor(z), z, ls=style, lw=1.6, label=label)
    ax0.axhline(10.0, color="0.5", lw=0.8, ls=":")
    ax0.text(0.05, 11.0, "reference height 10 m", fontsize=8, color="0.35")
    ax0.set_xlabel("steady wind u(z) / u(10 m)")
    ax0.set_ylabel("height above the field z [m]")
    ax0.set_yscale("log")
    ax0.set_xlim(0.0, 2.6)
    ax0.grid(alpha=0.3, which="both")
    ax0.legend(fontsize=7, loc="lower right")
    ax0.set_title("Steady wind shear (floors: 1 m, 2 z0)", fontsize=10)

    level = TurbulenceLevel.LIGHT
    sigma_w = 0.1 * level.w20_m_s
    ratio, _, _ = milspec_low_altitude(z)
    ax1.plot(ratio * sigma_w, z, color="tab:blue", lw=1.6, label="MIL-F-8785C sigma_u = sigma_v")
    ax1.plot(np.full_like(z, sigma_w), z, color="tab:red", lw=1.6, label="MIL-F-8785C sigma_w")
    stack = gust_stack(WindConditions(turbulence=level), seed, seconds, airspeed_m_s)
    rms = np.sqrt(np.mean(stack.gust_enu_m_s**2, axis=0))  # (H, 3)
    h = np.array(PROBE_HEIGHTS_M)
    ax1.plot(rms[:, 0], h, "o", color="tab:blue", ms=5, label="JSBSim stack, east RMS")
    ax1.plot(rms[:, 1], h, "s", color="tab:cyan", ms=4, label="JSBSim stack, north RMS")
    ax1.plot(rms[:, 2], h, "^", color="tab:red", ms=5, label="JSBSim stack, up RMS")
    ax1.set_xlabel("gust RMS [m/s] (light: W20 = 15 kt)")
    ax1.set_xlim(0.0, 1.7 * float(rms.max()))
    ax1.grid(alpha=0.3, which="both")
    ax1.legend(fontsize=7, loc="lower right")
    ax1.set_title(f"Turbulence at the probe heights ({seconds:.0f} s, {airspeed_m_s:g} m/s)", fontsize=10)
    fig.tight_layout()
    return fig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--wind-out", type=Path, default=DEFAULT_WIND_OUT)
    args = ap.parse_args()
    save_figure(ground_effect_figure(), args.out)
    print(args.out)
    save_figure(wind_profile_figure(), args.wind_out)
    print(args.wind_out)


if __name__ == "__main__":
    main()
