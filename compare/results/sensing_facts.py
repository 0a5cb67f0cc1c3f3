"""What a scenario's pilots sensed with and what a policy was trained to sense with, as a run records them
(run.json) and compares them: the GNSS sky (open or an urban canyon, outages and how long), the lidar's range and
the share of the buildings the prior map lacks.

`SensedFacts` is a scenario's (recorded below `perfect` sensing only: there nothing is simulated);
`SensingEnvelope` is a policy's training across sensing and map-error levels. `SensingEnvelope.outside` says why a
scenario lies outside it, as `compare.results.run_info.AirEnvelope.outside` does for the air. Both are plain data
(`compare.run.trained_air` builds them from a scenario and from a policy's task).
"""
from __future__ import annotations

from dataclasses import dataclass

_SLACK = 1e-6  # a recorded figure this close to the envelope's edge counts as inside it


@dataclass(frozen=True)
class SensedFacts:
    """The sensing a scenario flew with, where the sweep and a policy's envelope look at it.

    Attributes:
        gnss_urban_canyon: True: the true buildings block and reflect satellites; False: an open sky.
        gnss_max_outage_s: receiver outages last up to this long [s]; 0: no outages.
        lidar_range_m: the lidar's longest range [m].
    """

    gnss_urban_canyon: bool
    gnss_max_outage_s: float
    lidar_range_m: float

    def gnss_label(self) -> str:
        """The GNSS sky in words: "open sky", "urban canyon" or "urban canyon, outages to 30 s"."""
        if not self.gnss_urban_canyon and not self.gnss_max_outage_s:
            return "open sky"
        sky = "urban canyon" if self.gnss_urban_canyon else "open sky"
        return sky + (f", outages to {self.gnss_max_outage_s:g} s" if self.gnss_max_outage_s else "")


@dataclass(frozen=True)
class SensingEnvelope:
    """The sensing and map error a policy was trained across.

    Attributes:
        sensed: True when it trained below `perfect` sensing (on a navigation estimate and a lidar).
        gnss_urban_canyon: True when some of its training sensed through an urban canyon.
        gnss_max_outage_s: its longest GNSS outage [s] (0: none).
        lidar_range_m: the shortest lidar range it trained with [m] (None: it never flew a lidar).
        missing_fraction_max: the largest share of the buildings its prior maps lacked.
    """

    sensed: bool
    gnss_urban_canyon: bool
    gnss_max_outage_s: float
    lidar_range_m: float | None
    missing_fraction_max: float

    def outside(self, sensing: str, facts: SensedFacts | None, missing_fraction: float | None) -> tuple[str, ...]:
        """Why a scenario's sensing and map lie outside this envelope, one phrase per reason ("nominal sensing",
        "GNSS urban canyon", "GNSS outages to 60 s", "lidar range 40 m", "50 % of the buildings unmapped");
        empty: inside.

        Args:
            sensing: the scenario's sensing level label ("perfect", "nominal", "degraded+", ...).
            facts: its sensed facts (None: `perfect`, or not recorded: not compared).
            missing_fraction: the share of its buildings the prior lacks (None: not recorded).
        """
        why = []
        if facts is not None and not self.sensed:
            why.append(f"{sensing} sensing")  # every sensed figure is new to it: one reason says it
        elif facts is not None:
            if facts.gnss_urban_canyon and not self.gnss_urban_canyon:
                why.append("GNSS urban canyon")
            if facts.gnss_max_outage_s > self.gnss_max_outage_s + _SLACK:
                why.append(f"GNSS outages to {facts.gnss_max_outage_s:g} s")
            if self.lidar_range_m is not None and facts.lidar_range_m < self.lidar_range_m - _SLACK:
                why.append(f"lidar range {facts.lidar_range_m:g} m")
        if missing_fraction is not None and missing_fraction > self.missing_fraction_max + _SLACK:
            why.append(f"{100.0 * missing_fraction:g} % of the buildings unmapped")
        return tuple(why)

    def describe(self) -> str:
        """The envelope in words: "sensing perfect only, maps missing up to 0 % of the buildings" or "sensing
        below perfect (GNSS up to an urban canyon with outages to 30 s, lidar range from 100 m), ..."."""
        maps = f"maps missing up to {100.0 * self.missing_fraction_max:g} % of the buildings"
        if not self.sensed:
            return f"sensing perfect only, {maps}"
        gnss = SensedFacts(self.gnss_urban_canyon, self.gnss_max_outage_s, 0.0).gnss_label()
        lidar = "" if self.lidar_range_m is None else f", lidar range from {self.lidar_range_m:g} m"
        return f"sensing below perfect (GNSS up to {gnss}{lidar}), {maps}"
